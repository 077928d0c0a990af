#include "core/dsp/modes.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <numbers>
#include <stdexcept>
#include <string>

#include <fftw3.h>
#include <mutex>

#include "core/dsp/cross_check.hpp"
#include "core/dsp/fftw_planner.hpp"
#include "core/dsp/ml_fit.hpp"
#include "core/dsp/morlet_cwt.hpp"

namespace ridgewatch::dsp {

namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;
// Detection resolutions eta0 = 7 (the paper's) up to 1000 (relative filter sd 14 % .. 0.1 %). The
// time-mean of |W|^2 of a row is, by Parseval, the periodogram weighted by the filter's power response,
// so the spectra come from one FFT; a CWT (eta0 = 7, 8 voices per octave) is needed only for the noise
// floor (each row's |W|^2 in time). A resolution is used only where its filter's standard deviation
// f / eta0 spans at least 1.5 periodogram resolutions 1 / T.
constexpr double kFloorEta0 = 7.0;
constexpr std::size_t kFloorVoices = 8;
constexpr double kDetectFineEta0[] = {7.0, 20.0, 50.0, 150.0, 250.0, 400.0, 650.0, 1000.0};
constexpr double kMaxEta0 = 1000.0;  // the estimation's limit (MorletCwtConfig::fine_resolution)
// A backbone whose precise points scatter more than this (relative sd) with no amplitude law
// explaining it marks the mode not ok (check_backbone_variation).
constexpr double kMaxUnexplainedScatter = 0.25;
constexpr std::size_t kMaxJointModes = 8;   // above: the maximum-likelihood fit runs in groups of neighbours
constexpr std::size_t kMaxHiddenModes = 4;  // modes the residual rescan may add

struct Peak {
  double f_hz = 0.0;
  double level = 0.0;  // energy spectrum over the floor (linear)
  double eta0 = 0.0;
};

struct LevelScan {
  double eta0 = 0.0;
  std::vector<double> freqs, profile, floor;  // profile and floor per column (white-noise units)
};

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return NAN;
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

// One detection resolution over [f_lo, f_hi]: energy spectrum (time-mean |W|^2 over the row's white-
// noise gain, i.e. in units of a white noise variance) and the noise floor in the same units.
LevelScan scan_level(std::span<const double> x, double fs, double eta0, double f_lo, double f_hi,
                     std::size_t voices, double edge_widths) {
  LevelScan lv;
  lv.eta0 = eta0;
  const double duration = static_cast<double>(x.size()) / fs;
  // The kernel (time sd eta0 / (2 pi f)) must fit the record 16 times (edges plus a window).
  const double lo = std::max(f_lo, 16.0 * eta0 / (kTwoPi * duration));
  if (!(lo * 1.1 < f_hi)) return lv;
  // At least 1.5 rows per filter standard deviation (f / eta0) so that peaks are sampled.
  const auto v = std::max<std::size_t>(voices, static_cast<std::size_t>(std::ceil(1.5 * eta0 * std::numbers::ln2)));
  const auto rows = static_cast<std::size_t>(std::ceil(std::log2(f_hi / lo) * static_cast<double>(v))) + 1;
  MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.eta0 = eta0;
  cfg.frequencies_hz = make_frequency_grid(lo, f_hi, rows, GridSpacing::log);
  cfg.max_samples = x.size();
  MorletCwt<double> cwt(cfg);
  cwt.load(x);
  std::vector<std::complex<double>> w(cwt.columns());
  std::vector<double> noise(rows);
  lv.freqs = cfg.frequencies_hz;
  lv.profile.resize(rows);
  for (std::size_t r = 0; r < rows; ++r) {
    cwt.row_at(r, w);
    const double gain = cwt.noise_gain(lv.freqs[r]);
    double e = 0.0;
    for (const auto& c : w) e += std::norm(c);
    lv.profile[r] = e / static_cast<double>(w.size()) / gain;
    const auto edge = static_cast<std::size_t>(std::ceil(edge_widths * MorletCwt<double>::kernel_time_sd_s(eta0, lv.freqs[r]) / cwt.time_step_s()));
    const std::span<const std::complex<double>> all(w);
    noise[r] = (w.size() > 2 * edge + 16 ? estimate_row_noise_power(all.subspan(edge, w.size() - 2 * edge))
                                         : estimate_row_noise_power(all)) / gain;
  }
  // Floor: 25 % quantile of the rows' noise within +-1 octave. A mode that outlasts the record raises
  // its own rows' lower quartile, but covers far less than 3/4 of two octaves at eta0 >= 7.
  lv.floor.resize(rows);
  std::size_t a = 0, b = 0;
  for (std::size_t r = 0; r < rows; ++r) {
    while (lv.freqs[a] < lv.freqs[r] * 0.5) ++a;
    while (b + 1 < rows && lv.freqs[b + 1] <= lv.freqs[r] * 2.0) ++b;
    lv.floor[r] = quantile(std::vector<double>(noise.begin() + static_cast<std::ptrdiff_t>(a), noise.begin() + static_cast<std::ptrdiff_t>(b + 1)), 0.25);
  }
  return lv;
}

// Local maxima of the energy spectrum that stand min_ratio above the floor and fall to half their
// value within 3 filter standard deviations (3 / eta0 in ln f) on both sides (not a ripple on a
// neighbour's flank). Sub-row position by a parabola in (ln f, ln profile).
void find_peaks(const LevelScan& lv, double min_ratio, std::vector<Peak>& out) {
  const auto& p = lv.profile;
  const std::size_t rows = p.size();
  if (rows < 3) return;
  const double dlnf = std::log(lv.freqs[1] / lv.freqs[0]);
  const auto reach = std::max<std::size_t>(2, static_cast<std::size_t>(std::ceil(3.0 / lv.eta0 / dlnf)));
  for (std::size_t r = 1; r + 1 < rows; ++r) {
    if (!(p[r] > p[r - 1] && p[r] >= p[r + 1])) continue;
    if (!(lv.floor[r] > 0) || p[r] < lv.floor[r] * min_ratio) continue;
    const std::size_t lo = r > reach ? r - reach : 0;
    const std::size_t hi = std::min(rows - 1, r + reach);
    const double left_min = *std::min_element(p.begin() + static_cast<std::ptrdiff_t>(lo), p.begin() + static_cast<std::ptrdiff_t>(r));
    const double right_min = *std::min_element(p.begin() + static_cast<std::ptrdiff_t>(r + 1), p.begin() + static_cast<std::ptrdiff_t>(hi + 1));
    // At the ends of the scanned band a side may be cut short: only the side that exists must dip.
    const bool left_ok = p[r] >= 2.0 * left_min || r < reach;
    const bool right_ok = p[r] >= 2.0 * right_min || r + reach >= rows;
    if (!left_ok || !right_ok) continue;
    if (r < reach && r + reach >= rows) continue;
    const double y0 = std::log(p[r - 1]), y1 = std::log(p[r]), y2 = std::log(p[r + 1]);
    const double denom = y0 - 2.0 * y1 + y2;
    double offset = denom < 0 ? 0.5 * (y0 - y2) / denom : 0.0;
    offset = std::clamp(offset, -0.5, 0.5);
    out.push_back({lv.freqs[r] * std::exp(offset * dlnf), p[r] / lv.floor[r], lv.eta0});
  }
}

// Periodogram P_k = |X_k|^2 / n of x zero-padded to length >= 2 n (k = 0 .. L/2, bin width fs / L): for
// white noise of variance v, E P_k = v (the white-noise units of the scans).
std::vector<double> periodogram(std::span<const double> x, double fs, double& df_hz) {
  std::size_t len = 1;
  while (len < 2 * x.size()) len <<= 1;
  std::vector<double> in(len, 0.0);
  std::copy(x.begin(), x.end(), in.begin());
  std::vector<std::complex<double>> out(len / 2 + 1);
  fftw_plan plan;
  {
    const std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    plan = fftw_plan_dft_r2c_1d(static_cast<int>(len), in.data(), reinterpret_cast<fftw_complex*>(out.data()), FFTW_ESTIMATE);
  }
  fftw_execute(plan);
  {
    const std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    fftw_destroy_plan(plan);
  }
  std::vector<double> p(out.size());
  for (std::size_t k = 0; k < out.size(); ++k) p[k] = std::norm(out[k]) / static_cast<double>(x.size());
  df_hz = fs / static_cast<double>(len);
  return p;
}

double floor_at(const LevelScan& lv, double f);

// A fine detection resolution from the periodogram: row f is the mean of P weighted by the analysing
// filter's power response 4 exp(-eta0^2 (nu / f - 1)^2) (morlet_cwt.hpp). Floor from the CWT scan.
LevelScan smoothed_level(const std::vector<double>& pg, double df, double eta0, double f_lo, double f_hi,
                         double duration, const LevelScan& base, std::size_t voices) {
  LevelScan lv;
  lv.eta0 = eta0;
  // The filter's standard deviation f / eta0 must span at least 1.5 periodogram resolutions 1 / T.
  const double lo = std::max(f_lo, 1.5 * eta0 / duration);
  if (!(lo * 1.1 < f_hi) || base.freqs.empty()) return lv;
  // At least 1.5 rows per filter standard deviation, and at least `voices` per octave.
  const double dlnf = std::min(1.0 / (1.5 * eta0), std::numbers::ln2 / static_cast<double>(voices));
  const auto rows = static_cast<std::size_t>(std::ceil(std::log(f_hi / lo) / dlnf)) + 1;
  lv.freqs = make_frequency_grid(lo, f_hi, rows, GridSpacing::log);
  lv.profile.resize(rows);
  lv.floor.resize(rows);
  for (std::size_t r = 0; r < rows; ++r) {
    const double f = lv.freqs[r];
    const double reach = 5.0 * f / eta0;
    const auto k0 = static_cast<std::size_t>(std::max(1.0, std::floor((f - reach) / df)));
    const auto k1 = std::min(pg.size() - 1, static_cast<std::size_t>(std::ceil((f + reach) / df)));
    double sw = 0.0, swp = 0.0;
    for (std::size_t k = k0; k <= k1; ++k) {
      const double u = eta0 * (static_cast<double>(k) * df / f - 1.0);
      const double wk = std::exp(-u * u);
      sw += wk;
      swp += wk * pg[k];
    }
    lv.profile[r] = sw > 0 ? swp / sw : 0.0;
    lv.floor[r] = floor_at(base, f);
  }
  return lv;
}

// Floor (white-noise variance units) at f from the widest-range scan, interpolated in ln f.
double floor_at(const LevelScan& lv, double f) {
  if (lv.freqs.empty()) return NAN;
  if (f <= lv.freqs.front()) return lv.floor.front();
  if (f >= lv.freqs.back()) return lv.floor.back();
  const auto it = std::upper_bound(lv.freqs.begin(), lv.freqs.end(), f);
  const std::size_t i = static_cast<std::size_t>(it - lv.freqs.begin());
  const double t = std::log(f / lv.freqs[i - 1]) / std::log(lv.freqs[i] / lv.freqs[i - 1]);
  return lv.floor[i - 1] * std::pow(lv.floor[i] / lv.floor[i - 1], t);
}

// Envelope estimates of one mode on one signal at one eta0.
struct EnvelopeResult {
  DampingEstimate two_point, ridge_ls;
  double f_d = NAN, f_sd = NAN;
  double f_first = NAN, f_first_sd = NAN, f_second = NAN, f_second_sd = NAN;  // phase slope per half window
  Backbone backbone;
  std::vector<std::complex<double>> row;
  EnvelopeWindow window;
  double time_step_s = 0.0;
};

EnvelopeResult estimate_envelope(std::span<const double> x, double fs, double eta0, double f_peak, double floor_white,
                                 const ModeSearchOptions& opt, const EnvelopeOptions& env) {
  EnvelopeResult out;
  MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.eta0 = eta0;
  cfg.fine_resolution = true;
  cfg.frequencies_hz = {f_peak};
  cfg.max_samples = x.size();
  MorletCwt<double> cwt(cfg);
  cwt.load(x);
  out.row.resize(cwt.columns());
  out.time_step_s = cwt.time_step_s();
  auto noise_of = [&](double f) {
    const auto edge = static_cast<std::size_t>(std::ceil(env.edge_widths * MorletCwt<double>::kernel_time_sd_s(eta0, f) / cwt.time_step_s()));
    const std::span<const std::complex<double>> all(out.row);
    const double own = out.row.size() > 2 * edge + 16 ? estimate_row_noise_power(all.subspan(edge, out.row.size() - 2 * edge))
                                                      : estimate_row_noise_power(all);
    const double white = floor_white * cwt.noise_gain(f);
    return std::isfinite(white) && white > 0 ? std::min(own, white) : own;
  };
  cwt.row(f_peak, out.row);
  EnvelopeRow row{out.row, cwt.time_step_s(), f_peak, eta0, noise_of(f_peak)};
  EnvelopeWindow win = choose_window(row, env);
  double f_sd = NAN;
  double f_d = phase_slope_frequency(row, win, f_sd);
  if (!std::isfinite(f_d) || std::abs(f_d / f_peak - 1.0) > 3.0 / eta0) f_d = f_peak;
  // Envelope at the damped frequency itself (Eq. 12 at omega = omega_d).
  cwt.row(f_d, out.row);
  row.f_row_hz = f_d;
  row.noise_power = noise_of(f_d);
  win = choose_window(row, env);
  out.f_d = f_d;
  out.f_sd = f_sd;
  out.two_point = estimate_two_point(row, win, f_d);
  out.ridge_ls = estimate_ridge_ls(row, win, f_d);
  out.ridge_ls.f_sd_hz = f_sd;
  out.two_point.f_sd_hz = f_sd;
  if (win.end > win.start + 8) {
    EnvelopeWindow half = win;
    half.end = win.start + (win.end - win.start) / 2;
    out.f_first = phase_slope_frequency(row, half, out.f_first_sd);
    half.start = half.end;
    half.end = win.end;
    out.f_second = phase_slope_frequency(row, half, out.f_second_sd);
  }
  out.backbone = estimate_backbone(row, win, f_d, opt.backbone);
  out.window = win;
  return out;
}

void null_values(DampingEstimate& e) {
  e.zeta = e.zeta_sd = e.zeta_ci95_lo = e.zeta_ci95_hi = NAN;
}

void add_note(std::string& note, const std::string& text) {
  if (note.find(text) != std::string::npos) return;
  if (!note.empty()) note += "; ";
  note += text;
}

// Impossible values become null with a status that says so; a frequency outside the band is not ok.
void sanitize(DampingEstimate& e, double f_lo, double f_hi, std::string& note) {
  if (std::isfinite(e.zeta) && !(e.zeta > 0)) {
    null_values(e);
    e.status = EstimateStatus::not_decaying;
    add_note(note, std::string(to_string(e.method)) + ": zeta <= 0 (not decaying)");
  } else if (std::isfinite(e.zeta) && !(e.zeta < 1)) {
    null_values(e);
    e.status = EstimateStatus::fit_failed;
    add_note(note, std::string(to_string(e.method)) + ": zeta >= 1 (not an oscillating mode)");
  }
  if (!std::isfinite(e.f_hz) || !(e.f_hz > 0)) {
    e.f_hz = e.f_sd_hz = NAN;
    if (e.status == EstimateStatus::ok) e.status = EstimateStatus::fit_failed;
  } else if (e.status == EstimateStatus::ok && (e.f_hz < f_lo || e.f_hz > f_hi)) {
    e.status = EstimateStatus::inconsistent;
    add_note(note, std::string(to_string(e.method)) + ": frequency outside the band");
  }
  if (std::isfinite(e.zeta) && !(e.zeta_sd >= 0)) e.zeta_sd = e.zeta_ci95_lo = e.zeta_ci95_hi = NAN;
  if (e.status == EstimateStatus::ok && !(std::isfinite(e.zeta) && std::isfinite(e.zeta_sd))) e.status = EstimateStatus::fit_failed;
}

// Cross-check of two estimates of one mode: 3.5 (ln zeta) and 4 (f) combined standard uncertainties, with
// a 1 % (zeta) and 1e-4 (f) allowance for the envelope method's small deterministic biases (interference
// of neighbouring modes), which matter only when noise is negligible. No further room is given when zeta
// varies along the decay: the estimators then weight the decay differently and report different
// averages, and neither is "the" zeta (the backbone is; the note says so). A wider allowance let a
// single ridge over an unresolved pair pass as `ok` with zeta 17 % off (tests/test_modes_property.cpp).
// The rule is shared with the impact analyzer (core/dsp/cross_check.hpp), each with its own limits.
bool agree(const DampingEstimate& a, const DampingEstimate& b) { return estimates_agree(a, b, kModesRule); }

std::string fmt_g(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", v);
  return buf;
}

// Time-domain least squares of the complex amplitudes of given damped modes (f, zeta) over x[0, n):
// x[k] ~ sum_j Re(C_j exp((-sigma_j + i omega_j) k / fs)). Returns C_j (NaN when degenerate).
std::vector<std::complex<double>> mode_amplitudes(std::span<const double> x, double fs,
                                                  const std::vector<std::pair<double, double>>& f_zeta) {
  const std::size_t m = f_zeta.size(), p = 2 * m;
  std::vector<std::complex<double>> c(m, {NAN, NAN});
  if (m == 0) return c;
  std::vector<double> ata(p * p, 0.0), atb(p, 0.0), col(p);
  std::vector<std::complex<double>> z(m), zn(m, 1.0);
  for (std::size_t j = 0; j < m; ++j) {
    const double om = kTwoPi * f_zeta[j].first;
    const double sg = decay_from_zeta(f_zeta[j].second, om);
    z[j] = std::exp(std::complex<double>(-sg, om) / fs);
  }
  for (std::size_t k = 0; k < x.size(); ++k) {
    for (std::size_t j = 0; j < m; ++j) {
      col[2 * j] = zn[j].real();       // Re C
      col[2 * j + 1] = -zn[j].imag();  // Im C
      zn[j] *= z[j];
    }
    for (std::size_t a = 0; a < p; ++a) {
      atb[a] += col[a] * x[k];
      for (std::size_t b = a; b < p; ++b) ata[a * p + b] += col[a] * col[b];
    }
  }
  for (std::size_t a = 0; a < p; ++a)
    for (std::size_t b = 0; b < a; ++b) ata[a * p + b] = ata[b * p + a];
  // Cholesky solve.
  std::vector<double> l(p * p, 0.0);
  for (std::size_t i = 0; i < p; ++i) {
    for (std::size_t j = 0; j <= i; ++j) {
      double s = ata[i * p + j];
      for (std::size_t k = 0; k < j; ++k) s -= l[i * p + k] * l[j * p + k];
      if (i == j) {
        if (!(s > 1e-12 * ata[i * p + i])) return c;
        l[i * p + i] = std::sqrt(s);
      } else {
        l[i * p + j] = s / l[j * p + j];
      }
    }
  }
  std::vector<double> y(p), sol(p);
  for (std::size_t i = 0; i < p; ++i) {
    double s = atb[i];
    for (std::size_t k = 0; k < i; ++k) s -= l[i * p + k] * y[k];
    y[i] = s / l[i * p + i];
  }
  for (std::size_t i = p; i-- > 0;) {
    double s = y[i];
    for (std::size_t k = i + 1; k < p; ++k) s -= l[k * p + i] * sol[k];
    sol[i] = s / l[i * p + i];
  }
  for (std::size_t j = 0; j < m; ++j) c[j] = {sol[2 * j], sol[2 * j + 1]};
  return c;
}


// ---- The steps of identify_modes, in the order it runs them.

// The analysed part of the record and the quantities every step reads.
struct Record {
  std::span<const double> signal;  // the analysed part: the record up to end_s
  double fs = 0.0;                 // sample rate, Hz
  std::size_t n = 0;               // samples in signal
  std::size_t n0 = 0;              // the onset's sample
  double duration_s = 0.0;         // n / fs
  double after_s = 0.0;            // (n - n0) / fs: the free response's length
  double f_auto_min_hz = 0.0;      // the usable band [f_auto_min_hz, f_auto_max_hz]
  double f_auto_max_hz = 0.0;
};

void check_options(std::span<const double> signal_in, double fs, const ModeSearchOptions& opt) {
  if (signal_in.size() < 64) throw std::invalid_argument("signal too short for mode identification (" + std::to_string(signal_in.size()) + " samples, need >= 64)");
  if (!(fs > 0) || !std::isfinite(fs)) throw std::invalid_argument("sample rate must be > 0");
  if (opt.max_modes < 1) throw std::invalid_argument("max_modes must be >= 1");
  if (opt.voices_per_octave < 4 || opt.voices_per_octave > 256)
    throw std::invalid_argument("voices_per_octave must be in [4, 256]");
  if (opt.eta0 > 0 && !(opt.eta0 >= 5.0 && opt.eta0 <= kMaxEta0)) throw std::invalid_argument("eta0 must be in [5, 1000]");
}

// The analysed part (up to end_s), the band and the onset; sets result's end_s, f_min_hz, f_max_hz and
// onset_s. Throws std::invalid_argument when they leave too little to analyse or an empty band.
Record analysed_part(std::span<const double> signal_in, double fs, const ModeSearchOptions& opt, ModeSearchResult& result) {
  Record rec;
  rec.fs = fs;
  std::size_t n = signal_in.size();
  if (opt.end_s > 0) {
    const auto n_end = static_cast<std::size_t>(std::llround(opt.end_s * fs));
    if (n_end < 64) throw std::invalid_argument("end leaves fewer than 64 samples to analyse");
    n = std::min(n, n_end);
  }
  rec.n = n;
  rec.signal = signal_in.subspan(0, n);
  result.end_s = static_cast<double>(n) / fs;
  rec.duration_s = static_cast<double>(n) / fs;

  // Lowest useful frequency: the eta0 = 7 kernel must fit 16 times in the record.
  rec.f_auto_min_hz = std::max(20.0, 16.0 * 7.0 / (kTwoPi * rec.duration_s));
  rec.f_auto_max_hz = 0.45 * fs;
  result.f_min_hz = opt.f_min_hz > 0 ? opt.f_min_hz : rec.f_auto_min_hz;
  result.f_max_hz = opt.f_max_hz > 0 ? opt.f_max_hz : rec.f_auto_max_hz;
  if (!(result.f_max_hz < fs / 2))
    throw std::invalid_argument("f_max " + std::to_string(result.f_max_hz) + " Hz must be below half the sample rate (" + std::to_string(fs / 2) + " Hz)");
  if (!(result.f_min_hz < result.f_max_hz))
    throw std::invalid_argument("f_min " + std::to_string(result.f_min_hz) + " Hz must be below f_max " + std::to_string(result.f_max_hz) + " Hz");

  // Onset: given, or the first sample reaching half the peak magnitude.
  if (opt.onset_s >= 0) {
    result.onset_s = opt.onset_s;
  } else {
    double peak = 0.0;
    for (double v : rec.signal) peak = std::max(peak, std::abs(v));
    std::size_t i = 0;
    while (i < n && std::abs(rec.signal[i]) < 0.5 * peak) ++i;
    result.onset_s = static_cast<double>(std::min(i, n - 1)) / fs;
  }
  rec.n0 = static_cast<std::size_t>(std::llround(result.onset_s * fs));
  if (rec.n0 + 32 >= n) throw std::invalid_argument("onset leaves fewer than 32 samples to analyse");
  rec.after_s = static_cast<double>(n - rec.n0) / fs;
  return rec;
}

// Step 1's result: the noise floor's scan and every detected peak (sorted by frequency).
struct Detection {
  LevelScan base;           // the eta0 = 7 CWT scan: the noise floor at every frequency
  std::vector<Peak> peaks;  // every peak, also outside the band
  double min_ratio = 0.0;   // min_peak_snr_db as a power ratio
};

// 1. Detection over the whole usable band (and the user's, if wider), at every resolution; sets
// result's peaks and noise_sd.
Detection detect_peaks(const Record& rec, const ModeSearchOptions& opt, ModeSearchResult& result) {
  Detection det;
  const double det_lo = std::min(result.f_min_hz, rec.f_auto_min_hz);
  const double det_hi = std::max(result.f_max_hz, rec.f_auto_max_hz);
  std::vector<LevelScan> levels;
  det.min_ratio = std::pow(10.0, opt.min_peak_snr_db / 10.0);
  det.base = scan_level(rec.signal, rec.fs, kFloorEta0, det_lo, det_hi, kFloorVoices, opt.envelope.edge_widths);
  {
    double df = 0.0;
    const std::vector<double> pg = periodogram(rec.signal, rec.fs, df);
    for (double eta0 : kDetectFineEta0)
      levels.push_back(smoothed_level(pg, df, eta0, det_lo, det_hi, rec.duration_s, det.base, opt.voices_per_octave));
  }
  std::vector<Peak>& peaks = det.peaks;
  for (auto it = levels.rbegin(); it != levels.rend(); ++it) {  // finest first
    std::vector<Peak> found;
    find_peaks(*it, det.min_ratio, found);
    for (const Peak& p : found) {
      // The same mode as a peak a finer resolution found within 2 of this filter's standard deviations.
      bool dup = false;
      for (const Peak& q : peaks) dup = dup || std::abs(std::log(q.f_hz / p.f_hz)) < 2.0 / it->eta0;
      if (!dup) peaks.push_back(p);
    }
  }
  std::sort(peaks.begin(), peaks.end(), [](const Peak& a, const Peak& b) { return a.f_hz < b.f_hz; });
  for (const Peak& p : peaks) result.peaks.push_back({p.f_hz, 10.0 * std::log10(p.level), p.eta0});
  // Noise: the floor over the band, as the standard deviation of white noise with that density.
  std::vector<double> fl;
  for (std::size_t r = 0; r < det.base.freqs.size(); ++r)
    if (det.base.freqs[r] >= result.f_min_hz && det.base.freqs[r] <= result.f_max_hz) fl.push_back(det.base.floor[r]);
  if (fl.empty()) fl.push_back(floor_at(det.base, std::sqrt(result.f_min_hz * result.f_max_hz)));
  result.noise_sd = std::sqrt(std::max(0.0, quantile(fl, 0.5)));
  return det;
}

// In-band peaks, the strongest max_modes of them, sorted by frequency.
std::vector<Peak> strongest_in_band(const std::vector<Peak>& peaks, const ModeSearchResult& result, std::size_t max_modes) {
  std::vector<Peak> cand;
  for (const Peak& p : peaks)
    if (p.f_hz >= result.f_min_hz && p.f_hz <= result.f_max_hz) cand.push_back(p);
  std::sort(cand.begin(), cand.end(), [](const Peak& a, const Peak& b) { return a.level > b.level; });
  if (cand.size() > max_modes) cand.resize(max_modes);
  std::sort(cand.begin(), cand.end(), [](const Peak& a, const Peak& b) { return a.f_hz < b.f_hz; });
  return cand;
}

// One candidate mode through steps 2-4.
struct Work {
  IdentifiedMode mode;
  Peak peak;
  EnvelopeResult envr;
  std::vector<std::size_t> unresolved;  // indices into the analysed modes of neighbours closer than eta0 separates
  bool user_eta0_failed = false;        // the user's eta0 gave no envelope estimate (read at the automatic one)
};

// x[t] for t in [n0, n) minus the damped mode C z^(t - n0), z = exp((-sigma + i omega) / fs).
void subtract_mode(std::vector<double>& x, std::size_t n0, std::size_t n, double fs, std::complex<double> c,
                   const std::pair<double, double>& f_zeta) {
  const double om = kTwoPi * f_zeta.first, sg = decay_from_zeta(f_zeta.second, om);
  const std::complex<double> z = std::exp(std::complex<double>(-sg, om) / fs);
  std::complex<double> zn = c;
  for (std::size_t t = n0; t < n; ++t) {
    x[t] -= zn.real();
    zn *= z;
  }
}

// Joint maximum-likelihood fit of all guesses (ml_fit.hpp), in groups of neighbours when there are
// many. A group whose fit throws keeps the default estimates (status fit_failed).
MlFitResult fit_joint(SpectralModeFitter& fitter, std::span<const double> seg, const std::vector<ModeGuess>& guesses,
                      const MlFitOptions& ml_opt) {
  MlFitResult ml;
  ml.modes.assign(guesses.size(), DampingEstimate{});
  for (auto& e : ml.modes) e.method = DampingMethod::ml;
  if (guesses.size() <= kMaxJointModes) {
    try {
      ml = fitter.fit(seg, guesses, ml_opt);
    } catch (const std::exception&) {
    }
    return ml;
  }
  // Many modes (real structures): the joint fit's cost grows with the cube of the parameters, so
  // modes are fitted in groups of neighbours (consecutive modes less than 15 % apart), each over
  // its own band (10 half-power bandwidths or 5 % beyond its outer modes); the residual terms take
  // the tails of the other groups.
  std::size_t g0 = 0;
  while (g0 < guesses.size()) {
    std::size_t g1 = g0 + 1;
    while (g1 < guesses.size() && guesses[g1].f_hz < 1.15 * guesses[g1 - 1].f_hz && g1 - g0 < kMaxJointModes) ++g1;
    MlFitOptions grp = ml_opt;
    const ModeGuess& lo = guesses[g0];
    const ModeGuess& hi = guesses[g1 - 1];
    grp.f_lo_hz = std::max(ml_opt.f_lo_hz, lo.f_hz * (1.0 - std::max(0.05, 10.0 * lo.zeta)));
    grp.f_hi_hz = std::min(ml_opt.f_hi_hz, hi.f_hz * (1.0 + std::max(0.05, 10.0 * hi.zeta)));
    try {
      const MlFitResult part = fitter.fit(seg, std::span<const ModeGuess>(guesses).subspan(g0, g1 - g0), grp);
      for (std::size_t i = g0; i < g1; ++i) ml.modes[i] = part.modes[i - g0];
    } catch (const std::exception&) {
    }
    g0 = g1;
  }
  return ml;
}

// Steps 2-4 for a list of candidate peaks; run again when the residual rescan adds hidden modes.
class ModeAnalysis {
 public:
  ModeAnalysis(const Record& rec, const ModeSearchOptions& opt, const ModeSearchResult& result, const Detection& det)
      : rec_(rec), opt_(opt), result_(result), det_(det), env_(opt.envelope) {
    env_.onset_s = result.onset_s;
  }

  // The modes among cands that decay like a free response, with their envelope and ml estimates.
  std::vector<Work> run(const std::vector<Peak>& cands) {
    std::vector<Work> work;
    fitted_.clear();
    dropped_.clear();
    for (const Peak& pk : cands) {
      Work wk;
      if (read_candidate(pk, wk)) work.push_back(std::move(wk));
      else dropped_.push_back(pk);
    }
    mark_unresolved(work);
    if (!work.empty()) {
      const std::span<const double> seg = refine_ml(work);
      read_deflated(work, seg);
    }
    for (const Work& wk : work)
      if (std::isfinite(wk.mode.ml.f_hz) && wk.mode.ml.zeta > 0 && wk.mode.ml.zeta < 1) fitted_.emplace_back(wk.mode.ml.f_hz, wk.mode.ml.zeta);
    return work;
  }

  /// (f, zeta) of the last run's ml fits that are valid modes: the residual rescan subtracts them.
  const std::vector<std::pair<double, double>>& fitted() const { return fitted_; }
  /// In-band peaks the last run left out (no envelope estimate).
  const std::vector<Peak>& dropped() const { return dropped_; }

 private:
  // eta0 of an automatic choice: large enough to separate the mode from its neighbours (needed), at
  // least 7, and small enough that the kernel fits the free response 16 times.
  double automatic_eta0(double f_hz, double needed) const {
    const double eta0_record = kTwoPi * f_hz * rec_.after_s / 16.0;
    return std::clamp(std::max(7.0, needed), 5.0, std::max(5.0, std::min(kMaxEta0, eta0_record)));
  }

  // 2. eta0 from the neighbours (resolution) and the decay (time), then the envelope estimates (3).
  // False when the peak gives no decay estimate (not a free-response mode).
  bool read_candidate(const Peak& pk, Work& wk) const {
    wk.peak = pk;
    IdentifiedMode& mode = wk.mode;
    mode.detection_snr_db = 10.0 * std::log10(pk.level);
    double needed = 0.0;
    for (const Peak& q : det_.peaks) {
      if (q.f_hz == pk.f_hz) continue;
      const double df = std::abs(q.f_hz - pk.f_hz);
      if (!std::isfinite(mode.neighbour_hz) || df < std::abs(mode.neighbour_hz - pk.f_hz)) mode.neighbour_hz = q.f_hz;
      const double ratio = std::sqrt(std::max(1.0, q.level / pk.level));
      const double xk = std::sqrt(2.0 * std::log(100.0 * ratio));
      needed = std::max(needed, xk * pk.f_hz / df);
    }
    mode.eta0_needed = std::max(needed, 5.0);
    double eta0 = opt_.eta0 > 0 ? opt_.eta0 : automatic_eta0(pk.f_hz, needed);
    const double floor_white = floor_at(det_.base, pk.f_hz);
    const std::span<const double> signal = rec_.signal;
    EnvelopeResult er = estimate_envelope(signal, rec_.fs, eta0, pk.f_hz, floor_white, opt_, env_);
    if (opt_.eta0 <= 0 && std::isfinite(er.ridge_ls.zeta) && er.ridge_ls.zeta > 0 && std::isfinite(er.ridge_ls.snr_db)) {
      // Usable decay length: until the envelope power falls to end_snr times the noise; the edge
      // effect (edge_widths kernel widths) plus a window of 6 widths must fit in it.
      const double sigma = decay_from_zeta(er.ridge_ls.zeta, kTwoPi * er.f_d);
      const double snr = std::pow(10.0, er.ridge_ls.snr_db / 10.0);
      const double t_use = std::min(rec_.after_s, std::log(std::max(snr / env_.end_snr, std::exp(1.0))) / (2.0 * sigma));
      const double eta0_time = kTwoPi * pk.f_hz * t_use / (env_.edge_widths + 6.0);
      if (eta0 > eta0_time * 1.05) {
        eta0 = std::max(5.0, eta0_time);
        er = estimate_envelope(signal, rec_.fs, eta0, pk.f_hz, floor_white, opt_, env_);
      }
    }
    mode.eta0 = eta0;
    mode.resolved = eta0 >= needed * 0.999;
    // The user's eta0 may be unable to read this decay (kernel longer than the usable decay, or the
    // edge effect covering it): read it at the automatic eta0 instead, so that the mode still takes its
    // part in the joint fit (left out, it biases its neighbours' fits: Table 1 at eta0 50 lost the
    // 500 Hz mode and gave zeta 7 % off at 250 Hz with status ok). Its envelope estimators are then not
    // ok and the note says why.
    if (opt_.eta0 > 0 && !std::isfinite(er.ridge_ls.zeta)) {
      const double eta0_auto = automatic_eta0(pk.f_hz, needed);
      EnvelopeResult alt = estimate_envelope(signal, rec_.fs, eta0_auto, pk.f_hz, floor_white, opt_, env_);
      if (std::isfinite(alt.ridge_ls.zeta)) {
        er = std::move(alt);
        wk.user_eta0_failed = true;
        add_note(mode.note, "eta0 " + fmt_g(opt_.eta0) + " cannot read this decay (its kernel is too long for it); read at eta0 " +
                                fmt_g(eta0_auto) + " for the fit, envelope estimators not ok");
      }
    }
    // A peak whose envelope gives no decay estimate at all is not a free-response mode (noise bump,
    // hum, the skirt of the record edge): leave it out of the joint fit and the report.
    if (!std::isfinite(er.ridge_ls.zeta)) return false;
    wk.envr = std::move(er);
    return true;
  }

  // Unresolved neighbours among the kept modes: those closer than the mode's eta0 separates.
  static void mark_unresolved(std::vector<Work>& work) {
    for (std::size_t i = 0; i < work.size(); ++i)
      for (std::size_t j = 0; j < work.size(); ++j) {
        if (i == j) continue;
        const double df = std::abs(work[j].peak.f_hz - work[i].peak.f_hz);
        const double ratio = std::sqrt(std::max(1.0, work[j].peak.level / work[i].peak.level));
        if (std::sqrt(2.0 * std::log(100.0 * ratio)) * work[i].peak.f_hz / df > work[i].mode.eta0) work[i].unresolved.push_back(j);
      }
  }

  // 4. Maximum-likelihood refinement of all modes together, then alone where the joint fit failed;
  // sets each mode's ml estimate. Returns the fitted segment (from the onset).
  std::span<const double> refine_ml(std::vector<Work>& work) const {
    double latest_end_s = result_.onset_s;
    std::vector<ModeGuess> guesses;
    for (const Work& wk : work) {
      const DampingEstimate& r = wk.envr.ridge_ls;
      if (std::isfinite(r.window_end_s)) latest_end_s = std::max(latest_end_s, r.window_end_s);
      guesses.push_back({wk.envr.f_d, (r.zeta > 0 && r.zeta < 0.5) ? r.zeta : 0.01});
    }
    // The fit covers the decay and as much again (noise-only samples add little information but
    // cost time on long records).
    const std::size_t n = rec_.n, n0 = rec_.n0;
    std::size_t n_end = n;
    const double span_s = std::max(latest_end_s - result_.onset_s, 0.0);
    const auto capped = n0 + static_cast<std::size_t>(std::ceil(3.0 * span_s * rec_.fs)) + 256;
    if (n - n0 > (std::size_t{1} << 17)) n_end = std::min(n, capped);
    const std::span<const double> seg = rec_.signal.subspan(n0, n_end - n0);
    SpectralModeFitter fitter(n_end - n0, rec_.fs);
    MlFitOptions ml_opt;
    ml_opt.f_lo_hz = result_.f_min_hz;
    ml_opt.f_hi_hz = result_.f_max_hz;
    const MlFitResult ml = fit_joint(fitter, seg, guesses, ml_opt);
    for (std::size_t i = 0; i < work.size(); ++i) {
      DampingEstimate e = ml.modes[i];
      if (e.status == EstimateStatus::fit_failed || !std::isfinite(e.zeta)) {
        // Per-mode fallback: this mode alone in a band around it (the residual terms take the rest).
        const double f = guesses[i].f_hz;
        const double half = f * std::max({0.02, 20.0 * guesses[i].zeta, 3.0 / work[i].mode.eta0});
        MlFitOptions one = ml_opt;
        one.f_lo_hz = std::max(result_.f_min_hz, f - half);
        one.f_hi_hz = std::min(result_.f_max_hz, f + half);
        try {
          const MlFitResult alone = fitter.fit(seg, std::span<const ModeGuess>(&guesses[i], 1), one);
          e = alone.modes[0];
          add_note(work[i].mode.note, "ml: refitted alone (the joint fit failed)");
        } catch (const std::exception&) {
        }
      }
      e.window_start_s += result_.onset_s;
      e.window_end_s += result_.onset_s;
      e.snr_db = work[i].envr.ridge_ls.snr_db;
      work[i].mode.ml = e;
    }
    return seg;
  }

  // eta0 for mode i once its unresolved neighbours are subtracted: it need only separate the mode from
  // the others (a smaller eta0 keeps more of the early decay), unless the user fixed it.
  double deflated_eta0(const std::vector<Work>& work, std::size_t i) const {
    double eta0_defl = work[i].mode.eta0;
    if (opt_.eta0 > 0) return eta0_defl;
    double needed = 0.0;
    for (const Peak& q : det_.peaks) {
      if (q.f_hz == work[i].peak.f_hz) continue;
      bool gone = false;
      for (std::size_t j : work[i].unresolved) gone = gone || q.f_hz == work[j].peak.f_hz;
      if (gone) continue;
      const double ratio = std::sqrt(std::max(1.0, q.level / work[i].peak.level));
      needed = std::max(needed, std::sqrt(2.0 * std::log(100.0 * ratio)) * work[i].peak.f_hz / std::abs(q.f_hz - work[i].peak.f_hz));
    }
    return std::min(eta0_defl, std::max(7.0, needed));
  }

  // 3'. Modes not resolved from a neighbour: the envelope estimators read the signal with the
  // neighbours' maximum-likelihood fits (amplitudes over seg) subtracted.
  void read_deflated(std::vector<Work>& work, std::span<const double> seg) const {
    bool any = false;
    for (const Work& wk : work) any = any || !wk.unresolved.empty();
    if (!any) return;
    std::vector<std::pair<double, double>> fz;
    std::vector<std::size_t> idx;
    for (std::size_t i = 0; i < work.size(); ++i) {
      const DampingEstimate& e = work[i].mode.ml;
      if (std::isfinite(e.f_hz) && std::isfinite(e.zeta) && e.zeta > 0 && e.zeta < 1) {
        fz.emplace_back(e.f_hz, e.zeta);
        idx.push_back(i);
      }
    }
    const auto amps = mode_amplitudes(seg, rec_.fs, fz);
    for (std::size_t i = 0; i < work.size(); ++i) {
      if (work[i].unresolved.empty()) continue;
      std::vector<double> y(rec_.signal.begin(), rec_.signal.end());
      bool subtracted = false;
      for (std::size_t j : work[i].unresolved) {
        const auto it = std::find(idx.begin(), idx.end(), j);
        if (it == idx.end()) continue;
        const std::size_t k = static_cast<std::size_t>(it - idx.begin());
        if (!std::isfinite(amps[k].real())) continue;
        subtract_mode(y, rec_.n0, rec_.n, rec_.fs, amps[k], fz[k]);
        subtracted = true;
      }
      if (!subtracted) continue;
      const double eta0_defl = deflated_eta0(work, i);
      EnvelopeResult er = estimate_envelope(y, rec_.fs, eta0_defl, work[i].peak.f_hz, floor_at(det_.base, work[i].peak.f_hz), opt_, env_);
      if (std::isfinite(er.ridge_ls.zeta)) {
        work[i].mode.eta0 = eta0_defl;
        work[i].envr = std::move(er);
        add_note(work[i].mode.note, "envelope read with the unresolved neighbours' fits subtracted");
      }
    }
  }

  const Record& rec_;
  const ModeSearchOptions& opt_;
  const ModeSearchResult& result_;
  const Detection& det_;
  EnvelopeOptions env_;  // opt.envelope with the onset
  std::vector<std::pair<double, double>> fitted_;
  std::vector<Peak> dropped_;
};

// Modes hidden by a stronger neighbour (closer than any scan resolves, e.g. a pair 0.2 % apart): the
// fine scans again on the residual of the joint fit (the fitted modes subtracted). Returns the new
// peaks in the band that stand above the floor and are not one already known, strongest first, at
// most kMaxHiddenModes.
std::vector<Peak> hidden_peaks(const Record& rec, const Detection& det, const std::vector<std::pair<double, double>>& fitted,
                               const ModeSearchOptions& opt, const ModeSearchResult& result) {
  std::vector<double> res(rec.signal.begin(), rec.signal.end());
  const auto amps = mode_amplitudes(rec.signal.subspan(rec.n0), rec.fs, fitted);
  for (std::size_t j = 0; j < fitted.size(); ++j) {
    if (!std::isfinite(amps[j].real())) continue;
    subtract_mode(res, rec.n0, rec.n, rec.fs, amps[j], fitted[j]);
  }
  double df = 0.0;
  const std::vector<double> pg = periodogram(res, rec.fs, df);
  std::vector<Peak> extra;
  for (double eta0 : kDetectFineEta0) {
    if (eta0 < 100.0) continue;  // hidden neighbours are close: the fine resolutions only
    const LevelScan lv = smoothed_level(pg, df, eta0, result.f_min_hz, result.f_max_hz, rec.duration_s, det.base, opt.voices_per_octave);
    std::vector<Peak> found;
    find_peaks(lv, det.min_ratio, found);
    for (const Peak& p : found) {
      bool known = false;
      for (const Peak& q : det.peaks) known = known || std::abs(std::log(q.f_hz / p.f_hz)) < 2.0 / eta0;
      for (const Peak& q : extra) known = known || std::abs(std::log(q.f_hz / p.f_hz)) < 2.0 / eta0;
      if (!known) extra.push_back(p);
    }
  }
  std::sort(extra.begin(), extra.end(), [](const Peak& x, const Peak& y) { return x.level > y.level; });
  if (extra.size() > kMaxHiddenModes) extra.resize(kMaxHiddenModes);
  return extra;
}

// Adds the hidden peaks to the detected peaks, the candidates and the result's peak list (each kept
// sorted by frequency).
void add_hidden_peaks(const std::vector<Peak>& extra, Detection& det, std::vector<Peak>& cand, ModeSearchResult& result) {
  for (const Peak& p : extra) {
    det.peaks.push_back(p);
    cand.push_back(p);
    result.peaks.push_back({p.f_hz, 10.0 * std::log10(p.level), p.eta0});
  }
  std::sort(det.peaks.begin(), det.peaks.end(), [](const Peak& x, const Peak& y) { return x.f_hz < y.f_hz; });
  std::sort(cand.begin(), cand.end(), [](const Peak& x, const Peak& y) { return x.f_hz < y.f_hz; });
  std::sort(result.peaks.begin(), result.peaks.end(), [](const DetectedPeak& x, const DetectedPeak& y) { return x.f_hz < y.f_hz; });
}

// A ridge that left its mode: its frequency changes between the window halves by more than half
// the filter's standard deviation and beyond noise, or it sits nearer another detected peak.
bool ridge_left_mode(const Work& wk) {
  const IdentifiedMode& m = wk.mode;
  const EnvelopeResult& er = wk.envr;
  bool left = false;
  if (std::isfinite(er.f_first) && std::isfinite(er.f_second)) {
    const double d = std::abs(er.f_first - er.f_second);
    const double sd = std::hypot(std::isfinite(er.f_first_sd) ? er.f_first_sd : 0.0, std::isfinite(er.f_second_sd) ? er.f_second_sd : 0.0);
    left = d > 4.0 * sd && d > 0.5 * er.f_d / m.eta0;
  }
  if (std::isfinite(m.neighbour_hz) && std::isfinite(er.f_d) &&
      std::abs(er.f_d - m.neighbour_hz) < std::abs(er.f_d - wk.peak.f_hz))
    left = true;
  return left;
}

// A detected peak that was left out (no envelope estimate) close to this mode: the fits
// of this mode may have absorbed it (random independent signals: a pair 3.9 Hz apart at 241/245 Hz,
// the 245 Hz peak left out, the 241 Hz mode's zeta 21 % off with status ok).
void check_dropped_neighbours(Work& wk, const std::vector<Peak>& dropped, double after_s) {
  IdentifiedMode& m = wk.mode;
  for (const Peak& q : dropped) {
    const double df = std::abs(q.f_hz - wk.peak.f_hz);
    // Only a peak within 10 dB of this one matters (it can pull the fit); weaker ones are noise bumps
    // and minor modes whose share the estimators' cross-check sees.
    // And only one farther than 3 half-power bandwidths of this mode: nearer, it is this mode's own
    // peak seen again (short, heavily damped decays between impacts show that).
    const double zeta_own = std::isfinite(m.ml.zeta) ? m.ml.zeta : m.ridge_ls.zeta;
    const bool own = std::isfinite(zeta_own) && df <= 3.0 * zeta_own * wk.peak.f_hz;
    // Within 6 / T of the analysed length T (a few of the record's frequency resolution 1 / T): closer,
    // the fit cannot tell the two apart unless both are modelled (the 241/245 Hz pair is 4.2 / T
    // apart); farther, the joint fit's band and residual terms keep them apart (a stationary line
    // 200 Hz from a mode in a 40 ms segment between impacts does no harm).
    if (df > 0 && !own && q.level >= 0.1 * wk.peak.level && df < 6.0 / after_s) {
      for (DampingEstimate* e : {&m.two_point, &m.ridge_ls, &m.ml})
        if (e->status == EstimateStatus::ok) e->status = EstimateStatus::inconsistent;
      add_note(m.note, "a detected neighbour at " + fmt_g(q.f_hz) + " Hz could not be analysed: this mode's fit may include it");
    }
  }
}

// Variation of zeta along the decay (the backbone's points), see check_backbone_variation.
struct Variation {
  bool varies = false;       // the backbone's zeta varies beyond its uncertainties
  bool unexplained = false;  // ... and no amplitude law explains it
};

// Variation of zeta along the decay beyond the points' uncertainties (chi2 / dof > 4) or a backbone
// test that found amplitude dependence: the note gives the range of the backbone's zeta (and the
// amplitudes), so that a single viscous zeta is never read as valid at every amplitude. A variation
// that the fitted amplitude law explains (its chi2 / dof <= 4) is physics (friction, quadratic
// damping) and the viscous equivalent over the window stays a meaningful number. A variation that
// no monotone law explains is what an unresolved neighbour does (the envelope beats) or a ridge that
// does not follow one mode: then no estimate of this mode is ok (random independent signals: every
// such case had an undetected neighbour, zeta off by 4-19 %, tests/test_modes_property.cpp).
Variation check_backbone_variation(IdentifiedMode& m) {
  Variation out;
  if (!(m.backbone.tested && (m.backbone.amplitude_dependent || m.backbone.chi2_constant > 4.0 * static_cast<double>(m.backbone.dof))))
    return out;
  double zlo = INFINITY, zhi = -INFINITY, alo = INFINITY, ahi = -INFINITY, chi2_law = 0.0;
  std::size_t used = 0;
  for (const BackbonePoint& p : m.backbone.points)
    if (std::isfinite(p.zeta) && std::isfinite(p.amplitude)) {
      zlo = std::min(zlo, p.zeta);
      zhi = std::max(zhi, p.zeta);
      alo = std::min(alo, p.amplitude);
      ahi = std::max(ahi, p.amplitude);
      if (m.backbone.amplitude_dependent && std::isfinite(p.zeta_sd) && p.zeta_sd > 0 && p.amplitude > 0) {
        const double g = m.backbone.law == BackboneLaw::coulomb ? 1.0 / p.amplitude : p.amplitude;
        const double r = (p.zeta - (m.backbone.a + m.backbone.b * g)) / p.zeta_sd;
        chi2_law += r * r;
        ++used;
      }
    }
  if (!(zlo <= zhi)) return out;
  out.varies = true;
  const bool law_fits = m.backbone.amplitude_dependent && used > 2 && std::isfinite(chi2_law) &&
                        chi2_law <= 4.0 * static_cast<double>(used - 2);
  // Relative scatter of the precise points (zeta_sd < 25 % of zeta) about their mean.
  double s1 = 0, s2 = 0, k = 0;
  for (const BackbonePoint& p : m.backbone.points)
    if (std::isfinite(p.zeta) && std::isfinite(p.zeta_sd) && p.zeta_sd < 0.25 * p.zeta) {
      s1 += p.zeta;
      s2 += p.zeta * p.zeta;
      k += 1;
    }
  const double scatter = k > 2 ? std::sqrt(std::max(0.0, s2 / k - (s1 / k) * (s1 / k))) / (s1 / k) : NAN;
  // Not for a mode whose envelope was read with neighbours' fits subtracted: their residual errors
  // pass as variation (the hammer hit's 5970 Hz mode, ml and ridge-ls agreeing to 0.1 %, scatters
  // 29 % after its 5984 Hz neighbour is subtracted).
  const bool deflated = m.note.find("subtracted") != std::string::npos;
  out.unexplained = !deflated && m.backbone.chi2_constant > 4.0 * static_cast<double>(m.backbone.dof) && !law_fits &&
                    !(scatter <= kMaxUnexplainedScatter);
  add_note(m.note, "zeta varies along the decay: backbone zeta " + fmt_g(zlo) + " .. " + fmt_g(zhi) + " over amplitudes " +
                       fmt_g(alo) + " .. " + fmt_g(ahi) + " (scatter " + fmt_g(100 * scatter) + " %)" +
                       (out.unexplained ? "; no amplitude law explains the variation (an unresolved neighbour beating?)"
                                        : "; zeta is the viscous equivalent over the window"));
  return out;
}

// 5. Status rules ("ok is a promise", modes.hpp): each analysed mode's estimates sanitised, checked
// against each other and against the signs of a ridge that did not read one mode; the modes, with
// the requested method's estimate selected, go to result.modes.
void apply_status_rules(std::vector<Work>& work, const std::vector<Peak>& dropped, double after_s,
                        const ModeSearchOptions& opt, ModeSearchResult& result) {
  for (Work& wk : work) {
    IdentifiedMode& m = wk.mode;
    const EnvelopeResult& er = wk.envr;
    m.two_point = er.two_point;
    m.ridge_ls = er.ridge_ls;
    m.backbone = er.backbone;
    for (DampingEstimate* e : {&m.two_point, &m.ridge_ls, &m.ml}) sanitize(*e, result.f_min_hz, result.f_max_hz, m.note);
    if (wk.user_eta0_failed)
      for (DampingEstimate* e : {&m.two_point, &m.ridge_ls})
        if (e->status == EstimateStatus::ok) e->status = EstimateStatus::too_short;
    if (ridge_left_mode(wk)) {
      for (DampingEstimate* e : {&m.two_point, &m.ridge_ls})
        if (e->status == EstimateStatus::ok) e->status = EstimateStatus::inconsistent;
      add_note(m.note, "the ridge left its mode (frequency drifts within the window)");
    }
    check_dropped_neighbours(wk, dropped, after_s);
    // An ml fit that converged away from the spectral peak it started from (by more than two standard
    // deviations of the filter that resolved the peak and by more than three of its own): it fitted a blend of
    // this mode and an unresolved neighbour (seen on random independent signals: a peak at 627.6 Hz
    // fitted at 632.3 Hz with zeta 26 % off, between modes at 627.7 and 637.3 Hz).
    if (m.ml.status == EstimateStatus::ok && std::isfinite(m.ml.f_hz) && wk.peak.eta0 > 0 &&
        std::abs(m.ml.f_hz - wk.peak.f_hz) > std::max(2.0 * wk.peak.f_hz / wk.peak.eta0, 3.0 * (std::isfinite(m.ml.f_sd_hz) ? m.ml.f_sd_hz : 0.0))) {
      m.ml.status = EstimateStatus::inconsistent;
      add_note(m.note, "ml left its spectral peak (" + fmt_g(wk.peak.f_hz) + " Hz): a blend with an unresolved neighbour?");
    }
    const auto [varies, unexplained] = check_backbone_variation(m);
    if (unexplained)
      for (DampingEstimate* e : {&m.two_point, &m.ridge_ls, &m.ml})
        if (e->status == EstimateStatus::ok) e->status = EstimateStatus::inconsistent;
    // Estimators that disagree: the envelope fit and the time-series fit see the same mode through
    // different statistics.
    if (m.ml.status == EstimateStatus::ok && m.ridge_ls.status == EstimateStatus::ok && !agree(m.ml, m.ridge_ls)) {
      m.ml.status = m.ridge_ls.status = EstimateStatus::inconsistent;
      add_note(m.note, varies ? "ml and ridge-ls disagree beyond their uncertainties (they average a varying zeta differently: read the backbone)"
                              : "ml and ridge-ls disagree beyond their uncertainties");
    }
    // ml is ok only when an independent estimator confirms it: without an ok ridge-ls, nothing does.
    if (m.ml.status == EstimateStatus::ok && m.ridge_ls.status != EstimateStatus::ok) {
      m.ml.status = EstimateStatus::inconsistent;
      add_note(m.note, "ml not confirmed: ridge-ls is " + std::string(to_string(m.ridge_ls.status)) +
                           (opt.eta0 > 0 && m.ridge_ls.status == EstimateStatus::too_short
                                ? " at eta0 " + fmt_g(opt.eta0) + " (a smaller eta0, or the automatic choice, fits the decay)"
                                : std::string()));
    }
    const DampingEstimate* ref = m.ml.status == EstimateStatus::ok ? &m.ml : m.ridge_ls.status == EstimateStatus::ok ? &m.ridge_ls : nullptr;
    if (m.two_point.status == EstimateStatus::ok) {
      if (!ref) {
        m.two_point.status = EstimateStatus::inconsistent;
        add_note(m.note, "two-point has no agreeing estimator");
      } else if (!agree(*ref, m.two_point)) {
        m.two_point.status = EstimateStatus::inconsistent;
        add_note(m.note, "two-point disagrees with " + std::string(to_string(ref->method)));
      }
    }
    // The ridge-ls estimate alone (ml failed): only as good as its own statistics, kept.
    switch (opt.method) {
      case DampingMethod::two_point: m.selected = m.two_point; break;
      case DampingMethod::ridge_ls: m.selected = m.ridge_ls; break;
      case DampingMethod::ml: m.selected = m.ml; break;
    }
    if (!std::isfinite(m.selected.f_hz)) m.selected.f_hz = er.f_d;
    if (m.selected.status != EstimateStatus::ok && m.note.empty()) add_note(m.note, std::string(to_string(m.selected.status)));
    result.modes.push_back(std::move(m));
  }
  std::sort(result.modes.begin(), result.modes.end(),
            [](const IdentifiedMode& a, const IdentifiedMode& b) { return a.selected.f_hz < b.selected.f_hz; });
}

// When no mode was found: why.
std::string no_mode_note(const std::vector<Peak>& peaks, const ModeSearchResult& result, const ModeSearchOptions& opt) {
  std::size_t in_band = 0;
  for (const Peak& p : peaks) in_band += p.f_hz >= result.f_min_hz && p.f_hz <= result.f_max_hz;
  if (in_band == 0)
    return "no spectral peak in the band stands " + std::to_string(opt.min_peak_snr_db) +
           " dB above the noise floor (" + std::to_string(peaks.size()) + " outside the band)";
  return std::to_string(in_band) + " peak(s) in the band, but none decays like a free response";
}

}  // namespace

ModeSearchResult identify_modes(std::span<const double> signal_in, double fs, const ModeSearchOptions& opt) {
  check_options(signal_in, fs, opt);
  ModeSearchResult result;
  const Record rec = analysed_part(signal_in, fs, opt, result);
  Detection det = detect_peaks(rec, opt, result);
  std::vector<Peak> cand = strongest_in_band(det.peaks, result, opt.max_modes);

  ModeAnalysis analysis(rec, opt, result, det);
  std::vector<Work> work = analysis.run(cand);
  // Hidden modes found on the residual of the joint fit join the candidates; the analysis runs once
  // more with them.
  if (!analysis.fitted().empty()) {
    const std::vector<Peak> extra = hidden_peaks(rec, det, analysis.fitted(), opt, result);
    if (!extra.empty()) {
      add_hidden_peaks(extra, det, cand, result);
      work = analysis.run(cand);
    }
  }

  apply_status_rules(work, analysis.dropped(), rec.after_s, opt, result);
  if (result.modes.empty()) result.note = no_mode_note(det.peaks, result, opt);
  return result;
}

}  // namespace ridgewatch::dsp
