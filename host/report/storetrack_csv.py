"""CSV tables of the storetrack programs (fti.csv, marks.csv, storetrack-post's outputs) as
numpy columns."""
import csv
import os

import numpy as np


def read_csv(path):
    """Columns as numpy arrays keyed by the column name without its ' [unit]' suffix."""
    if not os.path.exists(path):
        return None
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = [h.split(" [")[0] for h in next(reader)]
        rows = list(reader)
    cols = {}
    for i, name in enumerate(header):
        values = [r[i] for r in rows]
        try:
            cols[name] = np.array([float(v) for v in values])
        except ValueError:
            cols[name] = np.array(values)
    return cols
