#!/usr/bin/env bash
# The project's folder dependencies point one way (README "Layout and design notes"): each folder may
# include only the folders listed for it below. Prints every include that breaks the rule and exits 1.
#
#   tests/structure/check_layering.sh SOURCE_DIR
set -euo pipefail
src=${1:?usage: check_layering.sh SOURCE_DIR}
cd "$src"
declare -A allowed=(
  [core/dsp/kernels]=""
  [core/dsp]="core/dsp/kernels"
  [core/rt]=""
  [core/trend]=""
  [core/model]=""
  [core/pipeline]="core/dsp core/dsp/kernels core/trend"
  [core/survey]="core/dsp core/pipeline"
  [core/diagnosis]="core/model core/pipeline core/dsp"
  [drivers]=""
  [app]="core/model core/pipeline core/trend core/survey core/dsp drivers"
  [cli]="app core/diagnosis core/dsp core/model core/pipeline core/survey core/trend drivers"
  [daemon]="app core/pipeline core/rt core/trend core/survey core/dsp drivers"
)
bad=0
for dir in "${!allowed[@]}"; do
  # Files directly in this folder (sub-folders with their own entry are checked on their own).
  while IFS= read -r line; do
    file=${line%%:*}
    target=$(sed -E 's/.*#include "([^"]+)".*/\1/' <<<"$line")
    tdir=$(dirname "$target")
    [[ $tdir == . || $tdir == "$dir" ]] && continue
    case " ${allowed[$dir]} " in *" $tdir "*) continue ;; esac
    # Generated headers (version, web page) and the test-support folder are not project folders.
    [[ $tdir == generated* ]] && continue
    echo "layering: $file includes $target ($dir may include only: ${allowed[$dir]:-nothing in the project})"
    bad=1
  done < <(find "$dir" -maxdepth 1 -name '*.[ch]pp' -print0 | xargs -0 grep -H '^#include "' || true)
done
exit $bad
