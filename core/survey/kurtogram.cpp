#include "core/survey/kurtogram.hpp"

#include <algorithm>
#include <cmath>

namespace ridgewatch::survey {

double spectral_kurtosis(const std::vector<std::complex<double>>& c, std::size_t block) {
  if (c.size() < 8) return NAN;
  if (block < 8 || block > c.size()) block = c.size();
  double sum = 0;
  std::size_t blocks = 0;
  for (std::size_t b0 = 0; b0 + block / 2 <= c.size() || b0 == 0; b0 += block) {
    const std::size_t b1 = std::min(c.size(), b0 + block);
    double s2 = 0, s4 = 0;
    for (std::size_t i = b0; i < b1; ++i) {
      const double p = std::norm(c[i]);
      s2 += p;
      s4 += p * p;
    }
    const double n = static_cast<double>(b1 - b0);
    if (s2 > 0) {
      sum += (s4 / n) / ((s2 / n) * (s2 / n));
      ++blocks;
    }
    if (b1 == c.size()) break;
  }
  if (blocks == 0) return NAN;
  return sum / static_cast<double>(blocks) - 2.0;
}

Kurtogram fast_kurtogram(const RecordSpectrum& spectrum, const KurtogramOptions& options) {
  Kurtogram k;
  const double fs = spectrum.sample_rate_hz();
  const double nyq = fs / 2;
  const double t_rec = static_cast<double>(spectrum.samples()) / fs;
  const double f_max = options.f_max_hz > 0 ? std::min(options.f_max_hz, nyq) : nyq;
  const double min_bw = options.min_bandwidth_hz > 0 ? options.min_bandwidth_hz
                                                      : std::max({fs / 2048.0, 100.0 / t_rec, 100.0});
  double best_sk = -INFINITY;
  k.best = static_cast<std::size_t>(-1);
  for (int l = 1;; ++l) {
    bool any = false;
    // Level l (2^l bands), then level l + 0.6 (3 * 2^(l-1) bands).
    for (int third = 0; third < 2; ++third) {
      const double bands = third ? 3.0 * std::ldexp(1.0, l - 1) : std::ldexp(1.0, l);
      const double bw = nyq / bands;
      if (bw < min_bw) continue;
      any = true;
      const double level = third ? l + std::log2(3.0) - 1.0 : l;
      k.levels.push_back(level);
      for (int b = 0; b < static_cast<int>(bands); ++b) {
        KurtogramCell cell;
        cell.level = level;
        cell.f_lo_hz = b * bw;
        cell.f_hi_hz = (b + 1) * bw;
        double rate = 0;
        const auto c = spectrum.envelope(cell.f_lo_hz, cell.f_hi_hz, 1.0, rate);
        cell.kurtosis = spectral_kurtosis(c, static_cast<std::size_t>(std::lround(kBlockS * rate)));
        cell.independent_samples = t_rec * bw;
        cell.z = cell.kurtosis * std::sqrt(cell.independent_samples) / 2.0;
        const bool candidate = cell.f_lo_hz >= options.f_min_hz * 0.999 && cell.f_hi_hz <= f_max * 1.001 &&
                               cell.independent_samples >= options.min_independent && std::isfinite(cell.kurtosis);
        if (candidate && cell.kurtosis > best_sk) {
          best_sk = cell.kurtosis;
          k.best = k.cells.size();
        }
        k.cells.push_back(cell);
      }
    }
    if (!any) break;
  }
  if (k.best == static_cast<std::size_t>(-1)) k.best = k.cells.size();
  return k;
}

}  // namespace ridgewatch::survey
