#include "core/pipeline/ml_step.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace ridgewatch::pipeline {

namespace {

// A line component fitted closer to the mode than this many DFT bins of the segment is not resolved.
constexpr double kLineSepBins = 1.0;

// Level of the test that the line component is real (line_p_value below it). The line's frequency is
// chosen as the strongest of ~10-20 DFT peaks of the segment, so the test's nominal level is divided by
// about that many looks: 1e-3 nominal is ~1-2 % for the search as a whole.
constexpr double kLineLevel = 1e-2;

// Level of the test for a component the segment does not resolve from the mode (unresolved_component):
// two fixed candidates, so about twice this for the test as a whole.
constexpr double kUnresolvedLevel = 1e-3;

// Optimiser budget of the unresolved-line test's fits (function evaluations; the fit's default is 400).
// The line of the independent record below is found within it (30 was too few); fits that wander
// off (a second component driven to an absurd damping on a clean decay) used the whole default budget.
constexpr int kUnresolvedEvaluations = 60;

// A component whose amplitude changes by less than this (sigma T, nepers over the segment) is steady.
constexpr double kSteadyDecay = 0.1;

// The unresolved-line test (two extra fits, about 4x the cost of the one-mode fit) runs only when the
// one-mode 95 % interval is wider than this ratio hi / lo (about +-5 %). A line strong enough to move
// zeta out of the interval adds its own residual, which widens the interval: the events this test
// exists for had +-11 % (hi / lo ~1.25), clean decays at 40 dB have +-1-2 % and skip it.
constexpr double kUnresolvedMinCiRatio = 1.1;

// Residual terms of the one-mode fit (MlStep::fit): a constant and a slope across the fit band, also
// on short segments. Steady lines and decaying components outside the band leak into it through the
// segment's ends like 1 / (f_line - f), which across a few DFT bins is a slope, not a constant. With
// a constant only, impact-locked lines outside the band bias every event of a short decay alike
// (README, survey section, "median |zeta error| above 2 %"). The price: two of the 12-14 values of
// the shortest segments (6 bins: 4 residual degrees of freedom; the intervals widen by Student's t,
// report_fit in core/dsp/ml_fit.cpp).
constexpr int kResidualTerms = 2;

// Residual degrees of freedom of a fit: 2 values per DFT bin minus 4 per mode and 2 per residual term.
double residual_dof(const dsp::MlFitResult& r, int residual_terms) {
  return 2.0 * static_cast<double>(r.bins) - 4.0 * static_cast<double>(r.modes.size()) - 2.0 * residual_terms;
}

// Probability that noise alone lowers the residual sum of squares by the observed ratio
// r = RSS(with line) / RSS(without) when a component of 4 parameters (f, ln zeta, complex amplitude) is
// added: under that null hypothesis r ~ Beta(dof / 2, 2) (the F test of nested linear models, dof the
// larger model's residual degrees of freedom), whose distribution function is closed:
// I_r(a, 2) = r^a (a + 1 - a r).
double line_p_value(double rss_ratio, double dof) {
  if (!(rss_ratio >= 0.0) || !(dof > 0.0)) return 1.0;
  if (rss_ratio >= 1.0) return 1.0;
  const double a = 0.5 * dof;
  return std::pow(rss_ratio, a) * (a + 1.0 - a * rss_ratio);
}

}  // namespace

MlStep::MlStep(std::size_t full_len, std::size_t in_dec, double fs, double ml_band_rel, double f_top_hz,
               double max_ci_ratio)
    : fs_(fs), fs_a_(fs / static_cast<double>(in_dec)), in_dec_(in_dec), ml_band_rel_(ml_band_rel),
      f_top_hz_(f_top_hz), max_ci_ratio_(max_ci_ratio) {
  // The lengths stay exact: rounding them to FFT-friendly sizes (1766 -> 1728 or 1536 at 51.2 kHz)
  // moved replay-data estimates of misspecified cases by several percent (sim-second-mode median
  // |zeta error| 1.5 % -> 18 %), and the fitter's Goertzel bins do not need a fast FFT length.
  // At half rate the lengths are the full-rate ones halved (copy samples): the complete window's
  // full_len / 2 (883 at 51.2 kHz) fits the copy samples a window with the onset at the pretrigger
  // holds, floor((n_pre + n_win) / 2) - ceil((n_pre + margin) / 2) (ImpactAnalyzer::analyze), and
  // gives the full-rate DFT bins; the shorter ones (cut windows) round down by half a sample where the
  // full-rate length is odd. A window whose onset has the other parity (only at a stream start) holds
  // one copy sample less and takes the next shorter fitter.
  const std::size_t min_len = 64 / in_dec_;
  for (std::size_t k = 1; k <= 8; ++k) {
    std::size_t len = full_len * k / 8 / in_dec_;
    // Long segments (long decay windows) take the FFT: their length is rounded down to an even
    // 2,3,5-smooth one (at most a few % shorter), for which FFTW's r2c plan runs without work space
    // (odd or prime lengths allocate on every execution: not real-time).
    if (len >= 64 && static_cast<double>(bins_for(len)) > 2.0 * std::log2(static_cast<double>(len))) {
      auto smooth = [](std::size_t m) {
        for (std::size_t p : {2u, 3u, 5u})
          while (m % p == 0) m /= p;
        return m == 1;
      };
      while (len > 64 && !(len % 2 == 0 && smooth(len))) --len;
    }
    if (len < min_len || (!fitter_len_.empty() && len == fitter_len_.back())) continue;
    fitter_len_.push_back(len);
    fitter_bins_.push_back(bins_for(len));
  }
}

MlStep::~MlStep() = default;

// The most bins a fit of this length uses (f_d <= the top row, half-width max(ml_band_rel f_d,
// 3 bins)), plus one for rounding: few enough for the Goertzel evaluation, so the fitter plans no FFT
// (start-up: ~2 ms of FFTW planning for the prime 883 and its kin).
std::size_t MlStep::bins_for(std::size_t len) const {
  const double bin_hz = fs_a_ / static_cast<double>(len);
  const double half = std::max(ml_band_rel_ * f_top_hz_, 3.0 * bin_hz);
  return static_cast<std::size_t>(std::floor(2.0 * half / bin_hz)) + 2;
}

void MlStep::prepare() {
  if (!fitters_.empty() || fitter_len_.empty()) return;
  one_.modes.reserve(1);
  base_.modes.reserve(1);
  with_line_.modes.reserve(2);
  try_.modes.reserve(2);
  std::size_t most = 0;
  for (std::size_t b : fitter_bins_) most = std::max(most, b);
  line_bins_.assign(2 * most + 4, {});
  for (std::size_t k = 0; k < fitter_len_.size(); ++k)
    // Room for the line component's fit too: its band is at most twice the fit band plus 3 bins.
    fitters_.push_back(std::make_unique<dsp::SpectralModeFitter>(fitter_len_[k], fs_a_, fitter_bins_[k],
                                                                 2 * fitter_bins_[k] + 6));
  // Warm-up: FFTW allocates work space on a plan's first execution, so each fitter's bin evaluation
  // runs once at its largest band. Only the FFT path needs it (the Goertzel recursions allocate
  // nothing and plan nothing).
  std::vector<double> seg;
  std::vector<std::complex<double>> bins;
  for (std::size_t k = 0; k < fitters_.size(); ++k) {
    const std::size_t len = fitter_len_[k];
    const double bin_hz = fs_a_ / static_cast<double>(len);
    const double half = std::max(ml_band_rel_ * f_top_hz_, 3.0 * bin_hz);
    const std::size_t top = (len - 1) / 2;
    const std::size_t count = std::min(static_cast<std::size_t>(std::floor(2.0 * half / bin_hz)) + 2, top);
    if (count > len || static_cast<double>(count) <= 2.0 * std::log2(static_cast<double>(len))) continue;
    if (count == 0) continue;
    seg.assign(len, 0.0);
    bins.assign(count, {});
    fitters_[k]->dft_bins(seg, 1, bins);
  }
}

std::size_t MlStep::segment_length(std::size_t a0, std::size_t a_end) const {
  std::size_t len = 0;
  if (a0 < a_end)
    for (const std::size_t l : fitter_len_)
      if (l <= a_end - a0) len = l;
  return len;
}

// ok with a 95 % interval that passes the precision rule (hi <= max_ci_ratio lo).
bool MlStep::precise(const dsp::MlFitResult& r) const {
  if (r.modes.empty() || r.modes.front().status != dsp::EstimateStatus::ok) return false;
  const dsp::DampingEstimate& e = r.modes.front();
  return std::isfinite(e.zeta_ci95_lo) && e.zeta_ci95_lo > 0 && e.zeta_ci95_hi <= max_ci_ratio_ * e.zeta_ci95_lo;
}

MlStep::Outcome MlStep::fit(std::span<const double> seg, std::size_t a0, double f_d, double zeta0) {
  std::size_t pick = 0;
  while (pick + 1 < fitter_len_.size() && fitter_len_[pick] != seg.size()) ++pick;
  const dsp::ModeGuess guess{f_d, zeta0};
  dsp::MlFitOptions mo;
  // Short segments have few bins in the band (662 samples at 25.6 kHz: 38.7 Hz bins, 5 bins in
  // +-12 % of 860 Hz). Widening the band would let stationary lines in (a 640 Hz line then biased ok
  // events by 20 %); such segments get at least +-3 bins. Every fit keeps two residual terms
  // (kResidualTerms).
  const double bin_hz = fs_a_ / static_cast<double>(fitter_len_[pick]);
  const double half = std::max(ml_band_rel_ * f_d, 3.0 * bin_hz);
  mo.f_lo_hz = std::max(f_d - half, 1.0);
  mo.f_hi_hz = std::min(f_d + half, 0.4999 * fs_a_);
  mo.residual_terms = kResidualTerms;
  fitters_[pick]->fit(seg, std::span<const dsp::ModeGuess>(&guess, 1), mo, one_);
  const dsp::MlFitResult* used = &one_;
  Outcome out;
  if (!one_.modes.empty() && std::isfinite(one_.modes.front().f_hz)) {
    if (!precise(one_)) {
      if (fit_with_line(pick, seg, guess, mo, one_.modes.front().f_hz)) used = &with_line_;
    } else if (one_.modes.front().zeta_ci95_hi > kUnresolvedMinCiRatio * one_.modes.front().zeta_ci95_lo) {
      out.unresolved_line = unresolved_component(pick, seg, guess, mo, one_.modes.front().f_hz);
    }
  }
  if (used == &with_line_ && used->noise_sd > 0) {
    // White-equivalent variance of x at fs: the copy's in-band noise is H^2 sigma^2 / 2 (step 0).
    const double h = in_dec_ == 2 ? std::pow(std::cos(std::numbers::pi * used->modes.front().f_hz / fs_), 2) : 1.0;
    out.resid_var = used->noise_sd * used->noise_sd * (in_dec_ == 2 ? 2.0 / (h * h) : 1.0);
  }
  if (used->modes.empty()) return out;
  out.fitted = true;
  dsp::DampingEstimate& ml = out.estimate;
  ml = used->modes.front();
  ml.window_start_s += static_cast<double>(a0) / fs_a_;
  ml.window_end_s += static_cast<double>(a0) / fs_a_;
  // The copy's mode amplitude is H(f) = cos^2(pi f / fs) times the window's: the taps' response to
  // the damped mode z = exp((-sigma + i omega) / fs) is (z + 2 + 1/z) / 4 = cosh^2(ln z / 2), of
  // modulus cos^2(omega / (2 fs)) + sinh^2(sigma / (2 fs)) (relative excess ~1e-7).
  if (in_dec_ == 2 && std::isfinite(ml.f_hz)) {
    const double c = std::cos(std::numbers::pi * ml.f_hz / fs_);
    ml.amplitude /= c * c;
  }
  return out;
}

// A steady line near the mode (a mesh harmonic sweeping through the band, a hum harmonic) that the
// single-mode model does not explain widens the interval. Second fit with a nearly undamped extra
// component started at the line: the strongest local maximum of the segment's DFT within half the fit
// band's width outside it and at least 1.5 bins from the mode fm (the fit band widened to hold it),
// or, without one (a line merged with the mode's peak), 1.25 bins below and above the mode, keeping
// the fit with the smaller residual. Its result is used only when its interval passes the precision
// rule, the mode stayed within a bin and the components are resolved (kLineSepBins apart).
bool MlStep::fit_with_line(std::size_t pick, std::span<const double> seg, const dsp::ModeGuess& guess,
                           const dsp::MlFitOptions& mo, double fm) {
  const std::size_t len = fitter_len_[pick];
  const double bin_hz = fs_a_ / static_cast<double>(len);
  const double span_hz = mo.f_hi_hz - mo.f_lo_hz;
  const auto k_lo = static_cast<std::size_t>(std::max(1.0, std::ceil((mo.f_lo_hz - 0.5 * span_hz) / bin_hz)));
  const auto k_hi = std::min(static_cast<std::size_t>(std::floor((mo.f_hi_hz + 0.5 * span_hz) / bin_hz)), (len - 1) / 2);
  double line_hz[2] = {NAN, NAN};
  if (k_hi >= k_lo + 2 && k_hi - k_lo + 1 <= line_bins_.size()) {
    const std::size_t count = k_hi - k_lo + 1;
    std::span<std::complex<double>> b(line_bins_.data(), count);
    fitters_[pick]->dft_bins(seg, k_lo, b);
    double best_mag = 0.0;
    for (std::size_t i = 1; i + 1 < count; ++i) {
      const double f = static_cast<double>(k_lo + i) * bin_hz;
      const double m = std::abs(b[i]);
      if (std::abs(f - fm) < 1.5 * bin_hz || m < std::abs(b[i - 1]) || m < std::abs(b[i + 1])) continue;
      if (m > best_mag) {
        best_mag = m;
        line_hz[0] = f;
      }
    }
  }
  if (!std::isfinite(line_hz[0])) {
    line_hz[0] = fm - 1.25 * bin_hz;
    line_hz[1] = fm + 1.25 * bin_hz;
  }
  double best_noise = std::numeric_limits<double>::infinity();
  bool replaced = false;
  for (const double fl : line_hz) {
    if (!std::isfinite(fl)) continue;
    const LineTest t = test_line(pick, seg, guess, mo, fl, 0);
    if (!t.significant || !t.resolved) continue;
    if (precise(try_) && std::abs(try_.modes.front().f_hz - fm) < bin_hz && try_.noise_sd < best_noise) {
      best_noise = try_.noise_sd;
      with_line_.modes = try_.modes;  // capacity 2: no allocation
      with_line_.noise_sd = try_.noise_sd;
      with_line_.converged = try_.converged;
      with_line_.bins = try_.bins;
      replaced = true;
    }
  }
  return replaced;
}

// The fit with a nearly undamped component started at fl (into try_) and the test that it is real: the
// one-mode fit on the same bins with the same residual terms (the first fit when the band and terms did
// not change) against the fit with the line, F test (line_p_value) at kLineLevel. max_evaluations 0:
// the fit's default budget, and no test for an unresolved line (fit_with_line does not use one);
// > 0: that budget, and the test runs for resolved and unresolved lines. Without the test, a
// line term that fitted noise passed the precision rule by chance: the residual of such fits has only
// 4-6 degrees of freedom, and on an independent 10 dB record (854 Hz, 25 / s, zeta 0.01) 2 of 4 ok
// intervals built that way missed the true zeta.
MlStep::LineTest MlStep::test_line(std::size_t pick, std::span<const double> seg, const dsp::ModeGuess& guess,
                                   const dsp::MlFitOptions& mo, double fl, int max_evaluations) {
  LineTest t;
  const double bin_hz = fs_a_ / static_cast<double>(fitter_len_[pick]);
  const dsp::ModeGuess pair[2] = {guess, {fl, 1e-4}};
  dsp::MlFitOptions mo2 = mo;
  mo2.f_lo_hz = std::max(std::min(mo.f_lo_hz, fl - 1.5 * bin_hz), 1.0);
  mo2.f_hi_hz = std::min(std::max(mo.f_hi_hz, fl + 1.5 * bin_hz), 0.4999 * fs_a_);
  // Residual terms as the bins allow: 8 mode parameters plus 2 per term, and the fit needs more than
  // params + 2 values (2 per bin).
  const double bins2 = (mo2.f_hi_hz - mo2.f_lo_hz) / bin_hz;
  mo2.residual_terms = bins2 >= 11.0 ? 2 : (bins2 >= 8.0 ? 1 : 0);
  if (max_evaluations > 0) mo2.max_evaluations = max_evaluations;
  fitters_[pick]->fit(seg, std::span<const dsp::ModeGuess>(pair, 2), mo2, try_);
  if (try_.modes.size() != 2 || !(try_.noise_sd > 0)) return t;
  t.resolved = std::abs(try_.modes[1].f_hz - try_.modes[0].f_hz) >= kLineSepBins * bin_hz;
  if (!t.resolved && max_evaluations == 0) return t;
  const dsp::MlFitResult* base = &one_;
  if (mo2.f_lo_hz != mo.f_lo_hz || mo2.f_hi_hz != mo.f_hi_hz || mo2.residual_terms != mo.residual_terms) {
    fitters_[pick]->fit(seg, std::span<const dsp::ModeGuess>(&guess, 1), mo2, base_);
    base = &base_;
  }
  const double dof = residual_dof(try_, mo2.residual_terms);
  const double dof0 = residual_dof(*base, mo2.residual_terms);
  if (base->modes.size() != 1 || base->bins != try_.bins || !(base->noise_sd > 0) || !(dof > 0)) return t;
  const double rss_ratio = (try_.noise_sd * try_.noise_sd * dof) / (base->noise_sd * base->noise_sd * dof0);
  t.p_value = line_p_value(rss_ratio, dof);
  t.significant = t.p_value < kLineLevel;
  return t;
}

// A precise one-mode fit can still be a wrong number: a steady line within a DFT bin of the mode
// (a mesh harmonic of the shaft the impacts come from, a hum harmonic) and the decaying mode together
// look like one damped sinusoid over a segment that cannot resolve them (resolution 1 / T), with a
// decay rate set by their beat at |f_mode - f_line| rather than by the damping (Eq. 16 holds for
// neither alone). Test: the fits with a nearly undamped component started 1.25 bins below and above
// the mode (the candidates of a line merged with the mode's peak). True when one lowers the residual
// beyond what noise does (F test at kUnresolvedLevel), its components are not resolved (closer than
// kLineSepBins), the added component is steady, and the mode's zeta with it lies outside the one-mode
// 95 % interval. (tests/support record, 854 Hz, 40 / s, zeta 0.01, 40 dB, a 22-tooth mesh line at
// 836-840 Hz, 25 % of the impact: one-mode zeta 43-66 % high with +-11 % intervals; with the line
// the mode's zeta came out at 0.0100-0.0107 and the line at 836-841 Hz, undamped.)
bool MlStep::unresolved_component(std::size_t pick, std::span<const double> seg, const dsp::ModeGuess& guess,
                                  const dsp::MlFitOptions& mo, double fm) {
  const double bin_hz = fs_a_ / static_cast<double>(fitter_len_[pick]);
  for (const double fl : {fm - 1.25 * bin_hz, fm + 1.25 * bin_hz}) {
    const LineTest t = test_line(pick, seg, guess, mo, fl, kUnresolvedEvaluations);
    if (!(t.p_value < kUnresolvedLevel) || t.resolved) continue;
    // A steady line: the component keeps its amplitude over the segment (sigma T <= kSteadyDecay). A
    // decaying second pole at the mode's frequency is the two-pole description of a decay that is not
    // exponential (amplitude-dependent damping, a drifting mode), for which the one-mode estimate is
    // the equivalent viscous one (noise-free replay-data sim-quadratic-damping: zeta_2 0.066).
    const dsp::DampingEstimate& line = try_.modes[1];
    const double sigma2 = dsp::decay_from_zeta(line.zeta, 2.0 * std::numbers::pi * line.f_hz);
    if (!(sigma2 * static_cast<double>(fitter_len_[pick]) / fs_a_ <= kSteadyDecay)) continue;
    // The one-mode number matters only when it depends on the line: the mode's zeta of the fit with
    // the line lies outside the one-mode 95 % interval.
    const double z2 = try_.modes.front().zeta;
    const dsp::DampingEstimate& e = one_.modes.front();
    if (!(z2 >= e.zeta_ci95_lo && z2 <= e.zeta_ci95_hi)) return true;
  }
  return false;
}

}  // namespace ridgewatch::pipeline
