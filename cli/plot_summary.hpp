// The plot of `ridgewatch analyze --summary FILE... --plots DIR` (the paper's Figure 9: damping
// estimates from several measurements around their mean), drawn with cli/plot_svg.hpp and written with
// plot_diagnosis.hpp's write_all:
//   summary.svg  per file (and stream) a bar at the mean ζ of its ok events with the 95 % interval of
//                the mean as an error bar, every ok event's ζ as a dot beside it, and the mean over all
//                files as a horizontal line
#pragma once

#include <string>
#include <vector>

#include "cli/plot_diagnosis.hpp"

namespace ridgewatch::cli::plots {

/// One measurement of the summary: its label and the figures of its ok events.
struct SummaryGroup {
  std::string label;          ///< file name (and stream), shown on the category axis
  std::vector<double> zeta;   ///< ζ of every ok event, in time order
  double mean = NAN;          ///< mean of `zeta` (NaN without ok events)
  double lo = NAN, hi = NAN;  ///< 95 % interval of the mean (NaN with fewer than 2 ok events)
};

/// `overall`: the same figures over every ok event of every group (label unused).
PlotFile summary_plot(const std::vector<SummaryGroup>& groups, const SummaryGroup& overall);

}  // namespace ridgewatch::cli::plots
