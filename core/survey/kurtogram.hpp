// Fast kurtogram (after J. Antoni, "Fast computation of the kurtogram for the detection of transient
// faults", Mech. Syst. Signal Process. 21 (2007) 108-124): spectral kurtosis of the record's complex
// band envelopes on Antoni's 1/3-binary tree of bands, and the band where impacts ring.
//
// Bands: level l splits [0, fs/2] into 2^l equal bands, the intermediate level l + log2(3) - 1
// ("l.6") into 3 * 2^(l-1); levels 1, 1.6, 2, 2.6, ... down to the narrowest bandwidth allowed.
// Antoni computes the band envelopes with a tree of quasi-analytic FIR filters and decimators; here
// each band is cut from one FFT of the record (band_envelope.hpp): same bands, brick-wall edges, and
// the whole tree costs about one record-length FFT per level.
//
// Spectral kurtosis of band b: SK = <|c|^4> / <|c|^2>^2 - 2 over the band's envelope samples
// (Antoni's definition for complex envelopes), the ratio taken per 0.5 s block and averaged over the
// blocks: a mesh line that a speed ramp or wobble sweeps through a narrow band makes that band's
// power come and go over seconds, which the whole-record ratio counts as bursts (measured: SK 15 in a
// 25 Hz band at 1150 Hz, above the impacts' band); per block it stays a steady line. It is: 0 for stationary Gaussian noise, -1 for a steady
// sinusoid (a mesh or hum line), > 0 for a band whose energy comes in bursts (impacts ringing), and
// large when the bursts are short against their spacing. Its sampling spread for Gaussian noise, with
// n = T B independent envelope samples (record length T, bandwidth B) and y = |c|^2 exponential:
// by the delta method on <y^2> / <y>^2, var = (20 + 16 - 32) / n = 4 / n, so sd(SK) = 2 / sqrt(n).
// Each cell carries z = SK / (2 / sqrt(n)), its significance against noise.
#pragma once

#include <cstddef>
#include <vector>

#include "core/survey/band_envelope.hpp"

namespace ridgewatch::survey {

struct KurtogramCell {
  double level = 0;        ///< 1, 1.6, 2, 2.6, ... (Antoni's numbering)
  double f_lo_hz = 0, f_hi_hz = 0;
  double kurtosis = 0;     ///< SK (dimensionless)
  double z = 0;            ///< SK / (2 / sqrt(T B))
  double independent_samples = 0;  ///< T B
};

struct KurtogramOptions {
  double f_min_hz = 100;   ///< a cell is a candidate only if it lies inside [f_min, f_max]
  double f_max_hz = 0;     ///< <= 0: 0.5 fs
  double min_bandwidth_hz = 0;  ///< narrowest band; <= 0: max(fs / 2^11, 100 / T, 100 Hz) (>= 50
                                ///< envelope samples per 0.5 s block)
  double min_independent = 100; ///< a candidate needs T B >= this (SK spread <= 0.2)
};

struct Kurtogram {
  std::vector<KurtogramCell> cells;  ///< every band of every level, level by level, low to high f
  std::vector<double> levels;        ///< the levels computed, in order
  /// Index of the candidate with the largest SK, or cells.size() when there is no candidate.
  std::size_t best = 0;
  bool has_best() const { return best < cells.size(); }
};

Kurtogram fast_kurtogram(const RecordSpectrum& spectrum, const KurtogramOptions& options);

/// Block length of the spectral kurtosis, s.
inline constexpr double kBlockS = 0.5;

/// SK of complex envelope samples, the moment ratio averaged over blocks of `block` samples (a last
/// block shorter than half is dropped; block 0 or > size: one block). NaN for fewer than 8 samples
/// or zero power.
double spectral_kurtosis(const std::vector<std::complex<double>>& c, std::size_t block = 0);

}  // namespace ridgewatch::survey
