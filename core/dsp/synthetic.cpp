#include "core/dsp/synthetic.hpp"

#include <cmath>
#include <numbers>
#include <random>

#include "core/dsp/damping.hpp"

namespace ridgewatch::dsp {

std::vector<double> damped_sum(const std::vector<DampedComponent>& components, double fs,
                               std::size_t samples, std::size_t onset_samples) {
  std::vector<double> x(samples, 0.0);
  for (const DampedComponent& c : components) {
    const double omega_d = 2.0 * std::numbers::pi * c.f_hz;
    const double sigma = decay_from_zeta(c.zeta, omega_d);
    for (std::size_t n = onset_samples; n < samples; ++n) {
      const double t = static_cast<double>(n - onset_samples) / fs;
      x[n] += c.amplitude * std::exp(-sigma * t) * std::sin(omega_d * t + c.phase_rad);
    }
  }
  return x;
}

double add_white_noise(std::vector<double>& signal, double snr_db, std::uint64_t seed) {
  if (signal.empty()) return 0.0;
  double power = 0.0;
  for (double v : signal) power += v * v;
  power /= static_cast<double>(signal.size());
  const double sd = std::sqrt(power / std::pow(10.0, snr_db / 10.0));
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, sd);
  for (double& v : signal) v += normal(rng);
  return sd;
}

std::vector<DampedComponent> paper_table1_components() {
  const double pi = std::numbers::pi;
  return {{1.0, 250.0, 0.02, -pi / 8}, {1.25, 500.0, 0.045, pi / 6}, {0.5, 1250.0, 0.005, pi / 8}};
}

}  // namespace ridgewatch::dsp
