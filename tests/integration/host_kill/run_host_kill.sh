#!/usr/bin/env bash
# kill -9 of storetrack-host itself at random moments during a test point. Four real
# storetrack-unit processes send on one schedule, like a triggered rig, in slow motion at PACE_HZ.
# (Units that send as fast as they render drift apart by tens of exposures on a loaded machine,
# and a host started fresh then rightly quarantines the cameras far from the first one it hears:
# in one CI run a restarted host wrote no sample until the units had ended, before its kill. At
# 400 fps a loaded machine's writer thread falls behind the killed runs' 16-item queue and drops,
# counted, more than the in-flight bound below.) The host is SIGKILLed KILLS times (0.2 .. 1.2 s
# after its file holds its first message packets) and restarted at once with the SAME --ch10
# path, so every run must keep the earlier files and record to the next number; the last run
# ends normally. Each run sends iNET-X to its own port, where a listener records every
# trigger_seq sent. Checked with the independent Chapter 10 reader (rig_ch10_dump): every file
# starts with TMATS, has no checksum error, ends at most in one partial packet, holds no sample
# twice, and a killed run lost at most the samples in flight: its open message batch (<= 10) +
# the one being processed + the recording queue (bounded here at 16).
set -euo pipefail
SIM="$1"; UNIT="$2"; HOST="$3"; CHECK="$4"; ROOT="$5"; OUT="$6"
NEXP=1000 PACE_HZ=100 KILLS=3  # 10 s: three kill cycles (~1-2 s each under load) fit in it
rm -rf "$OUT"; mkdir -p "$OUT/sim"
PORT=$(( 24000 + $$ % 1000 ))  # below the ephemeral ports (32768-60999)
# The units fly NEXP exposures; the simulator run only gives the surveys and the initial marks
# (its first exposure), so it simulates 400.
/usr/bin/python3 - "$ROOT/common/sim/scenarios/static.json" "$OUT" "$NEXP" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
for name, n in (("scenario.json", int(sys.argv[3])), ("scenario_sim.json", 400)):
    s["timing"]["num_exposures"] = n
    json.dump(s, open(sys.argv[2] + "/" + name, "w"))
PY
"$SIM" --scenario "$OUT/scenario_sim.json" --seed 3 --out "$OUT/sim" --mode observations >/dev/null
/usr/bin/python3 "$ROOT/tools/sim_setup.py" --initial-marks "$OUT/sim/truth_marks.csv" "$OUT/initial_marks.json" 0
# iNET-X listener: run i sends to PORT+1+i; one line "run trigger_seq" per packet.
/usr/bin/python3 - "$PORT" "$(( KILLS + 1 ))" "$OUT/inetx_seqs.txt" <<'PY' &
import select, socket, struct, sys, time
port, runs, path = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
socks = []
for i in range(runs):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port + 1 + i))
    socks.append(s)
with open(path, "w") as out:
    idle_since = time.time()
    while time.time() - idle_since < 8:
        ready, _, _ = select.select(socks, [], [], 0.5)
        for s in ready:
            data = s.recv(2048)
            out.write("%d %d\n" % (socks.index(s), struct.unpack_from(">I", data, 28 + 8)[0]))
            idle_since = time.time()
PY
LISTENER=$!
PIDS=""
trap 'for p in ${HOST_PID:-} $PIDS $LISTENER; do kill -9 "$p" 2>/dev/null || true; done' EXIT
# The killed runs bound their recording queue at 16 (the in-flight bound below). The last run,
# which ends normally, keeps the default queue: on a loaded CI machine a 16-item queue behind a
# starved writer thread drops (counted) samples, which is not what this test is about.
echo '{"aligner": {"max_wait_ms": 200}, "recording": {"queue_items": 16}}' >"$OUT/host.json"
echo '{"aligner": {"max_wait_ms": 200}}' >"$OUT/host_last.json"
start_host() {  # $1 = run index
  local config="$OUT/host.json"
  [ "$1" -lt "$KILLS" ] || config="$OUT/host_last.json"
  "$HOST" --calibration "$OUT/sim/rig_calibrated.json" --pylon-survey "$OUT/sim/survey_pylon.json" \
    --store-survey "$OUT/sim/survey_store.json" --initial-marks "$OUT/initial_marks.json" \
    --config "$config" --udp-port "$PORT" --udp-bind 127.0.0.1 --ch10 "$OUT/out.ch10" \
    --inetx "127.0.0.1:$(( PORT + 1 + $1 ))" --stats-json "$OUT/stats_run$1.json" \
    --idle-exit-s 3 >"$OUT/host_run$1.log" 2>&1 &
  HOST_PID=$!
}
start_host 0
# Exposure 0 of every unit is due 1 s from now (their start-up).
PACE_ORIGIN_NS=$(/usr/bin/python3 -c "import time; print(time.monotonic_ns() + 1000000000)")
for c in 0 1 2 3; do
  "$UNIT" run --source sim --scenario "$OUT/scenario.json" --camera-index "$c" --seed 3 \
    --trigger sim --realtime --sim-pace-hz "$PACE_HZ" --sim-pace-origin-mono-ns "$PACE_ORIGIN_NS" \
    --sim-background-pool 8 \
    --udp "127.0.0.1:$PORT" --no-modbus --frames "$NEXP" >"$OUT/unit_cam$c.log" 2>&1 &
  PIDS="$PIDS $!"
done
ch10_of_run() { [ "$1" -eq 0 ] && echo "$OUT/out.ch10" || echo "$OUT/out.$(printf %03d "$1").ch10"; }
RANDOM=$$
for run in $(seq 0 $(( KILLS - 1 ))); do
  F=$(ch10_of_run "$run")
  # Its first sample packet (not its size: TMATS and the recorded inputs at the file's start
  # are tens of kilobytes before any sample).
  for _ in $(seq 600); do
    n=$("$CHECK" "$F" 2>/dev/null | /usr/bin/python3 -c "import json,sys; print(len(json.load(sys.stdin)['samples']))" 2>/dev/null || echo 0)
    [ "$n" -gt 0 ] && break
    sleep 0.1
  done
  [ -f "$F" ] || { ls -l "$OUT"; echo "FAIL run $run never created $F (an earlier file overwritten?)"; exit 1; }
  sleep "$(( 2 + RANDOM % 11 ))e-1"
  kill -0 "$HOST_PID" 2>/dev/null || {
    tail -n 12 "$OUT/host_run$run.log"
    echo "FAIL run $run ended before its kill (the units ended first?)"
    exit 1
  }
  kill -9 "$HOST_PID"; wait "$HOST_PID" 2>/dev/null || true
  echo "killed run $run"
  start_host $(( run + 1 ))
done
for p in $PIDS; do wait "$p" || { cat "$OUT"/unit_cam*.log; echo "storetrack-unit failed"; exit 1; }; done
PIDS=""
wait "$HOST_PID" || { cat "$OUT/host_run$KILLS.log"; echo "the last storetrack-host failed"; exit 1; }
wait "$LISTENER" || true
cat "$OUT/host_run$KILLS.log"
FILES=()
for i in $(seq 0 "$KILLS"); do FILES+=("$(ch10_of_run "$i")"); done
for f in "${FILES[@]}"; do
  "$CHECK" "$f" | /usr/bin/python3 -c "import json,sys; d=json.load(sys.stdin); d['path']='$f'; print(json.dumps(d))" \
    >>"$OUT/ch10_check.jsonl" || echo "{\"path\": \"$f\", \"error\": \"unreadable\"}" >>"$OUT/ch10_check.jsonl"
done
/usr/bin/python3 - "$OUT" "$KILLS" <<'PY'
import json, sys
out, kills = sys.argv[1], int(sys.argv[2])
files = [json.loads(l) for l in open(out + "/ch10_check.jsonl")]
sent = {}
for line in open(out + "/inetx_seqs.txt"):
    run, seq = map(int, line.split())
    sent.setdefault(run, []).append(seq)
last_stats = json.load(open(out + "/stats_run%d.json" % kills))
failures = []
def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what)
    if not cond:
        failures.append(what)
IN_FLIGHT = 10 + 1 + 16
for run, f in enumerate(files):
    name = f["path"].rsplit("/", 1)[-1]
    check("error" not in f, "%s exists and reads (%s)" % (name, f.get("error", "")))
    if "error" in f:
        continue
    seqs = [x["trigger_seq"] for x in f["samples"]]
    trailing = f["file_bytes"] - f["bytes_in_whole_packets"]
    check(f["first_data_type"] == 1, "%s starts with TMATS" % name)
    check(f["header_checksum_errors"] == 0 and f["data_checksum_errors"] == 0
          and f["message_decode_errors"] == 0 and f["fti_block_errors"] == 0,
          "%s: no checksum error, every message packet decodes" % name)
    clean = f["stop_reason"] == "" or f["truncated"]
    check(clean and trailing <= 24 + 4 + 10 * 160 + 4,
          "%s: whole packets up to at most one partial last packet (%d bytes after, %s)"
          % (name, trailing, f["stop_reason"] or "read to its end"))
    check(len(seqs) == len(set(seqs)), "%s: no sample twice" % name)
    s = set(sent.get(run, []))
    check(set(seqs) <= s, "%s: every recorded sample was also sent on iNET-X" % name)
    lost = len(s - set(seqs))
    if run < kills:
        check(len(seqs) > 0, "killed run %d recorded %d samples" % (run, len(seqs)))
        check(lost <= IN_FLIGHT, "killed run %d: %d sent, %d lost <= %d in flight"
              % (run, len(s), lost, IN_FLIGHT))
    else:
        check(lost == 0, "last run (ended normally): %d sent, %d lost" % (len(s), lost))
d = last_stats["outputs"]["file_queue_dropped"]
check(d == 0, "last run: %d samples dropped at the recording queue" % d)
print("%d files checked" % len(files))
sys.exit(1 if failures else 0)
PY
