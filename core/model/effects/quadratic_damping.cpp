// quadratic_damping: velocity-squared (turbulent/oil-squeeze) damping.
#include <cmath>

#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class QuadraticDamping final : public Effect {
 public:
  explicit QuadraticDamping(double coefficient) : coefficient_(coefficient) {}
  // F = d2 q̇ |q̇|: continuous with a continuous first derivative, so RK4 needs no event location.
  double resisting_force_n(const MeshState& s, int) const override {
    return coefficient_ * s.v_m_per_s * std::abs(s.v_m_per_s);
  }
  StepHooks step_hooks() const override { return {true, false}; }

 private:
  double coefficient_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<QuadraticDamping>(v.at("coefficient_n_s2_per_m2"));
}

}  // namespace

EffectDescriptor quadratic_damping_descriptor() {
  return {
      "quadratic_damping",
      EffectKind::kDynamics,
      "Oil squeezed out of the closing gap between the flanks and churning losses give a resisting "
      "force growing with the square of the velocity, d2 q' |q'|, in addition to the viscous d_z q' of "
      "Eq. A1. Its equivalent viscous damping ratio is proportional to the vibration amplitude, so large "
      "impacts decay faster at first and the decay slows down as the motion dies out.",
      "damping falls as amplitude falls (zeta_eq ~ A); log envelope is concave upward",
      {{"coefficient_n_s2_per_m2", "N s^2/m^2", 0.0, 1e9, 1e6, 0.0, "d2 in F = d2 q'|q'|"}},
      create,
  };
}

}  // namespace ridgewatch::model
