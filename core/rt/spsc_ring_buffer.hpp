// Lock-free single-producer / single-consumer ring buffer for the sample stream (acquisition thread ->
// processing thread), with exact absolute sample indices across overruns and upstream gaps, and a
// guaranteed look-back window for pre-trigger capture.
//
// CONTRACT
//   * Exactly one producer thread calls the producer methods (write, write_space + commit, skip,
//     writable_items, write_stream_index) and exactly one consumer thread calls the consumer methods
//     (read_regions, consume, read, copy_lookback, read_stream_index).
//     The observer methods (capacity, *_items, fill_items) may be called from any thread.
//   * Nothing allocates, blocks, locks or throws after construction: the storage is allocated once in
//     the constructor (which throws std::invalid_argument on bad sizes). All methods except the
//     constructor are noexcept and wait-free (bounded work, no retry loops).
//   * T must be trivially copyable (samples: float/double/int).
//
// INDICES (both 64-bit and free-running; they never wrap in practice: 2^64 samples at 5 MHz is
// 117 000 years)
//   * buffer index: the position of an item among the items actually stored. write index = items stored
//     so far, read index = items consumed so far, fill = write - read.
//   * stream index: the absolute sample index of an item in the source stream. stream index = buffer
//     index + all items lost before it. Items are lost in two ways: an overrun (write() called while the
//     buffer is full: the write is truncated, the rest is dropped and counted in overrun_items()), or an
//     upstream gap the producer declares with skip(n) (an ALSA xrun, a device reconnect). The zero-copy
//     path never drops by itself: write_space() hands out free slots only, and commit() drops (and
//     counts as overrun) only when the gap table is full (below); a zero-copy producer that discards
//     data declares it with skip(). Both make a
//     jump in the stream index of the next stored item, which the consumer sees as a forward jump in
//     ReadRegions::first_stream_index — exactly what pipeline::StreamProcessor::process() expects.
//     A gap is published together with the first item stored after it, so a trailing gap (nothing
//     written since) is visible only in the counters.
//   * Up to kMaxGaps gaps may be pending (published, not yet reached by the consumer). If the producer
//     would need a further one, it keeps dropping (and counting) items until the consumer catches up; the
//     indices stay exact, only more data is lost. 64 pending gaps means the consumer is hopelessly late.
//
// LOOK-BACK (pre-trigger)
//   The constructor reserves `history_items` (H) slots: the producer never uses them, so it can store at
//   most capacity - H unconsumed items, and the H most recently consumed items stay intact however fast
//   the producer runs. copy_lookback(first, out) copies stream indices [first, first + out.size()) and
//   is guaranteed to succeed exactly when
//       read_stream_index() - H <= first,   first + out.size() <= read_stream_index(),
//   and no gap lies inside or after the range (first >= the stream index where the current gap-free run
//   of items began). Otherwise it copies nothing and says why. Older consumed items may still be in
//   memory but can be overwritten concurrently at any moment, so they are never handed out.
//
// Layout: the write index, the read index, the producer's private state and the consumer's private
// state each sit on their own 64-byte cache line, so the two threads do not false-share.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <cassert>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace ridgewatch::rt {

/// Why copy_lookback() refused (ok: the items were copied).
enum class LookbackStatus {
  ok,
  not_yet_consumed,  ///< the range reaches past read_stream_index(): read it normally instead
  overwritten,       ///< the range starts before read_stream_index() - history_items(): no longer guaranteed
  gap,               ///< the range starts before the current gap-free run: samples are missing in it
};

template <typename T>
class SpscRingBuffer {
  static_assert(std::is_trivially_copyable_v<T>, "SpscRingBuffer copies items with memcpy semantics");

 public:
  /// Most gaps that may be published and not yet reached by the consumer (see header comment).
  static constexpr std::size_t kMaxGaps = 64;

  /// Items the consumer may read now, contiguous in stream index: first_stream_index is the stream index
  /// of first[0], and second (possibly empty) continues first where the storage wraps.
  struct ReadRegions {
    std::span<const T> first;
    std::span<const T> second;
    std::uint64_t first_stream_index = 0;
    std::size_t size() const noexcept { return first.size() + second.size(); }
  };

  struct ReadResult {
    std::size_t count = 0;                ///< items copied
    std::uint64_t first_stream_index = 0;  ///< stream index of the first copied item
  };

  /// capacity_items: a power of two >= 2. history_items: look-back slots reserved for the consumer,
  /// 0 <= history_items < capacity_items. Throws std::invalid_argument otherwise.
  explicit SpscRingBuffer(std::size_t capacity_items, std::size_t history_items = 0)
      : capacity_(capacity_items), mask_(capacity_items - 1), history_(history_items) {
    if (capacity_items < 2 || (capacity_items & (capacity_items - 1)) != 0)
      throw std::invalid_argument("SpscRingBuffer: capacity_items must be a power of two >= 2 (got " +
                                  std::to_string(capacity_items) + ")");
    if (history_items >= capacity_items)
      throw std::invalid_argument("SpscRingBuffer: history_items must be < capacity_items (got " +
                                  std::to_string(history_items) + " >= " + std::to_string(capacity_items) + ")");
    storage_ = std::make_unique<T[]>(capacity_items);
  }

  SpscRingBuffer(const SpscRingBuffer&) = delete;
  SpscRingBuffer& operator=(const SpscRingBuffer&) = delete;

  // ---- observers (any thread) ----

  std::size_t capacity() const noexcept { return capacity_; }
  std::size_t history_items() const noexcept { return history_; }
  /// Most unconsumed items the buffer holds: capacity() - history_items().
  std::size_t usable_items() const noexcept { return capacity_ - history_; }
  /// Items stored so far (the write index).
  std::uint64_t written_items() const noexcept { return write_.value.load(std::memory_order_acquire); }
  /// Items consumed so far (the read index).
  std::uint64_t read_items() const noexcept { return read_.value.load(std::memory_order_acquire); }
  /// Items dropped because the buffer was full (or the gap table was full).
  std::uint64_t overrun_items() const noexcept { return overrun_items_.value.load(std::memory_order_relaxed); }
  /// Items the producer declared lost upstream with skip().
  std::uint64_t skipped_items() const noexcept { return skipped_items_.value.load(std::memory_order_relaxed); }
  /// Unconsumed items (a snapshot: either side may move it immediately).
  std::size_t fill_items() const noexcept {
    const std::uint64_t r = read_.value.load(std::memory_order_acquire);
    const std::uint64_t w = write_.value.load(std::memory_order_acquire);
    return static_cast<std::size_t>(w - r);
  }

  // ---- producer ----

  /// Stores as many of `items` as fit (at most usable_items() - fill) and returns how many. The rest is
  /// dropped, counted in overrun_items(), and becomes a gap in the stream index of the next stored item.
  std::size_t write(std::span<const T> items) noexcept {
    // At most two contiguous pieces (the storage wraps); each is copied into place and published.
    std::size_t stored = 0;
    for (int piece = 0; piece < 2 && stored < items.size(); ++piece) {
      const std::span<T> space = write_space(items.size() - stored);
      if (space.empty()) break;
      std::copy_n(items.data() + stored, space.size(), space.data());
      if (commit(space.size()) == 0) {  // gap table full: commit dropped and counted these; the rest too
        drop(items.size() - stored - space.size());
        return stored;
      }
      stored += space.size();
    }
    drop(items.size() - stored);
    return stored;
  }

  /// Zero-copy writing: the free slots at the write position, contiguous (up to where the storage
  /// wraps), at most `wanted`; empty when the ring is full. The producer fills a prefix of them and
  /// publishes it with commit(). Nothing is visible to the consumer before commit().
  std::span<T> write_space(std::size_t wanted) noexcept {
    const std::uint64_t w = producer_.write_index;
    const std::size_t start = static_cast<std::size_t>(w & mask_);
    const std::size_t n = std::min({wanted, free_items(w, wanted), capacity_ - start});
    producer_.last_space_items = n;
    return {storage_.get() + start, n};
  }

  /// Publishes the first n items of the last write_space() (n <= its size; larger n is clamped to it,
  /// and asserted in debug builds), with any pending gap before them. Returns n, or 0 when the gap
  /// table is full (or n == 0): then the n items are dropped and counted like an overrun (write()'s
  /// rule), and the consumer sees them as part of the gap.
  std::size_t commit(std::size_t n) noexcept {
    auto& p = producer_;
    assert(n <= p.last_space_items);
    n = std::min(n, p.last_space_items);
    p.last_space_items = 0;
    if (n == 0) return 0;
    const std::uint64_t w = p.write_index;
    if (p.pending_gap_items > 0) {
      // Publish the gap before the items that follow it; the release store of the write index below
      // makes the record visible to the consumer no later than those items.
      if (gap_write_.value.load(std::memory_order_relaxed) - gap_read_.value.load(std::memory_order_acquire) >=
          kMaxGaps) {
        drop(n);  // gap table full: keep dropping until the consumer has passed some gaps
        return 0;
      }
      const std::uint64_t g = gap_write_.value.load(std::memory_order_relaxed);
      gaps_[g & (kMaxGaps - 1)] = Gap{w, p.pending_gap_items};
      gap_write_.value.store(g + 1, std::memory_order_release);
      p.published_gap_items += p.pending_gap_items;
      p.pending_gap_items = 0;
    }
    p.write_index = w + n;
    write_.value.store(w + n, std::memory_order_release);
    return n;
  }

  /// Free space now (at least this much can be written without loss until the next write).
  std::size_t writable_items() noexcept { return free_items(producer_.write_index, usable_items()); }

  /// Declares `lost_items` samples lost upstream (xrun, reconnect): the next stored item's stream index
  /// is that much further on. Counted in skipped_items().
  void skip(std::uint64_t lost_items) noexcept {
    if (lost_items == 0) return;
    producer_.pending_gap_items += lost_items;
    skipped_items_.value.store(skipped_items_.value.load(std::memory_order_relaxed) + lost_items,
                               std::memory_order_relaxed);
  }

  /// Stream index the next stored item will get if nothing more is lost (producer thread only).
  std::uint64_t write_stream_index() const noexcept {
    return producer_.write_index + producer_.published_gap_items + producer_.pending_gap_items;
  }

  // ---- consumer ----

  /// The items readable now without crossing a gap. After the consumer has read them it calls
  /// consume(n). Returns empty regions when nothing is readable.
  ReadRegions read_regions() noexcept {
    auto& c = consumer_;
    const std::uint64_t w = write_.value.load(std::memory_order_acquire);
    std::uint64_t end = w;
    // Gaps published so far; any gap positioned before w is among them (published before w).
    const std::uint64_t gaps_published = gap_write_.value.load(std::memory_order_acquire);
    while (c.gap_read < gaps_published) {
      const Gap& gap = gaps_[c.gap_read & (kMaxGaps - 1)];
      if (gap.position > c.read_index) {
        end = std::min(end, gap.position);
        break;
      }
      // The gap lies right before the next item: apply it and start a new gap-free run.
      c.stream_offset += gap.lost_items;
      c.run_start_stream_index = c.read_index + c.stream_offset;
      ++c.gap_read;
      gap_read_.value.store(c.gap_read, std::memory_order_release);
    }
    ReadRegions regions;
    regions.first_stream_index = c.read_index + c.stream_offset;
    const auto n = static_cast<std::size_t>(end - c.read_index);
    const std::size_t start = static_cast<std::size_t>(c.read_index & mask_);
    const std::size_t first_part = std::min(n, capacity_ - start);
    regions.first = std::span<const T>(storage_.get() + start, first_part);
    regions.second = std::span<const T>(storage_.get(), n - first_part);
    return regions;
  }

  /// Marks `n` items as consumed; n must not exceed read_regions().size() of the last call.
  void consume(std::size_t n) noexcept {
    consumer_.read_index += n;
    read_.value.store(consumer_.read_index, std::memory_order_release);
  }

  /// Copies up to out.size() readable items (not crossing a gap) and consumes them.
  ReadResult read(std::span<T> out) noexcept {
    const ReadRegions regions = read_regions();
    const std::size_t n = std::min(out.size(), regions.size());
    const std::size_t first_part = std::min(n, regions.first.size());
    std::copy_n(regions.first.data(), first_part, out.data());
    std::copy_n(regions.second.data(), n - first_part, out.data() + first_part);
    consume(n);
    return ReadResult{n, regions.first_stream_index};
  }

  /// Stream index of the next item the consumer will read (gaps already reached are applied).
  std::uint64_t read_stream_index() const noexcept { return consumer_.read_index + consumer_.stream_offset; }

  /// Copies already consumed items [first_stream_index, first_stream_index + out.size()) into `out`;
  /// the exact availability rule is in the header comment. Copies nothing unless the status is ok.
  LookbackStatus copy_lookback(std::uint64_t first_stream_index, std::span<T> out) const noexcept {
    const auto& c = consumer_;
    const std::uint64_t read_stream = c.read_index + c.stream_offset;
    if (first_stream_index > read_stream || out.size() > read_stream - first_stream_index)
      return LookbackStatus::not_yet_consumed;
    if (read_stream - first_stream_index > history_) return LookbackStatus::overwritten;
    if (first_stream_index < c.run_start_stream_index) return LookbackStatus::gap;
    const std::uint64_t first_buffer_index = first_stream_index - c.stream_offset;
    const std::size_t start = static_cast<std::size_t>(first_buffer_index & mask_);
    const std::size_t first_part = std::min(out.size(), capacity_ - start);
    std::copy_n(storage_.get() + start, first_part, out.data());
    std::copy_n(storage_.get(), out.size() - first_part, out.data() + first_part);
    return LookbackStatus::ok;
  }

 private:
  static constexpr std::size_t kCacheLineBytes = 64;

  struct Gap {
    std::uint64_t position = 0;    ///< buffer index of the first item after the gap
    std::uint64_t lost_items = 0;  ///< stream indices skipped before that item
  };

  struct alignas(kCacheLineBytes) PaddedCounter {
    std::atomic<std::uint64_t> value{0};
  };

  struct alignas(kCacheLineBytes) ProducerState {
    std::uint64_t write_index = 0;        ///< private copy of write_
    std::uint64_t cached_read_index = 0;  ///< last read_ seen; refreshed only when space runs out
    std::uint64_t pending_gap_items = 0;  ///< lost items not yet published as a gap
    std::uint64_t published_gap_items = 0;  ///< lost items already published as gaps
    std::size_t last_space_items = 0;     ///< size of the last write_space(): commit() may publish up to it
  };

  struct alignas(kCacheLineBytes) ConsumerState {
    std::uint64_t read_index = 0;    ///< private copy of read_
    std::uint64_t stream_offset = 0;  ///< lost items before read_index
    std::uint64_t gap_read = 0;      ///< private copy of gap_read_
    std::uint64_t run_start_stream_index = 0;  ///< first stream index of the current gap-free run
  };

  /// Items lost at the producer (ring full, gap table full): counted, and a gap before the next stored item.
  void drop(std::size_t dropped) noexcept {
    if (dropped == 0) return;
    producer_.pending_gap_items += dropped;
    // Only the producer writes this counter, so load + store is not a lost update.
    overrun_items_.value.store(overrun_items_.value.load(std::memory_order_relaxed) + dropped,
                               std::memory_order_relaxed);
  }

  /// Free slots for the producer given its write index; reloads the consumer's read index only when the
  /// cached value does not leave room for `wanted` items (saves a cache-line transfer on most writes).
  std::size_t free_items(std::uint64_t w, std::size_t wanted) noexcept {
    auto& p = producer_;
    const std::size_t usable = capacity_ - history_;
    if (usable - static_cast<std::size_t>(w - p.cached_read_index) < wanted)
      p.cached_read_index = read_.value.load(std::memory_order_acquire);
    return usable - static_cast<std::size_t>(w - p.cached_read_index);
  }

  const std::size_t capacity_;
  const std::size_t mask_;
  const std::size_t history_;
  std::unique_ptr<T[]> storage_;
  std::array<Gap, kMaxGaps> gaps_{};

  PaddedCounter write_;  ///< items stored (released after the items and any gap record are written)
  PaddedCounter read_;   ///< items consumed (released after the consumer is done with them)
  PaddedCounter gap_write_;
  PaddedCounter gap_read_;
  PaddedCounter overrun_items_;
  PaddedCounter skipped_items_;
  ProducerState producer_;
  ConsumerState consumer_;
};

}  // namespace ridgewatch::rt
