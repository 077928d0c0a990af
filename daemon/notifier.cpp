#include "daemon/notifier.hpp"

#include <systemd/sd-daemon.h>

#include <cstdint>

namespace ridgewatch::daemon {

SystemdNotifier::SystemdNotifier() {
  std::uint64_t usec = 0;
  // > 0: watchdog enabled for this process (WATCHDOG_USEC set and WATCHDOG_PID ours or unset).
  if (sd_watchdog_enabled(0, &usec) > 0) watchdog_interval_ = std::chrono::microseconds(usec);
}

void SystemdNotifier::send(const std::string& text) { sd_notify(0, text.c_str()); }

void SystemdNotifier::ready(const std::string& status) { send("READY=1\nSTATUS=" + status); }
void SystemdNotifier::status(const std::string& status) { send("STATUS=" + status); }
void SystemdNotifier::watchdog() { send("WATCHDOG=1"); }
void SystemdNotifier::reloading() { send("RELOADING=1"); }
void SystemdNotifier::stopping() { send("STOPPING=1"); }

}  // namespace ridgewatch::daemon
