// transmission_error: displacement excitation e(θ_z) of Eq. A1 at the mesh harmonics.
#include <array>
#include <cmath>
#include <numbers>

#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class TransmissionError final : public Effect {
 public:
  TransmissionError(const std::array<double, 3>& amplitudes_m, const std::array<double, 3>& phases_rad)
      : amplitudes_m_(amplitudes_m), phases_rad_(phases_rad) {}
  // e(θ_z) = Σ_k e_k sin(k θ_z + φ_k); de/dθ_z = Σ_k k e_k cos(k θ_z + φ_k). Eq. A1 forces with
  // -c_z e - d_z ė. Each harmonic has its own phase: a real pair's profile and spacing errors put
  // the harmonics at arbitrary phases to each other (and a rig's sign convention for e may be the
  // opposite one, which is a phase of π on every harmonic and no common shift of θ_z).
  void add_transmission_error(double mesh_angle_rad, double& e_m,
                              double& de_dangle_m_per_rad) const override {
    for (std::size_t k = 0; k < amplitudes_m_.size(); ++k) {
      const double order = static_cast<double>(k + 1);
      const double angle = order * mesh_angle_rad + phases_rad_[k];
      e_m += amplitudes_m_[k] * std::sin(angle);
      de_dangle_m_per_rad += order * amplitudes_m_[k] * std::cos(angle);
    }
  }
  StepHooks step_hooks() const override { return {false, false}; }

 private:
  std::array<double, 3> amplitudes_m_;
  std::array<double, 3> phases_rad_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<TransmissionError>(std::array<double, 3>{v.at("e1_m"), v.at("e2_m"), v.at("e3_m")},
                                             std::array<double, 3>{v.at("phase1_rad"), v.at("phase2_rad"), v.at("phase3_rad")});
}

}  // namespace

EffectDescriptor transmission_error_descriptor() {
  // Phases within ±2π: two full turns, so that a fitted phase never has to stop at a range end.
  constexpr double kTwoPi = 2.0 * std::numbers::pi;
  return {
      "transmission_error",
      EffectKind::kDynamics,
      "Profile errors, tooth modifications and spacing errors make the wheel lag or lead the position "
      "a perfect involute pair would have; this unloaded transmission error e(theta_z) enters Eq. A1 as "
      "a displacement excitation -c_z e - d_z de/dt. It is periodic in the mesh angle, so it forces the "
      "gear pair continuously at the mesh frequency and its harmonics, independently of the impacts.",
      "lines at k f_z present before the impact too; they do not decay; amplified near f0",
      {{"e1_m", "m", 0.0, 1e-4, 0.5e-6, 0.0, "amplitude of the 1st mesh harmonic of e"},
       {"e2_m", "m", 0.0, 1e-4, 0.2e-6, 0.0, "amplitude of the 2nd mesh harmonic of e"},
       {"e3_m", "m", 0.0, 1e-4, 0.0, 0.0, "amplitude of the 3rd mesh harmonic of e"},
       {"phase1_rad", "rad", -kTwoPi, kTwoPi, 0.0, {}, "phase of the 1st harmonic: e1 sin(theta_z + phase1)"},
       {"phase2_rad", "rad", -kTwoPi, kTwoPi, 0.0, {}, "phase of the 2nd harmonic: e2 sin(2 theta_z + phase2)"},
       {"phase3_rad", "rad", -kTwoPi, kTwoPi, 0.0, {}, "phase of the 3rd harmonic: e3 sin(3 theta_z + phase3)"}},
      create,
  };
}

}  // namespace ridgewatch::model
