#include "core/diagnosis/residual_analysis.hpp"

#include <algorithm>
#include <cmath>
#include <complex>
#include <limits>
#include <numbers>

namespace ridgewatch::diagnosis {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Cycle-by-cycle backbone of one response (upward zero crossings, linearly interpolated): the cycle
// frequency 1/T_k, amplitude A_k = max |x| over the cycle, and ζ_k = ln(A_k / A_k+1) / 2π (the
// logarithmic decrement, paper Eq. 18 with m = 1). Cycles below `floor` are dropped (noise).
struct Cycle {
  double a, f, zeta;
};
std::vector<Cycle> cycles(const double* x, std::size_t n, double fs, double floor) {
  std::vector<double> tz;
  std::vector<double> amp;
  double peak = 0.0;
  for (std::size_t i = 1; i < n; ++i) {
    peak = std::max(peak, std::abs(x[i]));
    if (x[i - 1] < 0.0 && x[i] >= 0.0) {
      tz.push_back((static_cast<double>(i) - 1.0 + x[i - 1] / (x[i - 1] - x[i])) / fs);
      amp.push_back(peak);
      peak = 0.0;
    }
  }
  std::vector<Cycle> out;
  for (std::size_t k = 1; k + 2 < tz.size(); ++k) {
    const double a0 = amp[k + 1], a1 = amp[k + 2];
    if (a0 < floor || a1 < floor) break;
    out.push_back({a0, 1.0 / (tz[k + 1] - tz[k]), std::log(a0 / a1) / (2.0 * std::numbers::pi)});
  }
  return out;
}

Backbone bin_cycles(const std::vector<Cycle>& all, double a_max) {
  constexpr int kBins = 10;
  Backbone b;
  std::vector<double> sz(kBins, 0.0), sf(kBins, 0.0), cnt(kBins, 0.0);
  for (const auto& c : all) {
    const int k = std::clamp(static_cast<int>(c.a / a_max * kBins), 0, kBins - 1);
    sz[static_cast<std::size_t>(k)] += c.zeta;
    sf[static_cast<std::size_t>(k)] += c.f;
    cnt[static_cast<std::size_t>(k)] += 1.0;
  }
  for (int k = 0; k < kBins; ++k) {
    const auto i = static_cast<std::size_t>(k);
    b.amplitude_rel.push_back((k + 0.5) / kBins);
    // Fewer than 3 cycles in a bin: no estimate (a single decrement at low SNR is meaningless).
    b.zeta.push_back(cnt[i] >= 3 ? sz[i] / cnt[i] : kNaN);
    b.f_hz.push_back(cnt[i] >= 3 ? sf[i] / cnt[i] : kNaN);
  }
  return b;
}

/// Residual vs time after the onset (1 ms bins) and per held-out impact.
std::size_t residual_vs_time(const ModelFitter& fitter, const FitResult& fit, ResidualReport& rep) {
  const auto& seg = fitter.segmentation();
  const auto y = fitter.data();
  const double fs = seg.sample_rate_hz;
  const double sd = seg.noise_sd;
  // Residual vs time after onset (1 ms bins) and per impact.
  std::vector<double> tb_sum, tb_n;
  std::size_t max_len = 0;
  for (std::size_t w = 0; w < seg.windows.size(); ++w) {
    if (!fitter.is_heldout(w)) continue;
    const auto& win = seg.windows[w];
    max_len = std::max<std::size_t>(max_len, win.end - win.begin);
    rep.impact_time_s.push_back(win.onset_s);
    rep.impact_amplitude.push_back(std::exp(fit.params.ln_force[w]));
    rep.impact_excess.push_back(fit.impact_power[w] - 1.0);
    const double onset = win.onset_s * fs + fit.params.shift[w];
    for (std::size_t i = 0; i < fit.model[w].size(); ++i) {
      const double t_ms = (static_cast<double>(win.begin + i) - onset) / fs * 1000.0;
      if (t_ms < 0.0) continue;
      const auto b = static_cast<std::size_t>(t_ms / rep.dt_ms);
      if (b >= tb_sum.size()) {
        tb_sum.resize(b + 1, 0.0);
        tb_n.resize(b + 1, 0.0);
      }
      const double r = (y[win.begin + i] - fit.model[w][i]) / sd;
      tb_sum[b] += seg.weight[win.begin + i] * r * r;
      tb_n[b] += seg.weight[win.begin + i];
    }
  }
  for (std::size_t b = 0; b < tb_sum.size(); ++b) rep.excess_vs_time.push_back(tb_n[b] > 0 ? tb_sum[b] / tb_n[b] - 1.0 : kNaN);
  return max_len;
}

/// Residual spectrum, markers, harmonic levels and lines (see inside).
void residual_spectrum(const ModelFitter& fitter, const FitResult& fit, std::size_t max_len, ResidualReport& rep) {
  const auto& seg = fitter.segmentation();
  const auto y = fitter.data();
  const double fs = seg.sample_rate_hz;
  const double sd = seg.noise_sd;
  // Mean periodogram of the held-out residual windows, |Σ r_n e^{-iωn}|² / n in σ² units (1 = white
  // noise), on a grid of fs / (2 max_len) up to min(3 f0, 0.45 fs) by direct summation.
  const double df = fs / (2.0 * static_cast<double>(std::max<std::size_t>(max_len, 16)));
  // Up to 3.3 f0: the 2 f0 (asymmetric waveform: contact loss) and 3 f0 (symmetric cubic) lines.
  const double f_top = std::min(3.3 * rep.f0_hz, 0.45 * fs);
  for (double f = df; f < f_top; f += df) rep.spectrum_f_hz.push_back(f);
  rep.spectrum_level.assign(rep.spectrum_f_hz.size(), 0.0);
  double windows = 0.0;
  for (std::size_t w = 0; w < seg.windows.size(); ++w) {
    if (!fitter.is_heldout(w)) continue;
    const auto& win = seg.windows[w];
    const std::size_t n = fit.model[w].size();
    for (std::size_t k = 0; k < rep.spectrum_f_hz.size(); ++k) {
      const std::complex<double> step = std::polar(1.0, -2.0 * std::numbers::pi * rep.spectrum_f_hz[k] / fs);
      std::complex<double> ph = 1.0, acc = 0.0;
      for (std::size_t i = 0; i < n; ++i) {
        acc += seg.weight[win.begin + i] * (y[win.begin + i] - fit.model[w][i]) / sd * ph;
        ph *= step;
      }
      rep.spectrum_level[k] += std::norm(acc) / static_cast<double>(n);
    }
    windows += 1.0;
  }
  for (double& v : rep.spectrum_level) v /= std::max(1.0, windows);
  for (int k = 1; k <= 3; ++k) {
    rep.markers.push_back({std::to_string(k) + "fz", k * rep.fz_hz});
    rep.markers.push_back({"f0+" + std::to_string(k) + "fz", rep.f0_hz + k * rep.fz_hz});
    if (rep.f0_hz - k * rep.fz_hz > 0.0) rep.markers.push_back({"f0-" + std::to_string(k) + "fz", rep.f0_hz - k * rep.fz_hz});
  }
  rep.markers.push_back({"f0", rep.f0_hz});
  rep.markers.push_back({"2f0", 2.0 * rep.f0_hz});
  if (3.0 * rep.f0_hz < f_top) rep.markers.push_back({"3f0", 3.0 * rep.f0_hz});
  // Harmonic levels: the largest spectrum value within the resolution (2 bins) of 2 f0 and 3 f0.
  auto level_near = [&](double f) {
    double best = kNaN;
    for (std::size_t k = 0; k < rep.spectrum_f_hz.size(); ++k)
      if (std::abs(rep.spectrum_f_hz[k] - f) <= 2.0 * df) best = std::isfinite(best) ? std::max(best, rep.spectrum_level[k]) : rep.spectrum_level[k];
    return best;
  };
  rep.level_2f0 = level_near(2.0 * rep.f0_hz);
  rep.level_3f0 = level_near(3.0 * rep.f0_hz);
  // Lines: local maxima above 4 (the mean of K >= 6 independent χ²₂/2 periodogram values exceeds 4 with
  // p < 1e-6 per bin); the marker if within 2 bins (the window's resolution).
  for (std::size_t k = 1; k + 1 < rep.spectrum_level.size(); ++k) {
    const double v = rep.spectrum_level[k];
    if (v < 4.0 || v < rep.spectrum_level[k - 1] || v < rep.spectrum_level[k + 1]) continue;
    SpectrumPeak p{rep.spectrum_f_hz[k], v, ""};
    double best = 2.0 * df;
    for (const auto& [name, f] : rep.markers)
      if (std::abs(f - p.f_hz) <= best) {
        best = std::abs(f - p.f_hz);
        p.marker = name;
      }
    rep.peaks.push_back(p);
  }
  std::sort(rep.peaks.begin(), rep.peaks.end(), [](const auto& a, const auto& b) { return a.level > b.level; });
  if (rep.peaks.size() > 8) rep.peaks.resize(8);
}

/// Whiteness of the held-out residual (Ljung–Box).
void ljung_box(const ModelFitter& fitter, const FitResult& fit, ResidualReport& rep) {
  const auto& seg = fitter.segmentation();
  const auto y = fitter.data();
  const double sd = seg.noise_sd;
  // Whiteness: Ljung–Box Q over lags 1..10 of the held-out residual (pooled within windows).
  {
    constexpr int kLags = 10;
    double c0 = 0.0, n_all = 0.0;
    std::vector<double> ck(kLags + 1, 0.0);
    for (std::size_t w = 0; w < seg.windows.size(); ++w) {
      if (!fitter.is_heldout(w)) continue;
      const auto& win = seg.windows[w];
      const std::size_t n = fit.model[w].size();
      auto r = [&](std::size_t i) { return seg.weight[win.begin + i] * (y[win.begin + i] - fit.model[w][i]) / sd; };
      for (std::size_t i = 0; i < n; ++i) {
        c0 += r(i) * r(i);
        n_all += 1.0;
        for (int l = 1; l <= kLags; ++l)
          if (i + static_cast<std::size_t>(l) < n) ck[static_cast<std::size_t>(l)] += r(i) * r(i + static_cast<std::size_t>(l));
      }
    }
    for (int l = 1; l <= kLags && c0 > 0.0; ++l) {
      const double rho = ck[static_cast<std::size_t>(l)] / c0;
      rep.ljung_box_q += n_all * (n_all + 2.0) * rho * rho / (n_all - l);
    }
    rep.ljung_box_limit = 29.59;  // χ²(10) at 99.9 %
    rep.white = rep.ljung_box_q <= rep.ljung_box_limit;
  }
}

/// Measured and model backbones of the held-out impacts (see inside).
void backbones(const ModelFitter& fitter, const FitResult& fit, ResidualReport& rep) {
  const auto& seg = fitter.segmentation();
  const auto y = fitter.data();
  const double fs = seg.sample_rate_hz;
  const double sd = seg.noise_sd;
  // Backbones of the held-out impacts, measured and model, cycles above 5 σ (a decrement from cycles
  // nearer the noise is biased by it).
  std::vector<Cycle> meas, mod;
  double a_max = 0.0;
  for (std::size_t w = 0; w < seg.windows.size(); ++w) {
    if (!fitter.is_heldout(w)) continue;
    const auto& win = seg.windows[w];
    const auto skip = static_cast<std::size_t>(std::max(0.0, (win.onset_s - static_cast<double>(win.begin) / fs) * fs + 0.001 * fs));
    if (skip >= fit.model[w].size()) continue;
    const std::size_t n = fit.model[w].size() - skip;
    std::vector<double> ym(y.begin() + static_cast<std::ptrdiff_t>(win.begin + skip), y.begin() + static_cast<std::ptrdiff_t>(win.begin + skip + n));
    const auto cm = cycles(ym.data(), n, fs, 5.0 * sd);
    const auto cmod = cycles(fit.model[w].data() + skip, n, fs, 5.0 * sd);
    // A window whose measured envelope rises again (by 10 % and 2 σ: beyond the noise jitter of a
    // cycle maximum above 5 σ) or whose cycle frequency strays 25 % from f0 beats (two close modes,
    // a parametric modulation): its zero-crossing periods and decrements are beating artefacts, not
    // a backbone (issue 14: a 1378 Hz "backbone" point from a second mode at 930 Hz). Left out.
    bool beats = false;
    for (std::size_t k = 0; k + 1 < cm.size(); ++k)
      if (cm[k + 1].a > 1.1 * cm[k].a && cm[k + 1].a - cm[k].a > 2.0 * sd) beats = true;
    bool far = false;
    for (std::size_t k = 0; k < cm.size(); ++k)
      if (rep.f0_hz > 0.0 && std::abs(cm[k].f / rep.f0_hz - 1.0) > 0.25) {
        beats = true;
        // In the first three cycles the impact response dominates any steady mesh line.
        if (k < 3) far = true;
      }
    if (far) ++rep.far_windows;
    if (beats) {
      ++rep.beating_windows;
      continue;
    }
    meas.insert(meas.end(), cm.begin(), cm.end());
    mod.insert(mod.end(), cmod.begin(), cmod.end());
  }
  for (const auto& c : meas) a_max = std::max(a_max, c.a);
  for (const auto& c : mod) a_max = std::max(a_max, c.a);
  if (a_max > 0.0) {
    rep.measured = bin_cycles(meas, a_max * 1.0000001);
    rep.model = bin_cycles(mod, a_max * 1.0000001);
    rep.measured.amplitude_max = rep.model.amplitude_max = a_max;
  }
}

}  // namespace

ResidualReport analyse_residual(const ModelFitter& fitter, const FitResult& fit) {
  ResidualReport rep;
  const auto& seg = fitter.segmentation();
  for (const auto& e : fit.estimates)
    if (e.name == "c0_n_per_m") {
      model::RigParameters r = fitter.rig();
      r.mean_mesh_stiffness_n_per_m = e.value;
      rep.f0_hz = r.natural_frequency_hz();
    }
  double fz = 0.0;
  for (const auto& w : seg.windows) fz += w.mesh_hz;
  rep.fz_hz = fz / static_cast<double>(seg.windows.size());
  rep.spikes = seg.spikes.size();
  rep.dropouts = seg.dropouts.size();

  const std::size_t max_len = residual_vs_time(fitter, fit, rep);
  residual_spectrum(fitter, fit, max_len, rep);
  ljung_box(fitter, fit, rep);
  backbones(fitter, fit, rep);
  return rep;
}

}  // namespace ridgewatch::diagnosis
