// Gear-pair simulator: Eq. A1/A2 of the paper (Appendix A) with the rig of Appendix B, excited by a
// cracked-tooth impact once per pinion revolution, plus the effects of the catalogue
// (core/model/effect_registry.hpp). Pure computation: no I/O, no clock, no threads.
//
// The equation of motion and its integration (RK4, steps split at impact pulse edges, event location
// on switching effects with the stick test) are core/model/mesh_dynamics.hpp, shared with the model
// fit. Here: the pinion angle pre-pass (revolution marks, impact onsets with amplitude jitter), fixed
// steps at `substeps_per_sample` x the output rate (at least `min_internal_rate_hz`), the sensor
// effects, the tacho channel and the truth series.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/model/effect.hpp"
#include "core/model/effect_registry.hpp"
#include "core/model/rig_parameters.hpp"

namespace ridgewatch::model {

struct SimulationSettings {
  double duration_s = 2.0;                ///< > 0
  double sample_rate_hz = 51200.0;        ///< output rate, > 0
  double min_internal_rate_hz = 200000.0; ///< RK4 step rate floor (an integer multiple of the output rate)
  std::uint64_t seed = 1;                 ///< impact jitter and sensor effects
  bool impacts = true;                    ///< false: free response from the initial state only
  double initial_displacement_m = 0.0;    ///< x(0)
  double initial_velocity_m_per_s = 0.0;  ///< q̇(0)
  double truth_interval_s = 0.01;         ///< spacing of the ζ/f0 truth series
  double tacho_pulse_s = 5e-4;            ///< width of the once-per-revolution tacho pulse

  /// Throws std::invalid_argument naming the field.
  void validate() const;
};

struct ImpactTruth {
  double t_s = 0.0;           ///< pulse onset
  double peak_force_n = 0.0;  ///< half-sine peak (with jitter)
  double impulse_n_s = 0.0;   ///< 2 F τ / π
  double damping_ratio = 0.0; ///< true ζ at the onset
  double shaft_speed_hz = 0.0;
};

struct TruthSample {
  double t_s = 0.0;
  double damping_ratio = 0.0;      ///< ζ(t) including damping_drift
  double f0_hz = 0.0;              ///< sqrt(c0/m_red)/2π (small-amplitude, mean-stiffness value)
  double shaft_speed_hz = 0.0;
  double mesh_frequency_hz = 0.0;  ///< z1 × shaft speed
};

struct EffectTruth {
  ResolvedEffect effect;
  std::vector<double> event_times_s;  ///< e.g. spike times; empty for most effects
};

struct SimulationResult {
  double sample_rate_hz = 0.0;
  int substeps_per_sample = 0;
  std::vector<double> clean_output;  ///< sensor output before sensor effects (sensitivity × quantity)
  std::vector<double> output;        ///< with sensor effects
  std::vector<double> tacho;         ///< 1 for tacho_pulse_s after each revolution mark, else 0
  double clean_peak = 0.0;           ///< max |clean_output|
  std::vector<double> revolution_times_s;
  std::vector<ImpactTruth> impacts;
  std::vector<TruthSample> truth;
  std::vector<EffectTruth> effects;
  std::uint64_t located_events = 0;  ///< regime changes located (friction reversals, contact changes)
};

/// Runs the simulation. Throws std::invalid_argument for an invalid rig, settings or effect list
/// (unknown effect, parameter out of bounds, the same effect twice).
SimulationResult simulate(const RigParameters& rig, const std::vector<EffectSpec>& effects,
                          const SimulationSettings& settings);

}  // namespace ridgewatch::model
