// The SVG plotting module of `--plots` (cli/plot_svg.hpp): tick choice, data-to-pixel mapping,
// escaping, gaps at NaN, well-formed output.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <string>

#include "cli/plot_svg.hpp"
#include "test_plots_xml.hpp"

namespace plot = ridgewatch::cli::plot;
using ridgewatch::test::xml_problem;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + what.size())) ++n;
  return n;
}

// The d attribute of the first <path class="series">.
std::string first_path(const std::string& svg) {
  const auto p = svg.find("<path class=\"series\" d=\"");
  if (p == std::string::npos) return "";
  const auto b = p + std::string("<path class=\"series\" d=\"").size();
  return svg.substr(b, svg.find('"', b) - b);
}

}  // namespace

TEST(PlotTicks, LinearTicksUseOneTwoFiveSteps) {
  auto t = plot::linear_ticks(0.0, 10.0, 6);  // raw step 1.67 -> 2
  EXPECT_EQ(t.values, (std::vector<double>{0, 2, 4, 6, 8, 10}));
  EXPECT_EQ(t.labels, (std::vector<std::string>{"0", "2", "4", "6", "8", "10"}));
  t = plot::linear_ticks(0.013, 0.087, 5);  // raw 0.0148 -> 0.02, two decimals
  EXPECT_EQ(t.labels, (std::vector<std::string>{"0.02", "0.04", "0.06", "0.08"}));
  t = plot::linear_ticks(-3.0, 3.0, 6);  // zero is "0", never "-0"
  EXPECT_EQ(t.labels, (std::vector<std::string>{"-3", "-2", "-1", "0", "1", "2", "3"}));
  t = plot::linear_ticks(850.0, 870.0, 4);  // raw 5 -> 5
  EXPECT_EQ(t.labels, (std::vector<std::string>{"850", "855", "860", "865", "870"}));
  EXPECT_TRUE(plot::linear_ticks(1.0, 1.0).values.empty());
  EXPECT_TRUE(plot::linear_ticks(kNaN, 1.0).values.empty());
}

TEST(PlotTicks, LinearTicksPropertiesOverRandomRanges) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> mant(-1.0, 1.0), expo(-6.0, 6.0);
  for (int n = 0; n < 2000; ++n) {
    const double a = mant(rng) * std::pow(10.0, expo(rng));
    const double b = a + std::abs(mant(rng)) * std::pow(10.0, expo(rng)) + 1e-300;
    if (!(a < b)) continue;
    for (int target : {3, 6, 10}) {
      const auto t = plot::linear_ticks(a, b, target);
      ASSERT_GE(t.values.size(), 1u) << a << " " << b;
      ASSERT_LE(t.values.size(), static_cast<std::size_t>(target) + 1) << a << " " << b;
      ASSERT_EQ(t.values.size(), t.labels.size());
      for (double v : t.values) {
        ASSERT_GE(v, a - 1e-9 * (b - a));
        ASSERT_LE(v, b + 1e-9 * (b - a));
      }
      if (t.values.size() >= 2) {
        const double step = t.values[1] - t.values[0];
        // The mantissa of the step is 1, 2 or 5, to the rounding of the two tick values whose difference
        // gave it: each is off by up to 1 ulp of the range's magnitude, i.e. 2.2e-16 max(|a|,|b|).
        const double tol = 1e-9 + 4.5e-16 * std::max(std::abs(a), std::abs(b)) / step;
        const double m = step / std::pow(10.0, std::floor(std::log10(step) + tol));
        ASSERT_TRUE(std::abs(m - 1) < 5 * tol || std::abs(m - 2) < 5 * tol || std::abs(m - 5) < 5 * tol) << step;
        ASSERT_LE((b - a) / step, target * (1 + 1e-9));
      }
    }
  }
}

TEST(PlotTicks, LogTicks) {
  auto t = plot::log_ticks(1.0, 1000.0);  // 3 decades: powers of ten only
  EXPECT_EQ(t.labels, (std::vector<std::string>{"1", "10", "100", "1000"}));
  t = plot::log_ticks(1.0, 10.0);  // 1 decade: also 2 and 5
  EXPECT_EQ(t.labels, (std::vector<std::string>{"1", "2", "5", "10"}));
  t = plot::log_ticks(0.05, 2.0);
  EXPECT_EQ(t.labels, (std::vector<std::string>{"0.05", "0.1", "0.2", "0.5", "1", "2"}));
  t = plot::log_ticks(1e-3, 1e9);  // 12 decades: every second decade
  EXPECT_EQ(t.labels, (std::vector<std::string>{"0.001", "0.1", "10", "1000", "100000", "1e7", "1e9"}));
  EXPECT_TRUE(plot::log_ticks(0.0, 10.0).values.empty());
  EXPECT_TRUE(plot::log_ticks(-1.0, 10.0).values.empty());
}

TEST(PlotScale, MapsLinearAndLogAndRejectsUndrawable) {
  const plot::Scale lin{0.0, 10.0, 100.0, 300.0, false};
  EXPECT_DOUBLE_EQ(lin(0.0), 100.0);
  EXPECT_DOUBLE_EQ(lin(5.0), 200.0);
  EXPECT_DOUBLE_EQ(lin(10.0), 300.0);
  const plot::Scale y{0.0, 1.0, 400.0, 0.0, false};  // pixel y grows downwards
  EXPECT_DOUBLE_EQ(y(0.25), 300.0);
  const plot::Scale lg{1.0, 100.0, 0.0, 200.0, true};
  EXPECT_NEAR(lg(10.0), 100.0, 1e-12);
  EXPECT_NEAR(lg(1000.0), 300.0, 1e-12);
  EXPECT_TRUE(std::isnan(lg(0.0)));
  EXPECT_TRUE(std::isnan(lg(-3.0)));
  EXPECT_TRUE(std::isnan(lin(kNaN)));
  EXPECT_TRUE(std::isnan(lin(std::numeric_limits<double>::infinity())));
}

TEST(PlotFigure, KnownPointLandsOnTheRightPixel) {
  plot::Panel p;
  p.x_min = 0.0;
  p.x_max = 10.0;
  p.y_min = 0.0;
  p.y_max = 100.0;
  p.line({0.0, 5.0, 10.0}, {0.0, 50.0, 100.0}, plot::Style{});
  plot::Figure fig(400, 300);
  fig.add(std::move(p), plot::Rect{0, 0, 400, 300});
  const auto [sx, sy] = fig.scales(0);
  // Plot area: 74 px left margin, 18 right, 26 top, 46 bottom (cli/plot_svg.cpp layout constants).
  EXPECT_DOUBLE_EQ(sx.px_lo, 74.0);
  EXPECT_DOUBLE_EQ(sx.px_hi, 382.0);
  EXPECT_DOUBLE_EQ(sy.px_lo, 254.0);
  EXPECT_DOUBLE_EQ(sy.px_hi, 26.0);
  // (5, 50) is the middle of the area: x = 74 + 308/2 = 228, y = 254 - 228/2 = 140.
  EXPECT_EQ(first_path(fig.svg()), "M74.00 254.00L228.00 140.00L382.00 26.00");
}

TEST(PlotFigure, AutomaticLimitsAreNiceAndCoverTheData) {
  plot::Panel p;
  p.line({0.3, 9.2}, {-0.7, 41.0}, plot::Style{});
  plot::Figure fig(400, 300);
  fig.add(std::move(p), plot::Rect{0, 0, 400, 300});
  const auto [sx, sy] = fig.scales(0);
  EXPECT_DOUBLE_EQ(sx.lo, 0.0);
  EXPECT_DOUBLE_EQ(sx.hi, 10.0);
  EXPECT_DOUBLE_EQ(sy.lo, -10.0);
  EXPECT_DOUBLE_EQ(sy.hi, 50.0);
  plot::Panel q;
  q.y_log = true;
  q.line({1, 2, 3}, {0.03, 0.0, 70.0}, plot::Style{});  // 0 cannot be drawn on a log axis: ignored
  plot::Figure g(400, 300);
  g.add(std::move(q), plot::Rect{0, 0, 400, 300});
  EXPECT_DOUBLE_EQ(g.scales(0).second.lo, 0.01);
  EXPECT_DOUBLE_EQ(g.scales(0).second.hi, 100.0);
}

TEST(PlotFigure, NaNAndNonPositiveOnLogAxisLeaveGaps) {
  plot::Panel p;
  p.line({0, 1, 2, 3, 4, 5}, {1, 2, kNaN, 4, 5, 6}, plot::Style{});
  plot::Figure fig(400, 300);
  fig.add(std::move(p), plot::Rect{0, 0, 400, 300});
  std::string d = first_path(fig.svg());
  EXPECT_EQ(count(d, "M"), 2u) << d;
  EXPECT_EQ(count(d, "L"), 3u) << d;
  EXPECT_EQ(d.find("nan"), std::string::npos);

  plot::Panel q;
  q.y_log = true;
  q.line({0, 1, 2, 3, 4}, {1, 10, -1, 0, 100}, plot::Style{}, "", true);
  plot::Figure g(400, 300);
  g.add(std::move(q), plot::Rect{0, 0, 400, 300});
  const std::string svg = g.svg();
  d = first_path(svg);
  // (0,1)-(1,10) is a line; the lone (4,100) is a move only (no visible line) but has its dot.
  EXPECT_EQ(count(d, "M"), 2u) << d;
  EXPECT_EQ(count(d, "L"), 1u) << d;
  EXPECT_EQ(count(svg, "<circle"), 3u);
  EXPECT_EQ(xml_problem(svg), "");

  plot::Panel empty;  // nothing drawable at all: still a valid document with default axes
  empty.line({0, 1}, {kNaN, kNaN}, plot::Style{}, "nothing");
  plot::Figure h(400, 300);
  h.add(std::move(empty), plot::Rect{0, 0, 400, 300});
  const std::string e = h.svg();
  EXPECT_EQ(e.find("<path class=\"series\""), std::string::npos);
  EXPECT_EQ(xml_problem(e), "");
}

TEST(PlotFigure, TextIsEscaped) {
  EXPECT_EQ(plot::escape_xml("a<b & \"c\" 'd' >"), "a&lt;b &amp; &quot;c&quot; &apos;d&apos; &gt;");
  EXPECT_EQ(plot::escape_xml(std::string("x\x01y")), "xy");  // not allowed in XML 1.0
  plot::Panel p;
  p.title = "ζ < 0.1 & f > 5 \"Hz\"";
  p.x_label = "<script>";
  p.line({0, 1}, {0, 1}, plot::Style{}, "model [a&b]");
  p.bar("R1 <x>", 1.0, "#000", "bar rejected", "tip & <tool>");
  plot::Figure fig(400, 300, "title & <more>");
  fig.add(std::move(p), plot::Rect{0, 0, 400, 300});
  const std::string svg = fig.svg();
  EXPECT_EQ(svg.find("<script>"), std::string::npos);
  EXPECT_NE(svg.find("ζ &lt; 0.1 &amp; f &gt; 5 &quot;Hz&quot;"), std::string::npos);
  EXPECT_NE(svg.find("title &amp; &lt;more&gt;"), std::string::npos);
  EXPECT_NE(svg.find("model [a&amp;b]"), std::string::npos);
  EXPECT_EQ(xml_problem(svg), "");
}

TEST(PlotFigure, BarsHeatMapAndReferenceLinesAreWellFormed) {
  plot::Panel bars;
  bars.y_log = true;
  bars.bar("a", 0.5, "#2ca02c", "bar accepted");
  bars.bar("b", 3.0, "#999999", "bar rejected");
  bars.bar("c", -1.0, "#999999", "bar rejected");  // not drawable on a log axis: skipped
  bars.hline(0.1, plot::Style{"#d62728"}, "target 0.1");
  bars.segment(-0.45, 2.0, 2.45, 2.0, plot::Style{}, "before");
  bars.legend_entry("accepted", plot::Style{"#2ca02c"});
  plot::Panel heat;
  heat.heatmap(0, 2, 0, 2, 2, 2, {0.0, 1.0, kNaN, 1.0}, 0.0, 1.0, "level");
  heat.vline(1.0, plot::Style{}, "f0");
  plot::Figure fig(600, 700, "two panels");
  fig.add(std::move(bars), plot::Rect{0, 30, 600, 330});
  fig.add(std::move(heat), plot::Rect{0, 360, 600, 330});
  const std::string svg = fig.svg();
  EXPECT_EQ(count(svg, "class=\"bar "), 2u);
  EXPECT_EQ(count(svg, "class=\"xcat\""), 3u);  // every category is labelled, drawn or not
  // Heat map: 3 finite cells; (0,1) and (1,1) are different colours, row 1 has one cell.
  const auto heat_begin = svg.find("<g clip-path=\"url(#clip1)\" shape-rendering=\"crispEdges\">");
  ASSERT_NE(heat_begin, std::string::npos);
  const std::string heat_part = svg.substr(heat_begin, svg.find("</g>", heat_begin) - heat_begin);
  EXPECT_EQ(count(heat_part, "<rect"), 3u);
  EXPECT_NE(svg.find(plot::colour_map(1.0)), std::string::npos);
  EXPECT_EQ(count(svg, "<clipPath id=\"clip"), 2u);
  EXPECT_EQ(xml_problem(svg), "");
  if (ridgewatch::test::have_xmllint()) {
    const auto f = std::filesystem::temp_directory_path() / ("rw-plot-test-" + std::to_string(::getpid()) + ".svg");
    std::ofstream(f) << svg;
    EXPECT_EQ(ridgewatch::test::xmllint_problem(f), "");
    std::filesystem::remove(f);
  }
}

TEST(PlotFigure, CheckerCatchesBrokenXml) {
  // The checker itself must be able to fail.
  EXPECT_NE(xml_problem("<svg><g></svg>"), "");
  EXPECT_NE(xml_problem("<svg><text>a < b</text></svg>"), "");
  EXPECT_NE(xml_problem("<svg><text>a & b</text></svg>"), "");
  EXPECT_NE(xml_problem("<svg x=1/>"), "");
  EXPECT_NE(xml_problem("<svg/><svg/>"), "");
  EXPECT_EQ(xml_problem("<?xml version=\"1.0\"?>\n<svg a=\"1\"><g/><text>x &amp; y</text></svg>\n"), "");
}

TEST(PlotColours, MapEndsAndPalette) {
  EXPECT_EQ(plot::colour_map(0.0), "#440154");
  EXPECT_EQ(plot::colour_map(1.0), "#fde725");
  EXPECT_EQ(plot::colour_map(-5.0), plot::colour_map(0.0));
  EXPECT_EQ(plot::colour_map(kNaN), plot::colour_map(0.0));
  EXPECT_NE(plot::palette(0), plot::palette(1));
}
