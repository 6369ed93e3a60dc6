"""Shared HTML helpers of the storetrack reports (storetrack_eval_report.py,
storetrack_calib_report.py): an escaped table and the page around a report's body."""
import html
import os


def table(header, rows):
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table border=1 cellpadding=4><tr>{head}</tr>{body}</table>"


def write_page(out_dir, body, title="storetrack-eval"):
    path = os.path.join(out_dir, "index.html")
    with open(path, "w") as f:
        f.write(f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
                "</title></head><body>" + body + "</body></html>\n")
    print(f"report: {path}")
