#include "daemon/spool.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace ridgewatch::daemon {

namespace {

constexpr std::string_view kSeqKey = "{\"seq\":";

// seq of a spooled line ("{"seq":N,..."), 0 when the line does not start that way.
std::uint64_t line_seq(std::string_view line) {
  if (line.substr(0, kSeqKey.size()) != kSeqKey) return 0;
  std::uint64_t v = 0;
  const char* b = line.data() + kSeqKey.size();
  const auto [p, ec] = std::from_chars(b, line.data() + line.size(), v);
  return ec == std::errc() ? v : 0;
}

std::string read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

Spool::Spool(std::string dir, std::uint64_t max_bytes) : dir_(std::move(dir)), max_bytes_(max_bytes) {
  // Segments of an eighth of the bound: dropping the oldest when full loses at most that much.
  segment_bytes_ = std::clamp<std::uint64_t>(max_bytes_ / 8, 4096, 4u << 20);
  std::error_code ec;
  std::filesystem::create_directories(dir_, ec);
  if (ec) throw SpoolError(dir_ + ": cannot create the MQTT spool directory: " + ec.message());
  if (::access(dir_.c_str(), W_OK | X_OK) != 0)
    throw SpoolError(dir_ + ": MQTT spool directory not writable: " + std::strerror(errno));
  recover();
}

Spool::~Spool() {
  persist();
  if (fd_ >= 0) ::close(fd_);
  close_read_fd();
}

void Spool::close_read_fd() {
  if (read_fd_ >= 0) ::close(read_fd_);
  read_fd_ = -1;
}

std::string Spool::segment_path(std::uint64_t first_seq) const {
  char name[48];
  std::snprintf(name, sizeof name, "seg-%020llu.jsonl", static_cast<unsigned long long>(first_seq));
  return (std::filesystem::path(dir_) / name).string();
}

void Spool::recover() {
  const std::string state = read_all((std::filesystem::path(dir_) / "state").string());
  {
    std::istringstream in(state);
    std::string key;
    std::uint64_t value = 0;
    while (in >> key >> value) {
      if (key == "acked") acked_ = value;
      if (key == "dropped") dropped_ = value;
    }
  }
  std::vector<std::pair<std::uint64_t, std::string>> files;
  for (const auto& entry : std::filesystem::directory_iterator(dir_)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("seg-", 0) != 0 || name.size() != 4 + 20 + 6 || name.substr(24) != ".jsonl") continue;
    std::uint64_t first = 0;
    std::from_chars(name.data() + 4, name.data() + 24, first);
    files.emplace_back(first, entry.path().string());
  }
  std::sort(files.begin(), files.end());
  for (const auto& [first_name, path] : files) {
    const std::string text = read_all(path);
    // Whole lines only: a line a crash cut short never reached the broker, and its seq is reused.
    const std::size_t whole = text.rfind('\n') == std::string::npos ? 0 : text.rfind('\n') + 1;
    if (whole < text.size()) {
      if (::truncate(path.c_str(), static_cast<off_t>(whole)) != 0)
        throw SpoolError(path + ": cannot remove a partial line: " + std::strerror(errno));
    }
    Segment s;
    s.path = path;
    s.bytes = whole;
    s.first = first_name;
    s.last = first_name - 1;
    for (std::size_t pos = 0; pos < whole;) {
      const std::size_t nl = text.find('\n', pos);
      const std::uint64_t seq = line_seq(std::string_view(text).substr(pos, nl - pos));
      if (seq == 0) throw SpoolError(path + ": not a spool segment (a line without a seq)");
      if (pos == 0) s.first = seq;
      s.last = seq;
      pos = nl + 1;
    }
    if (s.last < s.first || s.last <= acked_) {
      ::unlink(path.c_str());
      last_seq_ = std::max(last_seq_, s.last < s.first ? 0 : s.last);
      continue;
    }
    last_seq_ = std::max(last_seq_, s.last);
    total_bytes_ += s.bytes;
    segments_.push_back(std::move(s));
  }
  last_seq_ = std::max(last_seq_, acked_);
  acked_persisted_ = acked_;
}

void Spool::open_segment(std::uint64_t first_seq) {
  if (fd_ >= 0) ::close(fd_);
  Segment s;
  s.first = first_seq;
  s.last = first_seq - 1;
  s.path = segment_path(first_seq);
  fd_ = ::open(s.path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_APPEND | O_CLOEXEC, 0640);
  if (fd_ < 0) return;
  segments_.push_back(std::move(s));
}

std::uint64_t Spool::append(std::string_view json_lines) {
  std::lock_guard<std::mutex> lock(mutex_);
  line_buf_.clear();
  std::uint64_t seq = last_seq_;
  char num[24];
  for (std::size_t pos = 0; pos < json_lines.size();) {
    std::size_t nl = json_lines.find('\n', pos);
    if (nl == std::string_view::npos) nl = json_lines.size();
    const std::string_view line = json_lines.substr(pos, nl - pos);
    pos = nl + 1;
    if (line.size() < 2 || line.front() != '{') continue;
    ++seq;
    const auto r = std::to_chars(num, num + sizeof num, seq);
    line_buf_ += kSeqKey;
    line_buf_.append(num, r.ptr);
    if (line[1] != '}') line_buf_ += ',';
    line_buf_.append(line.substr(1));
    line_buf_ += '\n';
  }
  const std::uint64_t n = seq - last_seq_;
  if (n == 0) return 0;
  if (fd_ < 0 || segments_.empty() || segments_.back().bytes >= segment_bytes_) open_segment(last_seq_ + 1);
  if (fd_ < 0) {
    write_failures_ += n;
    return 0;
  }
  Segment& s = segments_.back();
  std::size_t done = 0;
  while (done < line_buf_.size()) {
    const ssize_t w = ::write(fd_, line_buf_.data() + done, line_buf_.size() - done);
    if (w > 0) {
      done += static_cast<std::size_t>(w);
    } else if (w < 0 && errno == EINTR) {
      continue;
    } else {
      break;
    }
  }
  if (done < line_buf_.size()) {
    // Disk full or I/O error: take the part back so the segment holds whole lines only.
    if (done > 0 && ::ftruncate(fd_, static_cast<off_t>(s.bytes)) != 0) {
      ::close(fd_);  // the segment cannot be repaired: the next append starts a new one
      fd_ = -1;
    }
    write_failures_ += n;
    return 0;
  }
  const std::uint64_t first = last_seq_ + 1;
  s.last = seq;
  s.bytes += line_buf_.size();
  total_bytes_ += line_buf_.size();
  last_seq_ = seq;
  enforce_bound();
  return first;
}

void Spool::enforce_bound() {
  bool changed = false;
  while (total_bytes_ > max_bytes_ && segments_.size() > 1) {
    const Segment& s = segments_.front();
    if (s.last > acked_) {
      dropped_ += s.last - std::max(s.first, acked_ + 1) + 1;
      acked_ = s.last;
    }
    total_bytes_ -= s.bytes;
    changed = true;
    write_state();
    if (read_fd_first_ == s.first) close_read_fd();
    ::unlink(s.path.c_str());
    segments_.pop_front();
  }
  (void)changed;
}

std::size_t Spool::read(std::uint64_t after_seq, std::size_t max, std::vector<Message>& out) {
  std::lock_guard<std::mutex> lock(mutex_);
  const std::uint64_t want = std::max(after_seq, acked_) + 1;
  if (want > last_seq_ || max == 0) return 0;
  auto find = [&](std::uint64_t first) {
    return std::find_if(segments_.begin(), segments_.end(), [&](const Segment& s) { return s.first == first; });
  };
  if (cursor_seq_ != want || find(cursor_first_) == segments_.end()) {
    const auto it = std::find_if(segments_.begin(), segments_.end(),
                                 [&](const Segment& s) { return s.first <= want && want <= s.last; });
    if (it == segments_.end()) return 0;
    cursor_first_ = it->first;
    cursor_off_ = 0;
    cursor_seq_ = it->first;
  }
  std::size_t count = 0;
  while (count < max) {
    auto it = find(cursor_first_);
    if (it == segments_.end()) break;
    if (cursor_off_ >= it->bytes) {
      if (std::next(it) == segments_.end()) break;
      cursor_first_ = std::next(it)->first;
      cursor_off_ = 0;
      continue;
    }
    if (read_fd_ < 0 || read_fd_first_ != it->first) {
      close_read_fd();
      read_fd_ = ::open(it->path.c_str(), O_RDONLY | O_CLOEXEC);
      if (read_fd_ < 0) break;
      read_fd_first_ = it->first;
    }
    // About what `max - count` lines need (an event line is ~450 bytes), at most 256 kB.
    std::uint64_t chunk = std::min<std::uint64_t>(it->bytes - cursor_off_, std::min<std::uint64_t>(4096 + 1024 * (max - count), 256u << 10));
    read_buf_.resize(chunk);
    ssize_t got = ::pread(read_fd_, read_buf_.data(), chunk, static_cast<off_t>(cursor_off_));
    if (got > 0 && std::string_view(read_buf_.data(), static_cast<std::size_t>(got)).find('\n') == std::string_view::npos) {
      chunk = it->bytes - cursor_off_;  // one line longer than the chunk
      read_buf_.resize(chunk);
      got = ::pread(read_fd_, read_buf_.data(), chunk, static_cast<off_t>(cursor_off_));
    }
    if (got <= 0) break;
    const std::string_view text(read_buf_.data(), static_cast<std::size_t>(got));
    std::size_t pos = 0;
    bool progressed = false;
    while (count < max) {
      const std::size_t nl = text.find('\n', pos);
      if (nl == std::string_view::npos) break;
      const std::string_view line = text.substr(pos, nl - pos);
      const std::uint64_t seq = line_seq(line);
      cursor_off_ += nl + 1 - pos;
      pos = nl + 1;
      progressed = true;
      if (seq == 0) continue;  // cannot happen for lines this class wrote
      cursor_seq_ = seq + 1;
      if (seq < want) continue;
      out.push_back(Message{seq, std::string(line)});
      ++count;
    }
    if (!progressed) break;
  }
  return count;
}

void Spool::ack_through(std::uint64_t seq) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (seq <= acked_) return;
  acked_ = std::min(seq, last_seq_);
  bool state_written = false;
  while (!segments_.empty() && segments_.front().last <= acked_) {
    if (!state_written) write_state();  // first the state, then the files (a crash in between is safe)
    state_written = true;
    const Segment& s = segments_.front();
    if (segments_.size() == 1 && fd_ >= 0) {
      ::close(fd_);
      fd_ = -1;
    }
    total_bytes_ -= s.bytes;
    if (read_fd_first_ == s.first) close_read_fd();
    ::unlink(s.path.c_str());
    segments_.pop_front();
  }
}

void Spool::persist() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (acked_ != acked_persisted_) write_state();
}

void Spool::write_state() {
  const std::string path = (std::filesystem::path(dir_) / "state").string();
  const std::string tmp = path + ".tmp";
  const std::string text = "acked " + std::to_string(acked_) + "\ndropped " + std::to_string(dropped_) + "\n";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0640);
  if (fd < 0) return;  // the spool stays correct; a restart resends a little more
  const bool ok = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size());
  ::close(fd);
  if (ok && ::rename(tmp.c_str(), path.c_str()) == 0) acked_persisted_ = acked_;
}

std::uint64_t Spool::last_seq() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_seq_;
}
std::uint64_t Spool::acked() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return acked_;
}
std::uint64_t Spool::depth() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_seq_ - acked_;
}
std::uint64_t Spool::dropped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return dropped_;
}
std::uint64_t Spool::write_failures() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return write_failures_;
}
std::uint64_t Spool::bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return total_bytes_;
}

}  // namespace ridgewatch::daemon
