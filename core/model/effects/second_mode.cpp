// second_mode: a nearby linear mode (shaft torsion, bearing/housing) excited by the same impacts.
#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class SecondMode final : public Effect {
 public:
  explicit SecondMode(AuxiliaryMode mode) : mode_(mode) {}
  std::optional<AuxiliaryMode> auxiliary_mode() const override { return mode_; }
  StepHooks step_hooks() const override { return {false, false}; }

 private:
  AuxiliaryMode mode_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<SecondMode>(
      AuxiliaryMode{v.at("frequency_hz"), v.at("damping_ratio"), v.at("participation")});
}

}  // namespace

EffectDescriptor second_mode_descriptor() {
  return {
      "second_mode",
      EffectKind::kDynamics,
      "Eq. A1 keeps only the mesh mode of two rigid disks. Real rigs also have shaft-torsion, bearing "
      "and housing modes; one near f0 is excited by the same tooth impact and seen by the same sensor. "
      "It is added by modal superposition as p'' + 2 zeta2 w2 p' + w2^2 p = participation F(t) / m_red, "
      "and the sensor measures q + p (or their derivatives).",
      "envelope beats at |f2 - f0|; a decaying residual peak at f2; biases a single-mode damping fit",
      {{"frequency_hz", "Hz", 10.0, 20000.0, 930.0, std::nullopt, "natural frequency f2"},
       {"damping_ratio", "1", 0.0, 0.5, 0.02, std::nullopt, "damping ratio zeta2"},
       {"participation", "1", 0.0, 10.0, 0.5, 0.0, "modal force per impact force, relative to the mesh mode"}},
      create,
  };
}

}  // namespace ridgewatch::model
