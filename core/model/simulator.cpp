#include "core/model/simulator.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <numbers>
#include <set>
#include <sstream>
#include <stdexcept>

#include "core/model/mesh_dynamics.hpp"

namespace ridgewatch::model {

void SimulationSettings::validate() const {
  auto fail = [](const std::string& field, const std::string& rule, double got) {
    std::ostringstream os;
    os << field << ": must be " << rule << " (got " << got << ")";
    throw std::invalid_argument(os.str());
  };
  if (!std::isfinite(duration_s) || !(duration_s > 0.0)) fail("duration_s", "> 0", duration_s);
  if (!std::isfinite(sample_rate_hz) || !(sample_rate_hz > 0.0)) fail("sample_rate_hz", "> 0", sample_rate_hz);
  if (!std::isfinite(min_internal_rate_hz) || !(min_internal_rate_hz > 0.0))
    fail("min_internal_rate_hz", "> 0", min_internal_rate_hz);
  if (duration_s * sample_rate_hz > 2.0e9) fail("duration_s * sample_rate_hz", "<= 2e9", duration_s * sample_rate_hz);
  if (!std::isfinite(initial_displacement_m)) fail("initial_displacement_m", "finite", initial_displacement_m);
  if (!std::isfinite(initial_velocity_m_per_s)) fail("initial_velocity_m_per_s", "finite", initial_velocity_m_per_s);
  if (!std::isfinite(truth_interval_s) || !(truth_interval_s > 0.0)) fail("truth_interval_s", "> 0", truth_interval_s);
  if (!std::isfinite(tacho_pulse_s) || tacho_pulse_s < 0.0) fail("tacho_pulse_s", ">= 0", tacho_pulse_s);
}

SimulationResult simulate(const RigParameters& rig, const std::vector<EffectSpec>& specs,
                          const SimulationSettings& settings) {
  rig.validate();
  settings.validate();

  SimulationResult result;
  std::vector<std::unique_ptr<Effect>> effects;
  std::set<std::string> names;
  int aux_modes = 0;
  for (const auto& spec : specs) {
    if (!names.insert(spec.name).second)
      throw std::invalid_argument("effect " + spec.name + " given twice");
    ResolvedEffect resolved = resolve_effect(spec);
    effects.push_back(resolved.descriptor->create(resolved.values, rig));
    if (effects.back()->auxiliary_mode()) ++aux_modes;
    result.effects.push_back({std::move(resolved), {}});
  }
  if (aux_modes > 1) throw std::invalid_argument("at most one effect may add an auxiliary mode");

  std::vector<EffectKind> kinds;
  for (const auto& e : result.effects) kinds.push_back(e.effect.descriptor->kind);
  const MeshModel model(rig, effects, kinds, rig.impact_duration_s, false);
  auto shaft_speed_hz = [&](double t) { return rig.pinion_speed_hz() * model.speed_factor(t); };
  const double rate_hz = settings.sample_rate_hz;
  const auto n_samples = static_cast<std::size_t>(std::llround(settings.duration_s * rate_hz));
  const int substeps = std::max(1, static_cast<int>(std::ceil(settings.min_internal_rate_hz / rate_hz - 1e-9)));
  const double h_s = 1.0 / (rate_hz * substeps);
  const double duration_s = static_cast<double>(n_samples) / rate_hz;
  result.sample_rate_hz = rate_hz;
  result.substeps_per_sample = substeps;

  // Pre-pass: pinion angle θ1(t) = 2π ∫ n(t) dt (same RK4 step), revolution marks at θ1 = 2πk, impact
  // onsets at θ1 = crack angle + 2πk; crossings interpolated linearly within a step.
  std::vector<ImpactPulse> impacts;
  Rng jitter_rng = Rng::stream(settings.seed, 0);
  {
    const double two_pi = 2.0 * std::numbers::pi;
    const double crack = std::fmod(std::fmod(rig.crack_angle_rad, two_pi) + two_pi, two_pi);
    double theta = 0.0;
    double next_mark = 0.0, next_impact = crack;
    const auto total_steps = static_cast<std::uint64_t>(n_samples) * static_cast<std::uint64_t>(substeps);
    for (std::uint64_t n = 0; n <= total_steps; ++n) {
      const double t0 = static_cast<double>(n) * h_s;
      const double w0 = two_pi * shaft_speed_hz(t0);
      const double wm = two_pi * shaft_speed_hz(t0 + 0.5 * h_s);
      const double w1 = two_pi * shaft_speed_hz(t0 + h_s);
      const double theta1 = theta + h_s / 6.0 * (w0 + 4.0 * wm + w1);
      while (next_mark <= theta1) {
        const double t = t0 + h_s * std::clamp((next_mark - theta) / (theta1 - theta), 0.0, 1.0);
        if (t < duration_s) result.revolution_times_s.push_back(t);
        next_mark += two_pi;
      }
      while (next_impact <= theta1) {
        const double t = t0 + h_s * std::clamp((next_impact - theta) / (theta1 - theta), 0.0, 1.0);
        if (t < duration_s && settings.impacts) {
          const double amplitude = std::max(0.0, 1.0 + rig.impact_jitter_rel * jitter_rng.normal());
          impacts.push_back({t, rig.impact_force_n * amplitude});
        }
        next_impact += two_pi;
      }
      theta = theta1;
    }
  }
  for (const ImpactPulse& imp : impacts)
    result.impacts.push_back({imp.t_s, imp.peak_force_n, 2.0 * imp.peak_force_n * rig.impact_duration_s / std::numbers::pi,
                              model.damping_ratio(imp.t_s), shaft_speed_hz(imp.t_s)});
  MeshIntegrator dyn(model, impacts, rig.pinion_speed_hz(), 0.0, {});

  // Main integration.
  MeshIntegrator::State s{settings.initial_displacement_m, settings.initial_velocity_m_per_s, 0.0, 0.0, 0.0};
  double t_s = 0.0;
  dyn.initialise(t_s, s);
  result.clean_output.resize(n_samples);
  for (std::size_t i = 0; i < n_samples; ++i) {
    const double t_sample = static_cast<double>(i) / rate_hz;
    result.clean_output[i] = rig.sensor_sensitivity * dyn.output_quantity(t_sample, s, rig.sensor_quantity);
    for (int k = 0; k < substeps; ++k) {
      t_s = t_sample + static_cast<double>(k) * h_s;
      dyn.advance(t_s, s, h_s, result.located_events);
    }
  }
  for (double v : result.clean_output) result.clean_peak = std::max(result.clean_peak, std::abs(v));

  // Sensor effects, in the order given, each with its own random stream.
  result.output = result.clean_output;
  for (std::size_t i = 0; i < effects.size(); ++i)
    if (result.effects[i].effect.descriptor->kind == EffectKind::kSensor) {
      Rng rng = Rng::stream(settings.seed, i + 1);
      result.effects[i].event_times_s = effects[i]->apply_to_output(result.output, rate_hz, result.clean_peak, rng);
    }

  // Tacho channel and truth series.
  result.tacho.assign(n_samples, 0.0);
  for (double t : result.revolution_times_s) {
    const auto first = static_cast<std::size_t>(std::ceil(t * rate_hz));
    const auto last = static_cast<std::size_t>(std::ceil((t + settings.tacho_pulse_s) * rate_hz));
    for (std::size_t j = first; j < std::min(last, n_samples); ++j) result.tacho[j] = 1.0;
  }
  const double f0_hz = rig.natural_frequency_hz();
  for (double t = 0.0; t < duration_s; t += settings.truth_interval_s) {
    const double n_hz = shaft_speed_hz(t);
    result.truth.push_back({t, model.damping_ratio(t), f0_hz, n_hz, n_hz * rig.pinion_teeth});
  }
  return result;
}

}  // namespace ridgewatch::model
