// ridgewatchd with several streams (`streams:` in the configuration): one acquisition thread per
// device, one ring buffer, StreamProcessor, trend and alarm per stream, the processing on a
// WorkerPool of `workers` threads, the sinks on the processing loop's thread.
//
// Devices: an ALSA device is opened once with all source.alsa.channels and read interleaved
// (AlsaSource::read_frames); each stream's channel or weighted combination is picked out per period
// and written to its ring (live: a full ring drops and counts, like the one-stream daemon). Replayed
// files: the streams with the same file form one device, whose thread reads one reader per stream in
// lockstep (the same samples as `ridgewatch analyze --channel N` on that file) and waits for room in
// every ring (lossless); streams with their own files are their own devices.
//
// Processing: each step is one pool round in which stream i's worker (thread i % workers) processes up
// to 8192 new samples of stream i in place in its ring; after the round the processing loop writes
// all events of the step (one block per log: the streams' events in stream order, each stream's in
// time order) and drives the relays. Signals, status and watchdog as in the one-stream daemon.
// SIGHUP reopens the output files; stream and pipeline changes need a restart (logged).
#pragma once

#include "daemon/daemon.hpp"

namespace ridgewatch::daemon {

/// Runs the daemon on options.config.streams (non-empty). Exit codes as Daemon::run(); UsageError
/// (exit 2) names the key when a stream's channel does not exist or its pipeline does not fit.
int run_streams(const DaemonOptions& options, DaemonStats& stats, std::atomic<bool>& stop_flag,
                std::atomic<bool>& reload_flag, std::atomic<bool>& latch_reset_flag);

/// Threads for `streams` streams: `workers` when > 0, else one per stream up to the cores.
std::size_t worker_count(std::size_t workers, std::size_t streams);

}  // namespace ridgewatch::daemon
