#!/usr/bin/env bash
# Replay throughput of ridgewatchd with the network outputs on: MQTT (QoS 1 through the on-disk
# spool to a mosquitto started here on 127.0.0.1) and the HTTP listener (/metrics and /api/state
# scraped with curl in a loop while the replay runs), against the same daemon without them, in
# alternation, on the same simulated paper-rig recording as scripts/bench-daemon.sh.
#
#   scripts/bench-fleet.sh [BUILD_DIR] [SECONDS] [RUNS]
#
# Every ridgewatchd run has all its threads (acquisition, processing, MQTT sender, HTTP) pinned to one
# CPU with taskset, so the CPU factor is what one core sustains; the broker and the scraper are not
# pinned (their CPU is not the daemon's; the broker's is printed).
#
# Prints per run: CPU time of the daemon (user + system, all its threads), wall time to the end of
# processing (total wall minus the final MQTT drain the daemon logs), the drain, the broker's CPU,
# and the real-time factors = recording seconds / those times. Every event is checked to have been
# acknowledged by the broker (the spool's state file), so the factors are for a complete delivery.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$here/build-bench}
seconds=${2:-600}
runs=${3:-3}
for bin in "$build/cli/ridgewatch" "$build/daemon/ridgewatchd"; do
  [[ -x $bin ]] || { echo "bench-fleet: $bin not found; build it first" >&2; exit 2; }
done
for tool in mosquitto curl taskset; do
  command -v "$tool" >/dev/null || [[ -x /usr/sbin/$tool ]] || { echo "bench-fleet: $tool is missing" >&2; exit 2; }
done
tmp=$(mktemp -d "${TMPDIR:-/tmp}/ridgewatch-bench-fleet.XXXXXX")
broker_pid=""
scraper_pid=""
cleanup() {
  [[ -n $scraper_pid ]] && kill "$scraper_pid" 2>/dev/null || true
  [[ -n $broker_pid ]] && kill "$broker_pid" 2>/dev/null && wait "$broker_pid" 2>/dev/null || true
  rm -rf "$tmp"
}
trap cleanup EXIT
rec="${TMPDIR:-/tmp}/ridgewatch-bench-${seconds}s"
if [[ ! -f $rec.wav ]]; then
  "$build/cli/ridgewatch" simulate --rig "$here/config/rigs/paper-rig.yaml" --duration "$seconds" --rate 51200 \
    --noise 0.01 --out "$rec" >/dev/null 2>&1
fi
# Two free loopback ports (the kernel picks them).
read -r mqtt_port http_port < <(python3 -c 'import socket
s=[socket.socket() for _ in range(2)]
[x.bind(("127.0.0.1",0)) for x in s]
print(*[x.getsockname()[1] for x in s])')
printf 'listener %s 127.0.0.1\nallow_anonymous true\n' "$mqtt_port" >"$tmp/mosquitto.conf"
/usr/sbin/mosquitto -c "$tmp/mosquitto.conf" 2>"$tmp/broker.log" &
broker_pid=$!
sleep 0.5
cat >"$tmp/net.yaml" <<YAML
output:
  source_name: "bench"
  mqtt:
    host: "127.0.0.1"
    port: $mqtt_port
    spool_dir: "$tmp/spool"
    spool_max_mb: 512
http:
  listen: "127.0.0.1:$http_port"
YAML
# The first CPU this shell may run on (its affinity list, e.g. "0,1" or "0-1").
cpu=$(taskset -pc $$ | sed -E 's/.*: *([0-9]+).*/\1/')
broker_cpu() { awk '{ print ($14 + $15) / 100 }' "/proc/$broker_pid/stat"; }  # utime + stime, s (100 Hz ticks)
TIMEFORMAT='%3U %3S %3R'
plain="$tmp/plain.txt"
net="$tmp/net.txt"
: >"$plain"
: >"$net"
taskset -c "$cpu" "$build/daemon/ridgewatchd" --replay "$rec.wav" --speed max --events /dev/null 2>/dev/null  # warm-up
for ((i = 1; i <= runs; i++)); do
  { time taskset -c "$cpu" "$build/daemon/ridgewatchd" --replay "$rec.wav" --speed max --events "$tmp/plain.jsonl" 2>/dev/null; } 2>"$tmp/t"
  read -r u s w <"$tmp/t"
  awk -v S="$seconds" -v u="$u" -v s="$s" -v w="$w" 'BEGIN { printf "plain:    CPU %.3f s, wall %.3f s -> %.0fx CPU, %.0fx wall\n", u + s, w, S / (u + s), S / w }' | tee -a "$plain"
  rm -f "$tmp/plain.jsonl"

  rm -rf "$tmp/spool" "$tmp/net.jsonl"
  ( while :; do curl -s "http://127.0.0.1:$http_port/metrics" >/dev/null 2>&1 || true
                curl -s "http://127.0.0.1:$http_port/api/state" >/dev/null 2>&1 || true; sleep 0.1; done ) &
  scraper_pid=$!
  b0=$(broker_cpu)
  { time taskset -c "$cpu" "$build/daemon/ridgewatchd" --config "$tmp/net.yaml" --replay "$rec.wav" --speed max \
      --events "$tmp/net.jsonl" 2>"$tmp/net.log"; } 2>"$tmp/t"
  kill "$scraper_pid" 2>/dev/null; wait "$scraper_pid" 2>/dev/null || true
  scraper_pid=""
  b1=$(broker_cpu)
  read -r u s w <"$tmp/t"
  n=$(wc -l <"$tmp/net.jsonl")
  acked=$(awk '$1 == "acked" { print $2 }' "$tmp/spool/state" 2>/dev/null || echo 0)
  drain=$(sed -nE 's/.*drain took ([0-9.]+) s.*/\1/p' "$tmp/net.log" | tail -1)
  drain=${drain:-0}
  if [[ $acked != "$n" ]]; then
    echo "bench-fleet: only $acked of $n events acknowledged by the broker" >&2
    grep -E "warn|error" "$tmp/net.log" >&2 || true
    exit 1
  fi
  awk -v S="$seconds" -v u="$u" -v s="$s" -v w="$w" -v d="$drain" -v n="$n" -v b="$(awk -v a="$b0" -v c="$b1" 'BEGIN { print c - a }')" 'BEGIN {
    p = w - d; printf "mqtt+http: %d events all acknowledged; CPU %.3f s, processing wall %.3f s (+ drain %.3f s), broker CPU %.2f s -> %.0fx CPU, %.0fx wall, %.0fx wall incl. drain\n",
    n, u + s, p, d, b, S / (u + s), S / p, S / w }' | tee -a "$net"
done
median() { sort -n | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
echo "median of $runs runs: plain $(sed -E 's/.*-> ([0-9]+)x CPU.*/\1/' "$plain" | median)x CPU, $(sed -E 's/.*CPU, ([0-9]+)x wall.*/\1/' "$plain" | median)x wall;" \
     "MQTT+HTTP $(sed -E 's/.*-> ([0-9]+)x CPU.*/\1/' "$net" | median)x CPU, $(sed -E 's/.*CPU, ([0-9]+)x wall,.*/\1/' "$net" | median)x wall," \
     "$(sed -E 's/.*, ([0-9]+)x wall incl.*/\1/' "$net" | median)x incl. drain"
