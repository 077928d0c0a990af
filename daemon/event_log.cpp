#include "daemon/event_log.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <spdlog/fmt/fmt.h>
#include <sstream>
#include <vector>

#include "app/event_json.hpp"
#include "drivers/wav_writer.hpp"

namespace ridgewatch::daemon {

LineFile::LineFile(std::string path, std::string header) : path_(std::move(path)), header_(std::move(header)) {
  open();
}

LineFile::~LineFile() {
  if (owns_fd_ && fd_ >= 0) ::close(fd_);
}

bool LineFile::open() {
  if (path_ == "-") {
    fd_ = STDOUT_FILENO;
    owns_fd_ = false;
    return true;
  }
  fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  owns_fd_ = fd_ >= 0;
  if (fd_ < 0) {
    fault_ = true;
    last_error_ = path_ + ": cannot open for writing: " + std::strerror(errno);
    return false;
  }
  struct stat st {};
  if (!header_.empty() && ::fstat(fd_, &st) == 0 && st.st_size == 0) {
    const std::string h = header_ + "\n";
    if (::write(fd_, h.data(), h.size()) != static_cast<ssize_t>(h.size())) {
      fault_ = true;
      last_error_ = path_ + ": cannot write header: " + std::strerror(errno);
    }
  }
  return true;
}

bool LineFile::write_line(const std::string& text) {
  const std::string line = text + "\n";
  return write_lines(line, 1) == 0;
}

std::size_t LineFile::write_lines(std::string_view block, std::size_t lines) {
  if (lines == 0) return 0;
  if (fd_ < 0 && !open()) {
    failed_ += lines;
    return lines;
  }
  std::size_t done = 0;  // bytes written
  int error = 0;         // errno of the failed write(2), 0 for a write that took nothing
  while (done < block.size()) {
    const ssize_t n = ::write(fd_, block.data() + done, block.size() - done);
    if (n > 0) {
      done += static_cast<std::size_t>(n);
    } else if (n < 0 && errno == EINTR) {
      continue;
    } else {
      error = n < 0 ? errno : 0;
      break;
    }
  }
  if (done == block.size()) {
    written_ += lines;
    fault_ = false;
    return 0;
  }
  // The whole lines written are a prefix of the block; a partial line after them is cut back so the
  // file stays valid JSON Lines.
  const std::string_view out = block.substr(0, done);
  const std::size_t whole_bytes = out.rfind('\n') == std::string_view::npos ? 0 : out.rfind('\n') + 1;
  const auto whole = static_cast<std::size_t>(std::count(out.begin(), out.begin() + static_cast<std::ptrdiff_t>(whole_bytes), '\n'));
  const std::size_t partial = done - whole_bytes;
  last_error_ = path_ + ": write failed: " + (error != 0 ? std::strerror(error) : "short write (disk full?)");
  if (partial > 0 && owns_fd_) {
    const off_t end = ::lseek(fd_, 0, SEEK_END);
    const bool cut = end >= static_cast<off_t>(partial) && ::ftruncate(fd_, end - static_cast<off_t>(partial)) == 0;
    if (!cut) last_error_ += "; could not remove the partial line (" + std::string(end < 0 ? std::strerror(errno) : "truncate failed") + ")";
  }
  written_ += whole;
  failed_ += lines - whole;
  fault_ = true;
  return lines - whole;
}

void LineFile::reopen() {
  if (path_ == "-") return;
  if (owns_fd_ && fd_ >= 0) ::close(fd_);
  fd_ = -1;
  open();
}

void LineFile::sync() {
  if (fd_ >= 0 && owns_fd_) ::fsync(fd_);
}

// Damping ratio with 4 significant digits ("-" when not estimated).
std::string format_zeta(double zeta) { return std::isfinite(zeta) ? fmt::format("{:.4g}", zeta) : "-"; }

std::string iso8601_utc(std::chrono::system_clock::time_point tp) {
  const auto secs = std::chrono::time_point_cast<std::chrono::seconds>(tp);
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(tp - secs).count();
  const std::time_t t = std::chrono::system_clock::to_time_t(secs);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%S", &tm);
  return fmt::format("{}.{:03}Z", buf, ms);
}


std::string event_csv_header(bool with_stream) {
  return with_stream ? "t_s,sample_index,source,stream,f_hz,zeta,zeta_ci95_lo,zeta_ci95_hi,snr_db,status,alarm"
                     : "t_s,sample_index,source,f_hz,zeta,zeta_ci95_lo,zeta_ci95_hi,snr_db,status,alarm";
}

std::string event_csv_row(const pipeline::ImpactEvent& e, const std::string& source, const std::string& stream) {
  auto num = [](double v) {
    if (!std::isfinite(v)) return std::string();
    std::ostringstream o;
    o.precision(10);
    o << v;
    return o.str();
  };
  std::string quoted = "\"";
  for (char c : source) quoted += c == '"' ? std::string("\"\"") : std::string(1, c);
  quoted += "\"";
  if (!stream.empty()) quoted += ",\"" + stream + "\"";  // stream names are plain words (config_yaml.cpp)
  std::ostringstream o;
  o << num(e.t_s) << ',' << e.sample_index << ',' << quoted << ',' << num(e.f_hz) << ',' << num(e.zeta) << ','
    << num(e.zeta_ci95_lo) << ',' << num(e.zeta_ci95_hi) << ',' << num(e.snr_db) << ',' << pipeline::to_string(e.status)
    << ',' << trend::to_string(e.alarm.level);
  return o.str();
}

std::string write_capture(const std::string& dir, const pipeline::ImpactEvent& e, const std::string& source,
                          std::span<const float> window, std::uint64_t window_first_index, double fs) {
  try {
    std::filesystem::create_directories(dir);
    const std::string base = (std::filesystem::path(dir) / ("impact-" + std::to_string(e.sample_index))).string();
    std::vector<double> samples(window.begin(), window.end());
    drivers::write_wav(base + ".wav", samples, fs, 1);
    nlohmann::ordered_json side = {{"source", source},
                                   {"sample_rate_hz", fs},
                                   {"first_sample_index", window_first_index},
                                   {"onset_sample_index", e.sample_index},
                                   {"event", nlohmann::ordered_json::parse(app::event_json(e, source))}};
    std::ofstream f(base + ".json");
    f << side.dump(2) << "\n";
    f.close();
    if (!f) return base + ".json: write failed";
    return {};
  } catch (const std::exception& ex) {
    return ex.what();
  }
}

}  // namespace ridgewatch::daemon
