#!/usr/bin/env bash
# The live page in a real browser against the main job's chain: storetrack-sim writes the rig,
# surveys and scene; four storetrack-unit processes (unit ids 0,0,1,1) render, centroid and send
# over UDP loopback; storetrack-host runs with --live 127.0.0.1:0 and prints the URL. Debian's
# Chromium, driven by playwright-core (npm, installed into the build tree from the committed
# package-lock.json), reads the page while the host runs (live_view_browser.mjs);
# check_live_view.py compares what it displayed with the host's Chapter 10 and CSV.
# Screenshots per camera: OUT/page/camera-N.png. Exit 77 (skipped) when Node.js, npm,
# Chromium or playwright-core cannot be had, saying which.
set -euo pipefail
SIM="$1"; UNIT="$2"; HOST="$3"; ROOT="$4"; OUT="$5"
HERE="$(cd "$(dirname "$0")" && pwd)"
NEXP=120
CHROMIUM=${STORETRACK_CHROMIUM:-/usr/bin/chromium}
rm -rf "$OUT"; mkdir -p "$OUT/sim"

# The bind address is required: the host refuses --live without one, by name (exit 2).
set +e
"$HOST" --calibration /dev/null --pylon-survey /dev/null --store-survey /dev/null \
  --udp-port 1 --udp-bind 127.0.0.1 --live 8080 >"$OUT/no_address.log" 2>&1
rc=$?
set -e
if [ "$rc" -ne 2 ] || ! grep -q "expected ADDR:PORT" "$OUT/no_address.log"; then
  cat "$OUT/no_address.log"; echo "FAIL storetrack-host --live 8080: exit $rc, not 2 with 'expected ADDR:PORT'"; exit 1
fi
echo "ok   storetrack-host --live 8080 refused: $(grep -o "expected ADDR:PORT[^(]*" "$OUT/no_address.log" | head -1)"

command -v node >/dev/null || { echo "SKIP: Node.js is not installed (node); the browser test needs it"; exit 77; }
command -v npm >/dev/null || { echo "SKIP: npm is not installed; the browser test installs playwright-core with it"; exit 77; }
[ -x "$CHROMIUM" ] || { echo "SKIP: Chromium is not installed ($CHROMIUM; Debian package chromium, tools/install-deps.sh)"; exit 77; }
# playwright-core, once per build tree, exactly as package-lock.json pins it.
NODE_DIR="$(dirname "$OUT")/node"
if [ ! -f "$NODE_DIR/node_modules/playwright-core/package.json" ] \
   || ! cmp -s "$HERE/package-lock.json" "$NODE_DIR/package-lock.json"; then
  mkdir -p "$NODE_DIR"
  cp "$HERE/package.json" "$HERE/package-lock.json" "$NODE_DIR/"
  if ! (cd "$NODE_DIR" && npm ci --no-audit --no-fund >"$NODE_DIR/npm.log" 2>&1); then
    tail -5 "$NODE_DIR/npm.log"; echo "SKIP: npm ci could not install playwright-core (log: $NODE_DIR/npm.log)"; exit 77
  fi
fi
cp "$HERE/live_view_browser.mjs" "$NODE_DIR/"

PORT=$(( 24000 + $$ % 1000 ))  # below the ephemeral ports (32768-60999)
/usr/bin/python3 - "$ROOT/common/sim/scenarios/store_separation.json" "$OUT/scenario.json" "$NEXP" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["timing"]["num_exposures"] = int(sys.argv[3])
json.dump(s, open(sys.argv[2], "w"))
PY
"$SIM" --scenario "$OUT/scenario.json" --seed 7 --out "$OUT/sim" --mode observations >/dev/null
/usr/bin/python3 "$ROOT/tools/sim_setup.py" --initial-marks "$OUT/sim/truth_marks.csv" "$OUT/initial_marks.json"
# The coverage overlay's envelope: 12 poses of the run's own trajectory (host.json live.store_envelope).
/usr/bin/python3 "$ROOT/tools/sim_setup.py" --store-envelope "$OUT/sim/truth_poses.csv" "$OUT/host.json" 12
# The host keeps serving the page after the last observation (the page keeps showing the last
# snapshot) until the browser is done, then is stopped with SIGINT: an idle exit 6 s after the
# last observation raced the browser's reads and screenshots on a loaded machine (the page's
# stream cut: "ERR_INCOMPLETE_CHUNKED_ENCODING", its reconnects refused). 120 s is a ceiling.
"$HOST" --calibration "$OUT/sim/rig_calibrated.json" --pylon-survey "$OUT/sim/survey_pylon.json" \
  --store-survey "$OUT/sim/survey_store.json" --initial-marks "$OUT/initial_marks.json" \
  --udp-port "$PORT" --udp-bind 127.0.0.1 --udp-source 0@127.0.0.1 --udp-source 1@127.0.0.1 \
  --ch10 "$OUT/out.ch10" --csv "$OUT/fti.csv" --stats-json "$OUT/stats.json" \
  --live 127.0.0.1:0 --config "$OUT/host.json" --max-wait-ms 3000 --idle-exit-s 120 \
  >"$OUT/host.log" 2>&1 &
HOST_PID=$!
UNIT_PIDS=""
BROWSER_PID=""
trap 'for p in $HOST_PID $UNIT_PIDS $BROWSER_PID; do kill "$p" 2>/dev/null || true; done' EXIT
URL=""
for _ in $(seq 100); do
  URL=$(grep -o "live view at http://[^ ]*" "$OUT/host.log" | sed 's/live view at //' || true)
  [ -n "$URL" ] && break
  kill -0 $HOST_PID 2>/dev/null || break
  sleep 0.1
done
[ -n "$URL" ] || { cat "$OUT/host.log"; echo "FAIL storetrack-host printed no live view URL"; exit 1; }
echo "ok   storetrack-host printed the URL: $URL"
# The browser first, so it is reading while the exposures come in.
node "$NODE_DIR/live_view_browser.mjs" "$URL" "$OUT/page" 16 "$CHROMIUM" >"$OUT/browser.log" 2>&1 &
BROWSER_PID=$!
sleep 1
for c in 0 1 2 3; do
  "$UNIT" run --source sim --scenario "$OUT/scenario.json" --camera-index "$c" --seed 7 \
    --trigger sim --udp "127.0.0.1:$PORT" --no-modbus --frames "$NEXP" \
    >"$OUT/unit_cam$c.log" 2>&1 &
  UNIT_PIDS="$UNIT_PIDS $!"
done
for p in $UNIT_PIDS; do wait "$p" || { tail -n 5 "$OUT"/unit_cam*.log; echo "FAIL storetrack-unit failed"; exit 1; }; done
UNIT_PIDS=""
wait $BROWSER_PID || { cat "$OUT/browser.log"; echo "FAIL the browser run failed"; exit 1; }
BROWSER_PID=""
kill -0 $HOST_PID 2>/dev/null || { cat "$OUT/host.log"; echo "FAIL storetrack-host ended before the browser"; exit 1; }
kill -INT $HOST_PID
wait $HOST_PID || { cat "$OUT/host.log"; echo "FAIL storetrack-host failed"; exit 1; }
trap - EXIT
grep -E "exposures|samples" "$OUT/host.log" | head -5 || true
/usr/bin/python3 "$HERE/check_live_view.py" "$ROOT" "$OUT"
