#!/usr/bin/env bash
# Regenerates the simulated replay cases replay-data/sim-*.wav + sim-*.truth.json with
# `ridgewatch simulate` (see replay-data/README.md for the table). Deterministic: the same binary
# and seeds give the same bytes.
#   usage: replay-data/generate.sh [--long] [RIDGEWATCH_BINARY]
#   --long also writes sim-damping-drift-long (10 min, 150 MB; not committed, for trend tests).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$here")"
long=0
if [[ "${1:-}" == "--long" ]]; then long=1; shift; fi
rw="${1:-${RIDGEWATCH:-$root/build/cli/ridgewatch}}"
rw="$(realpath -m "$rw")"
[[ -x "$rw" ]] || { echo "generate.sh: ridgewatch binary not found at $rw (build first or pass its path)" >&2; exit 2; }
cd "$here"
rig="../config/rigs/paper-rig.yaml"
light="../config/rigs/paper-rig-light-load.yaml"
sim() { local name=$1; shift; "$rw" simulate "$@" --out "$name"; }
common=(--rate 25600 --duration 2 --seed 1)

sim sim-baseline                 --rig "$rig" "${common[@]}"
sim sim-mesh-stiffness-variation --rig "$rig" "${common[@]}" --effect mesh_stiffness_variation
sim sim-transmission-error       --rig "$rig" "${common[@]}" --effect transmission_error
sim sim-coulomb-friction         --rig "$rig" "${common[@]}" --effect coulomb_friction:force_n=50
sim sim-quadratic-damping        --rig "$rig" "${common[@]}" --effect quadratic_damping
sim sim-second-mode              --rig "$rig" "${common[@]}" --effect second_mode:frequency_hz=930,damping_ratio=0.02,participation=0.5
sim sim-contact-loss             --rig "$light" "${common[@]}" --effect contact_loss
sim sim-stiffness-nonlinearity   --rig "$rig" "${common[@]}" --effect stiffness_nonlinearity:kappa=0.3,reference_deflection_m=2e-6
sim sim-damping-drift            --rig "$rig" "${common[@]}" --effect damping_drift:rate_per_s=0.002
sim sim-speed-variation          --rig "$rig" "${common[@]}" --effect speed_variation:ramp_rel_per_s=0.05,fluctuation_rel=0.01,fluctuation_hz=2
sim sim-noise                    --rig "$rig" "${common[@]}" --effect noise:std_rel=0.01
sim sim-hum                      --rig "$rig" "${common[@]}" --effect hum:amplitude_rel=0.05,frequency_hz=50
sim sim-spikes                   --rig "$rig" "${common[@]}" --effect spikes:rate_per_s=2,amplitude_rel=1.5
sim sim-baseline-noise-0.5pct    --rig "$rig" "${common[@]}" --noise 0.005
sim sim-baseline-noise-3pct      --rig "$rig" "${common[@]}" --noise 0.03
sim sim-nuisance                 --rig "$rig" "${common[@]}" --noise 0.01 \
  --effect speed_variation:ramp_rel_per_s=0.1,fluctuation_rel=0 --effect transmission_error \
  --effect hum:amplitude_rel=0.05 --effect spikes:rate_per_s=3,amplitude_rel=2
sim sim-damping-step             --rig "$rig" "${common[@]}" --noise 0.005 \
  --effect damping_drift:rate_per_s=0,step=0.012,step_time_s=1
sim sim-tacho                    --rig "$rig" --rate 51200 --duration 1 --seed 1 --channels vib,tacho \
  --noise 0.005 --effect mesh_stiffness_variation
if ((long)); then
  sim sim-damping-drift-long     --rig "$rig" --rate 25600 --duration 600 --seed 1 --noise 0.01 \
    --effect damping_drift:rate_per_s=2e-5
fi
du -ch sim-*.wav sim-*.truth.json | tail -1 >&2
