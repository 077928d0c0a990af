#include "daemon/worker_pool.hpp"

#include <stdexcept>
#include <utility>

namespace ridgewatch::daemon {

WorkerPool::WorkerPool(std::size_t threads) {
  if (threads == 0) throw std::invalid_argument("worker pool: needs at least one thread");
  for (std::size_t w = 1; w < threads; ++w) helpers_.emplace_back([this, w] { helper(w); });
}

WorkerPool::~WorkerPool() {
  {
    std::lock_guard lock(mutex_);
    quit_ = true;
  }
  start_.notify_all();
  for (auto& t : helpers_) t.join();
}

void WorkerPool::share(std::size_t worker) {
  try {
    for (std::size_t i = worker; i < tasks_; i += threads()) (*task_)(i);
  } catch (...) {
    std::lock_guard lock(mutex_);
    if (!error_) error_ = std::current_exception();
  }
}

void WorkerPool::run(std::size_t n, const std::function<void(std::size_t)>& task) {
  {
    std::lock_guard lock(mutex_);
    task_ = &task;
    tasks_ = n;
    busy_ = helpers_.size();
    error_ = nullptr;
    ++round_;
  }
  start_.notify_all();
  share(0);
  std::unique_lock lock(mutex_);
  done_.wait(lock, [this] { return busy_ == 0; });
  task_ = nullptr;
  if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
}

void WorkerPool::helper(std::size_t worker) {
  std::uint64_t seen = 0;
  for (;;) {
    {
      std::unique_lock lock(mutex_);
      start_.wait(lock, [&] { return quit_ || round_ != seen; });
      if (quit_) return;
      seen = round_;
    }
    share(worker);
    std::lock_guard lock(mutex_);
    if (--busy_ == 0) done_.notify_one();
  }
}

}  // namespace ridgewatch::daemon
