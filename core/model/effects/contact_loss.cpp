// contact_loss: the teeth separate when the dynamic deflection exceeds the static one.
#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class ContactLoss final : public Effect {
 public:
  explicit ContactLoss(double loss_fraction) : loss_fraction_(loss_fraction) {}
  // Regime +1: teeth in contact (δ >= 0); -1: separated, the mesh force c_z δ + d_z δ' of Eq. A1 is
  // reduced by `loss_fraction`. The kink at δ = 0 is located by the integrator.
  double mesh_force_factor(int regime) const override { return regime < 0 ? 1.0 - loss_fraction_ : 1.0; }
  bool has_switching() const override { return true; }
  double switching_function(const MeshState& s) const override { return s.deflection_m; }
  StepHooks step_hooks() const override { return {false, false}; }

 private:
  double loss_fraction_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<ContactLoss>(v.at("loss_fraction"));
}

}  // namespace

EffectDescriptor contact_loss_descriptor() {
  return {
      "contact_loss",
      EffectKind::kDynamics,
      "Eq. A1 treats the mesh as a linear spring that can pull as well as push. Teeth can only push: "
      "when the dynamic deflection exceeds the static deflection q_s = M1/(r_b1 c0) the total deflection "
      "becomes negative and the teeth separate (within the backlash), so the mesh force drops to zero. "
      "The oscillator becomes piecewise linear and spends part of each large cycle free, which lowers the "
      "mean frequency at large amplitude. Needs impacts comparable with the static load to show (light "
      "load, see config/rigs/paper-rig-light-load.yaml).",
      "frequency drops at large amplitude (softening); asymmetric waveform; 2 f0 content",
      {{"loss_fraction", "1", 0.0, 1.0, 1.0, 0.0, "fraction of the mesh force lost while separated"}},
      create,
  };
}

}  // namespace ridgewatch::model
