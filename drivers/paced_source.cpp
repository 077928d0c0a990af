#include "drivers/paced_source.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <type_traits>
#include <utility>

namespace ridgewatch::drivers {

PacedSource::PacedSource(Factory factory, PacedSourceConfig config) : factory_(std::move(factory)), config_(config) {
  if (!std::isfinite(config_.speed) || config_.speed < 0.0) {
    std::ostringstream msg;
    msg << "speed: must be finite and >= 0 (0 = as fast as possible; got " << config_.speed << ")";
    throw std::invalid_argument(msg.str());
  }
  if (!factory_) throw std::invalid_argument("PacedSource: empty source factory");
  inner_ = factory_();
  if (!inner_) throw std::invalid_argument("PacedSource: the source factory returned no source");
  info_ = inner_->info();
  if (config_.loop) info_.frames.reset();
}

template <typename T>
void PacedSource::fill(std::span<T> out, std::size_t& filled) {
  while (filled < out.size() && !ended_) {
    std::size_t n = 0;
    if constexpr (std::is_same_v<T, float>) n = inner_->read_float(out.subspan(filled));
    else n = inner_->read(out.subspan(filled));
    filled += n;
    samples_this_pass_ += n;
    if (n > 0) continue;
    // End of the inner source.
    if (!config_.loop || samples_this_pass_ == 0) {
      ended_ = true;  // not looping, or a pass without samples (looping would spin forever)
      break;
    }
    auto next = factory_();
    if (!next) throw InputError(info_.name + ": reopening for the next loop returned no source");
    const SourceInfo& again = next->info();
    if (again.sample_rate_hz != info_.sample_rate_hz || again.channels != info_.channels ||
        again.channel != info_.channel) {
      std::ostringstream msg;
      msg << again.name << ": changed while looping (now " << again.sample_rate_hz << " Hz, " << again.channels
          << " channels, channel " << again.channel << "; was " << info_.sample_rate_hz << " Hz, "
          << info_.channels << " channels, channel " << info_.channel << ")";
      throw InputError(msg.str());
    }
    inner_ = std::move(next);
    samples_this_pass_ = 0;
    ++loops_completed_;
  }
}

template <typename T>
std::size_t PacedSource::paced_read(std::span<T> out) {
  if (!started_) {
    start_ = std::chrono::steady_clock::now();
    started_ = true;
  }
  if (pending_error_) std::rethrow_exception(std::exchange(pending_error_, nullptr));
  std::size_t filled = 0;
  // Any error after some samples of this call (the inner read, reopening for the next loop, a file that
  // changed while looping) is held back: those samples are delivered first, the error comes next call.
  try {
    fill(out, filled);
  } catch (...) {
    if (filled == 0) throw;
    pending_error_ = std::current_exception();
    ended_ = true;
  }
  samples_delivered_ += filled;
  if (filled > 0 && config_.speed > 0.0) {
    const double due_s = static_cast<double>(samples_delivered_) / (info_.sample_rate_hz * config_.speed);
    const auto due = start_ + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                  std::chrono::duration<double>(due_s));
    std::unique_lock<std::mutex> lock(stop_mutex_);
    stop_cv_.wait_until(lock, due, [this] { return stop_requested_; });
  }
  return filled;
}

std::size_t PacedSource::read(std::span<double> out) { return paced_read(out); }
std::size_t PacedSource::read_float(std::span<float> out) { return paced_read(out); }

void PacedSource::request_stop() {
  {
    std::lock_guard<std::mutex> lock(stop_mutex_);
    stop_requested_ = true;
  }
  stop_cv_.notify_all();
}

std::unique_ptr<PacedSource> open_paced_replay(const std::string& path, const ReplayOptions& options,
                                               PacedSourceConfig config) {
  return std::make_unique<PacedSource>([path, options] { return open_replay(path, options); }, config);
}

}  // namespace ridgewatch::drivers
