# Host-side preparation for guest/e2e.sh (run by run-suite.sh before the VM boots): the scene.
# Rendering full frames is floating-point heavy and would take minutes under TCG, and the
# simulator is the truth, not the system under test, so the frames are rendered here, with the
# same storetrack-sim binary, into $1 (shared writable into the VM at the same path).
#   $1/scenario.json   the scenario as run: pendulum (a moving board: every exposure has its own truth), its first 2 cameras on units 0 and 1,
#                      E2E_EXPOSURES exposures (default 40), trigger sequence numbers from 0
#                      (the units number the trigger edges from 0, so truth and host share them).
#                      The cameras are the scenario's optics at 2/3 scale on a 1280 x 720 sensor
#                      (larger pixels, a little more field below): vivid then carries 720p frames,
#                      which a single TCG vCPU can loop, capture and centroid for two cameras.
#   $1/sim/            storetrack-sim --mode frames output (frames/cam<id>/*.pgm, truth CSVs, rigs)
#   $1/setup/          the host's setup files (sim_setup.py, as tools/testpoint makes them)
set -eu
OUT=$1
HERE=$(cd "$(dirname "$0")" && pwd)
SIM=${STORETRACK_BIN_SIM:-}
[ -n "$SIM" ] && [ -x "$SIM" ] || { echo "SKIP: storetrack-sim is not built"; exit 77; }
N=${E2E_EXPOSURES:-40}
rm -rf "$OUT"; mkdir -p "$OUT"
python3 - "$STORETRACK_SOURCE_DIR/common/sim/scenarios/pendulum.json" "$OUT/scenario.json" "$N" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["cameras"] = s["cameras"][:2]
scale = 2.0 / 3.0
for i, c in enumerate(s["cameras"]):
    c["unit_id"] = i  # one storetrack-unit process (and unit id) per camera
    k = c["intrinsics"]
    # pixel centres at (0, 0) (docs/conventions.md): u' = scale (u + 0.5) - 0.5
    for f in ("fx", "fy", "skew"):
        k[f] *= scale
    for f in ("cx", "cy"):
        k[f] = scale * (k[f] + 0.5) - 0.5
    k["width"], k["height"] = 1280, 720  # the whole 720p frame: no padding rows to centroid
s["optics"]["psf_sigma_px"] *= scale
for f in ("focal_px", "principal_point_px", "skew_px"):
    s["calibration_errors"][f] *= scale
s["timing"]["num_exposures"] = int(sys.argv[3])
s["timing"]["first_trigger_seq"] = 0
json.dump(s, open(sys.argv[2], "w"), indent=1)
PY
"$SIM" --scenario "$OUT/scenario.json" --seed 7 --mode frames --out "$OUT/sim"
python3 "$HERE/../../../tools/sim_setup.py" "$OUT/scenario.json" "$OUT/sim" "$OUT/setup"
touch "$OUT/ok"
