#include "cli/plot_modes.hpp"

#include <algorithm>
#include <cmath>
#include <complex>
#include <numbers>
#include <string>

#include "cli/plot_svg.hpp"
#include "core/dsp/morlet_cwt.hpp"

namespace ridgewatch::cli::plots {

namespace {

using plot::Dash;
using plot::Figure;
using plot::Panel;
using plot::Rect;
using plot::Style;

constexpr double kWidth = 960.0;
constexpr double kTitle = 34.0;

std::string hz(double f) {
  char b[32];
  std::snprintf(b, sizeof b, "%.1f Hz", f);
  return b;
}

PlotFile scalogram(std::span<const double> x, double fs, const dsp::ModeSearchResult& r) {
  const std::size_t rows = 120, cols = 240;  // ~1.8 MB of SVG cells
  dsp::MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.eta0 = 7.0;
  cfg.frequencies_hz = dsp::make_frequency_grid(r.f_min_hz, r.f_max_hz, rows, dsp::GridSpacing::linear);
  cfg.max_samples = x.size();
  dsp::MorletCwt<double> cwt(cfg);
  cwt.load(x);
  std::vector<std::complex<double>> w(cwt.columns());
  std::vector<double> v(rows * cols, NAN);
  const double noise = std::max(r.noise_sd, 1e-300);
  double vmax = -1e300;
  for (std::size_t i = 0; i < rows; ++i) {
    cwt.row_at(i, w);
    const double floor_amp = noise * std::sqrt(cwt.noise_gain(cfg.frequencies_hz[i]));
    for (std::size_t c = 0; c < cols; ++c) {
      // the largest |W| of the columns this cell covers
      const std::size_t a = c * w.size() / cols, b = std::max(a + 1, (c + 1) * w.size() / cols);
      double m = 0.0;
      for (std::size_t k = a; k < b && k < w.size(); ++k) m = std::max(m, std::abs(w[k]));
      v[i * cols + c] = 20.0 * std::log10(std::max(m, 1e-300) / floor_amp);
      vmax = std::max(vmax, v[i * cols + c]);
    }
  }
  const double t_end = static_cast<double>(x.size()) / fs;
  Panel p;
  p.title = "Scalogram (eta0 = 7), dB over the noise floor, with the modes' ridges";
  p.x_label = "time (s)";
  p.y_label = "frequency (Hz)";
  p.heatmap(0.0, t_end, r.f_min_hz, r.f_max_hz, rows, cols, std::move(v), 0.0, std::max(vmax, 10.0), "dB");
  for (std::size_t i = 0; i < r.modes.size(); ++i) {
    const auto& m = r.modes[i];
    const auto& e = m.ridge_ls;
    if (!std::isfinite(e.window_start_s) || !std::isfinite(m.selected.f_hz)) continue;
    p.segment(e.window_start_s, m.selected.f_hz, e.window_end_s, m.selected.f_hz,
              Style{"#ffffff", 2.0, m.selected.status == dsp::EstimateStatus::ok ? Dash::solid : Dash::dashed, 0.9});
    p.annotate(e.window_end_s, m.selected.f_hz, hz(m.selected.f_hz));
  }
  p.legend = false;
  Figure fig(kWidth, kTitle + 480.0, "Modes: scalogram and ridges");
  fig.add(std::move(p), Rect{0, kTitle, kWidth, 480.0});
  return {"scalogram.svg", "Scalogram with ridges",
          "Each mode's ridge is drawn over the window its envelope estimate used (dashed: status not ok).", fig.svg()};
}

PlotFile envelopes(std::span<const double> x, double fs, const dsp::ModeSearchResult& r) {
  const double panel_h = 220.0;
  const std::size_t n = std::max<std::size_t>(1, r.modes.size());
  Figure fig(kWidth, kTitle + panel_h * static_cast<double>(n), "Modes: envelope and fitted decays");
  double y = kTitle;
  for (const auto& m : r.modes) {
    Panel p;
    p.title = hz(m.selected.f_hz) + " (eta0 " + std::to_string(static_cast<int>(std::lround(m.eta0))) + ", " +
              std::string(dsp::to_string(m.selected.status)) + ")";
    p.x_label = "time (s)";
    p.y_label = "|W| (signal units)";
    p.y_log = true;
    if (std::isfinite(m.eta0) && std::isfinite(m.selected.f_hz) && m.selected.f_hz > 0 && m.selected.f_hz < fs / 2) {
      dsp::MorletCwtConfig cfg;
      cfg.sample_rate_hz = fs;
      cfg.eta0 = std::clamp(m.eta0, 5.0, 1000.0);
      cfg.fine_resolution = true;
      cfg.frequencies_hz = {m.selected.f_hz};
      cfg.max_samples = x.size();
      dsp::MorletCwt<double> cwt(cfg);
      cwt.load(x);
      std::vector<std::complex<double>> w(cwt.columns());
      cwt.row_at(0, w);
      const std::size_t step = std::max<std::size_t>(1, w.size() / 800);
      std::vector<double> t, a;
      for (std::size_t k = 0; k < w.size(); k += step) {
        t.push_back(static_cast<double>(k) * cwt.time_step_s());
        a.push_back(std::abs(w[k]));
      }
      p.line(t, a, Style{"#555555", 1.0}, "|W| on the ridge");
      const double floor_amp = r.noise_sd * std::sqrt(cwt.noise_gain(m.selected.f_hz));
      if (floor_amp > 0) p.hline(floor_amp, Style{"#999999", 1.0, Dash::dotted}, "noise");
      auto decay = [&](const dsp::DampingEstimate& e, const std::string& colour, const std::string& label) {
        if (!std::isfinite(e.zeta) || !std::isfinite(e.amplitude) || !std::isfinite(e.window_start_s)) return;
        const double sigma = dsp::decay_from_zeta(e.zeta, 2.0 * std::numbers::pi * e.f_hz);
        std::vector<double> tt, aa;
        for (int k = 0; k <= 50; ++k) {
          const double ti = e.window_start_s + (e.window_end_s - e.window_start_s) * k / 50.0;
          tt.push_back(ti);
          aa.push_back(e.amplitude * std::exp(-sigma * (ti - e.window_start_s)));
        }
        p.line(tt, aa, Style{colour, 2.0, Dash::dashed}, label);
      };
      decay(m.ridge_ls, "#1f77b4", "ridge-ls");
      decay(m.ml, "#d62728", "ml");
    }
    fig.add(std::move(p), Rect{0, y, kWidth, panel_h});
    y += panel_h;
  }
  return {"envelopes.svg", "Envelope fit per mode",
          "The wavelet envelope on each mode's ridge (Eq. 12) with the fitted exponential decays; a straight line on "
          "this log scale is viscous damping.", fig.svg()};
}

PlotFile backbones(const dsp::ModeSearchResult& r) {
  Panel z, f;
  z.title = "Damping ratio against amplitude (backbone)";
  z.x_label = "envelope amplitude (signal units)";
  z.y_label = "zeta";
  z.x_log = true;
  f.title = "Frequency against amplitude, relative to each mode's frequency";
  f.x_label = "envelope amplitude (signal units)";
  f.y_label = "f / f_mode - 1";
  f.x_log = true;
  for (std::size_t i = 0; i < r.modes.size(); ++i) {
    const auto& m = r.modes[i];
    std::vector<double> a, zz, ff;
    for (const auto& p : m.backbone.points) {
      a.push_back(p.amplitude);
      zz.push_back(p.zeta);
      ff.push_back(p.f_hz / m.selected.f_hz - 1.0);
    }
    const std::string label = hz(m.selected.f_hz) + (m.backbone.amplitude_dependent ? " (amplitude dependent)" : "");
    z.line(a, zz, Style{plot::palette(i), 1.5}, label, true);
    f.line(a, ff, Style{plot::palette(i), 1.5}, label, true);
  }
  Figure fig(kWidth, kTitle + 2 * 320.0, "Modes: backbones");
  fig.add(std::move(z), Rect{0, kTitle, kWidth, 320.0});
  fig.add(std::move(f), Rect{0, kTitle + 320.0, kWidth, 320.0});
  return {"backbones.svg", "Backbones",
          "Equivalent viscous damping and frequency of each segment of the decay against its amplitude: flat for "
          "viscous damping, rising to the left for dry friction, to the right for quadratic damping.", fig.svg()};
}

}  // namespace

std::vector<PlotFile> mode_plots(std::span<const double> signal, double fs, const dsp::ModeSearchResult& result) {
  return {scalogram(signal, fs, result), envelopes(signal, fs, result), backbones(result)};
}

}  // namespace ridgewatch::cli::plots
