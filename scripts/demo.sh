#!/usr/bin/env bash
# Quick start, command 1: install dependencies, build, and run the main jobs on bundled data with the
# default configuration: the modes of the paper's Table-1 signal, and the per-impact monitoring of a
# simulated paper-rig recording (the daemon's pipeline, as `ridgewatch analyze`).
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
"$here/scripts/install-deps.sh"
"$here/scripts/build.sh" "$here/build" -DCMAKE_BUILD_TYPE=Release -DRIDGEWATCH_BUILD_TESTS=OFF -DRIDGEWATCH_BUILD_BENCH=OFF
bin="$here/build/cli/ridgewatch"

echo "== ridgewatch modes replay-data/paper-table1.wav"
"$bin" modes "$here/replay-data/paper-table1.wav"

echo "== ridgewatch analyze replay-data/sim-noise.wav --config config/ridgewatch.yaml (one JSON line per impact)"
events=$("$bin" analyze "$here/replay-data/sim-noise.wav" --config "$here/config/ridgewatch.yaml")
head -n 3 <<<"$events"
echo "... $(wc -l <<<"$events") events in all, $(grep -c '"status":"ok"' <<<"$events") with status ok"
