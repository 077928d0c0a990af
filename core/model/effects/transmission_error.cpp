// transmission_error: displacement excitation e(θ_z) of Eq. A1 at the mesh harmonics.
#include <array>
#include <cmath>

#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class TransmissionError final : public Effect {
 public:
  explicit TransmissionError(const std::array<double, 3>& amplitudes_m) : amplitudes_m_(amplitudes_m) {}
  // e(θ_z) = sum_k e_k sin(k θ_z); de/dθ_z = sum_k k e_k cos(k θ_z). Eq. A1 forces with -c_z e - d_z ė.
  void add_transmission_error(double mesh_angle_rad, double& e_m,
                              double& de_dangle_m_per_rad) const override {
    for (std::size_t k = 0; k < amplitudes_m_.size(); ++k) {
      const double order = static_cast<double>(k + 1);
      e_m += amplitudes_m_[k] * std::sin(order * mesh_angle_rad);
      de_dangle_m_per_rad += order * amplitudes_m_[k] * std::cos(order * mesh_angle_rad);
    }
  }

 private:
  std::array<double, 3> amplitudes_m_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<TransmissionError>(std::array<double, 3>{v.at("e1_m"), v.at("e2_m"), v.at("e3_m")});
}

}  // namespace

EffectDescriptor transmission_error_descriptor() {
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
       {"e3_m", "m", 0.0, 1e-4, 0.0, 0.0, "amplitude of the 3rd mesh harmonic of e"}},
      create,
  };
}

}  // namespace ridgewatch::model
