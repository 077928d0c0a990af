// A fixed pool of threads for the daemon's streams: run(n, task) calls task(i) for i in [0, n) and
// returns when all are done (fork-join, one round per processing step). Task i always runs on thread
// i % threads(), so a stream stays on one thread and its processor's memory in that core's cache; the
// calling thread is thread 0, so a pool of 1 starts no thread at all.
//
// Memory visibility: everything a task wrote is visible to the caller when run() returns, and
// everything the caller wrote before run() is visible to the tasks (the round starts and ends under
// the pool's mutex). Between rounds the caller may therefore touch the tasks' data without locks.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace ridgewatch::daemon {

class WorkerPool {
 public:
  /// `threads` >= 1 (std::invalid_argument otherwise); threads - 1 are started here.
  explicit WorkerPool(std::size_t threads);
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  /// Runs task(0..n-1) on the pool; rethrows the first exception a task threw (after all finished).
  void run(std::size_t n, const std::function<void(std::size_t)>& task);
  std::size_t threads() const { return helpers_.size() + 1; }

 private:
  void share(std::size_t worker);  // the tasks of one thread in this round
  void helper(std::size_t worker);

  std::mutex mutex_;
  std::condition_variable start_, done_;
  std::uint64_t round_ = 0;
  std::size_t busy_ = 0;  // helpers still working on this round
  bool quit_ = false;
  std::size_t tasks_ = 0;
  const std::function<void(std::size_t)>* task_ = nullptr;
  std::exception_ptr error_;
  std::vector<std::thread> helpers_;
};

}  // namespace ridgewatch::daemon
