#!/usr/bin/env bash
# Installs the Debian 12 packages ridgewatch needs to build and test. Skips apt when all are present.
set -euo pipefail
packages=(
  build-essential cmake ninja-build pkg-config
  ccache  # compiler cache: a second run of the test command recompiles only what changed
  libeigen3-dev libfftw3-dev libsndfile1-dev libspdlog-dev libyaml-cpp-dev
  libgtest-dev libgmock-dev libbenchmark-dev nlohmann-json3-dev
  libasound2-dev libgpiod-dev libsystemd-dev systemd
  dpkg-dev man-db  # the .deb (CPack, dpkg-shlibdeps) and its test (man -l)
  clang-14 libclang-rt-14-dev
  libmosquitto-dev mosquitto libcpp-httplib-dev prometheus
  libmuparser-dev  # expressions of user-defined effects (rig file model.custom_effects)
  chromium  # the live page's test loads it in headless Chromium (the test skips when it is absent)
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "install-deps: installing ${missing[*]}" >&2
  sudo_cmd=()
  [[ $(id -u) -eq 0 ]] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
fi
