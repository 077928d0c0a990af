// coulomb_friction: dry friction on the line-of-action coordinate, with stick.
#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class CoulombFriction final : public Effect {
 public:
  explicit CoulombFriction(double force_n) : force_n_(force_n) {}
  // F_c sign(q̇): the sign is the regime, frozen over a step; its changes are located by the
  // integrator (a smooth tanh made fixed-step RK4 unstable in the prototype).
  double resisting_force_n(const MeshState&, int regime) const override { return force_n_ * regime; }
  bool has_switching() const override { return true; }
  double switching_function(const MeshState& s) const override { return s.v_m_per_s; }
  double stick_force_limit_n() const override { return force_n_; }
  StepHooks step_hooks() const override { return {true, false}; }

 private:
  double force_n_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<CoulombFriction>(v.at("force_n"));
}

}  // namespace

EffectDescriptor coulomb_friction_descriptor() {
  return {
      "coulomb_friction",
      EffectKind::kDynamics,
      "Sliding between the tooth flanks (and in bearings and seals) dissipates energy by dry friction: "
      "a force of constant magnitude F_c opposing the relative velocity, here lumped onto the mesh "
      "coordinate q of Eq. A1. Each half cycle loses 2 F_c / c0 of amplitude, so the free response "
      "decays linearly (4 F_c / c0 per cycle) rather than exponentially and stops in finite time when "
      "the spring force can no longer overcome F_c (stick).",
      "envelope decays linearly, not exponentially; equivalent damping rises as amplitude falls "
      "(zeta_eq ~ 1/A); motion stops in finite time",
      {{"force_n", "N", 0.0, 1e4, 50.0, 0.0, "friction force magnitude F_c (static = kinetic)"}},
      create,
  };
}

}  // namespace ridgewatch::model
