#!/usr/bin/env bash
# End-to-end throughput of ridgewatchd on one core: a simulated paper-rig recording (51.2 kHz mono,
# noise 1 % of the impact peak, one impact per revolution at 25 Hz) replayed as fast as possible,
# with every daemon thread pinned to one CPU (taskset), events written to a file.
#
#   scripts/bench-daemon.sh [--net] [BUILD_DIR] [SECONDS] [RUNS]
#
# BUILD_DIR defaults to build-bench (a Release build: scripts/build.sh build-bench
# -DCMAKE_BUILD_TYPE=Release). Prints, per run, CPU time (user + system, all threads), wall time and
# peak RSS, and the real-time factors = recording seconds / CPU seconds and / wall seconds, then their
# medians. The recording is generated once into $TMPDIR and reused; one warm-up run is not reported.
#
# --net: every run is a pair, in alternation: the plain daemon, then the same daemon with the network
# outputs on — MQTT at QoS 1 through its on-disk spool to a mosquitto this script starts on
# 127.0.0.1 (and stops at the end), and the HTTP listener, whose /metrics and /api/state are fetched
# with curl every 0.1 s while the replay runs. The broker and the scraper are not pinned (their CPU is
# not the daemon's; the broker's is printed). A network run counts only when the broker acknowledged
# every event (the spool's state file); its wall time is up to the end of processing (the final MQTT
# drain the daemon logs is printed apart). Ends with the medians and the ratio network / plain.
set -euo pipefail
net=0
if [[ ${1:-} == --net ]]; then
  net=1
  shift
fi
here=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$here/build-bench}
seconds=${2:-600}
runs=${3:-3}
for bin in "$build/cli/ridgewatch" "$build/daemon/ridgewatchd"; do
  [[ -x $bin ]] || { echo "bench-daemon: $bin not found; build it first (scripts/build.sh $build -DCMAKE_BUILD_TYPE=Release)" >&2; exit 2; }
done
tools=(taskset)
((net)) && tools+=(mosquitto curl python3)
for tool in "${tools[@]}"; do
  command -v "$tool" >/dev/null || [[ -x /usr/sbin/$tool ]] || { echo "bench-daemon: $tool is missing" >&2; exit 2; }
done
tmp=${TMPDIR:-/tmp}
rec="$tmp/ridgewatch-bench-${seconds}s"
if [[ ! -f $rec.wav ]]; then
  "$build/cli/ridgewatch" simulate --rig "$here/config/rigs/paper-rig.yaml" --duration "$seconds" --rate 51200 \
    --noise 0.01 --out "$rec" >/dev/null 2>&1
fi
work=$(mktemp -d "$tmp/ridgewatch-bench.XXXXXX")
broker_pid=""
scraper_pid=""
cleanup() {
  [[ -n $scraper_pid ]] && kill "$scraper_pid" 2>/dev/null || true
  [[ -n $broker_pid ]] && kill "$broker_pid" 2>/dev/null && wait "$broker_pid" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
# The first CPU this shell may run on (its affinity list, e.g. "0,1" or "0-1").
cpu=$(taskset -pc $$ | sed -E 's/.*: *([0-9]+).*/\1/')
TIMEFORMAT='%3U %3S %3R'

# Starts mosquitto on two free loopback ports the kernel picks (mqtt_port, http_port) and waits until
# it accepts connections. The ports are free when picked but may be taken again before the broker
# binds (other programs on the host), so a broker that exits or does not listen within 5 s is retried
# on new ports, three times at most.
start_broker() {
  local attempt
  for attempt in 1 2 3; do
    read -r mqtt_port http_port < <(python3 -c 'import socket
s=[socket.socket() for _ in range(2)]
[x.bind(("127.0.0.1",0)) for x in s]
print(*[x.getsockname()[1] for x in s])')
    printf 'listener %s 127.0.0.1\nallow_anonymous true\n' "$mqtt_port" >"$work/mosquitto.conf"
    /usr/sbin/mosquitto -c "$work/mosquitto.conf" 2>"$work/broker.log" &
    broker_pid=$!
    if python3 -c 'import socket, sys, time
for _ in range(50):
    try:
        socket.create_connection(("127.0.0.1", int(sys.argv[1])), 0.1).close(); sys.exit(0)
    except OSError:
        time.sleep(0.1)
sys.exit(1)' "$mqtt_port" && kill -0 "$broker_pid" 2>/dev/null; then
      return 0
    fi
    echo "bench-daemon: mosquitto on port $mqtt_port did not come up (attempt $attempt):" >&2
    cat "$work/broker.log" >&2
    kill "$broker_pid" 2>/dev/null && wait "$broker_pid" 2>/dev/null
    broker_pid=""
  done
  echo "bench-daemon: no broker after three attempts" >&2
  exit 1
}

if ((net)); then
  start_broker
  cat >"$work/net.yaml" <<YAML
output:
  source_name: "bench"
  mqtt:
    host: "127.0.0.1"
    port: $mqtt_port
    spool_dir: "$work/spool"
    spool_max_mb: 512
http:
  listen: "127.0.0.1:$http_port"
YAML
fi
# The broker's utime + stime in s (100 Hz ticks); a broker that has exited ends the run with its log.
broker_cpu() {
  if ! kill -0 "$broker_pid" 2>/dev/null; then
    echo "bench-daemon: mosquitto (pid $broker_pid) has exited; its log:" >&2
    cat "$work/broker.log" >&2
    exit 1
  fi
  awk '{ print ($14 + $15) / 100 }' "/proc/$broker_pid/stat"
}

# One run of the pinned daemon; extra arguments go to ridgewatchd. Sets user, sys, wall, rss_kb, n.
run_daemon() {
  local events="$work/events.jsonl"
  rm -f "$events"  # ridgewatchd appends to an existing event log
  # CPU and wall time in ms from bash's `time` (getrusage of the waited-for children: GNU time prints
  # only 10 ms steps); it includes GNU time's and taskset's own ~2-3 ms, so the factors err low. GNU
  # time reports the peak RSS.
  { time /usr/bin/time -o "$work/rss" -f "%M" taskset -c "$cpu" "$build/daemon/ridgewatchd" --replay "$rec.wav" \
    --speed max --events "$events" "$@" 2>"$work/daemon.log"; } 2>"$work/cpu"
  read -r user sys wall <"$work/cpu"
  read -r rss_kb <"$work/rss"
  n=$(wc -l <"$events")
}

plain="$work/plain.txt"
netres="$work/net.txt"
: >"$plain"
: >"$netres"
# One unreported warm-up run: the recording into the page cache, the binaries and libraries loaded
# (the first run after a build or a while idle otherwise pays tens of ms of system time).
taskset -c "$cpu" "$build/daemon/ridgewatchd" --replay "$rec.wav" --speed max --events /dev/null 2>/dev/null
for ((i = 1; i <= runs; i++)); do
  run_daemon
  awk -v s="$seconds" -v u="$user" -v y="$sys" -v w="$wall" -v r="$rss_kb" -v n="$n" -v tag="$( ((net)) && echo 'plain: ' || echo 'run: ')" 'BEGIN {
    c = u + y; printf "%s%d events, CPU %.3f s (user %.3f, sys %.3f), wall %.3f s, RSS %.1f MB -> %.0fx CPU, %.0fx wall (one core)\n",
    tag, n, c, u, y, w, r / 1024, s / c, s / w }' | tee -a "$plain"
  ((net)) || continue

  rm -rf "$work/spool"
  (while :; do
    curl -s "http://127.0.0.1:$http_port/metrics" >/dev/null 2>&1 || true
    curl -s "http://127.0.0.1:$http_port/api/state" >/dev/null 2>&1 || true
    sleep 0.1
  done) &
  scraper_pid=$!
  b0=$(broker_cpu)
  run_daemon --config "$work/net.yaml"
  kill "$scraper_pid" 2>/dev/null
  wait "$scraper_pid" 2>/dev/null || true
  scraper_pid=""
  b1=$(broker_cpu)
  acked=$(awk '$1 == "acked" { print $2 }' "$work/spool/state" 2>/dev/null || echo 0)
  if [[ $acked != "$n" ]]; then
    echo "bench-daemon: only $acked of $n events acknowledged by the broker" >&2
    grep -E "warn|error" "$work/daemon.log" >&2 || true
    exit 1
  fi
  drain=$(sed -nE 's/.*drain took ([0-9.]+) s.*/\1/p' "$work/daemon.log" | tail -1)
  awk -v s="$seconds" -v u="$user" -v y="$sys" -v w="$wall" -v r="$rss_kb" -v n="$n" -v d="${drain:-0}" -v b="$b0" -v e="$b1" 'BEGIN {
    c = u + y; p = w - d; printf "mqtt+http: %d events all acknowledged, CPU %.3f s (user %.3f, sys %.3f), wall %.3f s (+ drain %.3f s), RSS %.1f MB, broker CPU %.2f s -> %.0fx CPU, %.0fx wall (one core)\n",
    n, c, u, y, p, d, r / 1024, e - b, s / c, s / p }' | tee -a "$netres"
done
# Medians over the runs of the CPU-time and the wall-time factors.
median() { sort -n | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
cpu_f=$(sed -E 's/.*-> ([0-9]+)x CPU.*/\1/' "$plain" | median)
wall_f=$(sed -E 's/.*CPU, ([0-9]+)x wall.*/\1/' "$plain" | median)
if ((!net)); then
  echo "median of $runs runs: ${cpu_f}x CPU, ${wall_f}x wall (all threads on CPU $cpu)"
  exit 0
fi
net_cpu=$(sed -E 's/.*-> ([0-9]+)x CPU.*/\1/' "$netres" | median)
net_wall=$(sed -E 's/.*CPU, ([0-9]+)x wall.*/\1/' "$netres" | median)
awk -v r="$runs" -v pc="$cpu_f" -v pw="$wall_f" -v nc="$net_cpu" -v nw="$net_wall" -v c="$cpu" -v l="$(cut -d' ' -f1-3 /proc/loadavg)" 'BEGIN {
  printf "median of %d alternations: plain %dx CPU, %dx wall; MQTT+HTTP %dx CPU, %dx wall; network / plain %.2f (CPU), %.2f (wall); all threads on CPU %d, load average %s\n",
  r, pc, pw, nc, nw, nc / pc, nw / pw, c, l }'
