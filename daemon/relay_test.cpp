#include "daemon/relay_test.hpp"

#include <iostream>
#include <string>
#include <thread>
#include <vector>

namespace ridgewatch::daemon {

int test_relays(GpioLines& lines, std::istream& in, std::ostream& out, bool confirmed, std::chrono::milliseconds hold) {
  struct Named {
    const char* role;
    drivers::RelayOutput* relay;
  };
  std::vector<Named> relays;
  if (lines.alert) relays.push_back({"alert", lines.alert.get()});
  if (lines.danger) relays.push_back({"danger", lines.danger.get()});
  if (relays.empty()) {
    out << "no relay configured: set gpio.enabled: true and gpio.alert_line / gpio.danger_line\n";
    return 2;
  }
  if (!confirmed) {
    out << "This switches the alarm relays (";
    for (std::size_t i = 0; i < relays.size(); ++i) out << (i ? ", " : "") << relays[i].role << " = " << relays[i].relay->name();
    out << ") and may trip whatever they are wired to. Type yes to continue: " << std::flush;
    std::string answer;
    std::getline(in, answer);
    if (answer != "yes") {
      out << "not confirmed; relays left as they were\n";
      return 2;
    }
  }
  const double hold_s = std::chrono::duration<double>(hold).count();
  int rc = 0;
  for (const auto& r : relays) {
    const std::uint64_t errors_before = r.relay->errors();
    for (const bool healthy : {true, false, true, false}) {
      r.relay->set_healthy(healthy);
      out << r.role << " relay " << r.relay->name() << ": "
          << (healthy ? "energised (healthy)" : "de-energised (alarm)") << std::flush;
      if (r.relay->errors() > errors_before) {
        out << " -- WRITE FAILED\n";
        rc = 3;
        break;
      }
      out << "\n";
      std::this_thread::sleep_for(hold);
    }
  }
  out << "done (" << hold_s << " s per step); relays left de-energised (alarm) until the service runs\n";
  return rc;
}

}  // namespace ridgewatch::daemon
