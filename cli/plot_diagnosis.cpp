#include "cli/plot_diagnosis.hpp"

#include <algorithm>
#include <cmath>
#include <complex>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <numeric>
#include <optional>
#include <sstream>
#include <system_error>

#include "app/args.hpp"
#include "cli/plot_svg.hpp"
#include "core/dsp/morlet_cwt.hpp"

namespace ridgewatch::cli::plots {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kWidth = 960.0;
constexpr double kTitle = 34.0;  // room for the figure title
constexpr double kEta0 = 7.0;    // Morlet η0 (paper Eq. 4) of the scalogram and the envelopes

using diagnosis::FitResult;
using diagnosis::ModelFitter;
using diagnosis::ResidualReport;
using plot::Dash;
using plot::Figure;
using plot::Panel;
using plot::Rect;
using plot::Style;

std::string num(double v, int digits = 3) { return diagnosis::format_number(v, digits); }

const Style kMeasured{"#222222", 1.2, Dash::solid, 1.0};
const Style kModel{"#d62728", 1.4, Dash::solid, 0.9};
const Style kStart{"#1f77b4", 1.2, Dash::dashed, 0.9};
const Style kFloor{"#7f7f7f", 1.2, Dash::dashed, 1.0};
const Style kTarget{"#d62728", 1.2, Dash::dashed, 1.0};

std::vector<std::size_t> heldout_windows(const ModelFitter& fitter, const FitResult& fit) {
  std::vector<std::size_t> w;
  for (std::size_t i = 0; i < fitter.segmentation().windows.size() && i < fit.model.size(); ++i)
    if (fitter.is_heldout(i)) w.push_back(i);
  return w;
}

// Sample position of the fitted onset of window w (detected onset + fitted shift).
double onset_sample(const ModelFitter& fitter, const FitResult& fit, std::size_t w) {
  const auto& win = fitter.segmentation().windows[w];
  const double shift = w < fit.params.shift.size() ? fit.params.shift[w] : 0.0;
  return win.onset_s * fitter.segmentation().sample_rate_hz + shift;
}

std::vector<double> time_ms(const ModelFitter& fitter, const FitResult& fit, std::size_t w) {
  const auto& win = fitter.segmentation().windows[w];
  const double fs = fitter.segmentation().sample_rate_hz, onset = onset_sample(fitter, fit, w);
  std::vector<double> t(fit.model[w].size());
  for (std::size_t i = 0; i < t.size(); ++i) t[i] = (static_cast<double>(win.begin + i) - onset) / fs * 1000.0;
  return t;
}

// Residual of window w in σ units; masked samples (spikes, dropouts) are NaN, i.e. gaps.
std::vector<double> residual_sigma(const ModelFitter& fitter, const FitResult& fit, std::size_t w, bool masked_as_zero = false) {
  const auto& seg = fitter.segmentation();
  const auto y = fitter.data();
  const auto& win = seg.windows[w];
  std::vector<double> r(fit.model[w].size());
  for (std::size_t i = 0; i < r.size(); ++i) {
    const std::size_t k = win.begin + i;
    const bool used = k < seg.weight.size() ? seg.weight[k] > 0.0 : true;
    r[i] = used ? (y[k] - fit.model[w][i]) / seg.noise_sd : (masked_as_zero ? 0.0 : kNaN);
  }
  return r;
}

std::vector<double> measured(const ModelFitter& fitter, const FitResult& fit, std::size_t w) {
  const auto y = fitter.data();
  const auto& win = fitter.segmentation().windows[w];
  return {y.begin() + static_cast<std::ptrdiff_t>(win.begin), y.begin() + static_cast<std::ptrdiff_t>(win.begin + fit.model[w].size())};
}

double f0_of(const ModelFitter& fitter, const ResidualReport& rep) {
  return rep.f0_hz > 0.0 ? rep.f0_hz : fitter.rig().natural_frequency_hz();
}

// Log axis when the values span more than a factor 30 above the 0.1 target; values are then clamped
// at 0.01 (an excess at or below the floor shows as "<= 0.01").
constexpr double kExcessFloor = 0.01;
bool excess_log_axis(const std::vector<double>& v) {
  double hi = 0.0;
  for (double x : v)
    if (std::isfinite(x)) hi = std::max(hi, x);
  return hi > 3.0;
}
double clamp_excess(double v, bool log) { return log && std::isfinite(v) ? std::max(v, kExcessFloor) : v; }

std::string model_label(const FitResult& fit) { return "model " + effect_list(fit.effects); }

void write_file(const std::filesystem::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f << text;
  f.close();
  if (!f) throw UsageError("--plots: cannot write " + p.string());
}

std::string html_escape(const std::string& s) { return plot::escape_xml(s); }

}  // namespace

std::string effect_list(const std::vector<std::string>& effects) {
  std::string s = "[";
  for (std::size_t i = 0; i < effects.size(); ++i) s += (i ? ", " : "") + effects[i];
  return s + "]";
}

std::filesystem::path prepare_dir(const std::string& dir) {
  if (dir.empty()) throw UsageError("--plots: needs a directory name");
  const std::filesystem::path p(dir);
  std::error_code ec;
  if (std::filesystem::exists(p, ec) && !std::filesystem::is_directory(p, ec))
    throw UsageError("--plots: '" + dir + "' exists and is not a directory");
  std::filesystem::create_directories(p, ec);
  if (ec) throw UsageError("--plots: cannot create directory '" + dir + "': " + ec.message());
  // Probe: a file must be creatable in it (a read-only directory fails here, before any fitting).
  const auto probe = p / ".ridgewatch-write-test";
  {
    std::ofstream f(probe, std::ios::binary | std::ios::trunc);
    f << "x";
    f.close();
    if (!f) throw UsageError("--plots: cannot write into directory '" + dir + "'");
  }
  std::filesystem::remove(probe, ec);
  return p;
}

void write_all(const std::filesystem::path& dir, const std::string& page_title, const std::string& report_text,
               const std::vector<PlotFile>& files) {
  for (const auto& f : files) write_file(dir / f.file, f.svg);
  std::ostringstream h;
  // HTML5 that is also well-formed XML (void elements closed with "/>").
  h << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\"/>\n<title>" << html_escape(page_title) << "</title>\n"
    << "<style>\nbody { font-family: DejaVu Sans, Arial, sans-serif; max-width: 1000px; margin: 1em auto; padding: 0 1em; color: #222; }\n"
    << "img { max-width: 100%; height: auto; border: 1px solid #ccc; }\n"
    << "pre { background: #f5f5f5; padding: 0.6em; overflow-x: auto; font-size: 12px; }\n"
    << "figure { margin: 2em 0; } figcaption { color: #444; margin-top: 0.3em; }\n</style>\n</head>\n<body>\n"
    << "<h1>" << html_escape(page_title) << "</h1>\n<pre>" << html_escape(report_text) << "</pre>\n<ul>\n";
  for (const auto& f : files) h << "<li><a href=\"#" << html_escape(f.file) << "\">" << html_escape(f.title) << "</a></li>\n";
  h << "</ul>\n";
  for (const auto& f : files)
    h << "<figure id=\"" << html_escape(f.file) << "\">\n<h2>" << html_escape(f.title) << "</h2>\n<a href=\"" << html_escape(f.file)
      << "\"><img src=\"" << html_escape(f.file) << "\" alt=\"" << html_escape(f.title) << "\"/></a>\n<figcaption>"
      << html_escape(f.caption) << "</figcaption>\n</figure>\n";
  h << "</body>\n</html>\n";
  write_file(dir / "index.html", h.str());
}

PlotFile impacts(const ModelFitter& fitter, const FitResult& fit, const FitResult* start) {
  const auto held = heldout_windows(fitter, fit);
  // The worst held-out impact (largest residual power) and a typical one (median of the others).
  std::vector<std::size_t> order = held;
  auto power = [&](std::size_t w) { return w < fit.impact_power.size() ? fit.impact_power[w] : 0.0; };
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return power(a) > power(b); });
  std::vector<std::pair<std::size_t, std::string>> pick;
  if (!order.empty()) pick.push_back({order.front(), "worst"});
  if (order.size() >= 2) pick.push_back({order[1 + (order.size() - 1) / 2], "typical"});

  const double sig_h = 250.0, res_h = 160.0;
  Figure fig(kWidth, kTitle + static_cast<double>(pick.size()) * (sig_h + res_h),
             "Measured vs " + model_label(fit) + " on held-out impacts");
  double y0 = kTitle;
  for (const auto& [w, what] : pick) {
    const auto t = time_ms(fitter, fit, w);
    const auto& win = fitter.segmentation().windows[w];
    // The window exactly: no room wasted by rounding the limits.
    const std::optional<double> t_first = t.size() >= 2 ? std::optional<double>(t.front()) : std::nullopt;
    const std::optional<double> t_last = t.size() >= 2 ? std::optional<double>(t.back()) : std::nullopt;
    Panel s;
    s.x_min = t_first;
    s.x_max = t_last;
    s.title = "held-out impact at " + num(win.onset_s, 4) + " s (" + what + ": excess " + num(power(w) - 1.0) + ")";
    s.y_label = "output";
    s.line(t, measured(fitter, fit, w), kMeasured, "measured");
    if (start && w < start->model.size() && start->model[w].size() == fit.model[w].size())
      s.line(t, start->model[w], kStart, "starting " + model_label(*start));
    s.line(t, fit.model[w], kModel, model_label(fit));
    fig.add(std::move(s), Rect{0, y0, kWidth, sig_h});
    Panel r;
    r.x_min = t_first;
    r.x_max = t_last;
    r.y_label = "residual / σ";
    r.x_label = "time after the impact (ms)";
    r.hline(0.0, Style{"#555555", 0.8, Dash::solid, 1.0});
    r.hline(2.0, kFloor, "±2 σ");
    r.hline(-2.0, kFloor);
    r.line(t, residual_sigma(fitter, fit, w), Style{"#444444", 1.0, Dash::solid, 1.0});
    if (start && w < start->model.size() && start->model[w].size() == fit.model[w].size())
      r.line(t, residual_sigma(fitter, *start, w), Style{"#1f77b4", 0.9, Dash::solid, 0.6}, "starting model");
    r.legend_at = Panel::LegendAt::bottom_right;
    fig.add(std::move(r), Rect{0, y0 + sig_h, kWidth, res_h});
    y0 += sig_h + res_h;
  }
  return {"impacts.svg", "Measured vs model on held-out impacts",
          "The worst held-out impact (largest residual power) and a typical one. The residual is in units of the noise "
          "sd σ between impacts: a good model leaves white noise within about ±2 σ; structure (a beat, a slow drift, "
          "a decay that is too fast or too slow) shows what is missing. Gaps are masked samples (spikes, dropouts).",
          fig.svg()};
}

PlotFile residual_scalogram(const ModelFitter& fitter, const FitResult& fit, const ResidualReport& rep) {
  const auto& seg = fitter.segmentation();
  const double fs = seg.sample_rate_hz;
  const double f0 = f0_of(fitter, rep);
  const double f_lo = 0.2 * f0, f_hi = std::min(3.0 * f0, 0.45 * fs);
  constexpr std::size_t kRows = 72;
  constexpr double kDtMs = 0.2;  // time cell; finer than the kernel's 1.3 ms time sd at f0 ≈ 860 Hz
  const auto held = heldout_windows(fitter, fit);
  std::size_t max_len = 1;
  double t_lo = 0.0, t_hi = 0.0;
  for (std::size_t w : held) {
    max_len = std::max(max_len, fit.model[w].size());
    const auto t = time_ms(fitter, fit, w);
    if (!t.empty()) {
      t_lo = std::min(t_lo, t.front());
      t_hi = std::max(t_hi, t.back());
    }
  }
  double t_end = t_hi;  // the earliest window end: beyond it fewer impacts contribute
  for (std::size_t w : held) {
    const auto t = time_ms(fitter, fit, w);
    if (!t.empty()) t_end = std::min(t_end, t.back());
  }
  const double t0 = std::floor(t_lo / kDtMs) * kDtMs;
  const auto cols = static_cast<std::size_t>(std::max(1.0, std::ceil((t_hi - t0) / kDtMs)));
  std::vector<double> acc(kRows * cols, 0.0), cnt(kRows * cols, 0.0);
  dsp::MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.eta0 = kEta0;
  cfg.frequencies_hz = dsp::make_frequency_grid(f_lo, f_hi, kRows, dsp::GridSpacing::linear);
  cfg.max_samples = max_len;
  dsp::MorletCwt<double> cwt(cfg);
  dsp::Scalogram<double> sc;
  for (std::size_t w : held) {
    const auto r = residual_sigma(fitter, fit, w, true);
    if (r.empty()) continue;
    cwt.transform(r, sc);
    const auto t = time_ms(fitter, fit, w);
    for (std::size_t row = 0; row < sc.rows; ++row)
      for (std::size_t c = 0; c < sc.cols && c < t.size(); ++c) {
        const auto b = static_cast<std::size_t>(std::clamp((t[c] - t0) / kDtMs, 0.0, static_cast<double>(cols - 1)));
        acc[row * cols + b] += std::norm(sc.at(row, c));
        cnt[row * cols + b] += 1.0;
      }
  }
  // RMS |W| over the held-out impacts, divided by that of white noise of variance σ² at the row's
  // frequency (MorletCwt::noise_gain): 1 is the noise floor at every frequency.
  std::vector<double> v(kRows * cols, kNaN);
  double vmax = 2.0;
  for (std::size_t row = 0; row < kRows; ++row) {
    const double gain = cwt.noise_gain(cfg.frequencies_hz[row]);
    for (std::size_t c = 0; c < cols; ++c) {
      const std::size_t k = row * cols + c;
      if (cnt[k] > 0.0 && gain > 0.0) {
        v[k] = std::sqrt(acc[k] / cnt[k] / gain);
        vmax = std::max(vmax, v[k]);
      }
    }
  }
  const double df = (f_hi - f_lo) / static_cast<double>(kRows - 1);
  Panel p;
  p.title = "RMS |CWT| of the held-out residual (" + std::to_string(held.size()) + " impacts), Morlet η0 = 7";
  p.x_label = "time after the impact (ms)";
  p.y_label = "frequency (Hz)";
  p.heatmap(t0, t0 + static_cast<double>(cols) * kDtMs, f_lo - df / 2, f_hi + df / 2, kRows, cols, std::move(v), 0.0, vmax,
            "RMS |W| / white-noise level (1 = noise floor)");
  for (const auto& [name, f] : rep.markers)
    if (f >= f_lo && f <= f_hi) p.hline(f, Style{name == "f0" ? "#ffffff" : "#ff9896", 1.0, Dash::dashed, 0.9}, name);
  // Cone of influence: within two kernel time sds (η0 / (2π f), paper Eq. 4 scale) of a window edge
  // the wavelet reaches past the window, where the residual is taken as zero, so |W| reads low there.
  std::vector<double> cone_f, cone_left, cone_right;
  for (double f : cfg.frequencies_hz) {
    const double two_sd_ms = 2000.0 * dsp::MorletCwt<double>::kernel_time_sd_s(kEta0, f);
    cone_f.push_back(f);
    cone_left.push_back(t_lo + two_sd_ms);
    cone_right.push_back(t_end - two_sd_ms);
  }
  const Style cone{"#ffffff", 1.2, Dash::dotted, 0.8};
  p.line(cone_left, cone_f, cone);
  p.line(cone_right, cone_f, cone);
  p.legend = false;
  Figure fig(kWidth, kTitle + 520.0, "Residual scalogram: where in time and frequency the model misses");
  fig.add(std::move(p), Rect{0, kTitle, kWidth, 520.0});
  return {"residual-scalogram.svg", "Residual scalogram",
          "Bright bands are residual the model does not explain: on a marker f0 ± k·f_z it points to a mesh-periodic "
          "modulation (stiffness variation, transmission error), on k·f_z to a mesh-synchronous signal, elsewhere to a "
          "second mode or a hum; a band that grows or fades with time after the impact points to damping or "
          "stiffness nonlinearity. Outside the dotted white curves (the cone of influence) the wavelet reaches "
          "past the fit window and the level reads low.",
          fig.svg()};
}

PlotFile envelopes(const ModelFitter& fitter, const FitResult& fit, const ResidualReport& rep) {
  const auto& seg = fitter.segmentation();
  const double fs = seg.sample_rate_hz;
  const double f0 = f0_of(fitter, rep);
  const auto held = heldout_windows(fitter, fit);
  std::size_t weak = held.empty() ? 0 : held.front(), strong = weak;
  std::size_t max_len = 1;
  for (std::size_t w : held) {
    max_len = std::max(max_len, fit.model[w].size());
    if (fit.params.ln_force[w] < fit.params.ln_force[weak]) weak = w;
    if (fit.params.ln_force[w] > fit.params.ln_force[strong]) strong = w;
  }
  dsp::MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.eta0 = kEta0;
  cfg.frequencies_hz = {f0};
  cfg.max_samples = max_len;
  dsp::MorletCwt<double> cwt(cfg);
  dsp::Scalogram<double> sc;
  // ln |W(t, f0)|: the wavelet envelope of Eq. (12) (MorletCwt's gain makes |W| the amplitude), whose
  // slope after the impact is -ζ ω0.
  // Shown from the onset to two kernel time sds (2 η0 / (2π f0), 2.6 ms at 860 Hz) before the window
  // end: nearer the end the kernel reaches past the window's last sample and |W| drops for that
  // reason alone.
  const auto edge = static_cast<std::size_t>(2.0 * dsp::MorletCwt<double>::kernel_time_sd_s(kEta0, f0) * fs);
  auto ln_env = [&](const std::vector<double>& x, const std::vector<double>& t) {
    cwt.transform(x, sc);
    std::vector<double> e(sc.cols, kNaN);
    for (std::size_t c = 0; c < sc.cols && c < t.size(); ++c)
      if (t[c] >= 0.0 && c + edge < sc.cols) e[c] = std::log(std::abs(sc.at(0, c)));
    return e;
  };
  Panel p;
  p.title = "ln envelope at f0 = " + num(f0, 4) + " Hz (wavelet η0 = 7)";
  p.x_label = "time after the impact (ms)";
  p.y_label = "ln |W(t, f0)| (output units)";
  if (!held.empty()) {
    const std::vector<std::pair<std::size_t, std::string>> pick = {{strong, "strong"}, {weak, "weak"}};
    for (std::size_t k = 0; k < pick.size(); ++k) {
      const std::size_t w = pick[k].first;
      if (k == 1 && w == strong) break;
      const auto t = time_ms(fitter, fit, w);
      const std::string what = pick[k].second + " (force x" + num(std::exp(fit.params.ln_force[w]), 3) + ")";
      p.line(t, ln_env(measured(fitter, fit, w), t), Style{k == 0 ? "#222222" : "#1f77b4", 1.3, Dash::solid, 1.0}, what + " measured");
      p.line(t, ln_env(fit.model[w], t), Style{k == 0 ? "#d62728" : "#ff7f0e", 1.3, Dash::dashed, 1.0}, what + " model");
    }
  }
  const double floor_level = seg.noise_sd * std::sqrt(cwt.noise_gain(f0));
  if (floor_level > 0.0) p.hline(std::log(floor_level), kFloor, "noise floor (RMS |W| of the noise)");
  p.legend_at = Panel::LegendAt::top_right;
  Figure fig(kWidth, kTitle + 480.0, "ln envelope: measured vs " + model_label(fit));
  fig.add(std::move(p), Rect{0, kTitle, kWidth, 480.0});
  return {"envelopes.svg", "ln envelope, weak and strong impact",
          "A linear viscous model decays along straight lines of slope -ζω0 (paper Eq. 12) with the same slope for "
          "weak and strong impacts. Curvature, or slopes that differ with the amplitude, point to amplitude-dependent "
          "damping (dry friction, quadratic damping); a ripple points to a beat with a second line. Below the noise "
          "floor the measured envelope flattens out: only the part above it carries information. The first ~1 ms "
          "after the onset is the impact smeared by the wavelet; the last two kernel sds of the window (2.6 ms at 860 Hz) "
          "are not shown.",
          fig.svg()};
}

PlotFile backbones(const ResidualReport& rep, const ResidualReport* start) {
  auto pct = [](const std::vector<double>& a) {
    std::vector<double> o(a.size());
    for (std::size_t i = 0; i < a.size(); ++i) o[i] = 100.0 * a[i];
    return o;
  };
  const double h = 400.0, w = kWidth / 2;
  Figure fig(kWidth, kTitle + h, "Backbones: damping and frequency vs amplitude");
  Panel z, f;
  z.title = "equivalent damping ratio";
  z.y_label = "ζ (cycle decrement / 2π)";
  f.title = "cycle frequency";
  f.y_label = "frequency (Hz)";
  for (Panel* p : {&z, &f}) {
    p->x_label = "amplitude (% of the largest cycle)";
    p->x_min = 0.0;
    p->x_max = 100.0;
    p->legend_at = Panel::LegendAt::bottom_right;
  }
  z.line(pct(rep.measured.amplitude_rel), rep.measured.zeta, kMeasured, "measured", true);
  z.line(pct(rep.model.amplitude_rel), rep.model.zeta, kModel, "model", true);
  f.line(pct(rep.measured.amplitude_rel), rep.measured.f_hz, kMeasured, "measured", true);
  f.line(pct(rep.model.amplitude_rel), rep.model.f_hz, kModel, "model", true);
  if (start) {
    z.line(pct(start->model.amplitude_rel), start->model.zeta, kStart, "starting model", true);
    f.line(pct(start->model.amplitude_rel), start->model.f_hz, kStart, "starting model", true);
  }
  fig.add(std::move(z), Rect{0, kTitle, w, h});
  fig.add(std::move(f), Rect{w, kTitle, w, h});
  return {"backbones.svg", "Damping and frequency backbones",
          "Cycle-by-cycle decrement and frequency of the held-out impacts, binned by amplitude (bins with fewer than "
          "3 cycles are gaps). A linear model gives flat lines. Damping rising as the amplitude falls: dry "
          "(Coulomb) friction; rising with amplitude: quadratic damping; frequency changing with amplitude: "
          "stiffness nonlinearity or contact loss.",
          fig.svg()};
}

PlotFile residual_where(const ResidualReport& rep) {
  const double h = 400.0, w = kWidth / 2;
  Figure fig(kWidth, kTitle + h, "Where the residual is: time after the impact and impact amplitude");
  Panel t;
  t.title = "held-out excess per " + num(rep.dt_ms) + " ms after the impact";
  t.x_label = "time after the impact (ms)";
  t.y_label = "excess over the noise floor";
  std::vector<double> tx, ty;
  for (std::size_t b = 0; b < rep.excess_vs_time.size(); ++b) {
    tx.push_back((static_cast<double>(b) + 0.5) * rep.dt_ms);
    ty.push_back(rep.excess_vs_time[b]);
  }
  t.line(tx, ty, Style{"#1f77b4", 1.5, Dash::solid, 1.0}, "", true);
  t.hline(0.0, kFloor, "noise floor (0)");
  t.legend = false;
  Panel a;
  a.title = "held-out impacts";
  a.x_label = "fitted impact force / nominal";
  a.y_label = "excess over the noise floor";
  a.points(rep.impact_amplitude, rep.impact_excess, Style{"#d62728", 1.0, Dash::solid, 1.0}, "", 3.5);
  a.hline(0.0, kFloor, "noise floor (0)");
  a.legend = false;
  fig.add(std::move(t), Rect{0, kTitle, w, h});
  fig.add(std::move(a), Rect{w, kTitle, w, h});
  return {"residual-where.svg", "Residual vs time after the impact and vs amplitude",
          "Left: excess right after the onset points to the impact pulse or the onset; growing later in the decay "
          "points to damping or frequency (the model decays too fast or too slow, or drifts in phase). Right: excess "
          "that grows with the impact force points to a nonlinearity (stiffness, quadratic damping, contact loss); "
          "excess at weak impacts to dry friction; one or two outliers to a disturbed impact.",
          fig.svg()};
}

PlotFile residual_spectra(const std::vector<std::pair<std::string, const ResidualReport*>>& steps) {
  Panel p;
  p.title = "mean periodogram of the held-out residual / σ² (1 = white noise floor)";
  p.x_label = "frequency (Hz)";
  p.y_label = "residual level / noise floor";
  p.y_log = true;
  p.y_min = 0.1;
  p.x_min = 0.0;
  const ResidualReport* last = steps.empty() ? nullptr : steps.back().second;
  for (std::size_t i = 0; i < steps.size(); ++i) {
    const auto& rep = *steps[i].second;
    const Style st{plot::palette(i), 1.3, Dash::solid, 0.9};
    p.line(rep.spectrum_f_hz, rep.spectrum_level, st, steps[i].first);
    std::vector<double> px, py;
    for (const auto& pk : rep.peaks) {
      px.push_back(pk.f_hz);
      py.push_back(pk.level);
    }
    p.points(px, py, st, "", 3.5);
  }
  if (last) {
    if (!last->spectrum_f_hz.empty()) p.x_max = last->spectrum_f_hz.back();
    for (const auto& [name, f] : last->markers) p.vline(f, Style{name == "f0" ? "#2ca02c" : "#8c8c8c", 1.0, Dash::dotted, 1.0}, name);
    std::size_t shown = 0;
    for (const auto& pk : last->peaks) {
      if (shown++ >= 4) break;
      p.annotate(pk.f_hz, pk.level, num(pk.f_hz, 4) + " Hz" + (pk.marker.empty() ? "" : " (" + pk.marker + ")"));
    }
  }
  p.hline(1.0, kFloor, "noise floor");
  p.hline(4.0, Style{"#bcbd22", 1.0, Dash::dashed, 1.0}, "line threshold (4)");
  Figure fig(kWidth, kTitle + 500.0, steps.size() > 1 ? "Residual spectrum per step" : "Residual spectrum");
  fig.add(std::move(p), Rect{0, kTitle, kWidth, 500.0});
  return {"residual-spectrum.svg", steps.size() > 1 ? "Residual spectrum per step" : "Residual spectrum",
          "Lines above the threshold are structured residual (dots: detected lines; the strongest of the last step "
          "are labelled). On f0 ± k·f_z: mesh-periodic modulation; on k·f_z: a mesh-synchronous signal; elsewhere: a "
          "second mode or a hum. A broad hump around f0 means the decay itself is wrong (damping or frequency). "
          "Each accepted effect should pull its curve down to the floor.",
          fig.svg()};
}

PlotFile candidate_ladder(const diagnosis::DiagnoseResult& r) {
  std::vector<double> all{r.baseline_excess};
  for (const auto& s : r.steps) {
    all.push_back(s.excess_after);
    all.push_back(s.excess_before);
  }
  const bool log = excess_log_axis(all);
  Panel p;
  p.title = "held-out excess after adding each candidate (baseline " + num(r.baseline_excess) + ", final " + num(r.final_excess) + ")";
  p.y_label = std::string("held-out excess over the noise floor") + (log ? " (<= 0.01 shown at 0.01)" : "");
  p.y_log = log;
  if (log) p.y_min = 0.5 * kExcessFloor;
  const std::string kAccepted = "#2ca02c", kPassed = "#1f77b4", kRejected = "#9a9a9a", kImplausible = "#ff7f0e";
  for (std::size_t i = 0; i < r.steps.size(); ++i) {
    const auto& s = r.steps[i];
    std::string colour = kRejected, cls = "bar rejected", what = "rejected";
    if (s.accepted) colour = kAccepted, cls = "bar accepted", what = "accepted";
    else if (s.passed) colour = kPassed, cls = "bar passed", what = "passed the gate, not the best";
    else if (!s.plausible) colour = kImplausible, cls = "bar implausible", what = "implausible: " + s.plausibility;
    const std::string tip = s.effect + ", round " + std::to_string(s.round) + ": " + what + "; excess " + num(s.excess_before) + " -> " +
                            num(s.excess_after) + " (need gain > " + num(s.required_gain, 2) + "), " +
                            num(100 * s.fraction_improved, 3) + " % impacts improve, dBIC " + num(s.delta_bic, 4);
    p.bar("R" + std::to_string(s.round) + " " + s.effect, clamp_excess(s.excess_after, log), colour, cls, tip);
  }
  // The excess before each round over that round's bars.
  bool labelled = false;
  for (std::size_t i = 0; i < r.steps.size();) {
    std::size_t e = i;
    while (e < r.steps.size() && r.steps[e].round == r.steps[i].round) ++e;
    const double y = clamp_excess(r.steps[i].excess_before, log);
    p.segment(static_cast<double>(i) - 0.45, y, static_cast<double>(e) - 0.55, y, Style{"#000000", 1.5, Dash::dashed, 1.0},
              labelled ? "" : "excess before the round");
    labelled = true;
    i = e;
  }
  p.hline(0.1, kTarget, "target 0.1");
  p.legend_entry("accepted", Style{kAccepted}, true);
  p.legend_entry("passed, not the best", Style{kPassed}, true);
  p.legend_entry("rejected by the gate", Style{kRejected}, true);
  p.legend_entry("implausible fitted values", Style{kImplausible}, true);
  p.legend_at = Panel::LegendAt::above;
  if (r.steps.empty()) p.annotate(0.0, 0.1, "no candidate was tried");
  Figure fig(kWidth, kTitle + 520.0, "Candidate ladder");
  fig.add(std::move(p), Rect{0, kTitle, kWidth, 520.0});
  return {"candidate-ladder.svg", "Candidate ladder",
          "One bar per candidate tried, grouped by round (R1, R2, ...): the held-out excess with that effect added. "
          "Accepted candidates pass all four gates (clear held-out gain, >= 75 % of held-out impacts improve, "
          "ΔBIC < -10, plausible values) and are the best of their round. Hover a bar for its numbers.",
          fig.svg()};
}

std::vector<HistoryRun> read_history(const std::string& path, const std::string& data_file) {
  std::vector<HistoryRun> runs;
  std::ifstream f(path);
  std::string line;
  while (std::getline(f, line)) {
    const auto j = nlohmann::json::parse(line, nullptr, false);
    if (j.is_discarded() || !j.is_object() || !j.contains("file") || !j["file"].is_string() || j["file"].get<std::string>() != data_file)
      continue;
    HistoryRun r;
    try {
      r.model = j.value("model", std::vector<std::string>{});
      r.verdict = j.value("verdict", std::vector<std::string>{});
      r.baseline_excess = j.value("baseline_excess", kNaN);
      r.final_excess = j.value("final_excess", kNaN);
    } catch (const nlohmann::json::exception&) {
      continue;  // a line of another shape: not a diagnose record
    }
    runs.push_back(r);
  }
  return runs;
}

PlotFile error_fall(const diagnosis::DiagnoseResult& r, const std::vector<HistoryRun>& history) {
  std::vector<double> all;
  for (const auto& rd : r.rounds) all.push_back(rd.heldout_excess);
  for (const auto& h : history) all.insert(all.end(), {h.baseline_excess, h.final_excess});
  const bool log = excess_log_axis(all);
  Panel p;
  p.title = "this run: held-out excess of the model after each round";
  p.x_label = "round (0 = starting model)";
  p.y_label = "held-out excess";
  p.y_log = log;
  if (log) p.y_min = 0.5 * kExcessFloor;
  p.x_integer_ticks = true;
  p.x_min = -0.5;
  p.x_max = std::max(1.0, static_cast<double>(r.rounds.size())) - 0.5 + 0.6;
  std::vector<double> x, y;
  for (std::size_t i = 0; i < r.rounds.size(); ++i) {
    x.push_back(static_cast<double>(i));
    y.push_back(clamp_excess(r.rounds[i].heldout_excess, log));
    const auto& ef = r.rounds[i].effects;
    const std::string what = i == 0 ? "start " + effect_list(ef) : "+" + (ef.empty() ? std::string("?") : ef.back());
    p.annotate(x.back(), y.back(), what + ": " + num(r.rounds[i].heldout_excess));
  }
  p.line(x, y, Style{"#1f77b4", 2.0, Dash::solid, 1.0}, "held-out excess", true);
  p.hline(0.1, kTarget, "target 0.1");
  p.legend = false;
  const double h1 = 380.0, h2 = 380.0;
  const bool with_history = !history.empty();
  Figure fig(kWidth, kTitle + h1 + (with_history ? h2 : 0.0), "Watch the error fall");
  fig.add(std::move(p), Rect{0, kTitle, kWidth, h1});
  if (with_history) {
    Panel q;
    q.title = "history: runs on this file (--history), excess of the given model and after diagnose";
    q.x_label = "run";
    q.y_label = "held-out excess";
    q.y_log = log;
    if (log) q.y_min = 0.5 * kExcessFloor;
    q.x_integer_ticks = true;
    q.x_min = 0.5;
    q.x_max = static_cast<double>(history.size()) + 1.0;
    std::vector<double> hx, hb, hf;
    for (std::size_t i = 0; i < history.size(); ++i) {
      hx.push_back(static_cast<double>(i + 1));
      hb.push_back(clamp_excess(history[i].baseline_excess, log));
      hf.push_back(clamp_excess(history[i].final_excess, log));
      q.annotate(hx.back(), hb.back(), effect_list(history[i].model));
    }
    q.line(hx, hb, Style{"#7f7f7f", 1.5, Dash::solid, 1.0}, "given model", true);
    q.line(hx, hf, Style{"#2ca02c", 1.5, Dash::solid, 1.0}, "after diagnose", true);
    q.hline(0.1, kTarget, "target 0.1");
    q.legend_at = Panel::LegendAt::bottom_left;
    fig.add(std::move(q), Rect{0, kTitle + h1, kWidth, h2});
  }
  return {"error-fall.svg", "Watch the error fall",
          "Held-out excess over the noise floor of the starting model and after each accepted effect; the goal is "
          "below 0.1 (red). With --history, the lower panel shows every recorded run on this file: the model given "
          "(grey, labelled) and what diagnose reached from it (green).",
          fig.svg()};
}

}  // namespace ridgewatch::cli::plots
