#include "daemon/capture_store.hpp"

#include <algorithm>
#include <filesystem>
#include <system_error>
#include <vector>

#include "daemon/event_log.hpp"

namespace ridgewatch::daemon {

namespace fs = std::filesystem;

namespace {

std::uint64_t size_or_zero(const fs::path& p) {
  std::error_code ec;
  const auto n = fs::file_size(p, ec);
  return ec ? 0 : static_cast<std::uint64_t>(n);
}

bool file_exists(const fs::path& p) {
  std::error_code ec;
  return fs::exists(p, ec);
}

}  // namespace

CaptureStore::CaptureStore(app::CaptureConfig config) : config_(std::move(config)) { scan(); }

bool CaptureStore::selected(const pipeline::ImpactEvent& e) const {
  if (config_.select == "not_ok") return e.status != pipeline::ImpactStatus::ok;
  if (config_.select == "alarm")
    return e.alarm.level == trend::AlarmLevel::alert || e.alarm.level == trend::AlarmLevel::danger;
  return true;
}

// Captures left by earlier runs: impact-*.wav / impact-*.json grouped by name, oldest first.
void CaptureStore::scan() {
  std::error_code ec;
  if (config_.dir.empty() || !fs::is_directory(config_.dir, ec)) return;
  struct Found {
    fs::file_time_type time;
    Entry entry;
  };
  std::vector<Found> found;
  for (auto it = fs::directory_iterator(config_.dir, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
    const fs::path& p = it->path();
    const std::string name = p.filename().string();
    if (name.rfind("impact-", 0) != 0 || p.extension() != ".wav") continue;
    Entry e;
    e.base = (p.parent_path() / p.stem()).string();
    for (const char* ext : {".wav", ".json"})
      if (file_exists(e.base + ext)) {
        e.bytes += size_or_zero(e.base + ext);
        ++e.files;
      }
    std::error_code tec;
    found.push_back({fs::last_write_time(p, tec), e});
  }
  // A sidecar whose WAV is gone (an interrupted removal) is a capture too: it counts and goes first.
  for (auto it = fs::directory_iterator(config_.dir, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
    const fs::path& p = it->path();
    if (p.filename().string().rfind("impact-", 0) != 0 || p.extension() != ".json") continue;
    const fs::path wav = fs::path(p).replace_extension(".wav");
    if (file_exists(wav)) continue;
    found.push_back({fs::file_time_type::min(), {(p.parent_path() / p.stem()).string(), size_or_zero(p), 1}});
  }
  std::sort(found.begin(), found.end(), [](const Found& a, const Found& b) {
    return a.time != b.time ? a.time < b.time : a.entry.base < b.entry.base;
  });
  for (auto& f : found) {
    bytes_ += f.entry.bytes;
    files_ += static_cast<std::size_t>(f.entry.files);
    entries_.push_back(std::move(f.entry));
  }
  enforce_limits();
}

void CaptureStore::remove_entry(const Entry& e) {
  std::error_code ec;
  for (const char* ext : {".json", ".wav"}) fs::remove(e.base + ext, ec);
  bytes_ -= std::min(bytes_, e.bytes);
  files_ -= std::min(files_, static_cast<std::size_t>(e.files));
}

void CaptureStore::enforce_limits() {
  auto over = [this] {
    return (config_.max_files > 0 && files_ > config_.max_files) || (config_.max_bytes > 0 && bytes_ > config_.max_bytes);
  };
  // The newest capture stays even if it alone exceeds max_bytes (the limit is then one capture).
  while (entries_.size() > 1 && over()) {
    remove_entry(entries_.front());
    entries_.pop_front();
    ++removed_;
  }
}

std::string CaptureStore::write(const pipeline::ImpactEvent& e, const std::string& source, std::span<const float> window,
                                std::uint64_t window_first_index, double sample_rate_hz) {
  const std::string base = (fs::path(config_.dir) / ("impact-" + std::to_string(e.sample_index))).string();
  // The same name again (the daemon restarted, indices start at 0): the old files are replaced.
  if (const auto it = std::find_if(entries_.begin(), entries_.end(), [&](const Entry& x) { return x.base == base; });
      it != entries_.end()) {
    bytes_ -= std::min(bytes_, it->bytes);
    files_ -= std::min(files_, static_cast<std::size_t>(it->files));
    entries_.erase(it);
  }
  const std::string err = write_capture(config_.dir, e, source, window, window_first_index, sample_rate_hz);
  if (!err.empty()) {
    // Disk full or not writable: no half capture stays behind.
    remove_entry({base, 0, 0});
    ++failed_;
    return err;
  }
  Entry entry{base, size_or_zero(base + ".wav") + size_or_zero(base + ".json"), 2};
  bytes_ += entry.bytes;
  files_ += 2;
  entries_.push_back(std::move(entry));
  ++written_;
  enforce_limits();
  return {};
}

}  // namespace ridgewatch::daemon
