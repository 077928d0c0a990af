#include "core/survey/averaged_response.hpp"

#include <fftw3.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <mutex>
#include <numeric>
#include <vector>

#include "core/dsp/fftw_planner.hpp"

namespace ridgewatch::survey {

namespace {

constexpr double kPi = 3.141592653589793;
constexpr double kGapS = 0.001;          // between the R window's end and the E window's start
constexpr std::size_t kMinImpacts = 6;   // fewer: the ratio's spread (F with 2N, 2N dof) is too wide to test
constexpr std::size_t kMinWindow = 32;   // 2L in samples, the shortest
constexpr std::size_t kMaxWindow = 8192; // ... and the longest
constexpr std::size_t kPad = 8;          // zero padding of the windows (bins for the peak's refinement)
constexpr double kLineOverFloor = 10.0;  // a stationary line: P_R >= 10x the median around it ...
constexpr double kLineRatio = 2.0;       // ... and P_E / P_R < 2 there (not the mode's own ringing tail)
constexpr double kMinIntervalS = 0.02;  // shortest interval between impacts (identify_averaged_mode)
constexpr double kMinCycles = 8.0;       // periods of f within the 2L window (identify_averaged_mode)
constexpr double kMaxBeforeShare = 0.3;  // excess before the onset over the excess after it (a decay: ~0)

std::string fmt(double v, int digits = 3) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*g", digits, v);
  return b;
}

double median(std::vector<double> v) {
  if (v.empty()) return NAN;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

// Averaged Hann power spectra of the E and R windows (2L = n_w samples of the complex envelope c at
// rate fe, zero-padded to kPad n_w) of the impacts whose both windows lie inside the record;
// returns N. The envelope is analytic (positive frequencies only): a real record's windows would
// also hold the negative-frequency image, whose leakage into a window of few cycles pulls the peak
// (measured on the real samples: 2278 Hz for 2500 Hz with 3 cycles per window, 2487 Hz with 20).
std::size_t averaged_spectra(const std::vector<std::complex<double>>& c, double fe, std::span<const double> onset_s,
                             std::size_t n_w, std::vector<double>& pe, std::vector<double>& pr) {
  const std::size_t m = kPad * n_w;
  fftw_complex* buf = fftw_alloc_complex(m);
  fftw_plan plan;
  {
    std::lock_guard<std::mutex> lock(dsp::fftw_planner_mutex());
    plan = fftw_plan_dft_1d(static_cast<int>(m), buf, buf, FFTW_FORWARD, FFTW_ESTIMATE);
  }
  std::vector<double> w(n_w);
  for (std::size_t i = 0; i < n_w; ++i)
    w[i] = 0.5 - 0.5 * std::cos(2 * kPi * (static_cast<double>(i) + 0.5) / static_cast<double>(n_w));
  pe.assign(m, 0.0);
  pr.assign(m, 0.0);
  const auto gap = static_cast<std::ptrdiff_t>(std::lround(kGapS * fe));
  std::size_t used = 0;
  auto add = [&](std::ptrdiff_t start, std::vector<double>& p) {
    for (std::size_t i = 0; i < m; ++i) buf[i][0] = buf[i][1] = 0.0;
    for (std::size_t i = 0; i < n_w; ++i) {
      const std::complex<double> v = w[i] * c[static_cast<std::size_t>(start) + i];
      buf[i][0] = v.real();
      buf[i][1] = v.imag();
    }
    fftw_execute(plan);
    for (std::size_t k = 0; k < m; ++k) p[k] += buf[k][0] * buf[k][0] + buf[k][1] * buf[k][1];
  };
  for (double t : onset_s) {
    const auto start_e = static_cast<std::ptrdiff_t>(std::lround(t * fe)) - static_cast<std::ptrdiff_t>(n_w / 2);
    const auto start_r = start_e - static_cast<std::ptrdiff_t>(n_w) - gap;
    if (start_r < 0 || start_e + static_cast<std::ptrdiff_t>(n_w) > static_cast<std::ptrdiff_t>(c.size())) continue;
    add(start_e, pe);
    add(start_r, pr);
    ++used;
  }
  {
    std::lock_guard<std::mutex> lock(dsp::fftw_planner_mutex());
    fftw_destroy_plan(plan);
  }
  fftw_free(buf);
  return used;
}

// The smallest ratio r with gamma_ratio_tail(n, r) <= p (bisection on the monotone tail).
double ratio_for_tail(std::size_t n, double p) {
  double lo = 1.0, hi = 2.0;
  while (gamma_ratio_tail(n, hi) > p && hi < 1e12) hi *= 2;
  for (int i = 0; i < 60; ++i) {
    const double mid = std::sqrt(lo * hi);
    (gamma_ratio_tail(n, mid) > p ? lo : hi) = mid;
  }
  return hi;
}

// f from the averaged spectra (bins df apart, kPad per Hann bin): the local maximum of the excess
// P_E - P_R nearest the ratio's peak k_ratio (within the Hann main lobe, 2 Hann bins), then the
// centroid of the excess over the contiguous bins around it above half that maximum. The expected
// excess is symmetric about the mode's f (a real, non-negative envelope times the carrier: |G(f' - f)|^2),
// and the centroid averages the noise of all those bins (a 3-point vertex on it read 2474 Hz for
// 2500 Hz at 10 dB, 24 impacts; README).
// half_width_hz receives half the width of that region.
double peak_frequency(const std::vector<double>& pe, const std::vector<double>& pr, std::size_t k_ratio, double df,
                      double& half_width_hz) {
  auto excess = [&](std::size_t k) { return pe[k] - pr[k]; };
  std::size_t k = k_ratio;
  const std::size_t lobe = 2 * kPad;
  while (k + 2 < pe.size() && k + 1 <= k_ratio + lobe && excess(k + 1) > excess(k)) ++k;
  while (k > 1 && k - 1 + lobe >= k_ratio && excess(k - 1) > excess(k)) --k;
  const double half = 0.5 * excess(k);
  std::size_t lo = k, hi = k;
  while (lo > 1 && excess(lo - 1) >= half) --lo;
  while (hi + 2 < pe.size() && excess(hi + 1) >= half) ++hi;
  half_width_hz = 0.5 * static_cast<double>(hi - lo + 1) * df;
  double sw = 0, swk = 0;
  for (std::size_t j = lo; j <= hi; ++j) {
    sw += excess(j) - half;
    swk += (excess(j) - half) * static_cast<double>(j);
  }
  return (sw > 0 ? swk / sw : static_cast<double>(k)) * df;
}

// Step 3's decay rate from the shape of the averaged excess power over its main lobe (the samples
// around its peak k_peak above 3 sd): the envelope of a brick-wall band f +- hw (the record's DFT bins,
// RecordSpectrum::envelope) of a decay exp(-sigma t) cos(2 pi f t) started at t0 is
//   y(t) = integral over |nu| <= hw of exp(i 2 pi nu (t - t0)) / (sigma + i 2 pi nu) d nu,
// and the excess is A |y|^2 averaged over the onsets' scatter (a Gaussian of sd 0-0.5 ms: the
// survey's onsets come from ~0.25 ms envelope bins, and at 10 dB scatter more); sigma, t0 (the
// onsets may be biased), the scatter and A by least squares (A in closed form; sigma on a log grid
// refined by a parabola, t0 on a grid of 1/(4 fe), the scatter in steps of 0.1 ms). When the band's
// response 1/hw is not short against the decay (8 kHz, zeta 0.01: hw 245 Hz, 4 ms, against a power
// time constant of 1 ms) the averaged power is mostly the band's own response, and a line through its
// logarithm read sigma 1.6x too high; without the scatter the fit read 2.5 kHz zeta 0.05 (seed 160)
// 32 % low. NaN when the fit fails or lands on the grid's edge.
double fit_band_limited_decay(const std::vector<double>& avg, double floor_p, double sd, double fe, std::size_t k_peak,
                              double hw, double sigma_guess) {
  std::size_t k_a = k_peak, k_b = k_peak;
  while (k_a > 0 && avg[k_a - 1] - floor_p > 3 * sd) --k_a;
  while (k_b + 1 < avg.size() && avg[k_b + 1] - floor_p > 3 * sd) ++k_b;
  if (k_b - k_a < 6) return NAN;
  constexpr std::size_t kSub = 4;     // model grid: 1/(4 fe)
  constexpr std::size_t kNu = 400;    // frequency points over the band (midpoint rule)
  constexpr std::size_t kSigmas = 81; // log grid sigma_guess / 8 .. 2 sigma_guess
  const double dt = 1.0 / (fe * static_cast<double>(kSub));
  // Onset t0 = t(k_peak) - s dt for s = 0 .. shifts: up to the lobe's start + 3 ms before the peak.
  const auto shifts = static_cast<std::size_t>(std::ceil((static_cast<double>(k_peak - k_a) / fe + 0.003) / dt));
  // Model times tau_j = (j - j0) dt, j0 = kSub (k_peak - k_a): data sample k at shift s reads
  // j = kSub (k - k_a) + s.
  const std::size_t n_j = kSub * (k_b - k_a) + shifts + 1;
  const double j0 = static_cast<double>(kSub * (k_peak - k_a));
  std::vector<std::complex<double>> rot(kNu), start(kNu);
  std::vector<double> nu(kNu);
  for (std::size_t n = 0; n < kNu; ++n) {
    nu[n] = -hw + (static_cast<double>(n) + 0.5) * 2 * hw / static_cast<double>(kNu);
    rot[n] = std::polar(1.0, 2 * kPi * nu[n] * dt);
    start[n] = std::polar(1.0, -2 * kPi * nu[n] * j0 * dt);
  }
  std::vector<std::complex<double>> phase(kNu * n_j);  // exp(i 2 pi nu_n tau_j), j-major
  for (std::size_t n = 0; n < kNu; ++n) {
    std::complex<double> ph = start[n];
    for (std::size_t j = 0; j < n_j; ++j) {
      phase[j * kNu + n] = ph;
      ph *= rot[n];
      if (j % 64 == 63) ph /= std::abs(ph);
    }
  }
  double e2 = 0;
  for (std::size_t k = k_a; k <= k_b; ++k) e2 += (avg[k] - floor_p) * (avg[k] - floor_p);
  std::vector<double> cost(kSigmas, INFINITY), sig(kSigmas);
  std::vector<std::complex<double>> c(kNu);
  std::vector<double> model(n_j), smooth(n_j);
  constexpr std::size_t kWidths = 6;  // onset scatter sd 0 .. 0.5 ms
  for (std::size_t i = 0; i < kSigmas; ++i) {
    sig[i] = sigma_guess / 8 * std::pow(16.0, static_cast<double>(i) / static_cast<double>(kSigmas - 1));
    for (std::size_t n = 0; n < kNu; ++n) c[n] = 1.0 / std::complex<double>(sig[i], 2 * kPi * nu[n]);
    for (std::size_t j = 0; j < n_j; ++j) {
      std::complex<double> y{0.0, 0.0};
      const std::complex<double>* ph = &phase[j * kNu];
      for (std::size_t n = 0; n < kNu; ++n) y += ph[n] * c[n];
      model[j] = std::norm(y);
    }
    for (std::size_t w = 0; w < kWidths; ++w) {
      // The onsets' scatter: the model averaged over a Gaussian of sd w x 0.1 ms.
      const double sd_t = 1e-4 * static_cast<double>(w);
      if (w == 0) {
        smooth = model;
      } else {
        const auto half = static_cast<std::ptrdiff_t>(std::ceil(3 * sd_t / dt));
        std::vector<double> g(static_cast<std::size_t>(2 * half + 1));
        for (std::ptrdiff_t q = -half; q <= half; ++q) g[static_cast<std::size_t>(q + half)] = std::exp(-0.5 * std::pow(static_cast<double>(q) * dt / sd_t, 2));
        for (std::size_t j = 0; j < n_j; ++j) {
          double acc = 0, ws = 0;
          for (std::ptrdiff_t q = -half; q <= half; ++q) {
            const std::ptrdiff_t jj = static_cast<std::ptrdiff_t>(j) + q;
            if (jj < 0 || jj >= static_cast<std::ptrdiff_t>(n_j)) continue;
            acc += g[static_cast<std::size_t>(q + half)] * model[static_cast<std::size_t>(jj)];
            ws += g[static_cast<std::size_t>(q + half)];
          }
          smooth[j] = acc / ws;
        }
      }
      for (std::size_t sft = 0; sft <= shifts; ++sft) {
        double em = 0, mm = 0;
        for (std::size_t k = k_a; k <= k_b; ++k) {
          const double m = smooth[kSub * (k - k_a) + sft];
          em += (avg[k] - floor_p) * m;
          mm += m * m;
        }
        if (mm > 0 && em > 0) cost[i] = std::min(cost[i], e2 - em * em / mm);
      }
    }
  }
  const auto best = static_cast<std::size_t>(std::min_element(cost.begin(), cost.end()) - cost.begin());
  if (best == 0 || best + 1 == kSigmas || !std::isfinite(cost[best])) return NAN;
  // Parabola through the three costs around the minimum, in log sigma (equal steps).
  const double a = cost[best - 1], b = cost[best], d = cost[best + 1];
  const double den = a - 2 * b + d;
  const double off = den > 0 ? std::clamp(0.5 * (a - d) / den, -0.5, 0.5) : 0.0;
  return sig[best] * std::pow(16.0, off / static_cast<double>(kSigmas - 1));
}

// Step 3 (header): zeta from the band power of f +- hw averaged over the impacts, minus its floor.
// NAN when the excess shows no decay.
double averaged_band_decay(const RecordSpectrum& spectrum, double f, double hw, double half_window_s,
                           std::span<const double> onset_s, double t_min, std::string& why) {
  // The envelope at ~fs / 2 at least: the decay may be far shorter than the window that detected it
  // (8 kHz, zeta 0.01: 1 ms power time constant, most significant at L = 11 ms).
  const double oversample = std::max(2.0, 0.25 * spectrum.sample_rate_hz() / hw);
  double fe = 0;
  const auto c = spectrum.envelope(f - hw, f + hw, oversample, fe);
  const auto before = static_cast<std::ptrdiff_t>(std::floor(0.45 * t_min * fe));
  const auto after = static_cast<std::ptrdiff_t>(std::floor(0.5 * t_min * fe));
  std::vector<double> avg(static_cast<std::size_t>(before + after), 0.0);
  std::size_t used = 0;
  for (double t : onset_s) {
    const auto k0 = static_cast<std::ptrdiff_t>(std::lround(t * fe)) - before;
    if (k0 < 0 || k0 + before + after > static_cast<std::ptrdiff_t>(c.size())) continue;
    for (std::size_t k = 0; k < avg.size(); ++k) avg[k] += std::norm(c[static_cast<std::size_t>(k0) + k]);
    ++used;
  }
  if (used < kMinImpacts) {
    why = "too few impacts inside the record for the band-power average";
    return NAN;
  }
  // Floor: the average before the onsets, clear of the E window and the band's rise (1/hw).
  const auto floor_end = before - static_cast<std::ptrdiff_t>(std::ceil((half_window_s + 1.0 / hw) * fe));
  if (floor_end < 8) {
    why = "no room before the impacts for the band power's floor";
    return NAN;
  }
  const std::vector<double> fl(avg.begin(), avg.begin() + floor_end);
  const double floor_p = std::accumulate(fl.begin(), fl.end(), 0.0) / static_cast<double>(fl.size());
  double var = 0;
  for (double v : fl) var += (v - floor_p) * (v - floor_p);
  const double sd = std::sqrt(var / static_cast<double>(fl.size() - 1));
  // Peak of the excess within the E window (onset +- L).
  const auto e_lo = static_cast<std::size_t>(before - static_cast<std::ptrdiff_t>(std::ceil(half_window_s * fe)));
  const auto e_hi = std::min(avg.size(), static_cast<std::size_t>(before + static_cast<std::ptrdiff_t>(std::ceil(half_window_s * fe))));
  const std::size_t k_peak = static_cast<std::size_t>(std::max_element(avg.begin() + static_cast<std::ptrdiff_t>(e_lo),
                                                                       avg.begin() + static_cast<std::ptrdiff_t>(e_hi)) - avg.begin());
  if (!(avg[k_peak] - floor_p > 5 * sd)) {
    why = "the band power averaged over the impacts rises only " + fmt((avg[k_peak] - floor_p) / sd) +
          " standard deviations of its floor (need > 5)";
    return NAN;
  }
  // Fit from a quarter of the band's rise time (1/hw) after the peak to where the excess falls to
  // 3 standard deviations of the floor.
  std::size_t k = k_peak + static_cast<std::size_t>(std::lround(0.25 / hw * fe));
  double sw = 0, st = 0, sy = 0, stt = 0, sty = 0;
  std::size_t points = 0;
  for (; k < avg.size(); ++k) {
    const double e = avg[k] - floor_p;
    if (!(e > 3 * sd)) break;
    const double t = static_cast<double>(k) / fe, y = std::log(e), wgt = e * e;
    sw += wgt;
    st += wgt * t;
    sy += wgt * y;
    stt += wgt * t * t;
    sty += wgt * t * y;
    ++points;
  }
  const double den = sw * stt - st * st;
  if (points < 4 || !(den > 0)) {
    why = "the averaged band power's decay spans " + std::to_string(points) + " envelope samples (need >= 4)";
    return NAN;
  }
  const double slope = (sw * sty - st * sy) / den;  // of ln(power): -2 sigma
  double sigma = -0.5 * slope;
  if (!(sigma > 0)) {
    why = "the averaged band power after the impacts does not decay";
    return NAN;
  }
  // A free decay starts at the impact: the excess before the peak (more than the band's rise time
  // 1/hw and 0.5 ms of onset scatter earlier) holds little of what the same span after it holds. A
  // line swept through the band by the speed variation (whose passages can form a "train") rises
  // as it falls and fails this.
  {
    const double span = std::min(1.5 / sigma, 0.4 * t_min);  // three power time constants 1/(2 sigma)
    const auto n_span = static_cast<std::size_t>(std::max(1.0, std::round(span * fe)));
    const auto lead = static_cast<std::size_t>(std::ceil((1.0 / hw + 0.0005) * fe));
    double after_sum = 0, before_sum = 0;
    for (std::size_t i = 0; i < n_span && k_peak + i < avg.size(); ++i) after_sum += avg[k_peak + i] - floor_p;
    for (std::size_t i = 0; i < n_span && k_peak >= lead + i + 1; ++i) before_sum += avg[k_peak - lead - 1 - i] - floor_p;
    if (!(before_sum < kMaxBeforeShare * after_sum)) {
      why = "the averaged band power at " + fmt(f, 5) + " Hz rises before the impacts as it falls after them (" +
            fmt(before_sum / after_sum) + " of the excess after the peak, need < " + fmt(kMaxBeforeShare) + "): not a free decay";
      return NAN;
    }
  }
  const double sigma_fit = fit_band_limited_decay(avg, floor_p, sd, fe, k_peak, hw, sigma);
  if (std::isfinite(sigma_fit)) sigma = sigma_fit;
  const double delta = sigma / f;  // logarithmic decrement per period (eq. 17)
  return delta / std::sqrt(4 * kPi * kPi + delta * delta);  // eq. 19
}

}  // namespace

double log_gamma_ratio_tail(std::size_t n, double r) {
  if (!(r >= 0) || n == 0) return 0.0;
  // X / (X + Y) ~ Beta(n, n); P(X / Y > r) = P(Beta < 1 / (1 + r)) = P(Binomial(2n - 1, p) >= n),
  // summed in logarithms (a strong mode's tail is far below the smallest double).
  const double p = 1.0 / (1.0 + r);
  if (p <= 0) return -INFINITY;
  const std::size_t trials = 2 * n - 1;
  const double lp = std::log(p), lq = std::log1p(-p);
  std::vector<double> terms;
  for (std::size_t j = n; j <= trials; ++j)
    terms.push_back(std::lgamma(static_cast<double>(trials) + 1) - std::lgamma(static_cast<double>(j) + 1) -
                    std::lgamma(static_cast<double>(trials - j) + 1) + static_cast<double>(j) * lp +
                    static_cast<double>(trials - j) * lq);
  const double top = *std::max_element(terms.begin(), terms.end());
  double sum = 0;
  for (double t : terms) sum += std::exp(t - top);
  return std::min(0.0, top + std::log(sum));
}

double gamma_ratio_tail(std::size_t n, double r) { return std::exp(log_gamma_ratio_tail(n, r)); }

AveragedMode identify_averaged_mode(const RecordSpectrum& spectrum, std::span<const double> onset_s,
                                    std::span<const double> previous_s, const AveragedModeSearch& opt) {
  AveragedMode res;
  const double fs = spectrum.sample_rate_hz();
  const double f_lo = std::max(opt.f_lo_hz, 1.0);
  const double f_hi = opt.f_hi_hz > 0 ? std::min(opt.f_hi_hz, 0.45 * fs) : 0.45 * fs;
  double t_min = INFINITY;
  for (std::size_t j = 0; j < onset_s.size() && j < previous_s.size(); ++j) t_min = std::min(t_min, onset_s[j] - previous_s[j]);
  if (onset_s.size() < kMinImpacts || !(t_min > 0) || !(f_hi > f_lo)) {
    res.why = "too few impacts to average (" + std::to_string(onset_s.size()) + ", need " + std::to_string(kMinImpacts) + ")";
    return res;
  }
  // Impacts closer than 20 ms leave windows (<= 1/6 of the interval) too short to tell a mode from a
  // mesh line swept by the speed variation (teeth x the rate lies within a few of their bins;
  // measured: a control without impacts, 119/s +-5 % wobble, 25 dB, "mode" at the 2618 Hz mesh line).
  if (t_min < kMinIntervalS) {
    res.why = "impacts " + fmt(t_min * 1e3) + " ms apart, under the " + fmt(kMinIntervalS * 1e3) + " ms the averaging needs";
    return res;
  }
  // The searched range's analytic envelope, shifted down by its first bin (band_envelope.cpp).
  double fe = 0;
  const auto c = spectrum.envelope(f_lo, f_hi, 2.0, fe);
  if (c.empty()) {
    res.why = "the searched range holds no bin";
    return res;
  }
  const double f_shift = std::ceil(f_lo / spectrum.bin_hz()) * spectrum.bin_hz();
  // Half-lengths: R (2L) + gap + half of E (L) within the second half of the shortest interval.
  struct Try {
    std::size_t n_w = 0, n = 0, k = 0;
    double ratio = NAN, log_p = INFINITY;
    std::vector<double> pe, pr;
  };
  std::vector<Try> tries;
  for (std::size_t n_w = kMinWindow; n_w <= kMaxWindow; n_w *= 2) {
    if (1.5 * static_cast<double>(n_w) / fe + kGapS > 0.5 * t_min) break;
    Try t;
    t.n_w = n_w;
    t.n = averaged_spectra(c, fe, onset_s, n_w, t.pe, t.pr);
    if (t.n < kMinImpacts) continue;
    const double df = fe / static_cast<double>(kPad * n_w);
    const auto k_hi = std::min(t.pe.size() / 2, static_cast<std::size_t>(std::floor((f_hi - f_shift) / df)));
    // At least kMinCycles periods in the window: with fewer, a line's windowed power depends on its
    // phase at the window (its negative-frequency image overlaps), and mesh lines are locked to the
    // shaft angle as the impacts are, so E and R differ systematically (measured: a 110/220 Hz mesh
    // pair read 11.6x at 257 Hz with 5.5 ms windows, 8 kHz mode, 5/s).
    const double f_min_w = std::max(f_lo, kMinCycles * fe / static_cast<double>(n_w));
    const auto k_lo = static_cast<std::size_t>(std::max(1.0, std::ceil((f_min_w - f_shift) / df)));
    for (std::size_t k = k_lo; k + 1 <= k_hi; ++k)
      if (t.pr[k] > 0 && !(t.pe[k] / t.pr[k] <= t.ratio)) {
        t.ratio = t.pe[k] / t.pr[k];
        t.k = k;
      }
    if (t.k == 0) continue;
    t.log_p = log_gamma_ratio_tail(t.n, t.ratio);
    // Independent Hann bins in the searched range (spacing fe / n_w), twice for maxima between them.
    res.tests += 2 * static_cast<std::size_t>(std::ceil((f_hi - f_lo) * static_cast<double>(n_w) / fe));
    tries.push_back(std::move(t));
  }
  if (tries.empty()) {
    res.why = "no averaging window fits between the impacts (" + fmt(t_min * 1e3) + " ms apart)";
    return res;
  }
  const Try& best = *std::min_element(tries.begin(), tries.end(), [](const Try& a, const Try& b) { return a.log_p < b.log_p; });
  const double p_needed = opt.false_alarm / static_cast<double>(res.tests);
  res.half_window_s = 0.5 * static_cast<double>(best.n_w) / fe;
  res.impacts = best.n;
  res.ratio = best.ratio;
  res.ratio_needed = ratio_for_tail(best.n, p_needed);
  // f from the longest window whose peak passes the test (the best one's when none does): the
  // decay's abrupt start gives its spectrum a tail on both sides of 0 Hz, and the negative
  // frequency's tail tilts the positive peak by a factor ~(1 -+ (f' - f) / f) (the sign from the
  // start's phase), which moves the centroid by ~w^2 / (3 f) for a peak of half-width w; a long
  // window narrows w to the decay's own zeta f (measured, 2500 Hz zeta 0.05 at 10 dB from the true
  // onsets: 2301, 2433, 2472, 2490, 2495 Hz for 2L = 32 .. 512 envelope samples at 23 kHz).
  const Try* for_f = &best;
  for (const Try& t : tries)
    if (t.ratio >= ratio_for_tail(t.n, p_needed) && t.n_w > for_f->n_w) for_f = &t;
  const std::vector<double>& pe = for_f->pe;
  const std::vector<double>& pr = for_f->pr;
  const double df = fe / static_cast<double>(kPad * for_f->n_w);
  double half_width = 0;
  const double f = f_shift + peak_frequency(pe, pr, for_f->k, df, half_width);
  res.f_hz = f;
  if (!(res.ratio >= res.ratio_needed)) {
    res.why = "the power after the impacts, averaged over " + std::to_string(best.n) + ", stands at most " + fmt(res.ratio) +
              "x the power before them (at " + fmt(f, 5) + " Hz; need " + fmt(res.ratio_needed) + "x for a false-alarm probability " +
              fmt(opt.false_alarm) + " over " + std::to_string(res.tests) + " tests)";
    return res;
  }
  // Stationary lines in P_R within f/2 .. 2f: a line within the main lobe (2 Hann bins, 2 fe / n_w)
  // biases the peak; farther ones narrow the band of step 3.
  // The band of step 3: three half-widths of the averaged peak (the decay's zeta f, broadened by the
  // window), so that the band's own response (~1/hw) is shorter than the decay; 3-15 % of f.
  double hw = std::clamp(3 * half_width, 0.03 * f, 0.15 * f);
  {
    auto bin_of = [&](double hz) { return static_cast<std::size_t>(std::clamp((hz - f_shift) / df, 1.0, static_cast<double>(pr.size() / 2 - 1))); };
    const std::size_t j_lo = bin_of(0.5 * f), j_hi = bin_of(2 * f);
    const double floor_r = median(std::vector<double>(pr.begin() + static_cast<std::ptrdiff_t>(j_lo), pr.begin() + static_cast<std::ptrdiff_t>(j_hi) + 1));
    const double lobe_hz = 2 * fe / static_cast<double>(for_f->n_w);
    for (std::size_t j = j_lo; j <= j_hi; ++j) {
      if (!(pr[j] > pr[j - 1] && pr[j] >= pr[j + 1] && pr[j] >= kLineOverFloor * floor_r && pe[j] < kLineRatio * pr[j])) continue;
      const double fl = f_shift + static_cast<double>(j) * df;
      // Within +-15 % (the detector band) too: a line swept by the speed variation sits elsewhere in R
      // than in E, and its passages read as a huge ratio (control seed 1019: 4800x at 2628 Hz).
      if (std::fabs(fl - f) <= std::max(lobe_hz, 0.15 * f)) {
        res.why = "a stationary line at " + fmt(fl, 5) + " Hz lies within the averaged peak at " + fmt(f, 5) +
                  " Hz (its frequency would be biased)";
        return res;
      }
      hw = std::min(hw, 0.5 * std::fabs(fl - f));
    }
  }
  hw = std::max(hw, 0.01 * f);
  res.zeta = averaged_band_decay(spectrum, f, hw, res.half_window_s, onset_s, t_min, res.why);
  res.found = std::isfinite(res.zeta);
  return res;
}

}  // namespace ridgewatch::survey
