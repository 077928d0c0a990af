// On-disk store-and-forward queue for the MQTT sink: every event is written here first (by the
// processing thread, one write(2) per processing step, no network involved) and leaves only when the
// broker has acknowledged it (the sender thread calls ack_through()). A broker outage or a daemon
// restart therefore resends what was not acknowledged, in order.
//
// Each event gets a per-stream sequence number `seq` (1, 2, 3, ... for the life of the spool
// directory, also across restarts), written as the first key of its JSON object: consumers
// de-duplicate by it (a message acknowledged just before a crash may be sent twice).
//
// Layout of the directory:
//   seg-<first seq, 20 digits>.jsonl  segments of JSON Lines, one event per line, ascending seq
//   state                              "acked A\ndropped D\n": every seq <= A acknowledged or dropped
// A segment is deleted once all its events are acknowledged. Bounded: when the segments exceed
// max_bytes the oldest segment is deleted whether acknowledged or not, and its unacknowledged events
// are counted in dropped() (they are lost for MQTT; the local event log still has them).
//
// Thread safety: one producer (append) and one consumer (read/ack) may call concurrently; a mutex
// guards the index. The producer never waits for the network, only for the consumer's short reads.
#pragma once

#include <cstdint>
#include <deque>
#include <mutex>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace ridgewatch::daemon {

class SpoolError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class Spool {
 public:
  struct Message {
    std::uint64_t seq = 0;
    std::string payload;  ///< the JSON object, no newline
  };

  /// Opens (creating) the directory and recovers its state; a line cut short by a crash is removed.
  /// Throws SpoolError naming the directory when it cannot be created or read.
  Spool(std::string dir, std::uint64_t max_bytes);
  ~Spool();
  Spool(const Spool&) = delete;
  Spool& operator=(const Spool&) = delete;

  /// Producer: `json_lines` holds complete JSON objects, each starting with '{' and ending in '\n'.
  /// Each gets the next seq inserted as its first key and all go to disk in one write(2). Returns the
  /// seq of the first (the rest follow consecutively), or 0 when the write failed (nothing was
  /// queued, the seqs are not used up, write_failures() counts the events).
  std::uint64_t append(std::string_view json_lines);

  /// Consumer: appends to `out` up to `max` messages with seq > after_seq, in order. Returns how many.
  std::size_t read(std::uint64_t after_seq, std::size_t max, std::vector<Message>& out);
  /// Consumer: every seq <= seq has been acknowledged. Deletes fully acknowledged segments; the
  /// state file is rewritten (atomically, rename) when a segment goes or on persist().
  void ack_through(std::uint64_t seq);
  /// Writes the state file now (at shutdown).
  void persist();

  std::uint64_t last_seq() const;   ///< highest seq queued so far (0: none ever)
  std::uint64_t acked() const;      ///< every seq <= this is acknowledged or dropped
  std::uint64_t depth() const;      ///< events waiting for acknowledgement
  std::uint64_t dropped() const;    ///< events dropped because the spool was full (since creation)
  std::uint64_t write_failures() const;
  std::uint64_t bytes() const;      ///< size of the segments on disk
  const std::string& dir() const { return dir_; }

 private:
  struct Segment {
    std::uint64_t first = 0, last = 0;  // seqs held (last < first: empty)
    std::uint64_t bytes = 0;
    std::string path;
  };
  void recover();
  void open_segment(std::uint64_t first_seq);
  void enforce_bound();
  void write_state();
  std::string segment_path(std::uint64_t first_seq) const;

  std::string dir_;
  std::uint64_t max_bytes_ = 0, segment_bytes_ = 0;
  mutable std::mutex mutex_;
  std::deque<Segment> segments_;
  int fd_ = -1;  // the newest segment, O_APPEND
  std::uint64_t last_seq_ = 0, acked_ = 0, dropped_ = 0, write_failures_ = 0, total_bytes_ = 0;
  std::uint64_t acked_persisted_ = 0;
  std::string line_buf_;
  // Consumer cursor: the byte offset of seq cursor_seq_ in the segment that starts at cursor_first_.
  std::uint64_t cursor_seq_ = 0, cursor_first_ = 0, cursor_off_ = 0;
  std::string read_buf_;
  int read_fd_ = -1;  // consumer: the segment being read (first seq read_fd_first_)
  std::uint64_t read_fd_first_ = 0;
  void close_read_fd();
};

}  // namespace ridgewatch::daemon
