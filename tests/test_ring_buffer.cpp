// SpscRingBuffer: single-thread behaviour (wrap, full, overrun count, gaps in the stream index,
// look-back availability rule) and two-thread ordering tests with 2^20 items that also run under
// ThreadSanitizer (scripts/test.sh builds build-tsan and runs this executable).
#include "core/rt/spsc_ring_buffer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <random>
#include <stdexcept>
#include <thread>
#include <vector>

namespace {

using ridgewatch::rt::LookbackStatus;
using Ring = ridgewatch::rt::SpscRingBuffer<std::uint32_t>;

std::vector<std::uint32_t> iota_block(std::uint32_t first, std::size_t n) {
  std::vector<std::uint32_t> v(n);
  std::iota(v.begin(), v.end(), first);
  return v;
}

/// Reads everything readable now (across gaps), returning (stream index, value) pairs.
std::vector<std::pair<std::uint64_t, std::uint32_t>> drain(Ring& ring) {
  std::vector<std::pair<std::uint64_t, std::uint32_t>> out;
  std::vector<std::uint32_t> block(7);  // odd block size so reads straddle the wrap point
  for (;;) {
    const auto r = ring.read(block);
    if (r.count == 0) break;
    for (std::size_t i = 0; i < r.count; ++i) out.emplace_back(r.first_stream_index + i, block[i]);
  }
  return out;
}

TEST(RingBuffer, RejectsBadSizes) {
  EXPECT_THROW(Ring(0), std::invalid_argument);
  EXPECT_THROW(Ring(1), std::invalid_argument);
  EXPECT_THROW(Ring(12), std::invalid_argument);
  EXPECT_THROW(Ring(16, 16), std::invalid_argument);
  EXPECT_NO_THROW(Ring(16, 15));
}

TEST(RingBuffer, WrapsAndKeepsOrder) {
  Ring ring(8);
  std::uint32_t next_value = 0;
  std::uint32_t expected = 0;
  // 5-item writes against 8 slots: every second write wraps.
  for (int round = 0; round < 20; ++round) {
    const auto block = iota_block(next_value, 5);
    ASSERT_EQ(ring.write(block), 5u);
    next_value += 5;
    const auto regions = ring.read_regions();
    ASSERT_EQ(regions.size(), 5u);
    EXPECT_EQ(regions.first_stream_index, expected);
    if (round % 8 == 1) {
      EXPECT_FALSE(regions.second.empty()) << "round " << round << " should wrap";
    }
    for (auto v : regions.first) EXPECT_EQ(v, expected++);
    for (auto v : regions.second) EXPECT_EQ(v, expected++);
    ring.consume(regions.size());
  }
  EXPECT_EQ(ring.written_items(), 100u);
  EXPECT_EQ(ring.read_items(), 100u);
  EXPECT_EQ(ring.overrun_items(), 0u);
  EXPECT_EQ(ring.fill_items(), 0u);
}

TEST(RingBuffer, FullWriteIsTruncatedAndCountedAsAGap) {
  Ring ring(8);
  EXPECT_EQ(ring.write(iota_block(0, 6)), 6u);
  EXPECT_EQ(ring.write(iota_block(6, 5)), 2u);  // only 2 slots left: 3 dropped (values 8, 9, 10)
  EXPECT_EQ(ring.fill_items(), 8u);
  EXPECT_EQ(ring.overrun_items(), 3u);
  EXPECT_EQ(ring.write(iota_block(11, 4)), 0u);  // still full: 4 more dropped (11..14)
  EXPECT_EQ(ring.overrun_items(), 7u);
  EXPECT_EQ(ring.written_items(), 8u);

  auto got = drain(ring);
  ASSERT_EQ(got.size(), 8u);
  for (std::size_t i = 0; i < got.size(); ++i) EXPECT_EQ(got[i], std::make_pair(std::uint64_t{i}, std::uint32_t(i)));

  // The next stored item carries the gap: its stream index is 15, the value the source gave it.
  EXPECT_EQ(ring.write_stream_index(), 15u);
  EXPECT_EQ(ring.write(iota_block(15, 3)), 3u);
  got = drain(ring);
  ASSERT_EQ(got.size(), 3u);
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].first, 15u + i);
    EXPECT_EQ(got[i].second, 15u + i);
  }
  EXPECT_EQ(ring.read_stream_index(), 18u);
}

TEST(RingBuffer, ReadStopsAtAGapSoEveryRegionIsContiguous) {
  Ring ring(16);
  ring.write(iota_block(0, 4));
  ring.skip(10);  // e.g. an ALSA xrun lost 10 frames
  ring.write(iota_block(14, 4));
  EXPECT_EQ(ring.skipped_items(), 10u);
  auto regions = ring.read_regions();
  EXPECT_EQ(regions.first_stream_index, 0u);
  EXPECT_EQ(regions.size(), 4u);  // not 8: the gap splits the items
  ring.consume(4);
  regions = ring.read_regions();
  EXPECT_EQ(regions.first_stream_index, 14u);
  ASSERT_EQ(regions.size(), 4u);
  EXPECT_EQ(regions.first[0], 14u);
  ring.consume(4);
  EXPECT_EQ(ring.read_regions().size(), 0u);
}

TEST(RingBuffer, GapBeforeTheFirstItem) {
  Ring ring(8);
  ring.skip(5);
  ring.write(iota_block(5, 2));
  const auto got = drain(ring);
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[0], std::make_pair(std::uint64_t{5}, 5u));
}

TEST(RingBuffer, TooManyPendingGapsDropInsteadOfLosingTrack) {
  Ring ring(1024);
  std::uint32_t stream = 0;
  // kMaxGaps gaps are published, the next write has no room for its gap record and is dropped.
  for (std::size_t g = 0; g <= Ring::kMaxGaps; ++g) {
    ring.skip(1);
    ++stream;
    const std::size_t stored = ring.write(iota_block(stream, 1));
    EXPECT_EQ(stored, g < Ring::kMaxGaps ? 1u : 0u) << "gap " << g;
    ++stream;
  }
  EXPECT_EQ(ring.overrun_items(), 1u);
  const auto got = drain(ring);
  ASSERT_EQ(got.size(), Ring::kMaxGaps);
  for (const auto& [index, value] : got) EXPECT_EQ(index, value);
  // Consumer caught up: the dropped item and its gap fold into the next one.
  ring.write(iota_block(stream, 1));
  const auto after = drain(ring);
  ASSERT_EQ(after.size(), 1u);
  EXPECT_EQ(after[0].first, stream);
}

// Zero-copy writing: write_space() hands out contiguous free slots (never past the storage end or
// the free space), commit() publishes a prefix, with any pending gap before it; stream indices and
// contents come out as with write().
TEST(RingBuffer, WriteSpaceAndCommitKeepOrderAndGaps) {
  Ring ring(16);
  std::uint32_t stream = 0;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> got;
  for (int round = 0; round < 20; ++round) {
    if (round % 5 == 4) {  // an upstream gap of 3 items
      ring.skip(3);
      stream += 3;
    }
    const std::span<std::uint32_t> space = ring.write_space(7);
    ASSERT_LE(space.size(), 7u);
    ASSERT_GT(space.size(), 0u);  // drained every round: there is room
    const std::size_t fill = space.size() > 1 ? space.size() - 1 : 1;  // publish a prefix only
    for (std::size_t i = 0; i < fill; ++i) space[i] = stream + static_cast<std::uint32_t>(i);
    ASSERT_EQ(ring.commit(fill), fill);
    stream += static_cast<std::uint32_t>(fill);
    for (const auto& item : drain(ring)) got.push_back(item);
  }
  ASSERT_EQ(got.size(), stream - 3u * 4u);  // 4 gaps of 3
  for (const auto& [index, value] : got) EXPECT_EQ(index, value);
  EXPECT_EQ(ring.overrun_items(), 0u);
  EXPECT_EQ(ring.skipped_items(), 12u);
}

TEST(RingBuffer, WriteSpaceIsEmptyWhenFullAndCommitDropsWhenTheGapTableIsFull) {
  Ring small(8);
  ASSERT_EQ(small.write(iota_block(0, 8)), 8u);
  EXPECT_TRUE(small.write_space(1).empty());
  // kMaxGaps gaps published and not yet reached by the consumer: the next commit after a gap has no
  // room for its record, so its items are dropped and counted (write()'s rule).
  Ring ring(1024);
  std::uint32_t stream = 0;
  for (std::size_t g = 0; g < Ring::kMaxGaps; ++g) {
    ring.skip(1);
    ++stream;
    const std::span<std::uint32_t> space = ring.write_space(1);
    ASSERT_EQ(space.size(), 1u);
    space[0] = stream++;
    ASSERT_EQ(ring.commit(1), 1u) << "gap " << g;
  }
  ring.skip(1);
  const std::span<std::uint32_t> space = ring.write_space(2);
  ASSERT_EQ(space.size(), 2u);
  EXPECT_EQ(ring.commit(2), 0u);
  EXPECT_EQ(ring.overrun_items(), 2u);
  const auto got = drain(ring);
  ASSERT_EQ(got.size(), Ring::kMaxGaps);
  for (const auto& [index, value] : got) EXPECT_EQ(index, value);
}

TEST(RingBuffer, HistoryReserveLimitsTheFill) {
  Ring ring(16, 6);
  EXPECT_EQ(ring.usable_items(), 10u);
  EXPECT_EQ(ring.write(iota_block(0, 16)), 10u);
  EXPECT_EQ(ring.overrun_items(), 6u);
}

TEST(RingBuffer, LookbackAvailabilityRule) {
  Ring ring(16, 6);
  std::uint32_t next = 0;
  std::vector<std::uint32_t> sink(10);
  // Run the producer far ahead several times so the storage has wrapped repeatedly.
  for (int i = 0; i < 5; ++i) {
    next += static_cast<std::uint32_t>(ring.write(iota_block(next, 10)));
    ring.read(std::span(sink).first(i == 4 ? 7 : 10));
  }
  next += static_cast<std::uint32_t>(ring.write(iota_block(next, 10)));  // buffer full again
  const std::uint64_t r = ring.read_stream_index();
  ASSERT_EQ(r, 47u);

  std::vector<std::uint32_t> out(6, 0xdead);
  EXPECT_EQ(ring.copy_lookback(r - 6, out), LookbackStatus::ok);
  for (std::size_t i = 0; i < out.size(); ++i) EXPECT_EQ(out[i], r - 6 + i);
  std::vector<std::uint32_t> two(2);
  EXPECT_EQ(ring.copy_lookback(r - 2, two), LookbackStatus::ok);
  EXPECT_EQ(two[1], r - 1);
  EXPECT_EQ(ring.copy_lookback(r, std::span<std::uint32_t>()), LookbackStatus::ok);  // empty range at r

  std::vector<std::uint32_t> seven(7, 0xdead);
  EXPECT_EQ(ring.copy_lookback(r - 7, seven), LookbackStatus::overwritten);
  EXPECT_EQ(seven[0], 0xdeadu) << "nothing copied on failure";
  EXPECT_EQ(ring.copy_lookback(r - 1, two), LookbackStatus::not_yet_consumed);
  EXPECT_EQ(ring.copy_lookback(r + 1, std::span(two).first(1)), LookbackStatus::not_yet_consumed);
}

TEST(RingBuffer, LookbackRefusesAcrossAGap) {
  Ring ring(16, 8);
  ring.write(iota_block(0, 4));
  ring.skip(3);
  ring.write(iota_block(7, 4));
  drain(ring);
  ASSERT_EQ(ring.read_stream_index(), 11u);
  std::vector<std::uint32_t> out(4);
  EXPECT_EQ(ring.copy_lookback(7, out), LookbackStatus::ok);
  EXPECT_EQ(out[0], 7u);
  EXPECT_EQ(ring.copy_lookback(6, std::span(out).first(2)), LookbackStatus::gap);
  EXPECT_EQ(ring.copy_lookback(3, std::span(out).first(2)), LookbackStatus::gap);  // all before the gap
}

// ---- two threads (run under ThreadSanitizer in build-tsan) ----

constexpr std::uint32_t kThreadedItems = 1u << 20;  // >= 10^6, the requirement

/// Lossless: the producer retries the unwritten remainder, so the consumer must see 0, 1, 2, ... with
/// nothing missing, duplicated or reordered, and the stream index must equal the value.
/// Consumer of the threaded lossless tests: reads kThreadedItems items whose values are their stream
/// indices and counts every item or region out of place; meanwhile checks the look-back window (the
/// reserved history must stay intact while the producer keeps writing).
std::uint64_t consume_in_order(Ring& ring) {
  std::uint64_t expected = 0;
  std::uint64_t mismatches = 0;
  std::vector<std::uint32_t> lookback(64);
  while (expected < kThreadedItems) {
    const auto regions = ring.read_regions();
    if (regions.size() == 0) {
      std::this_thread::yield();
      continue;
    }
    if (regions.first_stream_index != expected) ++mismatches;
    for (auto v : regions.first) mismatches += (v != expected++);
    for (auto v : regions.second) mismatches += (v != expected++);
    ring.consume(regions.size());
    if (expected >= 64 && ring.copy_lookback(expected - 64, lookback) == LookbackStatus::ok)
      mismatches += (lookback.front() != expected - 64) + (lookback.back() != expected - 1);
  }
  return mismatches;
}

TEST(RingBufferThreaded, MillionItemsInOrderWithoutLoss) {
  Ring ring(1024, 64);
  std::thread producer([&] {
    std::mt19937 rng(1);
    std::uniform_int_distribution<std::size_t> block_size(1, 300);
    std::vector<std::uint32_t> block;
    std::uint32_t next = 0;
    while (next < kThreadedItems) {
      const auto n = std::min<std::size_t>(block_size(rng), kThreadedItems - next);
      block = iota_block(next, n);
      std::span<const std::uint32_t> rest(block);
      while (!rest.empty()) {
        // Lossless producer for this test only: write what fits, wait for room for the rest.
        const std::size_t room = ring.writable_items();
        if (room == 0) {
          std::this_thread::yield();
          continue;
        }
        const std::size_t written = ring.write(rest.first(std::min(room, rest.size())));
        rest = rest.subspan(written);
      }
      next += static_cast<std::uint32_t>(n);
    }
  });
  const std::uint64_t mismatches = consume_in_order(ring);
  producer.join();
  EXPECT_EQ(mismatches, 0u);
  EXPECT_EQ(ring.overrun_items(), 0u);
  EXPECT_EQ(ring.read_items(), kThreadedItems);
}

// The same with the zero-copy producer path (write_space + commit), the one the daemon's replay uses.
TEST(RingBufferThreaded, MillionItemsZeroCopyInOrderWithoutLoss) {
  Ring ring(1024, 64);
  std::thread producer([&] {
    std::mt19937 rng(2);
    std::uniform_int_distribution<std::size_t> block_size(1, 300);
    std::uint32_t next = 0;
    while (next < kThreadedItems) {
      const auto wanted = std::min<std::size_t>(block_size(rng), kThreadedItems - next);
      const std::span<std::uint32_t> space = ring.write_space(wanted);
      if (space.empty()) {
        std::this_thread::yield();
        continue;
      }
      for (std::size_t i = 0; i < space.size(); ++i) space[i] = next + static_cast<std::uint32_t>(i);
      next += static_cast<std::uint32_t>(ring.commit(space.size()));
    }
  });
  const std::uint64_t mismatches = consume_in_order(ring);
  producer.join();
  EXPECT_EQ(mismatches, 0u);
  EXPECT_EQ(ring.overrun_items(), 0u);
  EXPECT_EQ(ring.read_items(), kThreadedItems);
}

/// Lossy: the producer never waits, so the small buffer overruns often. Every stored value is its own
/// stream index, so the consumer checks that gaps are accounted exactly: value == stream index for
/// every item, indices strictly increasing, and stored + dropped == produced.
TEST(RingBufferThreaded, OverrunsKeepStreamIndicesExact) {
  Ring ring(256, 32);
  std::atomic<bool> done{false};
  std::thread producer([&] {
    std::vector<std::uint32_t> block;
    std::uint32_t next = 0;
    while (next < kThreadedItems) {
      const auto n = std::min<std::size_t>(97, kThreadedItems - next);
      block = iota_block(next, n);
      ring.write(block);
      if (next % 4096 < 97) ring.skip(0);  // no-op skip must not disturb anything
      next += static_cast<std::uint32_t>(n);
    }
    done.store(true, std::memory_order_release);
  });
  std::uint64_t last = 0;
  bool first = true;
  std::uint64_t mismatches = 0;
  std::uint64_t received = 0;
  std::vector<std::uint32_t> block(61);
  for (;;) {
    const bool finished = done.load(std::memory_order_acquire);
    const auto r = ring.read(block);
    if (r.count == 0) {
      if (finished) break;
      std::this_thread::yield();
      continue;
    }
    for (std::size_t i = 0; i < r.count; ++i) {
      const std::uint64_t index = r.first_stream_index + i;
      mismatches += (block[i] != index);
      mismatches += (!first && index <= last);
      last = index;
      first = false;
    }
    received += r.count;
  }
  producer.join();
  EXPECT_EQ(mismatches, 0u);
  EXPECT_EQ(received + ring.overrun_items(), kThreadedItems);
  EXPECT_EQ(received, ring.written_items());
}

}  // namespace
