// mesh_stiffness_variation: the Fourier terms of Eq. B1, run on the mesh angle.
#include <cmath>
#include <stdexcept>

#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class MeshStiffnessVariation final : public Effect {
 public:
  MeshStiffnessVariation(double scale, double static_coupling, const RigParameters& rig)
      : harmonics_(rig.stiffness_harmonics), static_coupling_(static_coupling) {
    double sum = 0.0;
    for (auto& h : harmonics_) {
      h.amplitude_n_per_m *= scale;
      sum += h.amplitude_n_per_m;
    }
    // c_z must stay positive at every mesh angle (sufficient: sum of |c_k| < c0).
    if (sum >= rig.mean_mesh_stiffness_n_per_m)
      throw std::invalid_argument("effect mesh_stiffness_variation: scale: c1+c2+... must stay < c0");
  }
  // Eq. B1 with ω_z t replaced by the mesh angle θ_z: sum_k c_k cos(k θ_z + γ_k).
  double stiffness_variation_n_per_m(double mesh_angle_rad) const override {
    double dc = 0.0;
    for (std::size_t k = 0; k < harmonics_.size(); ++k)
      dc += harmonics_[k].amplitude_n_per_m *
            std::cos(static_cast<double>(k + 1) * mesh_angle_rad + harmonics_[k].phase_rad);
    return dc;
  }
  double static_stiffness_variation_n_per_m(double mesh_angle_rad) const override {
    return static_coupling_ == 0.0 ? 0.0 : static_coupling_ * stiffness_variation_n_per_m(mesh_angle_rad);
  }
  StepHooks step_hooks() const override { return {false, false}; }

 private:
  std::vector<StiffnessHarmonic> harmonics_;
  double static_coupling_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters& rig) {
  return std::make_unique<MeshStiffnessVariation>(v.at("scale"), v.at("static_coupling"), rig);
}

}  // namespace

EffectDescriptor mesh_stiffness_variation_descriptor() {
  return {
      "mesh_stiffness_variation",
      EffectKind::kDynamics,
      "The number of tooth pairs in contact and their bending/Hertzian compliance change as the teeth "
      "roll through the mesh, so the mesh stiffness c_z is periodic in the mesh angle (Eq. B1: c0 + "
      "sum_k c_k cos(k theta_z + gamma_k), with the rig's c_k, gamma_k scaled by `scale`). This makes "
      "Eq. A2 a parametrically excited oscillator: the free response after an impact is modulated at "
      "the mesh frequency, and under load the varying stiffness times the static deflection forces the "
      "gears at k f_z. `static_coupling` is the fraction of the static deflection the variation acts on: "
      "1 for unmodified teeth; a profile relieved for the nominal load cancels the static transmission "
      "error (0): then the only evidence is the modulation of each free decay (sidebands f0 +- k f_z).",
      "residual lines at f0 +- k f_z; ridge frequency modulated at f_z; lines at k f_z under load; "
      "no bias of the damping estimate",
      {{"scale", "1", 0.0, 5.0, 1.0, 0.0, "factor on the rig's Fourier terms c_k (1 = rig values)"},
       {"static_coupling", "1", 0.0, 1.0, 1.0, std::nullopt,
        "fraction of the static deflection q_s the variation multiplies (1 = lines at k f_z under load, "
        "0 = load-compensated profile, sidebands only)"}},
      create,
  };
}

}  // namespace ridgewatch::model
