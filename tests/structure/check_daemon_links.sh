#!/usr/bin/env bash
# ridgewatchd links neither the plots (cli/) nor the simulator and diagnosis (ridgewatch_modelling):
# lists any such symbol in the binary and exits 1.
#
#   tests/structure/check_daemon_links.sh PATH/TO/ridgewatchd
set -euo pipefail
bin=${1:?usage: check_daemon_links.sh RIDGEWATCHD}
command -v nm >/dev/null || { echo "check_daemon_links: nm (binutils) is missing" >&2; exit 2; }
found=$(nm -C "$bin" | grep -E 'ridgewatch::cli::|ridgewatch::diagnosis::|ridgewatch::model::simulate\(' | head -20 || true)
if [[ -n $found ]]; then
  echo "ridgewatchd holds code it must not link (plots, simulator or diagnosis):"
  echo "$found"
  exit 1
fi
echo "ridgewatchd: no plot, simulator or diagnosis symbols"
