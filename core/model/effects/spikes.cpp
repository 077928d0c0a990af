// spikes: isolated one-sample outliers (vibrometer dropouts, electrical transients).
#include <cmath>

#include "core/model/effect.hpp"

namespace ridgewatch::model {
namespace {

class Spikes final : public Effect {
 public:
  Spikes(double rate_per_s, double amplitude_rel) : rate_per_s_(rate_per_s), amplitude_rel_(amplitude_rel) {}
  // Poisson arrivals (exponential gaps); each spike is one sample of random sign with magnitude
  // uniform in [0.5, 1] × amplitude_rel × clean peak.
  std::vector<double> apply_to_output(std::span<double> samples, double rate_hz, double clean_peak,
                                      Rng& rng) const override {
    std::vector<double> times_s;
    if (rate_per_s_ <= 0.0) return times_s;
    const double duration_s = static_cast<double>(samples.size()) / rate_hz;
    double t_s = -std::log(rng.uniform()) / rate_per_s_;
    while (t_s < duration_s) {
      const auto index = static_cast<std::size_t>(t_s * rate_hz);
      const double sign = rng.uniform() < 0.5 ? -1.0 : 1.0;
      samples[index] += sign * (0.5 + 0.5 * rng.uniform()) * amplitude_rel_ * clean_peak;
      times_s.push_back(static_cast<double>(index) / rate_hz);
      t_s += -std::log(rng.uniform()) / rate_per_s_;
    }
    return times_s;
  }
  StepHooks step_hooks() const override { return {false, false}; }

 private:
  double rate_per_s_, amplitude_rel_;
};

std::unique_ptr<Effect> create(const EffectValues& v, const RigParameters&) {
  return std::make_unique<Spikes>(v.at("rate_per_s"), v.at("amplitude_rel"));
}

}  // namespace

EffectDescriptor spikes_descriptor() {
  return {
      "spikes",
      EffectKind::kSensor,
      "A laser vibrometer loses the return beam for an instant (speckle dropout) and switching "
      "transients couple into cables; both show as isolated outliers that are not vibration of the gear "
      "pair. Single-sample spikes at Poisson-distributed times; their times are listed in the truth file.",
      "isolated outliers; high kurtosis; broadband (looks like a very damped mode to a score test)",
      {{"rate_per_s", "1/s", 0.0, 1000.0, 2.0, 0.0, "mean number of spikes per second"},
       {"amplitude_rel", "1", 0.0, 100.0, 1.5, std::nullopt, "largest spike magnitude / clean peak"}},
      create,
  };
}

}  // namespace ridgewatch::model
