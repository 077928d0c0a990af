// stiffness_nonlinearity: cubic (Duffing) hardening or softening of the mesh spring.
#include <stdexcept>

#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class StiffnessNonlinearity final : public Effect {
 public:
  StiffnessNonlinearity(double kappa, double reference_m, double c0_n_per_m)
      : coefficient_n_per_m3_(kappa * c0_n_per_m / (reference_m * reference_m)) {}
  // Restoring force c0 x (1 + κ (x/x_ref)^2): the cubic part is added to the mesh force of Eq. A1.
  double resisting_force_n(const MeshState& s, int) const override {
    return coefficient_n_per_m3_ * s.x_m * s.x_m * s.x_m;
  }
  StepHooks step_hooks() const override { return {true, false}; }

 private:
  double coefficient_n_per_m3_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters& rig) {
  return std::make_unique<StiffnessNonlinearity>(v.at("kappa"), v.at("reference_deflection_m"),
                                                 rig.mean_mesh_stiffness_n_per_m);
}

}  // namespace

EffectDescriptor stiffness_nonlinearity_descriptor() {
  return {
      "stiffness_nonlinearity",
      EffectKind::kDynamics,
      "Hertzian contact stiffens as the contact line widens under load, while tooth bending and root "
      "cracks can soften the mesh; to lowest order the restoring force is c0 x (1 + kappa (x/x_ref)^2) "
      "about the static equilibrium (a Duffing oscillator). The backbone frequency is "
      "f0 (1 + 3/8 kappa (A/x_ref)^2) for amplitude A, so the free response chirps as it decays. "
      "kappa < 0 (softening) is bounded at -0.2: the potential loses its minimum at |x| = x_ref/sqrt(-kappa).",
      "frequency rises with amplitude (hardening, kappa > 0) or falls (softening, kappa < 0); 3 f0 content",
      {{"kappa", "1", -0.2, 5.0, 0.3, 0.0, "relative cubic stiffness at x = x_ref"},
       {"reference_deflection_m", "m", 1e-9, 1e-3, 2e-6, std::nullopt, "reference deflection x_ref"}},
      create,
  };
}

}  // namespace ridgewatch::model
