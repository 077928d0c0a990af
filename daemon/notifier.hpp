// systemd service notification (sd_notify(3) from libsystemd): READY, STATUS, WATCHDOG, RELOADING,
// STOPPING. Without NOTIFY_SOCKET (not started by systemd) every call is a cheap no-op.
#pragma once

#include <chrono>
#include <string>

namespace ridgewatch::daemon {

class SystemdNotifier {
 public:
  SystemdNotifier();
  bool watchdog_enabled() const { return watchdog_interval_.count() > 0; }
  /// WatchdogSec= of the unit (0 when disabled).
  std::chrono::microseconds watchdog_interval() const { return watchdog_interval_; }
  void ready(const std::string& status);
  void status(const std::string& status);
  void watchdog();
  void reloading();
  void stopping();

 private:
  void send(const std::string& text);
  std::chrono::microseconds watchdog_interval_{0};
};

}  // namespace ridgewatch::daemon
