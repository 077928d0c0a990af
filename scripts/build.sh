#!/usr/bin/env bash
# Configures and builds one build tree. Usage: scripts/build.sh BUILD_DIR [extra cmake args...]
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
# shellcheck source=scripts/ccache-args.sh
. "$here/scripts/ccache-args.sh"
ccache_setup "$here"
dir=${1:?usage: scripts/build.sh BUILD_DIR [cmake args]}
shift
cmake -S "$here" -B "$dir" -G Ninja "${CCACHE_CMAKE_ARGS[@]}" "$@" >/dev/null
cmake --build "$dir" -j "$(nproc)"
