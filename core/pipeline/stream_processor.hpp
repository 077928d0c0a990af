// The per-impact pipeline on a sample stream, shared by `ridgewatch analyze` (a file as fast as
// possible) and ridgewatchd (live or paced replay): impact detection -> impact-triggered window with
// pre-trigger -> band CWT, ridge near the expected natural frequency, damping estimate -> status ->
// trend/alarm state. Pure computation: no I/O, threads or clock; sample indices are the clock.
//
// Real-time contract: buffers and FFT plans are made in the constructor, except those of the decay
// windows' analyzers (one per maximum window, window_s down to 16 ms in steps of sqrt(2)): each is
// prepared (buffers, ML fitters, a first run of its FFT plans) by the first impact whose window it
// analyses, once, so that a stream pays only for the window lengths its decays use (all of them:
// ~76 ms of start-up and ~26 MB at 51.2 kHz with window_s = 1 s; a steady stream uses one or two).
// After that, process() and flush() allocate nothing (operator new or malloc), per sample or per
// impact: the per-sample path
// (spike test, trigger band, STA/LTA, onset), the per-impact CWT, ridge, envelope estimators (their
// scratch is reserved, dsp::EnvelopeWorkspace) and ML fit (fixed-capacity matrices), and the trend
// monitor. Events are appended to the caller's vector (reserve it). Tested with allocation counters in
// tests/test_stream_processor.cpp (ProcessAllocatesNothingAfterWarmUp).
//
// Design and numbers: core/pipeline/impact_detector.hpp (detection, onset) and impact_analyzer.hpp
// (CWT, ridge, estimators, status). Event latency: an impact is analysed once its window
// [onset - pretrigger_s, onset + window_s) is final, i.e. when the next onset cuts it or 11.1-11.3 ms
// (the detector's report_delay_samples(): onset look-back plus decision delay, default settings)
// after its end.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "core/dsp/damping.hpp"
#include "core/pipeline/analyzer_config.hpp"
#include "core/pipeline/detector_config.hpp"
#include "core/pipeline/impact_event.hpp"
#include "core/trend/trend_monitor.hpp"

namespace ridgewatch::pipeline {

struct PipelineConfig {
  double sample_rate_hz = 51200.0;  ///< > 0
  ImpactDetectorConfig detector;
  ImpactAnalyzerConfig analyzer;
  trend::TrendConfig trend;
};

/// Throws std::invalid_argument naming the field ("detector.band_hi_hz: ...") when out of range.
void validate(const PipelineConfig& config);

class StreamProcessor {
 public:
  explicit StreamProcessor(const PipelineConfig& config);
  ~StreamProcessor();
  StreamProcessor(const StreamProcessor&) = delete;
  StreamProcessor& operator=(const StreamProcessor&) = delete;

  /// Feeds the next block. first_index is the absolute index of block[0]; it must not go backwards.
  /// A jump forward is a data gap (xrun, device loss): an impact in progress is finished with status
  /// window_cut and detection restarts after the gap. Completed events are appended to `events` in
  /// onset order, each carrying the alarm state after it.
  void process(std::span<const float> block, std::uint64_t first_index, std::vector<ImpactEvent>& events);

  /// End of stream: finishes an impact in progress (status window_cut if its window is incomplete).
  void flush(std::vector<ImpactEvent>& events);

  /// Total samples seen and counters for status lines. impacts_detected counts confirmed onsets
  /// (each yields exactly one event), spikes_seen isolated outliers removed before detection,
  /// gaps_seen forward jumps of first_index.
  std::uint64_t samples_seen() const;
  std::uint64_t impacts_detected() const;
  std::uint64_t spikes_seen() const;
  std::uint64_t gaps_seen() const;

  trend::TrendMonitor& trend();
  const PipelineConfig& config() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace ridgewatch::pipeline
