// In-memory GPIO lines for tests (no gpiochip needed): a tacho input whose edges the test injects,
// possibly from another thread, and relay outputs that record every value they were driven to.
#pragma once

#include <chrono>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "drivers/gpio.hpp"

namespace ridgewatch::drivers {

class FakeTachoInput : public TachoInput {
 public:
  explicit FakeTachoInput(std::string name = "fake tacho") : name_(std::move(name)) {}

  /// Queues an edge; wakes a waiting wait_edges(). Thread-safe.
  void inject(TachoEdge edge) {
    {
      std::lock_guard lock(mutex_);
      pending_.push_back(edge);
    }
    ready_.notify_all();
  }
  /// The next wait_edges() fails once (counted), as the real line would on a read error.
  void inject_error() {
    std::lock_guard lock(mutex_);
    fail_next_ = true;
  }

  std::size_t wait_edges(std::chrono::nanoseconds timeout, std::vector<TachoEdge>& out) override {
    std::unique_lock lock(mutex_);
    ready_.wait_for(lock, timeout, [&] { return !pending_.empty() || fail_next_; });
    if (fail_next_) {
      fail_next_ = false;
      ++errors_;
      return 0;
    }
    const std::size_t n = pending_.size();
    out.insert(out.end(), pending_.begin(), pending_.end());
    pending_.clear();
    return n;
  }
  const std::string& name() const override { return name_; }
  std::uint64_t errors() const override {
    std::lock_guard lock(mutex_);
    return errors_;
  }

 private:
  std::string name_;
  mutable std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<TachoEdge> pending_;
  bool fail_next_ = false;
  std::uint64_t errors_ = 0;
};

/// A TachoInput that forwards to a FakeTachoInput the test keeps (the daemon owns this one).
class SharedTachoInput : public TachoInput {
 public:
  explicit SharedTachoInput(std::shared_ptr<FakeTachoInput> fake) : fake_(std::move(fake)) {}
  std::size_t wait_edges(std::chrono::nanoseconds timeout, std::vector<TachoEdge>& out) override {
    return fake_->wait_edges(timeout, out);
  }
  const std::string& name() const override { return fake_->name(); }
  std::uint64_t errors() const override { return fake_->errors(); }

 private:
  std::shared_ptr<FakeTachoInput> fake_;
};

/// Records the line value (true = active = energised) of every set_healthy() call. Starts de-energised,
/// like the real output.
class FakeRelayOutput : public RelayOutput {
 public:
  explicit FakeRelayOutput(std::string name = "fake relay") : name_(std::move(name)) {}

  void set_healthy(bool healthy) override {
    std::lock_guard lock(mutex_);
    if (fail_writes_) {
      ++errors_;
      return;
    }
    healthy_ = healthy;
    history_.push_back(healthy);
  }
  bool healthy() const override {
    std::lock_guard lock(mutex_);
    return healthy_;
  }
  bool energised() const { return healthy(); }
  /// Every value written, oldest first.
  std::vector<bool> history() const {
    std::lock_guard lock(mutex_);
    return history_;
  }
  /// Makes writes fail (counted, value unchanged), like a lost chip.
  void fail_writes(bool fail) {
    std::lock_guard lock(mutex_);
    fail_writes_ = fail;
  }
  const std::string& name() const override { return name_; }
  std::uint64_t errors() const override {
    std::lock_guard lock(mutex_);
    return errors_;
  }

 private:
  std::string name_;
  mutable std::mutex mutex_;
  bool healthy_ = false;
  bool fail_writes_ = false;
  std::vector<bool> history_;
  std::uint64_t errors_ = 0;
};

}  // namespace ridgewatch::drivers
