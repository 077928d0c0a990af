// hum: mains interference at the line frequency and its third harmonic.
#include <cmath>
#include <numbers>

#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class Hum final : public Effect {
 public:
  Hum(double amplitude_rel, double frequency_hz, double harmonic3_rel)
      : amplitude_rel_(amplitude_rel), frequency_hz_(frequency_hz), harmonic3_rel_(harmonic3_rel) {}
  std::vector<double> apply_to_output(std::span<double> samples, double rate_hz, double clean_peak,
                                      Rng& rng) const override {
    const double a = amplitude_rel_ * clean_peak;
    const double phase1 = 2.0 * std::numbers::pi * rng.uniform();
    const double phase3 = 2.0 * std::numbers::pi * rng.uniform();
    const double w = 2.0 * std::numbers::pi * frequency_hz_ / rate_hz;  // rad per sample
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const double n = static_cast<double>(i);
      samples[i] += a * (std::sin(w * n + phase1) + harmonic3_rel_ * std::sin(3.0 * w * n + phase3));
    }
    return {};
  }
  StepHooks step_hooks() const override { return {false, false}; }

 private:
  double amplitude_rel_, frequency_hz_, harmonic3_rel_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<Hum>(v.at("amplitude_rel"), v.at("frequency_hz"), v.at("harmonic3_rel"));
}

}  // namespace

EffectDescriptor hum_descriptor() {
  return {
      "hum",
      EffectKind::kSensor,
      "Ground loops and motor drives couple the mains frequency (and its odd harmonics from saturated "
      "transformers and rectifiers) into the sensor cable. A sine at the line frequency plus a third "
      "harmonic, with random phases, amplitude relative to the clean peak.",
      "constant lines at the line frequency and 3x; unrelated to shaft speed; present between impacts",
      {{"amplitude_rel", "1", 0.0, 10.0, 0.05, 0.0, "amplitude of the fundamental / clean peak"},
       {"frequency_hz", "Hz", 1.0, 1000.0, 50.0, std::nullopt, "line frequency"},
       {"harmonic3_rel", "1", 0.0, 1.0, 0.3, std::nullopt, "third harmonic / fundamental"}},
      create,
  };
}

}  // namespace ridgewatch::model
