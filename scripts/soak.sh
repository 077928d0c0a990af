#!/usr/bin/env bash
# Accelerated soak of ridgewatchd: the equivalent of HOURS (default 24) of signal at 51.2 kHz, replayed
# as fast as possible from a looping simulated recording, with the daemon's resident memory sampled
# from /proc/PID/status every few seconds. Reports start/end/max RSS, events written vs impacts in the
# simulation truth, ring overruns and wall time; fails (exit 1) if memory grows or events are missing.
#
#   scripts/soak.sh [BUILD_DIR] [HOURS]      # BUILD_DIR default: build-rel (needs ridgewatch, ridgewatchd)
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$here/build-rel}
hours=${2:-24}
rate=51200
file_s=10                     # the looped recording: 10 s = 250 whole revolutions at 1500 rpm
work=$(mktemp -d /tmp/ridgewatch-soak.XXXXXX)
trap 'rm -rf "$work"' EXIT

cli=$build/cli/ridgewatch
daemon=$build/daemon/ridgewatchd
"$cli" simulate --rig "$here/config/rigs/paper-rig.yaml" --duration "$file_s" --rate "$rate" --noise 0.01 \
  --seed 1 --out "$work/soak" >/dev/null
samples=$(python3 -c "print(int($hours * 3600 * $rate))")
# Impacts in the stream: every impact of each whole pass, plus those of the last partial pass.
read -r impacts_per_file loops expected < <(python3 - "$work/soak.truth.json" "$samples" <<'PY'
import json, sys
truth = json.load(open(sys.argv[1]))
samples, frames = int(sys.argv[2]), truth["frames"]
idx = [i["sample_index"] for i in truth["impacts"]]
loops, rest = divmod(samples, frames)
print(len(idx), loops, loops * len(idx) + sum(1 for i in idx if i < rest))
PY
)
echo "soak: $hours h at $rate Hz = $samples samples = $loops whole passes of a ${file_s} s recording with $impacts_per_file impacts -> $expected impacts expected"

mkfifo "$work/events"
wc -l <"$work/events" >"$work/count" &
counter=$!
start=$(date +%s.%N)
"$daemon" --replay "$work/soak.wav" --speed max --loop --max-samples "$samples" --events - \
  >"$work/events" 2>"$work/daemon.log" &
pid=$!
echo "t_s,rss_kib" >"$work/rss.csv"
while kill -0 "$pid" 2>/dev/null; do
  rss=$(awk '/^VmRSS:/ {print $2}' "/proc/$pid/status" 2>/dev/null || true)
  [[ -n $rss ]] && echo "$(python3 -c "print(round($(date +%s.%N) - $start, 1))"),$rss" >>"$work/rss.csv"
  sleep 5
done
wait "$pid" && code=0 || code=$?
wait "$counter"
end=$(date +%s.%N)
events=$(cat "$work/count")
grep -E "stopped:" "$work/daemon.log" || true
python3 - "$work/rss.csv" "$events" "$expected" "$code" "$start" "$end" "$hours" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
events, expected, code = int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
wall = float(sys.argv[6]) - float(sys.argv[5])
rss = [int(r["rss_kib"]) for r in rows]
# Start: the first sample after 10 s (plans, buffers and the learning phase are set up by then).
steady = [int(r["rss_kib"]) for r in rows if float(r["t_s"]) >= 10] or rss
print(f"wall time {wall:.0f} s ({float(sys.argv[7]) * 3600 / wall:.0f}x real time), exit code {code}")
print(f"RSS samples {len(rss)}: first {rss[0]} KiB, after 10 s {steady[0]} KiB, end {rss[-1]} KiB, max {max(rss)} KiB")
print(f"events written {events}, impacts expected {expected}")
ok = code == 0 and events == expected and max(steady) - steady[0] <= 1024
print("soak: PASS" if ok else "soak: FAIL")
sys.exit(0 if ok else 1)
PY
