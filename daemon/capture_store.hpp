// Bounded capture-on-trigger (`output.capture`): each selected impact window as DIR/impact-N.wav
// (float32) + DIR/impact-N.json (the event and where the window sits in the stream). After each
// capture the oldest captures (by modification time, then name) are removed until the directory holds
// at most max_files capture files and max_bytes bytes of them; removals are counted. Captures already
// in DIR when the daemon starts count toward the limits. Like the event log, a capture that cannot be
// written (disk full, permission lost) is counted and its partial files removed; writing resumes by
// itself when the disk accepts data again. Never throws.
#pragma once

#include <cstdint>
#include <deque>
#include <span>
#include <string>

#include "app/config_yaml.hpp"
#include "core/pipeline/impact_event.hpp"

namespace ridgewatch::daemon {

class CaptureStore {
 public:
  explicit CaptureStore(app::CaptureConfig config);

  /// Whether `select` wants this event: all; not_ok (status not ok); alarm (level alert or danger).
  bool selected(const pipeline::ImpactEvent& e) const;
  /// Writes one capture, then removes the oldest beyond the limits. Returns "" or an error text.
  std::string write(const pipeline::ImpactEvent& e, const std::string& source, std::span<const float> window,
                    std::uint64_t window_first_index, double sample_rate_hz);

  const app::CaptureConfig& config() const { return config_; }
  std::uint64_t written() const { return written_; }   ///< captures written by this store
  std::uint64_t removed() const { return removed_; }   ///< captures removed to keep the limits
  std::uint64_t failed() const { return failed_; }     ///< captures that could not be written
  std::size_t files() const { return files_; }         ///< capture files now in the directory
  std::uint64_t bytes() const { return bytes_; }       ///< their total size

 private:
  struct Entry {
    std::string base;  ///< path without .wav/.json
    std::uint64_t bytes = 0;
    int files = 0;
  };
  void scan();
  void enforce_limits();
  void remove_entry(const Entry& e);

  app::CaptureConfig config_;
  std::deque<Entry> entries_;  ///< oldest first
  std::uint64_t bytes_ = 0, written_ = 0, removed_ = 0, failed_ = 0;
  std::size_t files_ = 0;  // sum of entries_[i].files
};

}  // namespace ridgewatch::daemon
