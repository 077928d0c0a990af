#!/usr/bin/env bash
# Quick start, command 2: install dependencies, build, and run the whole test suite twice:
# an optimised build, and an AddressSanitizer + UndefinedBehaviorSanitizer build; then the threading
# tests (ring buffer, daemon) under ThreadSanitizer (only those targets are built there, to keep CI
# time small); then a short libFuzzer run of each input reader.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
"$here/scripts/install-deps.sh"
# shellcheck source=scripts/ccache-args.sh
. "$here/scripts/ccache-args.sh"
ccache_setup "$here"
jobs=$(nproc)

echo "== release build + tests"
"$here/scripts/build.sh" "$here/build-test" -DCMAKE_BUILD_TYPE=RelWithDebInfo
ctest --test-dir "$here/build-test" --output-on-failure -j "$jobs"

echo "== ASan + UBSan build + tests"
"$here/scripts/build.sh" "$here/build-asan" -DCMAKE_BUILD_TYPE=Debug -DRIDGEWATCH_SANITIZE=ON -DRIDGEWATCH_BUILD_BENCH=OFF
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir "$here/build-asan" --output-on-failure -j "$jobs"

echo "== ThreadSanitizer build + threading tests (ring buffer, daemon, daemon with GPIO, several streams, MQTT sender, HTTP)"
# The daemon tests run the TSan-built ridgewatchd/ridgewatch binaries as child processes too, so data
# races in the acquisition/processing threads of the real daemon are reported (halt_on_error: any
# report fails the run). No suppressions.
cmake -S "$here" -B "$here/build-tsan" -G Ninja "${CCACHE_CMAKE_ARGS[@]}" -DRIDGEWATCH_TSAN=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DRIDGEWATCH_BUILD_BENCH=OFF >/dev/null
cmake --build "$here/build-tsan" -j "$jobs" --target ridgewatch ridgewatchd test_ring_buffer test_daemon test_daemon_gpio \
  test_daemon_streams test_mqtt test_http
for t in test_ring_buffer test_daemon test_daemon_gpio test_daemon_streams test_mqtt test_http; do
  TSAN_OPTIONS=halt_on_error=1:second_deadlock_stack=1 "$here/build-tsan/tests/$t"
done

echo "== libFuzzer targets (clang, ASan+UBSan), 30 s each from the seed corpora"
cmake -S "$here" -B "$here/build-fuzz" -G Ninja "${CCACHE_CMAKE_ARGS[@]}" -DCMAKE_CXX_COMPILER=clang++-14 -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DRIDGEWATCH_FUZZ=ON -DRIDGEWATCH_BUILD_TESTS=OFF -DRIDGEWATCH_BUILD_BENCH=OFF >/dev/null
cmake --build "$here/build-fuzz" -j "$jobs" --target fuzz_csv fuzz_wav fuzz_config fuzz_rig
for t in csv wav config rig; do
  scratch=$(mktemp -d)  # new corpus entries go here, the checked-in seeds stay as they are
  "$here/build-fuzz/fuzz/fuzz_$t" -max_total_time="${RIDGEWATCH_FUZZ_SECONDS:-30}" -timeout=10 -rss_limit_mb=2048 \
    -print_final_stats=1 "$scratch" "$here/fuzz/corpus/$t" 2>&1 | grep -E "^(#[0-9]+ +DONE|stat::number_of_executed_units|INFO: -max_total_time)|ERROR|SUMMARY" || true
  rm -rf "$scratch"
  # libFuzzer exits non-zero and writes crash-*/leak-*/timeout-* on a finding.
  if compgen -G "crash-*" >/dev/null || compgen -G "leak-*" >/dev/null || compgen -G "timeout-*" >/dev/null; then
    echo "fuzz_$t: finding, see the crash-/leak-/timeout- file in $(pwd)" >&2
    exit 1
  fi
done
