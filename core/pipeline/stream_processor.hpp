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
#include "core/pipeline/detector_config.hpp"
#include "core/pipeline/impact_event.hpp"
#include "core/trend/trend_monitor.hpp"

namespace ridgewatch::pipeline {

struct ImpactAnalyzerConfig {
  double f_expected_hz = 854.0;  ///< expected natural frequency of the gear pair, Hz
  double band_rel = 0.3;         ///< ridge searched within f_expected * (1 +- band_rel), (0, 0.9)
  double eta0 = 7.0;             ///< Morlet eta0 (Eq. 4), [5, 50]
  double pretrigger_s = 0.002;   ///< samples kept before the detected onset, s (>= 0)
  /// Longest decay window analysed after the onset, s (> 0). Each window ends where the decay reaches
  /// the noise floor (StreamProcessor: trigger-band power at most twice the floor between impacts, or
  /// 40 dB below its peak), at the next impact, or at this maximum, whichever comes first: zeta from
  /// 1e-4 to 0.1 needs no tuning as long as the maximum covers the decay (1 s: 7 time constants of
  /// zeta = 1.3e-3 at 900 Hz). The key's old meaning (a fixed window) is the same maximum.
  double window_s = 1.0;
  dsp::DampingMethod method = dsp::DampingMethod::ml;
  double min_snr_db = 20.0;      ///< below: status low_snr
  /// An ok event's 95 % interval spans at most this ratio hi / lo (1.25: about +-11 %); wider: low_snr
  /// (ok promises a usable number). > 1.
  double max_ci_ratio = 1.25;
  /// |x| >= clip_level inside the window: clipped (signal units; 0.999 suits data scaled to a full
  /// scale of 1.0). NaN: no clipping check (float data in physical units have no converter limit).
  /// The configuration file's default, null, takes it from the source's format (cli:
  /// resolve_format_defaults(): 0.999 of an integer format's full scale, none for float).
  double clip_level = 0.999;
  /// ml: DFT bins within f_d * (1 +- ml_band_rel) are fitted, (0, band_rel]. The default 0.12 keeps
  /// the paper rig's mesh lines (550/1100 Hz, and 550 Hz + 20 % under a speed ramp) well outside the
  /// fit of an 860 Hz mode while leaving >= 6 DFT bins for a 30 ms segment (measured on replay-data:
  /// 0.15 lets a line at 640 Hz bias an ok event by 10 %, 0.10 starves cut windows of bins).
  double ml_band_rel = 0.12;
};

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
