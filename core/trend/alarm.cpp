#include "core/trend/alarm.hpp"

namespace ridgewatch::trend {

std::string_view to_string(AlarmLevel level) {
  switch (level) {
    case AlarmLevel::learning: return "learning";
    case AlarmLevel::normal: return "normal";
    case AlarmLevel::alert: return "alert";
    case AlarmLevel::danger: return "danger";
  }
  return "?";
}

}  // namespace ridgewatch::trend
