// Synthetic free responses with known truth: sums of damped sinusoids (Eq. 16, 20) plus white
// Gaussian noise at a stated SNR. Deterministic for a given seed.
#pragma once

#include <cstdint>
#include <vector>

namespace ridgewatch::dsp {

struct DampedComponent {
  double amplitude = 1.0;  ///< a_i
  double f_hz = 100.0;     ///< damped frequency omega_d / 2 pi (the frequency the ridge shows)
  double zeta = 0.01;      ///< damping ratio
  double phase_rad = 0.0;  ///< phi_i
};

/// x(t) = sum a_i exp(-zeta_i omega_0i t) sin(omega_di t + phi_i), t = (n - onset) / fs for
/// n >= onset_samples, 0 before. Eq. (20) writes omega_i in both places; this reads omega_i as the
/// damped frequency and uses the decay rate zeta_i omega_0i = zeta_i omega_di / sqrt(1 - zeta_i^2)
/// of Eq. (16), so that zeta_i is exactly the damping ratio of the viscous model Eq. (14).
std::vector<double> damped_sum(const std::vector<DampedComponent>& components, double sample_rate_hz,
                               std::size_t samples, std::size_t onset_samples = 0);

/// Adds white Gaussian noise whose variance is the mean power of `signal` over the whole record
/// divided by 10^(snr_db / 10). Returns the noise standard deviation used.
double add_white_noise(std::vector<double>& signal, double snr_db, std::uint64_t seed);

/// The paper's Table 1 test signal components (250/500/1250 Hz, zeta 0.02/0.045/0.005).
std::vector<DampedComponent> paper_table1_components();

}  // namespace ridgewatch::dsp
