// Event outputs of the daemon: the JSON Lines log (the contract in the README), an optional CSV log,
// and capture-on-trigger files. Writes never throw: a line that cannot be written (disk full,
// permission lost) is counted, the log enters a fault state, and writing resumes by itself when the
// file accepts data again. Lines go out in blocks, one write(2) per block to an O_APPEND descriptor
// (the daemon writes the events of one processing step as one block); a line the disk cuts short is
// removed again, so the file holds whole lines only, also when the process is killed.
#pragma once

#include <chrono>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>

#include "core/pipeline/impact_event.hpp"

namespace ridgewatch::daemon {

class LineFile {
 public:
  /// path "-" is standard output. `header` is written when the file is new or empty.
  LineFile(std::string path, std::string header = {});
  ~LineFile();
  LineFile(const LineFile&) = delete;
  LineFile& operator=(const LineFile&) = delete;

  /// Appends text + '\n'. Returns false (and counts) when it could not be written completely.
  bool write_line(const std::string& text);
  /// Appends `lines` complete lines (`block` is their text, each line ending in '\n'), in one
  /// write(2) unless the file takes less (then the rest follows). Returns how many of the lines could
  /// not be written (0: all of them were); those are the last ones of the block, and a line cut short
  /// is truncated away again.
  std::size_t write_lines(std::string_view block, std::size_t lines);
  /// Closes and opens the path again (log rotation, SIGHUP).
  void reopen();
  /// fsync(2): called before exit so written events survive a power cut.
  void sync();

  const std::string& path() const { return path_; }
  std::uint64_t lines_written() const { return written_; }
  std::uint64_t lines_failed() const { return failed_; }
  bool fault() const { return fault_; }
  const std::string& last_error() const { return last_error_; }

 private:
  bool open();
  std::string path_, header_;
  int fd_ = -1;
  bool owns_fd_ = false;
  bool fault_ = false;
  std::uint64_t written_ = 0, failed_ = 0;
  std::string last_error_;
};

/// One CSV row per event (header: t_s,sample_index,source,f_hz,zeta,zeta_ci95_lo,zeta_ci95_hi,snr_db,status,alarm).
/// Damping ratio with 4 significant digits for status lines ("-" when not estimated).
std::string format_zeta(double zeta);
/// ISO 8601 UTC with milliseconds, the events' wall_time ("2026-01-02T03:04:05.678Z").
std::string iso8601_utc(std::chrono::system_clock::time_point tp);
/// `stream`: one of several streams (ridgewatchd `streams:`), a column after source; "" = no column.
std::string event_csv_row(const pipeline::ImpactEvent& e, const std::string& source, const std::string& stream = {});
std::string event_csv_header(bool with_stream = false);

/// Writes BASE.wav (float32) and BASE.json for one impact window; returns an error text or "".
std::string write_capture(const std::string& dir, const pipeline::ImpactEvent& e, const std::string& source,
                          std::span<const float> window, std::uint64_t window_first_index, double sample_rate_hz);

}  // namespace ridgewatch::daemon
