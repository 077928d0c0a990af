#include "core/model/effect.hpp"

#include <charconv>
#include <cmath>
#include <stdexcept>

namespace ridgewatch::model {

const char* to_string(EffectKind kind) {
  switch (kind) {
    case EffectKind::kDynamics: return "dynamics";
    case EffectKind::kKinematics: return "kinematics";
    case EffectKind::kSensor: return "sensor";
  }
  return "unknown";
}

EffectSpec parse_effect_spec(const std::string& text) {
  EffectSpec spec;
  const auto colon = text.find(':');
  spec.name = text.substr(0, colon);
  if (spec.name.empty()) throw std::invalid_argument("effect '" + text + "': missing name");
  if (colon == std::string::npos) return spec;
  std::string rest = text.substr(colon + 1);
  std::size_t pos = 0;
  while (pos <= rest.size()) {
    const auto comma = rest.find(',', pos);
    const std::string item = rest.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    const auto eq = item.find('=');
    if (item.empty() || eq == std::string::npos || eq == 0)
      throw std::invalid_argument("effect " + spec.name + ": '" + item + "' is not key=value");
    const std::string key = item.substr(0, eq);
    const std::string value = item.substr(eq + 1);
    double x = 0.0;
    const char* last = value.data() + value.size();
    const auto res = std::from_chars(value.data(), last, x);
    if (value.empty() || res.ec != std::errc() || res.ptr != last || !std::isfinite(x))
      throw std::invalid_argument("effect " + spec.name + ": " + key + ": '" + value + "' is not a number");
    if (!spec.values.emplace(key, x).second)
      throw std::invalid_argument("effect " + spec.name + ": " + key + " given twice");
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  return spec;
}

}  // namespace ridgewatch::model
