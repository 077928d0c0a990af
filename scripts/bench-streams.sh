#!/usr/bin/env bash
# Throughput of ridgewatchd with several streams: 16 simulated paper rigs (seeds 1-16, 25.6 kHz,
# noise 1 % of the impact peak) as the 16 channels of one float32 recording, one stream per channel
# (`streams:`), replayed as fast as possible, events to a file.
#
#   scripts/bench-streams.sh [BUILD_DIR] [SECONDS] [RUNS]
#
# BUILD_DIR: a Release build with the targets ridgewatch, ridgewatchd and merge_channels (default
# build-bench). Per run it prints CPU time (user + system, all threads), wall time, peak RSS and the
# real-time factor for all 16 streams together = 16 x SECONDS / CPU seconds (and / wall seconds):
#   1. workers: 1, everything pinned to one core (taskset): the one-core throughput;
#   2. workers: 1 and workers: 2 on two cores: the scaling with workers (wall time).
# The medians of RUNS runs end each part. The recording is made once into $TMPDIR.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$here/build-bench}
seconds=${2:-60}
runs=${3:-3}
channels=16
for bin in "$build/cli/ridgewatch" "$build/daemon/ridgewatchd" "$build/bench/merge_channels"; do
  [[ -x $bin ]] || { echo "bench-streams: $bin not found; build it first (Release, targets ridgewatch ridgewatchd merge_channels)" >&2; exit 2; }
done
command -v taskset >/dev/null || { echo "bench-streams: taskset (util-linux) is missing" >&2; exit 2; }
tmp=${TMPDIR:-/tmp}
rec="$tmp/ridgewatch-streams-${channels}x${seconds}s.wav"
if [[ ! -f $rec ]]; then
  inputs=()
  for ((k = 1; k <= channels; k++)); do
    "$build/cli/ridgewatch" simulate --rig "$here/config/rigs/paper-rig.yaml" --duration "$seconds" --rate 25600 \
      --noise 0.01 --seed "$k" --out "$tmp/ridgewatch-streams-rig$k" >/dev/null 2>&1
    inputs+=("$tmp/ridgewatch-streams-rig$k.wav")
  done
  "$build/bench/merge_channels" "$rec" "${inputs[@]}"
  rm -f "$tmp"/ridgewatch-streams-rig*.wav "$tmp"/ridgewatch-streams-rig*.truth.json
fi
config() {  # workers -> a configuration with one stream per channel
  local f="$tmp/ridgewatch-streams-w$1.yaml"
  { echo "workers: $1"; echo "streams:"; for ((c = 0; c < channels; c++)); do echo "  - {name: ch$c, channel: $c}"; done; } >"$f"
  echo "$f"
}
events="$tmp/ridgewatch-streams-events.jsonl"
timing="$tmp/ridgewatch-streams-time.txt"
cpu_times="$tmp/ridgewatch-streams-cpu.txt"
TIMEFORMAT='%3U %3S %3R'
median() { sort -n | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
# run LABEL CPUS WORKERS: RUNS timed runs after one unreported warm-up.
run() {
  local label=$1 cpus=$2 cfg results="$tmp/ridgewatch-streams-results-$1.txt"
  cfg=$(config "$3")
  : >"$results"
  taskset -c "$cpus" "$build/daemon/ridgewatchd" --config "$cfg" --replay "$rec" --speed max --events /dev/null 2>/dev/null
  for ((i = 1; i <= runs; i++)); do
    rm -f "$events"
    { time /usr/bin/time -o "$timing" -f "%M" taskset -c "$cpus" "$build/daemon/ridgewatchd" --config "$cfg" \
      --replay "$rec" --speed max --events "$events" 2>/dev/null; } 2>"$cpu_times"
    read -r user sys wall <"$cpu_times"
    read -r rss_kb <"$timing"
    awk -v s="$((seconds * channels))" -v u="$user" -v y="$sys" -v w="$wall" -v r="$rss_kb" -v n="$(wc -l <"$events")" \
      -v l="$label" 'BEGIN { c = u + y; printf "%s: %d events, CPU %.3f s (user %.3f, sys %.3f), wall %.3f s, RSS %.1f MB -> %.0fx CPU, %.0fx wall\n",
      l, n, c, u, y, w, r / 1024, s / c, s / w }' | tee -a "$results"
  done
  echo "$label median of $runs runs: $(sed -E 's/.*-> ([0-9]+)x CPU.*/\1/' "$results" | median)x CPU, $(sed -E 's/.*CPU, ([0-9]+)x wall.*/\1/' "$results" | median)x wall (all $channels streams together)"
}
cpu=$(taskset -pc $$ | sed -E 's/.*: *([0-9]+).*/\1/')
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg) on $(nproc) cores"
run "one-core-workers1" "$cpu" 1
if (($(nproc) >= 2)); then
  run "two-cores-workers1" 0,1 1
  run "two-cores-workers2" 0,1 2
fi
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
