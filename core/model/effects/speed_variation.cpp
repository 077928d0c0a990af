// speed_variation: pinion speed ramp and periodic fluctuation.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class SpeedVariation final : public Effect {
 public:
  SpeedVariation(double ramp_rel_per_s, double fluctuation_rel, double fluctuation_hz)
      : ramp_rel_per_s_(ramp_rel_per_s), fluctuation_rel_(fluctuation_rel), fluctuation_hz_(fluctuation_hz) {}
  // n(t)/n0 = 1 + ramp t + a sin(2π f t), floored at 5 % so the shaft never turns backwards.
  double speed_factor(double t_s) const override {
    const double f = 1.0 + ramp_rel_per_s_ * t_s +
                     fluctuation_rel_ * std::sin(2.0 * std::numbers::pi * fluctuation_hz_ * t_s);
    return std::max(f, 0.05);
  }
  StepHooks step_hooks() const override { return {false, false}; }

 private:
  double ramp_rel_per_s_, fluctuation_rel_, fluctuation_hz_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<SpeedVariation>(v.at("ramp_rel_per_s"), v.at("fluctuation_rel"),
                                          v.at("fluctuation_hz"));
}

}  // namespace

EffectDescriptor speed_variation_descriptor() {
  return {
      "speed_variation",
      EffectKind::kKinematics,
      "Test rigs are run up and down and their motors and loads fluctuate. The pinion angle is the "
      "integral of the speed, the cracked tooth meets once per revolution and the mesh terms run on the "
      "mesh angle, so a varying speed changes the impact spacing and smears the mesh lines, while the "
      "natural frequency f0 of Eq. A2 stays where it is.",
      "impact spacing changes with time; mesh lines k f_z move or smear; f0 and zeta unchanged",
      {{"ramp_rel_per_s", "1/s", -0.2, 0.2, 0.05, 0.0, "relative speed change per second"},
       {"fluctuation_rel", "1", 0.0, 0.5, 0.01, 0.0, "relative amplitude of a sinusoidal fluctuation"},
       {"fluctuation_hz", "Hz", 0.01, 1000.0, 2.0, std::nullopt, "frequency of the fluctuation"}},
      create,
  };
}

}  // namespace ridgewatch::model
