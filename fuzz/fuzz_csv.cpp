// Fuzz target: the CSV/text sample reader (drivers/csv_reader.hpp). Byte 0 chooses the channel and
// whether a sample rate is given; the rest is the file. Only InputError is an expected outcome; any
// other exception, crash or sanitizer report is a finding.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <optional>

#include "drivers/csv_reader.hpp"
#include "drivers/sample_source.hpp"
#include "fuzz/temp_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::uint8_t mode = data[0];
  const std::string path = ridgewatch::fuzz::write_input(data + 1, size - 1, ".csv");
  const std::size_t channel = mode & 0x3;
  const std::optional<double> rate = (mode & 0x4) ? std::optional<double>(25600.0) : std::nullopt;
  try {
    const auto series = ridgewatch::drivers::read_csv_series(path, channel, rate);
    // Postconditions the replay driver relies on.
    if (series.values.empty() || !(series.sample_rate_hz > 0) || channel >= series.value_columns) std::abort();
    for (double v : series.values)
      if (!std::isfinite(v)) std::abort();
  } catch (const ridgewatch::drivers::InputError&) {
  }
  return 0;
}
