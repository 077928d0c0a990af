// Fuzz target: the rig description loader (cli/rig_yaml.hpp parse_rig_yaml) on arbitrary text. Only
// UsageError is an expected outcome; an accepted rig must pass the model's own validation.
#include <cstddef>
#include <cstdint>
#include <string>

#include "cli/args.hpp"
#include "cli/rig_yaml.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const auto rig = ridgewatch::cli::parse_rig_yaml(text, "fuzz.yaml");
    rig.rig.validate();  // std::invalid_argument here would be a loader bug (accepted an impossible rig)
  } catch (const ridgewatch::cli::UsageError&) {
  }
  return 0;
}
