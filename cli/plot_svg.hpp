// A small SVG plotting module for the files `ridgewatch compare/diagnose --plots DIR` write
// (cli/plot_diagnosis.hpp): panels with linear or logarithmic axes and nice ticks, lines (with gaps at
// NaN), markers, bars on a categorical axis, reference lines, a heat map with a colour bar, a legend,
// labels and titles; every text is XML-escaped.
//
// Why hand-written: the plots must be files a rig engineer opens without anything else installed and
// the build must use only Debian-packaged libraries. Debian 12 packages no C++ plotting library that
// writes SVG without a runtime (matplot++ is not packaged and drives gnuplot as a child process;
// gnuplot/PLplot/MathGL are external programs or large GUI-oriented libraries with their own output
// back ends), and the plots need only lines, bars and rectangles, which SVG draws natively.
//
// Conventions: data coordinates in, pixel coordinates out (y grows downwards in SVG). A value that
// cannot be drawn (NaN, ±inf, or <= 0 on a log axis) breaks a line into separate pieces and is
// skipped by markers and bars. Output is a complete, standalone SVG 1.1 document.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace ridgewatch::cli::plot {

/// `text` with & < > " ' replaced by their XML entities (usable in element text and attributes).
std::string escape_xml(std::string_view text);

struct Ticks {
  std::vector<double> values;
  std::vector<std::string> labels;
};

/// Ticks at the multiples of a 1-2-5 step (1, 2 or 5 times a power of ten) inside [lo, hi]: the
/// smallest such step that splits hi - lo into at most `target` intervals (so target / 2.5 .. target + 1
/// ticks). Labels carry just the decimals the step needs. Empty unless lo < hi are finite.
Ticks linear_ticks(double lo, double hi, int target = 6);

/// Ticks at powers of ten inside [lo, hi] (0 < lo < hi); when hi / lo spans at most 2.5 decades also
/// at 2 and 5 times them; with more than 10 decades only every second (or more) decade.
Ticks log_ticks(double lo, double hi);

/// A map from a data interval [lo, hi] to a pixel interval [px_lo, px_hi], linear or logarithmic.
struct Scale {
  double lo = 0.0, hi = 1.0;
  double px_lo = 0.0, px_hi = 1.0;
  bool log = false;
  /// Pixel coordinate of `v`, or NaN when `v` cannot be drawn (non-finite, or <= 0 on a log scale).
  double operator()(double v) const;
};

enum class Dash { solid, dashed, dotted };

struct Style {
  std::string colour = "#1f77b4";
  double width = 1.5;  ///< stroke width, px
  Dash dash = Dash::solid;
  double opacity = 1.0;
};

/// A colour for series `i` (a qualitative palette that stays distinguishable in grey-scale print).
std::string palette(std::size_t i);

/// A colour on a perceptually ordered map (dark blue -> green -> yellow) for t in [0, 1] (clamped).
std::string colour_map(double t);

/// One plotting area with its axes. Fill it, then add it to a Figure.
class Panel {
 public:
  std::string title, x_label, y_label;
  bool x_log = false, y_log = false;
  std::optional<double> x_min, x_max, y_min, y_max;  ///< fixed limits; otherwise from the data
  bool x_integer_ticks = false;  ///< keep only whole-number x ticks (rounds, runs)
  bool legend = true;
  /// Where the legend goes: a box inside a corner of the plotting area, or one row between the panel
  /// title and the plotting area (`above`, for panels whose data fill every corner).
  enum class LegendAt { top_right, top_left, bottom_right, bottom_left, above } legend_at = LegendAt::top_right;

  /// A line through (x[i], y[i]); non-drawable points leave gaps. `markers`: also a dot per point.
  void line(std::vector<double> x, std::vector<double> y, Style style, std::string label = "", bool markers = false);
  /// Dots only.
  void points(std::vector<double> x, std::vector<double> y, Style style, std::string label = "", double radius = 3.0);
  /// A horizontal / vertical line across the whole panel, with an optional label at its end.
  void hline(double y, Style style, std::string label = "");
  void vline(double x, Style style, std::string label = "");
  /// A straight segment in data coordinates (e.g. a baseline over a group of bars).
  void segment(double x0, double y0, double x1, double y1, Style style, std::string label = "");
  /// A text in data coordinates (left-aligned, just above and right of the point).
  void annotate(double x, double y, std::string text);
  /// A bar per category on a categorical x axis (category i at x = i); `css_class` lets tests and
  /// style sheets find the bars. Bars start at 0 (linear y) or at the bottom of the axis (log y).
  void bar(std::string category, double value, std::string colour, std::string css_class = "bar",
           std::string tooltip = "");
  /// A legend entry without a series (e.g. for bar colours): a swatch when `swatch`, else a line.
  void legend_entry(std::string label, Style style, bool swatch = true);
  /// A heat map: `values` row-major, rows = y cells from y0 to y1, cols = x cells from x0 to x1,
  /// coloured from vmin to vmax with a colour bar labelled `colour_label`. NaN cells stay blank.
  void heatmap(double x0, double x1, double y0, double y1, std::size_t rows, std::size_t cols,
               std::vector<double> values, double vmin, double vmax, std::string colour_label);

  bool categorical() const { return !bars_.empty(); }
  bool has_heatmap() const { return heat_.has_value(); }

 private:
  friend class Figure;
  struct Series {
    std::vector<double> x, y;
    Style style;
    std::string label;
    bool line = true, markers = false;
    double radius = 3.0;
  };
  struct Ref {
    bool horizontal = true;
    double at = 0.0;
    Style style;
    std::string label;
  };
  struct Seg {
    double x0, y0, x1, y1;
    Style style;
    std::string label;
  };
  struct Note {
    double x, y;
    std::string text;
  };
  struct Bar {
    std::string category;
    double value;
    std::string colour, css_class, tooltip;
  };
  struct Entry {
    std::string label;
    Style style;
    bool swatch;
  };
  struct Heat {
    double x0, x1, y0, y1;
    std::size_t rows, cols;
    std::vector<double> values;
    double vmin, vmax;
    std::string label;
  };
  std::vector<Series> series_;
  std::vector<Ref> refs_;
  std::vector<Seg> segs_;
  std::vector<Note> notes_;
  std::vector<Bar> bars_;
  std::vector<Entry> entries_;
  std::optional<Heat> heat_;
};

/// Pixel rectangle of a panel inside the figure (the outer box, axes labels included).
struct Rect {
  double x = 0.0, y = 0.0, w = 0.0, h = 0.0;
};

/// A standalone SVG document holding one or more panels.
class Figure {
 public:
  Figure(double width_px, double height_px, std::string title = "");
  void add(Panel panel, Rect outer);
  /// The scales a panel was (or will be) drawn with: for tests of the coordinate mapping.
  std::pair<Scale, Scale> scales(std::size_t panel_index) const;
  std::string svg() const;

 private:
  struct Placed {
    Panel panel;
    Rect outer;
  };
  double width_, height_;
  std::string title_;
  std::vector<Placed> panels_;
};

}  // namespace ridgewatch::cli::plot
