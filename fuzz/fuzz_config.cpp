// Fuzz target: the ridgewatch configuration loader (app/config_yaml.hpp parse_config) on arbitrary
// text. Only UsageError is an expected outcome; an accepted configuration must print and parse back
// to the same text.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "app/args.hpp"
#include "app/config_yaml.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const auto config = ridgewatch::app::parse_config(text, "fuzz.yaml");
    const std::string printed = ridgewatch::app::to_yaml(config);
    if (ridgewatch::app::to_yaml(ridgewatch::app::parse_config(printed, "printed.yaml")) != printed) std::abort();
  } catch (const ridgewatch::app::UsageError&) {
  }
  return 0;
}
