#!/usr/bin/env bash
# Quick start, command 2: install dependencies, build, and run the whole test suite twice:
# an optimised build, and an AddressSanitizer + UndefinedBehaviorSanitizer build; then the threading
# tests (ring buffer) under ThreadSanitizer (only that target is built there, to keep CI time small).
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
"$here/scripts/install-deps.sh"
jobs=$(nproc)

echo "== release build + tests"
"$here/scripts/build.sh" "$here/build-test" -DCMAKE_BUILD_TYPE=RelWithDebInfo
ctest --test-dir "$here/build-test" --output-on-failure -j "$jobs"

echo "== ASan + UBSan build + tests"
"$here/scripts/build.sh" "$here/build-asan" -DCMAKE_BUILD_TYPE=Debug -DRIDGEWATCH_SANITIZE=ON -DRIDGEWATCH_BUILD_BENCH=OFF
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir "$here/build-asan" --output-on-failure -j "$jobs"

echo "== ThreadSanitizer build + threading tests (ring buffer)"
cmake -S "$here" -B "$here/build-tsan" -G Ninja -DRIDGEWATCH_TSAN=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DRIDGEWATCH_BUILD_BENCH=OFF >/dev/null
cmake --build "$here/build-tsan" -j "$jobs" --target test_ring_buffer
TSAN_OPTIONS=halt_on_error=1:second_deadlock_stack=1 "$here/build-tsan/tests/test_ring_buffer"
