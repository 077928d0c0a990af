#!/usr/bin/env bash
# End-to-end throughput of ridgewatchd on one core: a simulated paper-rig recording (51.2 kHz mono,
# noise 1 % of the impact peak, one impact per revolution at 25 Hz) replayed as fast as possible,
# with both daemon threads pinned to one CPU (taskset), events written to a file.
#
#   scripts/bench-daemon.sh [BUILD_DIR] [SECONDS] [RUNS]
#
# BUILD_DIR defaults to build-bench (a Release build: scripts/build.sh build-bench
# -DCMAKE_BUILD_TYPE=Release). Prints, per run, CPU time (user + system, both threads), wall time and
# peak RSS, and the real-time factors = recording seconds / CPU seconds and / wall seconds, then their
# medians. The recording is generated once into $TMPDIR and reused; one warm-up run is not reported.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$here/build-bench}
seconds=${2:-600}
runs=${3:-3}
for bin in "$build/cli/ridgewatch" "$build/daemon/ridgewatchd"; do
  [[ -x $bin ]] || { echo "bench-daemon: $bin not found; build it first (scripts/build.sh $build -DCMAKE_BUILD_TYPE=Release)" >&2; exit 2; }
done
command -v taskset >/dev/null || { echo "bench-daemon: taskset (util-linux) is missing" >&2; exit 2; }
tmp=${TMPDIR:-/tmp}
rec="$tmp/ridgewatch-bench-${seconds}s"
if [[ ! -f $rec.wav ]]; then
  "$build/cli/ridgewatch" simulate --rig "$here/config/rigs/paper-rig.yaml" --duration "$seconds" --rate 51200 \
    --noise 0.01 --out "$rec" >/dev/null 2>&1
fi
events="$tmp/ridgewatch-bench-events.jsonl"
# The first CPU this shell may run on (its affinity list, e.g. "0,1" or "0-1").
cpu=$(taskset -pc $$ | sed -E 's/.*: *([0-9]+).*/\1/')
timing="$tmp/ridgewatch-bench-time.txt"
cpu_times="$tmp/ridgewatch-bench-cpu.txt"
TIMEFORMAT='%3U %3S %3R'
results="$tmp/ridgewatch-bench-results.txt"
: >"$results"
# One unreported warm-up run: the recording into the page cache, the binaries and libraries loaded
# (the first run after a build or a while idle otherwise pays tens of ms of system time).
taskset -c "$cpu" "$build/daemon/ridgewatchd" --replay "$rec.wav" --speed max --events /dev/null 2>/dev/null
for ((i = 1; i <= runs; i++)); do
  rm -f "$events"  # ridgewatchd appends to an existing event log
  # CPU and wall time in ms from bash's `time` (getrusage of the waited-for children: GNU time prints
  # only 10 ms steps); it includes GNU time's and taskset's own ~2-3 ms, so the factors err low. GNU
  # time reports the peak RSS.
  { time /usr/bin/time -o "$timing" -f "%M" taskset -c "$cpu" "$build/daemon/ridgewatchd" --replay "$rec.wav" \
    --speed max --events "$events" 2>/dev/null; } 2>"$cpu_times"
  read -r user sys wall <"$cpu_times"
  read -r rss_kb <"$timing"
  awk -v s="$seconds" -v u="$user" -v y="$sys" -v w="$wall" -v r="$rss_kb" -v n="$(wc -l <"$events")" 'BEGIN {
    c = u + y; printf "run: %d events, CPU %.3f s (user %.3f, sys %.3f), wall %.3f s, RSS %.1f MB -> %.0fx CPU, %.0fx wall (one core)\n",
    n, c, u, y, w, r / 1024, s / c, s / w }' | tee -a "$results"
done
# Medians over the runs of the CPU-time and the wall-time factors.
median() { sort -n | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
cpu_f=$(sed -E 's/.*-> ([0-9]+)x CPU.*/\1/' "$results" | median)
wall_f=$(sed -E 's/.*CPU, ([0-9]+)x wall.*/\1/' "$results" | median)
echo "median of $runs runs: ${cpu_f}x CPU, ${wall_f}x wall (both threads on CPU $cpu)"
