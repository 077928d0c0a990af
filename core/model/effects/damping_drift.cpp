// damping_drift: the damping ratio changing slowly or in a step (wear, temperature, oil, a new fault).
#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class DampingDrift final : public Effect {
 public:
  DampingDrift(double rate_per_s, double step, double step_time_s)
      : rate_per_s_(rate_per_s), step_(step), step_time_s_(step_time_s) {}
  // Δζ(t) = rate t + step [t >= t_step]; the simulator clamps ζ + Δζ to [0, 0.99].
  double damping_ratio_offset(double t_s) const override {
    return rate_per_s_ * t_s + (t_s >= step_time_s_ ? step_ : 0.0);
  }
  StepHooks step_hooks() const override { return {false, true}; }

 private:
  double rate_per_s_, step_, step_time_s_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<DampingDrift>(v.at("rate_per_s"), v.at("step"), v.at("step_time_s"));
}

}  // namespace

EffectDescriptor damping_drift_descriptor() {
  return {
      "damping_drift",
      EffectKind::kDynamics,
      "The damping ratio zeta of Eq. A2 is not a constant of the rig: oil temperature and viscosity, "
      "wear and a growing crack change it over minutes to hours, and a fault or a lubrication change can "
      "step it. zeta(t) = zeta + rate t + step [t >= step_time]; each single impact is still a linear "
      "free response, only the sequence of impacts shows the change.",
      "per-impact zeta trends (or steps) over time; each single impact fits fine",
      {{"rate_per_s", "1/s", -0.01, 0.01, 0.002, 0.0, "d zeta / dt"},
       {"step", "1", -0.5, 0.5, 0.0, 0.0, "step in zeta at step_time_s"},
       {"step_time_s", "s", 0.0, 1e6, 1.0, std::nullopt, "time of the step"}},
      create,
  };
}

}  // namespace ridgewatch::model
