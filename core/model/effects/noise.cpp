// noise: white Gaussian sensor/ADC noise.
#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class Noise final : public Effect {
 public:
  explicit Noise(double std_rel) : std_rel_(std_rel) {}
  std::vector<double> apply_to_output(std::span<double> samples, double, double clean_peak,
                                      Rng& rng) const override {
    const double sigma = std_rel_ * clean_peak;
    for (double& s : samples) s += sigma * rng.normal();
    return {};
  }
  StepHooks step_hooks() const override { return {false, false}; }

 private:
  double std_rel_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<Noise>(v.at("std_rel"));
}

}  // namespace

EffectDescriptor noise_descriptor() {
  return {
      "noise",
      EffectKind::kSensor,
      "Vibrometer speckle noise, preamplifier and ADC noise add a broadband random signal independent "
      "of the vibration. Modelled as white Gaussian noise with a standard deviation relative to the "
      "peak of the clean sensor output.",
      "white residual floor; Gaussian amplitude distribution; also present between impacts",
      {{"std_rel", "1", 0.0, 10.0, 0.01, 0.0, "noise standard deviation / clean peak"}},
      create,
  };
}

}  // namespace ridgewatch::model
