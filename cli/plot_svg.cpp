#include "cli/plot_svg.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>
#include <utility>

namespace ridgewatch::cli::plot {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Pixel coordinates with two decimals: finer than any screen, short files.
std::string px(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", v);
  return buf;
}

std::string fmt_g(double v, int digits) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

std::string dash_attr(Dash d) {
  switch (d) {
    case Dash::dashed: return " stroke-dasharray=\"6 4\"";
    case Dash::dotted: return " stroke-dasharray=\"2 3\"";
    case Dash::solid: break;
  }
  return "";
}

std::string stroke_attrs(const Style& s) {
  std::string a = " stroke=\"" + escape_xml(s.colour) + "\" stroke-width=\"" + px(s.width) + "\"" + dash_attr(s.dash);
  if (s.opacity < 1.0) a += " stroke-opacity=\"" + px(s.opacity) + "\"";
  return a;
}

bool drawable(double v, bool log) { return std::isfinite(v) && (!log || v > 0.0); }

// Layout constants (px).
constexpr double kLeft = 74.0, kRight = 18.0, kTop = 26.0, kBottom = 46.0;
constexpr double kCategoryBottom = 110.0;  // room for rotated category names
constexpr double kColourBar = 78.0;        // extra right margin for a heat map's colour bar

struct Range {
  double lo = std::numeric_limits<double>::infinity(), hi = -std::numeric_limits<double>::infinity();
  void add(double v, bool log) {
    if (!drawable(v, log)) return;
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  bool empty() const { return !(lo <= hi); }
};

// Final axis limits: fixed ones where given, else the data range widened to nice values.
std::pair<double, double> limits(Range r, std::optional<double> fix_lo, std::optional<double> fix_hi, bool log, bool widen) {
  if (fix_lo) r.lo = *fix_lo;
  if (fix_hi) r.hi = *fix_hi;
  if (r.empty()) {
    if (log) return {fix_lo.value_or(1.0), fix_hi.value_or(10.0)};
    return {fix_lo.value_or(0.0), fix_hi.value_or(1.0)};
  }
  if (r.lo == r.hi) {
    if (log) {
      r.lo /= 10.0;
      r.hi *= 10.0;
    } else {
      const double d = r.lo == 0.0 ? 1.0 : 0.1 * std::abs(r.lo);
      r.lo -= d;
      r.hi += d;
    }
  }
  if (!widen) return {r.lo, r.hi};
  if (log) {
    const double lo = fix_lo ? r.lo : std::pow(10.0, std::floor(std::log10(r.lo) + 1e-9));
    const double hi = fix_hi ? r.hi : std::pow(10.0, std::ceil(std::log10(r.hi) - 1e-9));
    return {lo, hi};
  }
  const Ticks t = linear_ticks(r.lo, r.hi);
  const double step = t.values.size() >= 2 ? t.values[1] - t.values[0] : (r.hi - r.lo);
  const double lo = fix_lo ? r.lo : std::floor(r.lo / step + 1e-9) * step;
  const double hi = fix_hi ? r.hi : std::ceil(r.hi / step - 1e-9) * step;
  return {lo, hi};
}

struct Layout {
  Rect plot;  // the plotting area inside the axes
  Scale x, y;
};

}  // namespace

std::string escape_xml(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      case '\'': out += "&apos;"; break;
      default:
        // Control characters other than tab/newline are not allowed in XML 1.0: drop them.
        if (static_cast<unsigned char>(c) < 0x20 && c != '\t' && c != '\n' && c != '\r') break;
        out += c;
    }
  }
  return out;
}

Ticks linear_ticks(double lo, double hi, int target) {
  Ticks t;
  if (!(std::isfinite(lo) && std::isfinite(hi) && lo < hi) || target < 1) return t;
  const double raw = (hi - lo) / target;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  double step = 10.0 * mag;
  for (double m : {1.0, 2.0, 5.0})
    if (m * mag >= raw * (1.0 - 1e-9)) {
      step = m * mag;
      break;
    }
  const auto k0 = static_cast<long long>(std::ceil(lo / step - 1e-9));
  const auto k1 = static_cast<long long>(std::floor(hi / step + 1e-9));
  const int decimals = std::max(0, static_cast<int>(-std::floor(std::log10(step) + 1e-9)));
  const bool sci = std::max(std::abs(lo), std::abs(hi)) >= 1e6 || step < 1e-4;
  for (long long k = k0; k <= k1; ++k) {
    double v = static_cast<double>(k) * step;
    if (std::abs(v) < 1e-12 * step) v = 0.0;
    t.values.push_back(v);
    char buf[40];
    if (sci) std::snprintf(buf, sizeof buf, "%.3g", v);
    else std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
    t.labels.push_back(buf);
  }
  return t;
}

Ticks log_ticks(double lo, double hi) {
  Ticks t;
  if (!(std::isfinite(lo) && std::isfinite(hi) && lo > 0.0 && lo < hi)) return t;
  const int d0 = static_cast<int>(std::floor(std::log10(lo) + 1e-9));
  const int d1 = static_cast<int>(std::ceil(std::log10(hi) - 1e-9));
  const int decades = d1 - d0;
  const int stride = std::max(1, (decades + 9) / 10);
  const bool fine = std::log10(hi / lo) <= 2.5;
  for (int k = d0; k <= d1; ++k) {
    for (double m : {1.0, 2.0, 5.0}) {
      if (m != 1.0 && !fine) continue;
      if (m == 1.0 && (k - d0) % stride != 0) continue;
      const double v = m * std::pow(10.0, k);
      if (v < lo * (1.0 - 1e-9) || v > hi * (1.0 + 1e-9)) continue;
      t.values.push_back(v);
      t.labels.push_back(k >= -4 && k <= 5 ? fmt_g(v, 6) : fmt_g(m, 1) + "e" + std::to_string(k));
    }
  }
  return t;
}

double Scale::operator()(double v) const {
  if (!drawable(v, log)) return kNaN;
  double t = log ? (std::log10(v) - std::log10(lo)) / (std::log10(hi) - std::log10(lo)) : (v - lo) / (hi - lo);
  // Far-off points still draw their line towards the right direction; the clip path hides them.
  t = std::clamp(t, -50.0, 50.0);
  return px_lo + t * (px_hi - px_lo);
}

std::string palette(std::size_t i) {
  static const char* const kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd",
                                         "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#bcbd22"};
  return kColours[i % (sizeof kColours / sizeof kColours[0])];
}

std::string colour_map(double t) {
  // Anchors of a viridis-like map; linear interpolation in RGB between them.
  static const double kAnchors[][3] = {{68, 1, 84}, {59, 82, 139}, {33, 145, 140}, {94, 201, 98}, {253, 231, 37}};
  constexpr int kN = 5;
  if (!std::isfinite(t)) t = 0.0;
  t = std::clamp(t, 0.0, 1.0) * (kN - 1);
  const int i = std::min(static_cast<int>(t), kN - 2);
  const double f = t - i;
  char buf[8];
  int c[3];
  for (int k = 0; k < 3; ++k) c[k] = static_cast<int>(std::lround(kAnchors[i][k] + f * (kAnchors[i + 1][k] - kAnchors[i][k])));
  std::snprintf(buf, sizeof buf, "#%02x%02x%02x", c[0], c[1], c[2]);
  return buf;
}

void Panel::line(std::vector<double> x, std::vector<double> y, Style style, std::string label, bool markers) {
  series_.push_back({std::move(x), std::move(y), std::move(style), std::move(label), true, markers, 2.5});
}

void Panel::points(std::vector<double> x, std::vector<double> y, Style style, std::string label, double radius) {
  series_.push_back({std::move(x), std::move(y), std::move(style), std::move(label), false, true, radius});
}

void Panel::hline(double y, Style style, std::string label) { refs_.push_back({true, y, std::move(style), std::move(label)}); }
void Panel::vline(double x, Style style, std::string label) { refs_.push_back({false, x, std::move(style), std::move(label)}); }

void Panel::segment(double x0, double y0, double x1, double y1, Style style, std::string label) {
  segs_.push_back({x0, y0, x1, y1, std::move(style), std::move(label)});
}

void Panel::annotate(double x, double y, std::string text) { notes_.push_back({x, y, std::move(text)}); }

void Panel::bar(std::string category, double value, std::string colour, std::string css_class, std::string tooltip) {
  bars_.push_back({std::move(category), value, std::move(colour), std::move(css_class), std::move(tooltip)});
}

void Panel::legend_entry(std::string label, Style style, bool swatch) { entries_.push_back({std::move(label), std::move(style), swatch}); }

void Panel::heatmap(double x0, double x1, double y0, double y1, std::size_t rows, std::size_t cols, std::vector<double> values,
                    double vmin, double vmax, std::string colour_label) {
  values.resize(rows * cols, kNaN);
  heat_ = Heat{x0, x1, y0, y1, rows, cols, std::move(values), vmin, vmax, std::move(colour_label)};
}

Figure::Figure(double width_px, double height_px, std::string title) : width_(width_px), height_(height_px), title_(std::move(title)) {}

void Figure::add(Panel panel, Rect outer) { panels_.push_back({std::move(panel), outer}); }

namespace {

constexpr double kLegendRow = 20.0;  // extra top margin for a legend above the plotting area

Layout layout_of(const Panel& p, const Rect& o) {
  Layout L;
  const double right = kRight + (p.has_heatmap() ? kColourBar : 0.0);
  const double bottom = p.categorical() ? kCategoryBottom : kBottom;
  const double top = kTop + (p.legend && p.legend_at == Panel::LegendAt::above ? kLegendRow : 0.0);
  L.plot = {o.x + kLeft, o.y + top, std::max(10.0, o.w - kLeft - right), std::max(10.0, o.h - top - bottom)};
  return L;
}

}  // namespace

std::pair<Scale, Scale> Figure::scales(std::size_t panel_index) const {
  const Placed& pl = panels_.at(panel_index);
  const Panel& p = pl.panel;
  Range rx, ry;
  for (const auto& s : p.series_) {
    const std::size_t n = std::min(s.x.size(), s.y.size());
    for (std::size_t i = 0; i < n; ++i) {
      if (!drawable(s.x[i], p.x_log) || !drawable(s.y[i], p.y_log)) continue;
      rx.add(s.x[i], p.x_log);
      ry.add(s.y[i], p.y_log);
    }
  }
  for (const auto& r : p.refs_) (r.horizontal ? ry : rx).add(r.at, r.horizontal ? p.y_log : p.x_log);
  for (const auto& s : p.segs_) {
    rx.add(s.x0, p.x_log);
    rx.add(s.x1, p.x_log);
    ry.add(s.y0, p.y_log);
    ry.add(s.y1, p.y_log);
  }
  for (const auto& b : p.bars_) ry.add(b.value, p.y_log);
  if (!p.bars_.empty() && !p.y_log) ry.add(0.0, false);
  if (p.heat_) {
    rx.add(p.heat_->x0, p.x_log);
    rx.add(p.heat_->x1, p.x_log);
    ry.add(p.heat_->y0, p.y_log);
    ry.add(p.heat_->y1, p.y_log);
  }
  const bool cat = p.categorical();
  std::pair<double, double> xl, yl;
  if (cat) xl = {-0.5, static_cast<double>(p.bars_.size()) - 0.5};
  else xl = limits(rx, p.x_min, p.x_max, p.x_log, !p.heat_);
  yl = limits(ry, p.y_min, p.y_max, p.y_log, !p.heat_);
  const Layout L = layout_of(p, pl.outer);
  Scale sx{xl.first, xl.second, L.plot.x, L.plot.x + L.plot.w, p.x_log && !cat};
  Scale sy{yl.first, yl.second, L.plot.y + L.plot.h, L.plot.y, p.y_log};
  return {sx, sy};
}

std::string Figure::svg() const {
  std::ostringstream o;
  o << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
    << "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"" << px(width_) << "\" height=\"" << px(height_)
    << "\" viewBox=\"0 0 " << px(width_) << " " << px(height_) << "\" font-family=\"DejaVu Sans, Arial, sans-serif\" font-size=\"12\">\n";
  o << "<rect x=\"0\" y=\"0\" width=\"" << px(width_) << "\" height=\"" << px(height_) << "\" fill=\"#ffffff\"/>\n";
  if (!title_.empty())
    o << "<text class=\"title\" x=\"" << px(width_ / 2) << "\" y=\"20\" text-anchor=\"middle\" font-size=\"15\" font-weight=\"bold\">"
      << escape_xml(title_) << "</text>\n";
  for (std::size_t pi = 0; pi < panels_.size(); ++pi) {
    const Panel& p = panels_[pi].panel;
    const Rect& outer = panels_[pi].outer;
    const bool cat = p.categorical();
    const auto [sx, sy] = scales(pi);
    const Layout L = layout_of(p, outer);
    const Rect& a = L.plot;
    const std::string clip = "clip" + std::to_string(pi);
    o << "<g class=\"panel\">\n";
    o << "<defs><clipPath id=\"" << clip << "\"><rect x=\"" << px(a.x) << "\" y=\"" << px(a.y) << "\" width=\"" << px(a.w)
      << "\" height=\"" << px(a.h) << "\"/></clipPath></defs>\n";

    // Grid and tick labels.
    const Ticks ty = p.y_log ? log_ticks(sy.lo, sy.hi) : linear_ticks(sy.lo, sy.hi);
    for (std::size_t k = 0; k < ty.values.size(); ++k) {
      const double y = sy(ty.values[k]);
      o << "<line x1=\"" << px(a.x) << "\" y1=\"" << px(y) << "\" x2=\"" << px(a.x + a.w) << "\" y2=\"" << px(y)
        << "\" stroke=\"#e3e3e3\" stroke-width=\"1\"/>\n";
      o << "<text class=\"ytick\" x=\"" << px(a.x - 6) << "\" y=\"" << px(y) << "\" dy=\"0.35em\" text-anchor=\"end\">"
        << escape_xml(ty.labels[k]) << "</text>\n";
    }
    if (cat) {
      for (std::size_t k = 0; k < p.bars_.size(); ++k) {
        const double x = sx(static_cast<double>(k));
        const double y = a.y + a.h + 12;
        o << "<text class=\"xcat\" x=\"" << px(x) << "\" y=\"" << px(y) << "\" text-anchor=\"end\" font-size=\"11\" transform=\"rotate(-35 "
          << px(x) << " " << px(y) << ")\">" << escape_xml(p.bars_[k].category) << "</text>\n";
      }
    } else {
      Ticks tx = p.x_log ? log_ticks(sx.lo, sx.hi) : linear_ticks(sx.lo, sx.hi, std::max(3, static_cast<int>(a.w / 90)));
      if (p.x_integer_ticks) {
        Ticks whole;
        for (std::size_t k = 0; k < tx.values.size(); ++k)
          if (tx.values[k] == std::round(tx.values[k])) {
            whole.values.push_back(tx.values[k]);
            whole.labels.push_back(std::to_string(std::lround(tx.values[k])));
          }
        tx = std::move(whole);
      }
      for (std::size_t k = 0; k < tx.values.size(); ++k) {
        const double x = sx(tx.values[k]);
        o << "<line x1=\"" << px(x) << "\" y1=\"" << px(a.y) << "\" x2=\"" << px(x) << "\" y2=\"" << px(a.y + a.h)
          << "\" stroke=\"#e3e3e3\" stroke-width=\"1\"/>\n";
        o << "<text class=\"xtick\" x=\"" << px(x) << "\" y=\"" << px(a.y + a.h + 15) << "\" text-anchor=\"middle\">"
          << escape_xml(tx.labels[k]) << "</text>\n";
      }
    }

    // Heat map (under everything else), merged into runs of equal colour per row.
    if (p.heat_) {
      const auto& h = *p.heat_;
      const double span = h.vmax > h.vmin ? h.vmax - h.vmin : 1.0;
      o << "<g clip-path=\"url(#" << clip << ")\" shape-rendering=\"crispEdges\">\n";
      for (std::size_t r = 0; r < h.rows; ++r) {
        const double ya = sy(h.y0 + (h.y1 - h.y0) * static_cast<double>(r) / static_cast<double>(h.rows));
        const double yb = sy(h.y0 + (h.y1 - h.y0) * static_cast<double>(r + 1) / static_cast<double>(h.rows));
        std::size_t c = 0;
        while (c < h.cols) {
          const double v = h.values[r * h.cols + c];
          if (!std::isfinite(v)) {
            ++c;
            continue;
          }
          const std::string col = colour_map((v - h.vmin) / span);
          std::size_t e = c + 1;
          while (e < h.cols && std::isfinite(h.values[r * h.cols + e]) && colour_map((h.values[r * h.cols + e] - h.vmin) / span) == col) ++e;
          const double xa = sx(h.x0 + (h.x1 - h.x0) * static_cast<double>(c) / static_cast<double>(h.cols));
          const double xb = sx(h.x0 + (h.x1 - h.x0) * static_cast<double>(e) / static_cast<double>(h.cols));
          o << "<rect x=\"" << px(std::min(xa, xb)) << "\" y=\"" << px(std::min(ya, yb)) << "\" width=\"" << px(std::abs(xb - xa) + 0.3)
            << "\" height=\"" << px(std::abs(yb - ya) + 0.3) << "\" fill=\"" << col << "\"/>\n";
          c = e;
        }
      }
      o << "</g>\n";
      // Colour bar.
      const double bx = a.x + a.w + 14, bw = 14;
      constexpr int kSteps = 64;
      o << "<g class=\"colourbar\" shape-rendering=\"crispEdges\">\n";
      for (int k = 0; k < kSteps; ++k) {
        const double y0 = a.y + a.h * (1.0 - static_cast<double>(k + 1) / kSteps);
        o << "<rect x=\"" << px(bx) << "\" y=\"" << px(y0) << "\" width=\"" << px(bw) << "\" height=\"" << px(a.h / kSteps + 0.3)
          << "\" fill=\"" << colour_map((k + 0.5) / kSteps) << "\"/>\n";
      }
      o << "</g>\n";
      const Ticks tc = linear_ticks(h.vmin, h.vmax, 5);
      for (std::size_t k = 0; k < tc.values.size(); ++k) {
        const double y = a.y + a.h * (1.0 - (tc.values[k] - h.vmin) / span);
        o << "<text x=\"" << px(bx + bw + 4) << "\" y=\"" << px(y) << "\" dy=\"0.35em\" font-size=\"10\">" << escape_xml(tc.labels[k])
          << "</text>\n";
      }
      const double lx = bx + bw + 44, ly = a.y + a.h / 2;
      o << "<text x=\"" << px(lx) << "\" y=\"" << px(ly) << "\" text-anchor=\"middle\" font-size=\"11\" transform=\"rotate(-90 " << px(lx)
        << " " << px(ly) << ")\">" << escape_xml(h.label) << "</text>\n";
    }

    // Bars.
    if (cat) {
      const double base = p.y_log ? sy.lo : 0.0;
      for (std::size_t k = 0; k < p.bars_.size(); ++k) {
        const auto& b = p.bars_[k];
        const double yv = sy(b.value), yb = sy(base);
        if (!std::isfinite(yv)) continue;
        const double x0 = sx(static_cast<double>(k) - 0.35), x1 = sx(static_cast<double>(k) + 0.35);
        o << "<rect class=\"" << escape_xml(b.css_class) << "\" x=\"" << px(x0) << "\" y=\"" << px(std::min(yv, yb)) << "\" width=\""
          << px(x1 - x0) << "\" height=\"" << px(std::abs(yb - yv)) << "\" fill=\"" << escape_xml(b.colour) << "\" clip-path=\"url(#"
          << clip << ")\">";
        if (!b.tooltip.empty()) o << "<title>" << escape_xml(b.tooltip) << "</title>";
        o << "</rect>\n";
      }
    }

    // Reference lines and segments.
    for (const auto& r : p.refs_) {
      const double v = r.horizontal ? sy(r.at) : sx(r.at);
      if (!std::isfinite(v)) continue;
      if (r.horizontal) {
        if (v < a.y - 0.5 || v > a.y + a.h + 0.5) continue;
        o << "<line class=\"ref\" x1=\"" << px(a.x) << "\" y1=\"" << px(v) << "\" x2=\"" << px(a.x + a.w) << "\" y2=\"" << px(v) << "\""
          << stroke_attrs(r.style) << "/>\n";
        if (!r.label.empty())
          o << "<text x=\"" << px(a.x + a.w - 4) << "\" y=\"" << px(v - 3) << "\" text-anchor=\"end\" font-size=\"10\" fill=\""
            << escape_xml(r.style.colour) << "\">" << escape_xml(r.label) << "</text>\n";
      } else {
        if (v < a.x - 0.5 || v > a.x + a.w + 0.5) continue;
        o << "<line class=\"ref\" x1=\"" << px(v) << "\" y1=\"" << px(a.y) << "\" x2=\"" << px(v) << "\" y2=\"" << px(a.y + a.h) << "\""
          << stroke_attrs(r.style) << "/>\n";
        if (!r.label.empty()) {
          const double lx = v + 3, ly = a.y + 4;
          o << "<text x=\"" << px(lx) << "\" y=\"" << px(ly) << "\" text-anchor=\"end\" font-size=\"10\" fill=\"" << escape_xml(r.style.colour)
            << "\" transform=\"rotate(-90 " << px(lx) << " " << px(ly) << ")\" dy=\"0.8em\">" << escape_xml(r.label) << "</text>\n";
        }
      }
    }
    for (const auto& s : p.segs_) {
      const double x0 = sx(s.x0), y0 = sy(s.y0), x1 = sx(s.x1), y1 = sy(s.y1);
      if (!(std::isfinite(x0) && std::isfinite(y0) && std::isfinite(x1) && std::isfinite(y1))) continue;
      o << "<line class=\"segment\" x1=\"" << px(x0) << "\" y1=\"" << px(y0) << "\" x2=\"" << px(x1) << "\" y2=\"" << px(y1) << "\""
        << stroke_attrs(s.style) << " clip-path=\"url(#" << clip << ")\"/>\n";
    }

    // Series: a path with a new subpath after every gap, then the markers.
    for (const auto& s : p.series_) {
      const std::size_t n = std::min(s.x.size(), s.y.size());
      if (s.line) {
        std::string d;
        bool pen = false;
        for (std::size_t i = 0; i < n; ++i) {
          const double x = sx(s.x[i]), y = sy(s.y[i]);
          if (!std::isfinite(x) || !std::isfinite(y)) {
            pen = false;
            continue;
          }
          d += (pen ? "L" : (d.empty() ? "M" : " M")) + px(x) + " " + px(y);
          pen = true;
        }
        if (!d.empty())
          o << "<path class=\"series\" d=\"" << d << "\" fill=\"none\"" << stroke_attrs(s.style)
            << " stroke-linejoin=\"round\" clip-path=\"url(#" << clip << ")\"/>\n";
      }
      if (s.markers) {
        o << "<g fill=\"" << escape_xml(s.style.colour) << "\" clip-path=\"url(#" << clip << ")\">";
        for (std::size_t i = 0; i < n; ++i) {
          const double x = sx(s.x[i]), y = sy(s.y[i]);
          if (!std::isfinite(x) || !std::isfinite(y)) continue;
          o << "<circle cx=\"" << px(x) << "\" cy=\"" << px(y) << "\" r=\"" << px(s.radius) << "\"/>";
        }
        o << "</g>\n";
      }
    }
    for (const auto& nt : p.notes_) {
      const double x = sx(nt.x), y = sy(nt.y);
      if (!std::isfinite(x) || !std::isfinite(y)) continue;
      o << "<text class=\"note\" x=\"" << px(x + 4) << "\" y=\"" << px(y - 6) << "\" font-size=\"10\">" << escape_xml(nt.text) << "</text>\n";
    }

    // Frame, titles, axis labels.
    o << "<rect x=\"" << px(a.x) << "\" y=\"" << px(a.y) << "\" width=\"" << px(a.w) << "\" height=\"" << px(a.h)
      << "\" fill=\"none\" stroke=\"#333333\" stroke-width=\"1\"/>\n";
    if (!p.title.empty()) {
      const double title_y = a.y - 8 - (p.legend && p.legend_at == Panel::LegendAt::above ? kLegendRow : 0.0);
      o << "<text class=\"ptitle\" x=\"" << px(a.x) << "\" y=\"" << px(title_y) << "\" font-size=\"13\">" << escape_xml(p.title) << "</text>\n";
    }
    if (!p.x_label.empty())
      o << "<text class=\"xlabel\" x=\"" << px(a.x + a.w / 2) << "\" y=\"" << px(outer.y + outer.h - 8) << "\" text-anchor=\"middle\">"
        << escape_xml(p.x_label) << "</text>\n";
    if (!p.y_label.empty()) {
      const double lx = outer.x + 16, ly = a.y + a.h / 2;
      o << "<text class=\"ylabel\" x=\"" << px(lx) << "\" y=\"" << px(ly) << "\" text-anchor=\"middle\" transform=\"rotate(-90 " << px(lx)
        << " " << px(ly) << ")\">" << escape_xml(p.y_label) << "</text>\n";
    }

    // Legend: labelled series and segments, then the extra entries.
    struct Item {
      std::string label;
      Style style;
      bool swatch, dot;
    };
    std::vector<Item> items;
    for (const auto& s : p.series_)
      if (!s.label.empty()) items.push_back({s.label, s.style, false, !s.line});
    for (const auto& s : p.segs_)
      if (!s.label.empty()) items.push_back({s.label, s.style, false, false});
    for (const auto& e : p.entries_) items.push_back({e.label, e.style, e.swatch, false});
    // The glyph of a legend entry, 22 px wide from x, centred on y.
    auto glyph = [&](const Item& it, double x, double y) {
      if (it.swatch)
        o << "<rect x=\"" << px(x + 2) << "\" y=\"" << px(y - 5) << "\" width=\"18\" height=\"10\" fill=\"" << escape_xml(it.style.colour) << "\"/>";
      else if (it.dot)
        o << "<circle cx=\"" << px(x + 11) << "\" cy=\"" << px(y) << "\" r=\"3\" fill=\"" << escape_xml(it.style.colour) << "\"/>";
      else
        o << "<line x1=\"" << px(x) << "\" y1=\"" << px(y) << "\" x2=\"" << px(x + 22) << "\" y2=\"" << px(y) << "\"" << stroke_attrs(it.style) << "/>";
    };
    if (p.legend && !items.empty() && p.legend_at == Panel::LegendAt::above) {
      // One row, left-aligned, between the panel title and the plotting area.
      double x = a.x;
      const double y = a.y - 10.0;
      o << "<g class=\"legend\">";
      for (const auto& it : items) {
        glyph(it, x, y);
        o << "<text x=\"" << px(x + 26) << "\" y=\"" << px(y) << "\" dy=\"0.35em\" font-size=\"11\">" << escape_xml(it.label) << "</text>";
        x += 26.0 + 6.6 * static_cast<double>(it.label.size()) + 16.0;
      }
      o << "</g>\n";
    } else if (p.legend && !items.empty()) {
      std::size_t chars = 0;
      for (const auto& it : items) chars = std::max(chars, it.label.size());
      const double lw = 36.0 + 6.6 * static_cast<double>(chars), lh = 8.0 + 16.0 * static_cast<double>(items.size());
      const bool right = p.legend_at == Panel::LegendAt::top_right || p.legend_at == Panel::LegendAt::bottom_right;
      const bool top = p.legend_at == Panel::LegendAt::top_right || p.legend_at == Panel::LegendAt::top_left;
      const double lx = right ? a.x + a.w - lw - 6 : a.x + 6;
      const double ly = top ? a.y + 6 : a.y + a.h - lh - 6;
      o << "<g class=\"legend\"><rect x=\"" << px(lx) << "\" y=\"" << px(ly) << "\" width=\"" << px(lw) << "\" height=\"" << px(lh)
        << "\" fill=\"#ffffff\" fill-opacity=\"0.85\" stroke=\"#999999\" stroke-width=\"0.8\"/>\n";
      for (std::size_t k = 0; k < items.size(); ++k) {
        const double y = ly + 12.0 + 16.0 * static_cast<double>(k);
        glyph(items[k], lx + 6, y);
        o << "<text x=\"" << px(lx + 32) << "\" y=\"" << px(y) << "\" dy=\"0.35em\" font-size=\"11\">" << escape_xml(items[k].label) << "</text>\n";
      }
      o << "</g>\n";
    }
    o << "</g>\n";
  }
  o << "</svg>\n";
  return o.str();
}

}  // namespace ridgewatch::cli::plot
