#!/usr/bin/env bash
# The fleet example: one mosquitto on loopback, three ridgewatchd replaying different simulated rigs
# (MQTT QoS 1 through their spools, /metrics and the live page on 127.0.0.1:9421-9423), and
# fleet_check verifying that every event of every rig arrived exactly once. See README.md here.
#
#   examples/fleet/run.sh [--build DIR] [--speed N|max] [--port P] [--http-base PORT] [--workdir DIR]
#                         [--outage S]
#
# --speed: replay speed (default 4, i.e. each 2 s recording takes 0.5 s; "max" as fast as possible).
# --outage S: stop the broker S seconds into the run for 3 s (the daemons spool and resend).
# Everything binds to 127.0.0.1. Exit 0 when every event arrived exactly once.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
build=$root/build
speed=4
port=18830
http_base=9421
work=""
outage=""
while (($#)); do
  case $1 in
    --build) build=$2; shift 2 ;;
    --speed) speed=$2; shift 2 ;;
    --port) port=$2; shift 2 ;;
    --http-base) http_base=$2; shift 2 ;;
    --workdir) work=$2; shift 2 ;;
    --outage) outage=$2; shift 2 ;;
    *) echo "run.sh: unknown argument '$1'" >&2; exit 2 ;;
  esac
done
daemon=$build/daemon/ridgewatchd
check=$build/examples/fleet/fleet_check
for bin in "$daemon" "$check"; do
  [[ -x $bin ]] || { echo "run.sh: $bin not found; build first (cmake --build $build --target ridgewatchd fleet_check)" >&2; exit 2; }
done
[[ -n $work ]] || work=$(mktemp -d "${TMPDIR:-/tmp}/ridgewatch-fleet.XXXXXX")
mkdir -p "$work/broker"
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; }
trap cleanup EXIT

# The broker: loopback only, persistence so a restart keeps queued messages of persistent sessions.
sed -e "s|@PORT@|$port|" -e "s|@DIR@|$work/broker/|" "$here/mosquitto.conf" >"$work/mosquitto.conf"
# Started as root, mosquitto drops to the user "mosquitto", which cannot write the work directory.
[[ $(id -u) -ne 0 ]] || echo "user root" >>"$work/mosquitto.conf"
start_broker() {
  /usr/sbin/mosquitto -c "$work/mosquitto.conf" 2>>"$work/broker.log" &
  broker=$!
  for _ in $(seq 50); do (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null && return 0; sleep 0.1; done
  echo "run.sh: mosquitto did not start on 127.0.0.1:$port" >&2; exit 1
}
start_broker
pids+=("$broker")

# Three rigs: a healthy one, one whose damping drifts, one with a step (config/rigs, replay-data/).
rigs=(rig-a rig-b rig-c)
files=(sim-baseline.wav sim-damping-drift.wav sim-damping-step.wav)
args=()
for i in 0 1 2; do
  rig=${rigs[$i]}
  sed -e "s|@RIG@|$rig|" -e "s|@PORT@|$port|" -e "s|@SPOOL@|$work/$rig-spool|" -e "s|@HTTP@|$((http_base + i))|" \
    "$here/rig.yaml.in" >"$work/$rig.yaml"
  args+=("$rig=$work/$rig.jsonl")
done
rm -f "$work/done"
"$check" --port "$port" --done-file "$work/done" "${args[@]}" >"$work/check.txt" 2>&1 &
checker=$!
pids+=("$checker")
sleep 0.3
daemons=()
for i in 0 1 2; do
  rig=${rigs[$i]}
  "$daemon" --config "$work/$rig.yaml" --replay "$root/replay-data/${files[$i]}" --speed "$speed" \
    --events "$work/$rig.jsonl" 2>"$work/$rig.log" &
  daemons+=($!)
  pids+=($!)
done
if [[ -n $outage ]]; then
  sleep "$outage"
  kill "$broker"; wait "$broker" 2>/dev/null || true
  echo "broker stopped for 3 s" >&2
  sleep 3
  start_broker
  pids+=("$broker")
fi
status=0
for p in "${daemons[@]}"; do wait "$p" || status=$?; done
((status == 0)) || { echo "run.sh: a daemon failed (exit $status); logs in $work" >&2; exit 1; }
touch "$work/done"
wait "$checker" && rc=0 || rc=$?
cat "$work/check.txt"
echo "work directory: $work (event logs, daemon logs, spools, broker log)"
exit "$rc"
