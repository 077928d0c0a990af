// Rate limit for repeated log messages: the first occurrence of a key is logged, repeats within the
// interval are counted and reported with the next one that gets through ("... (repeated 41 times)").
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <string>

namespace ridgewatch::daemon {

class LogLimiter {
 public:
  using Clock = std::chrono::steady_clock;
  explicit LogLimiter(double interval_s) : interval_(std::chrono::duration<double>(interval_s)) {}

  void set_interval(double interval_s) { interval_ = std::chrono::duration<double>(interval_s); }

  /// True when a message with this key should be logged now; `suppressed` receives how many were
  /// swallowed since the last one logged.
  bool allow(const std::string& key, Clock::time_point now, std::uint64_t& suppressed) {
    Entry& e = entries_[key];
    if (e.logged_once && now - e.last < interval_) {
      ++e.suppressed;
      return false;
    }
    suppressed = e.suppressed;
    e.suppressed = 0;
    e.last = now;
    e.logged_once = true;
    return true;
  }

 private:
  struct Entry {
    Clock::time_point last{};
    std::uint64_t suppressed = 0;
    bool logged_once = false;
  };
  std::chrono::duration<double> interval_;
  std::map<std::string, Entry> entries_;
};

}  // namespace ridgewatch::daemon
