#!/usr/bin/env bash
# Quick start, command 1: install dependencies, build, and identify the modes of the bundled
# Table-1 test signal with the default settings.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
"$here/scripts/install-deps.sh"
"$here/scripts/build.sh" "$here/build" -DCMAKE_BUILD_TYPE=Release -DRIDGEWATCH_BUILD_TESTS=OFF -DRIDGEWATCH_BUILD_BENCH=OFF
"$here/build/cli/ridgewatch" modes "$here/replay-data/paper-table1.wav"
