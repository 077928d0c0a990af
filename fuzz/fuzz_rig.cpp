// Fuzz target: the rig description loader (app/rig_yaml.hpp parse_rig_yaml) on arbitrary text. Only
// UsageError is an expected outcome; an accepted rig must pass the model's own validation.
#include <cstddef>
#include <cstdint>
#include <string>

#include "app/args.hpp"
#include "app/rig_yaml.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const auto rig = ridgewatch::app::parse_rig_yaml(text, "fuzz.yaml");
    rig.rig.validate();  // std::invalid_argument here would be a loader bug (accepted an impossible rig)
  } catch (const ridgewatch::app::UsageError&) {
  }
  return 0;
}
