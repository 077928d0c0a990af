#include "core/pipeline/ridge_track.hpp"

#include <algorithm>
#include <cmath>

#include "core/dsp/kernels/isa.hpp"
#include "core/dsp/kernels/subtract_and_max.hpp"
#include "core/dsp/select.hpp"

namespace ridgewatch::pipeline {

namespace {

// A ridge that strays from the mode after its power fell this far below its peak (15 dB) marks the
// end of the free response (the motion stopped), not a lost ridge.
constexpr double kEndedPowerDrop = 0.0316;

// Whether column c (row r) is the stop of the free response: its decay per column exceeds twice the
// early decay plus 0.4 in two consecutive columns (fast_ratio = exp(2 early_decay + 0.4), compared as
// power ratios: no logarithm per column), and no row within a filter sd of the mode row r0 regains
// that power later (a beat of two close modes recovers).
bool stops_at(const RidgeGrid& g, const RidgeFollowInputs& in, std::size_t r0, std::size_t r, std::size_t c,
              double fast_ratio) {
  if (!(g.raw(r, c - 1) / g.raw(r, c) > fast_ratio && g.raw(r, c) / g.raw(r, c + 1) > fast_ratio)) return false;
  for (std::size_t c2 = c + 2; c2 < in.last_col; ++c2)
    for (std::size_t r2 = 0; r2 < g.rows; ++r2)
      if (in.near[r2 * g.rows + r0] && g.raw(r2, c2) >= g.raw(r, c)) return false;
  return true;
}

// Parabola through (ln f, ln energy) of the ridge's energy in rows r0 - 1, r0, r0 + 1: the Gaussian
// filter makes ln energy nearly quadratic in ln f. The row's frequency when r0 is an edge row or an
// energy is not positive.
double ridge_frequency(std::span<const double> rows_hz, std::size_t r0, const double (&prof)[3]) {
  const std::size_t rows = rows_hz.size();
  if (!(r0 > 0 && r0 + 1 < rows && prof[0] > 0 && prof[1] > 0 && prof[2] > 0)) return rows_hz[r0];
  const double y0 = std::log(prof[0]), y1 = std::log(prof[1]), y2 = std::log(prof[2]);
  const double denom = y0 - 2.0 * y1 + y2;
  const double off = denom < 0 ? std::clamp(0.5 * (y0 - y2) / denom, -0.5, 0.5) : 0.0;
  const double step = std::log(off < 0 ? rows_hz[r0] / rows_hz[r0 - 1] : rows_hz[r0 + 1] / rows_hz[r0]);
  return rows_hz[r0] * std::exp(off * step);
}

}  // namespace

namespace {

[[gnu::always_inline]] inline RidgeStart find_ridge_body(std::span<const std::complex<float>> grid, std::size_t rows,
                                                         std::size_t cols, std::size_t onset_col, std::size_t last_col,
                                                         std::span<double> power, std::span<double> row_median,
                                                         std::span<double> scratch) {
  // One pass per row: |W|^2 into the power grid, the median (dsp::select_kth_nonnegative: the value
  // nth_element gives, mostly without a partition pass), then the subtraction together with the row's
  // maximum after the onset. The ridge starts at the largest value after the onset, the first one in
  // row-major order on ties: the first row whose maximum exceeds the earlier rows' (>), at its first
  // column holding that maximum, found once after the rows (a first-maximum scan per row would branch
  // on every new maximum).
  RidgeStart s;
  for (std::size_t r = 0; r < rows; ++r) {
    const std::complex<float>* g = grid.data() + r * cols;
    double* p = power.data() + r * cols;
    for (std::size_t c = 0; c < cols; ++c) {
      const double re = g[c].real(), im = g[c].imag();
      p[c] = re * re + im * im;
    }
    const double med = dsp::select_kth_nonnegative(p, scratch.data(), cols, cols / 2);
    row_median[r] = med;
    const double row_max = dsp::kernels::subtract_and_max(p, cols, med, onset_col, last_col);
    if (r == 0 || row_max > s.power) {
      s.power = row_max;
      s.row = r;
    }
  }
  s.col = onset_col;
  while (s.col + 1 < last_col && power[s.row * cols + s.col] != s.power) ++s.col;
  return s;
}

RidgeStart find_ridge_baseline(std::span<const std::complex<float>> grid, std::size_t rows, std::size_t cols,
                               std::size_t onset_col, std::size_t last_col, std::span<double> power,
                               std::span<double> row_median, std::span<double> scratch) {
  return find_ridge_body(grid, rows, cols, onset_col, last_col, power, row_median, scratch);
}

// The same code with AVX2 encodings (dsp/kernels/isa.hpp: no FMA, the same results): the powers'
// widening and the median's counting pass (kernels::pivot_counts) take four values per instruction.
RIDGEWATCH_TARGET_AVX2 RidgeStart find_ridge_avx2(std::span<const std::complex<float>> grid, std::size_t rows,
                                                  std::size_t cols, std::size_t onset_col, std::size_t last_col,
                                                  std::span<double> power, std::span<double> row_median,
                                                  std::span<double> scratch) {
  return find_ridge_body(grid, rows, cols, onset_col, last_col, power, row_median, scratch);
}

}  // namespace

RidgeStart find_ridge(std::span<const std::complex<float>> grid, std::size_t rows, std::size_t cols,
                      std::size_t onset_col, std::size_t last_col, std::span<double> power,
                      std::span<double> row_median, std::span<double> scratch) {
  if (dsp::kernels::use_avx2())
    return find_ridge_avx2(grid, rows, cols, onset_col, last_col, power, row_median, scratch);
  return find_ridge_baseline(grid, rows, cols, onset_col, last_col, power, row_median, scratch);
}

RidgeTrack follow_ridge(const RidgeGrid& g, const RidgeStart& start, const RidgeFollowInputs& in) {
  // A free response that stops (dry friction: the motion sticks once the amplitude is small) leaves
  // the transform's response to the stop: the row's power then falls like the kernel's Gaussian,
  // exp(-(t - t_stop)^2 / s^2), ever faster, and the lower rows (longer kernels) keep it longest, so
  // the maximum walks down the band. Two signs of a stop, on the ridge's own power (median added back,
  // so that the subtraction does not fake an acceleration): an accelerating decay that does not
  // recover (stops_at), or a stray from the mode after the power fell 15 dB below the peak. Either
  // ends the ridge there (not lost; a ridge that strays while strong is lost).
  const std::size_t rows = g.rows, r0 = start.row, c0 = start.col, w = in.width_cols;
  RidgeTrack t;
  t.row = r0;
  t.col = c0;
  t.end_col = g.cols;
  t.lost = r0 == 0 || r0 + 1 == rows;
  double prof[3] = {0.0, 0.0, 0.0};  // ridge energy in rows r0-1, r0, r0+1
  double early_decay = NAN;  // ln power per column over the first kernel width after 2 widths
  double fast_ratio = NAN;   // exp(2 early_decay + 0.4): the per-column power ratio of a stop
  std::size_t r = r0;
  for (std::size_t c = c0; c < in.last_col; ++c) {
    if (c > c0) {
      std::size_t best = r;
      if (r > 0 && g.at(r - 1, c) > g.at(best, c)) best = r - 1;
      if (r + 1 < rows && g.at(r + 1, c) > g.at(best, c)) best = r + 1;
      r = best;
    }
    const double floor = 100.0 * (in.noise_var * in.row_gain[r]);
    if (c == c0 + 3 * w && g.raw(r, c) > 0) {
      early_decay = std::log(g.raw(r0, c0 + 2 * w) / g.raw(r, c)) / static_cast<double>(w);
      fast_ratio = std::exp(2.0 * early_decay + 0.4);
    }
    // The stop test: after the early decay is known, while the next column is still 20 dB up.
    if (!t.lost && std::isfinite(early_decay) && early_decay > 0 && c > c0 + 3 * w && c + 1 < in.last_col &&
        g.raw(r, c + 1) >= floor && stops_at(g, in, r0, r, c, fast_ratio)) {
      t.end_col = c;
      t.ended = true;
      break;
    }
    if (g.at(r, c) < floor) break;  // 20 dB: the strong part of the decay
    if (r == 0 || r + 1 == rows || !in.near[r * rows + r0]) {
      if (!t.lost && g.at(r, c) <= kEndedPowerDrop * g.at(r0, c0)) {
        t.end_col = c;
        t.ended = true;
        break;
      }
      t.lost = true;
    }
    if (r0 > 0 && r0 + 1 < rows)
      for (std::size_t k = 0; k < 3; ++k) prof[k] += g.at(r0 - 1 + k, c);
  }
  t.f_hz = ridge_frequency(in.rows_hz, r0, prof);
  return t;
}

}  // namespace ridgewatch::pipeline
