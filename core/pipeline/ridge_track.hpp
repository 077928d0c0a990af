// Step 2 of the impact analysis (core/pipeline/impact_analyzer.hpp): the ridge of the band's CWT power.
//
// find_ridge: |W|^2 of every grid row minus the row's median over the window (stationary lines have
// the same power in every column, the free response decays within the window, so the subtraction
// keeps the impact's ridge and removes the lines'); the ridge starts at the largest value after the
// onset and before the last 4 kernel widths (which see the window end).
// follow_ridge: the ridge's continuation column by column, moving at most one row per column, while
// |W|^2 stays 20 dB above the row's noise; the ridge frequency from the ridge's time-integrated
// energy in the three rows around its maximum (a parabola in ln f).
#pragma once

#include <complex>
#include <cstddef>
#include <cstdint>
#include <span>

namespace ridgewatch::pipeline {

/// The band's power grid: rows x cols, row-major, |W|^2 minus each row's median over the window.
struct RidgeGrid {
  std::span<const double> power;       ///< rows * cols values (signal units squared)
  std::span<const double> row_median;  ///< the median subtracted from each row
  std::size_t rows = 0, cols = 0;
  double at(std::size_t r, std::size_t c) const { return power[r * cols + c]; }
  /// The row's power with its median added back (the ridge's own power, for the stop test).
  double raw(std::size_t r, std::size_t c) const { return at(r, c) + row_median[r]; }
};

/// Where the ridge starts: the largest grid value in columns [onset_col, last_col), the first one in
/// row-major order on ties.
struct RidgeStart {
  std::size_t row = 0, col = 0;
  double power = 0.0;  ///< its value (median subtracted)
};

/// Fills `power` (rows * cols) with |grid|^2 minus each row's median (into row_median, rows values;
/// scratch: 2 * cols values) and returns the ridge's start. Requires onset_col < last_col <= cols.
RidgeStart find_ridge(std::span<const std::complex<float>> grid, std::size_t rows, std::size_t cols,
                      std::size_t onset_col, std::size_t last_col, std::span<double> power,
                      std::span<double> row_median, std::span<double> scratch);

/// What follow_ridge needs besides the grid.
struct RidgeFollowInputs {
  std::span<const double> rows_hz;      ///< the grid rows' frequencies (log-spaced, ascending), Hz
  std::span<const double> row_gain;     ///< each row's white-noise variance gain
  std::span<const std::uint8_t> near;   ///< rows x rows: 1 when |ln(f_r / f_q)| <= 1 / eta0
  double noise_var = 0.0;               ///< white-equivalent noise variance of the input (> 0)
  std::size_t width_cols = 1;           ///< one kernel time width in columns (>= 1)
  std::size_t last_col = 0;             ///< first column that sees the window end
};

/// The ridge as followed from its start.
struct RidgeTrack {
  std::size_t row = 0;        ///< the row of the ridge's maximum (r0)
  std::size_t col = 0;        ///< the column of its maximum (c0)
  std::size_t end_col = 0;    ///< columns [0, end_col) hold the free response
  bool ended = false;         ///< the free response stopped before the window end (end_col < cols)
  bool lost = false;          ///< the maximum lies on a band-edge row, or the ridge left the mode
  double f_hz = 0.0;          ///< ridge frequency, Hz (the row's when the parabola is undefined)
};

/// Follows the ridge from `start` (see impact_analyzer.hpp, step 2, for the stop and stray rules).
RidgeTrack follow_ridge(const RidgeGrid& grid, const RidgeStart& start, const RidgeFollowInputs& in);

}  // namespace ridgewatch::pipeline
