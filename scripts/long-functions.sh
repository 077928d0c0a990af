#!/usr/bin/env bash
# Functions longer than a limit (default 120 lines) under the given folders (default core), longest
# first, as "lines name file:line". Uses Universal Ctags (its `end:` field); lambdas are counted as part
# of the function that contains them. Exit status 1 when any function is over the limit.
#
#   scripts/long-functions.sh [--limit N] [DIR...]
set -euo pipefail
limit=120
if [[ ${1:-} == --limit ]]; then limit=$2; shift 2; fi
(($#)) || set -- core
command -v ctags >/dev/null || { echo "long-functions: ctags (universal-ctags) is missing" >&2; exit 2; }
out=$(ctags --languages=C++ --c++-kinds=f --fields=+ne -R -f - "$@" |
  awk -F'\t' -v limit="$limit" '{
    l = 0; e = 0
    for (i = 4; i <= NF; i++) { if ($i ~ /^line:/) l = substr($i, 6); if ($i ~ /^end:/) e = substr($i, 5) }
    if (e - l + 1 > limit) print e - l + 1, $1, $2 ":" l
  }' | sort -rn)
[[ -z $out ]] && exit 0
echo "$out"
exit 1
