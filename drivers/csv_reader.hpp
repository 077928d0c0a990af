// Text (CSV-like) sample files: the format engineers export from oscilloscopes, DAQ software and
// spreadsheets. Parsed completely on open (the time column's median spacing needs every time stamp);
// the replay driver then serves the values through the SampleSource interface.
//
// Accepted layout (this comment is the reference; the README should point users here):
//   * Header lines: non-numeric lines at the top are skipped (column titles, units, instrument
//     banners). Blank lines and lines starting with '#' are skipped anywhere.
//   * Separator, chosen from the first data line: tab if present, else ';' if present, else ',' if
//     present, else runs of spaces. With a tab or ';' separator a ',' inside a field is a decimal
//     comma ("0,125;1,5"). With a ',' separator the decimal mark must be '.' (a one-column file with
//     decimal commas is therefore ambiguous and needs ';' or tab separators or '.' decimals).
//   * One column: values only; the sample rate must be supplied (`--rate HZ`).
//   * Two or more columns: the first is time in seconds, the others are value columns; `channel`
//     selects among the value columns (0 = first value column). Time must increase strictly and be
//     uniform: every step within 1 % of the median step (plus the rounding quantum of the printed
//     time stamps, so `0.000023` style stamps at 44.1 kHz are accepted).
//   * Every data line has the same number of fields; values must be finite numbers.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

namespace ridgewatch::drivers {

/// Maximum relative deviation of a single time step from the median step (1 %).
inline constexpr double kCsvMaxTimeStepDeviation = 0.01;

struct CsvSeries {
  std::vector<double> values;   ///< the selected value column, in file order
  double sample_rate_hz = 0.0;  ///< from the time column or from the supplied rate
  std::size_t value_columns = 1;
  bool has_time_column = false;
};

/// Parses `path` as described above. `channel` selects a value column (0-based); `rate_hz` is
/// required for one-column files and, if given for a file with a time column, must agree with it
/// within 1 %. Throws InputError ("<path>: line 17: missing value", ...) on any problem.
/// The sample rate range is NOT checked here (the replay driver checks it for every format).
CsvSeries read_csv_series(const std::string& path, std::size_t channel, std::optional<double> rate_hz);

}  // namespace ridgewatch::drivers
