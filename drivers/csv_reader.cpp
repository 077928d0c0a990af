#include "drivers/csv_reader.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <string_view>
#include <system_error>

#include "drivers/sample_source.hpp"

namespace ridgewatch::drivers {
namespace {

/// Shortest readable form of a number for messages (6 significant digits).
std::string num(double value) {
  std::ostringstream out;
  out << std::setprecision(10) << value;
  return out.str();
}

std::string_view trim(std::string_view text) {
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first == std::string_view::npos) return {};
  const auto last = text.find_last_not_of(" \t\r\n");
  return text.substr(first, last - first + 1);
}

/// How fields are separated; ' ' stands for "runs of spaces/tabs".
struct Dialect {
  char separator = ' ';
  bool decimal_comma = false;  ///< ',' in a field is a decimal mark
};

/// Rule documented in csv_reader.hpp: tab, else ';', else ',', else whitespace.
Dialect detect_dialect(std::string_view line) {
  if (line.find('\t') != std::string_view::npos) return {'\t', true};
  if (line.find(';') != std::string_view::npos) return {';', true};
  if (line.find(',') != std::string_view::npos) return {',', false};
  return {' ', true};
}

/// Splits a line into trimmed fields. Empty fields are kept (they mean "missing value") except in
/// whitespace mode, where runs of blanks are one separator.
std::vector<std::string_view> split(std::string_view line, const Dialect& dialect) {
  std::vector<std::string_view> fields;
  if (dialect.separator == ' ') {
    std::size_t pos = 0;
    while (pos < line.size()) {
      const auto start = line.find_first_not_of(" \t", pos);
      if (start == std::string_view::npos) break;
      auto end = line.find_first_of(" \t", start);
      if (end == std::string_view::npos) end = line.size();
      fields.push_back(line.substr(start, end - start));
      pos = end;
    }
    return fields;
  }
  std::size_t start = 0;
  for (;;) {
    const auto end = line.find(dialect.separator, start);
    fields.push_back(trim(line.substr(start, end == std::string_view::npos ? std::string_view::npos : end - start)));
    if (end == std::string_view::npos) break;
    start = end + 1;
  }
  return fields;
}

/// A parsed field: its value and the rounding quantum of its printed form (10^-decimals, scaled by
/// the exponent), used to tolerate time stamps printed with few digits.
struct ParsedNumber {
  double value = 0.0;
  double quantum = 1.0;
};

/// Locale-independent parse of one field; the whole field must be a number. Accepts surrounding
/// double quotes, a leading '+', and (when the dialect says so) a decimal comma.
std::optional<ParsedNumber> parse_number(std::string_view field, const Dialect& dialect) {
  if (field.size() >= 2 && field.front() == '"' && field.back() == '"') field = trim(field.substr(1, field.size() - 2));
  if (!field.empty() && field.front() == '+') field.remove_prefix(1);
  if (field.empty()) return std::nullopt;
  std::string text(field);
  if (dialect.decimal_comma) std::replace(text.begin(), text.end(), ',', '.');
  ParsedNumber parsed;
  const char* const begin = text.data();
  const char* const end = begin + text.size();
  const auto [ptr, ec] = std::from_chars(begin, end, parsed.value, std::chars_format::general);
  if (ec != std::errc() || ptr != end) {
    // Out-of-range magnitudes ("1e999") are numbers, just not finite ones: report them as such.
    if (ec == std::errc::result_out_of_range && ptr == end) {
      parsed.value = text.front() == '-' ? -HUGE_VAL : HUGE_VAL;
      return parsed;
    }
    return std::nullopt;
  }
  // Rounding quantum: digits after the decimal point, shifted by any exponent.
  int decimals = 0;
  int exponent = 0;
  const auto dot = text.find('.');
  const auto exp_pos = text.find_first_of("eE");
  if (dot != std::string::npos) {
    const auto stop = exp_pos == std::string::npos ? text.size() : exp_pos;
    decimals = static_cast<int>(stop - dot - 1);
  }
  if (exp_pos != std::string::npos) {
    const char* exp_begin = text.data() + exp_pos + 1;
    if (exp_begin < end && *exp_begin == '+') ++exp_begin;
    std::from_chars(exp_begin, end, exponent);
  }
  parsed.quantum = std::pow(10.0, exponent - decimals);
  return parsed;
}

}  // namespace

CsvSeries read_csv_series(const std::string& path, std::size_t channel, std::optional<double> rate_hz) {
  const auto fail = [&path](const std::string& what) -> InputError { return InputError(path + ": " + what); };
  const auto fail_line = [&path](std::size_t line_no, const std::string& what) -> InputError {
    return InputError(path + ": line " + std::to_string(line_no) + ": " + what);
  };

  std::ifstream in(path, std::ios::binary);
  if (!in) throw fail("cannot open for reading");

  CsvSeries series;
  std::optional<Dialect> dialect;  // fixed by the first data line
  std::size_t fields_per_line = 0;
  std::vector<double> times_s;
  std::vector<std::size_t> time_lines;  // file line of each time stamp, for messages
  std::vector<double> time_quanta_s;   // rounding quantum of each printed time stamp

  std::string raw;
  std::size_t line_no = 0;
  while (std::getline(in, raw)) {
    ++line_no;
    std::string_view line = raw;
    if (line_no == 1 && line.starts_with("\xEF\xBB\xBF")) line.remove_prefix(3);  // UTF-8 byte-order mark
    line = trim(line);
    if (line.empty() || line.front() == '#') continue;

    if (!dialect) {
      // Still in the header: a line whose first field is not a number is a header line.
      const Dialect candidate = detect_dialect(line);
      const auto fields = split(line, candidate);
      if (fields.empty() || !parse_number(fields.front(), candidate)) continue;
      dialect = candidate;
      fields_per_line = fields.size();
      series.has_time_column = fields_per_line >= 2;
      series.value_columns = series.has_time_column ? fields_per_line - 1 : 1;
      if (channel >= series.value_columns) {
        throw fail("channel " + std::to_string(channel) + " out of range (file has " +
                   std::to_string(series.value_columns) + " value column" + (series.value_columns == 1 ? "" : "s") +
                   (series.has_time_column ? " after the time column)" : ")"));
      }
    }

    const auto fields = split(line, *dialect);
    if (fields.size() < fields_per_line ||
        std::any_of(fields.begin(), fields.end(), [](std::string_view f) { return f.empty(); })) {
      throw fail_line(line_no, "missing value (expected " + std::to_string(fields_per_line) + " fields, found " +
                                   std::to_string(std::count_if(fields.begin(), fields.end(),
                                                                [](std::string_view f) { return !f.empty(); })) +
                                   ")");
    }
    if (fields.size() > fields_per_line) {
      throw fail_line(line_no, "too many values (" + std::to_string(fields.size()) + " fields, expected " +
                                   std::to_string(fields_per_line) + " as on the first data line)");
    }
    const std::size_t value_field = series.has_time_column ? channel + 1 : 0;
    for (std::size_t i = 0; i < fields.size(); ++i) {
      const auto parsed = parse_number(fields[i], *dialect);
      if (!parsed) throw fail_line(line_no, "'" + std::string(fields[i]) + "' is not a number");
      const bool is_time = series.has_time_column && i == 0;
      if ((is_time || i == value_field) && !std::isfinite(parsed->value)) {
        throw fail_line(line_no, std::string(is_time ? "time" : "value") + " '" + std::string(fields[i]) +
                                     "' is not finite (NaN or Inf)");
      }
      if (is_time) {
        if (!times_s.empty() && !(parsed->value > times_s.back())) {
          throw fail_line(line_no, "time " + num(parsed->value) + " s is not after the previous time " +
                                       num(times_s.back()) + " s (line " + std::to_string(time_lines.back()) +
                                       "); time must increase");
        }
        times_s.push_back(parsed->value);
        time_lines.push_back(line_no);
        time_quanta_s.push_back(parsed->quantum);
      } else if (i == value_field) {
        series.values.push_back(parsed->value);
      }
    }
  }
  if (in.bad()) throw fail("read error");
  if (series.values.empty()) throw fail("empty (0 samples: no numeric data lines)");

  if (!series.has_time_column) {
    if (!rate_hz) throw fail("one value column and no time column: the sample rate is unknown, pass --rate HZ");
    if (!std::isfinite(*rate_hz) || *rate_hz <= 0.0) {
      throw fail("sample rate " + num(*rate_hz) + " Hz (from --rate) is not a positive number");
    }
    series.sample_rate_hz = *rate_hz;
    return series;
  }

  if (times_s.size() < 2) throw fail("only one data line: cannot derive the sample rate from the time column");
  std::vector<double> steps_s(times_s.size() - 1);
  for (std::size_t i = 1; i < times_s.size(); ++i) steps_s[i - 1] = times_s[i] - times_s[i - 1];
  std::vector<double> sorted = steps_s;
  const auto middle = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2);
  std::nth_element(sorted.begin(), middle, sorted.end());
  const double median_step_s = *middle;
  // Each printed stamp is off by up to half its rounding quantum, so a step between two stamps may
  // be off by the sum of the halves; allow that on top of the 1 % (capped below half a step, so a
  // missing sample is never excused by coarse rounding).
  for (std::size_t i = 0; i < steps_s.size(); ++i) {
    const double rounding_s = 0.5 * (time_quanta_s[i] + time_quanta_s[i + 1]);
    const double allowed_s = kCsvMaxTimeStepDeviation * median_step_s + std::min(rounding_s, 0.49 * median_step_s);
    const double deviation_s = std::abs(steps_s[i] - median_step_s);
    if (deviation_s > allowed_s) {
      throw fail_line(time_lines[i + 1], "non-uniform time step " + num(steps_s[i]) + " s (median step " +
                                             num(median_step_s) + " s, deviation " +
                                             num(100.0 * deviation_s / median_step_s) +
                                             " %, allowed 1 %); gap or jitter in the time column");
    }
  }
  // With uniformity established, the overall span gives the most precise rate (rounding of single
  // stamps averages out); the median step only served as the robust reference for the check.
  series.sample_rate_hz = static_cast<double>(times_s.size() - 1) / (times_s.back() - times_s.front());
  if (rate_hz && !(std::abs(*rate_hz - series.sample_rate_hz) <= kCsvMaxTimeStepDeviation * series.sample_rate_hz)) {
    throw fail("sample rate " + num(*rate_hz) + " Hz (from --rate) disagrees with the time column (" +
               num(series.sample_rate_hz) + " Hz)");
  }
  return series;
}

}  // namespace ridgewatch::drivers
