#include "cli/plot_summary.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "cli/plot_svg.hpp"

namespace ridgewatch::cli::plots {

namespace {

std::string zeta_text(double z) {
  char b[48];
  std::snprintf(b, sizeof b, "%.4g", z);
  return b;
}

}  // namespace

PlotFile summary_plot(const std::vector<SummaryGroup>& groups, const SummaryGroup& overall) {
  using plot::Style;
  plot::Panel p;
  p.title = "zeta per measurement: mean of the ok events (95 % interval) and each ok event";
  p.y_label = "damping ratio zeta";
  p.legend_at = plot::Panel::LegendAt::above;
  const Style bar_edge{"#333333", 1.5};
  const Style dots{plot::palette(1), 1.0};
  double y_top = 0.0;
  for (std::size_t g = 0; g < groups.size(); ++g) {
    const SummaryGroup& s = groups[g];
    const double x = static_cast<double>(g);
    // The bar: the mean (0 when the file has no ok event, with the count saying so).
    p.bar(s.label + " (" + std::to_string(s.zeta.size()) + " ok)", std::isfinite(s.mean) ? s.mean : 0.0, "#c6dbef",
          "zeta-mean", "mean zeta " + zeta_text(s.mean));
    if (std::isfinite(s.lo) && std::isfinite(s.hi)) {
      p.segment(x, s.lo, x, s.hi, bar_edge);
      p.segment(x - 0.12, s.lo, x + 0.12, s.lo, bar_edge);
      p.segment(x - 0.12, s.hi, x + 0.12, s.hi, bar_edge);
      y_top = std::max(y_top, s.hi);
    }
    // The events beside the bar, spread over [x + 0.2, x + 0.4] in time order.
    std::vector<double> ex, ey;
    for (std::size_t i = 0; i < s.zeta.size(); ++i) {
      ex.push_back(x + 0.2 + 0.2 * static_cast<double>(i) / static_cast<double>(std::max<std::size_t>(1, s.zeta.size() - 1)));
      ey.push_back(s.zeta[i]);
      y_top = std::max(y_top, s.zeta[i]);
    }
    p.points(std::move(ex), std::move(ey), dots, g == 0 ? "ok events" : "", 2.0);
  }
  if (std::isfinite(overall.mean)) {
    const std::string ci = std::isfinite(overall.lo) ? " [" + zeta_text(overall.lo) + ", " + zeta_text(overall.hi) + "]" : "";
    p.hline(overall.mean, Style{plot::palette(3), 1.5, plot::Dash::dashed},
            "mean over all " + std::to_string(overall.zeta.size()) + " ok events: " + zeta_text(overall.mean) + ci);
  }
  p.legend_entry("mean of a measurement, 95 % interval", Style{"#c6dbef"});
  p.y_min = 0.0;
  if (y_top > 0) p.y_max = 1.1 * y_top;
  const double width = std::max(640.0, 140.0 + 110.0 * static_cast<double>(groups.size()));
  plot::Figure fig(width, 34.0 + 460.0, "Damping estimates of several measurements");
  fig.add(std::move(p), plot::Rect{0, 34.0, width, 460.0});
  return {"summary.svg", "Damping ratio per measurement",
          "Each bar is the mean zeta of one file's (or stream's) ok events with the 95 % interval of that mean; the "
          "dots beside it are the single events; the dashed line is the mean over all files. Bars whose intervals "
          "miss the dashed line differ by more than their scatter explains.",
          fig.svg()};
}

}  // namespace ridgewatch::cli::plots
