// Impact segmentation of a recording for model fitting: impact onsets (the pipeline's detector,
// core/pipeline/impact_detector.hpp), fit windows, the noise floor from the data between impacts, and
// sensor faults (isolated spikes, dropouts) that are masked before any fit. Pure computation.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "core/model/rig_parameters.hpp"

namespace ridgewatch::diagnosis {

struct SegmentationOptions {
  double pre_s = 0.001;    ///< window start before the detected onset (the onset is refined by the fit)
  /// Window length after the onset. 20 ms is 2.6 decay time constants at ζ = 0.024, 860 Hz (the
  /// envelope falls to 7 %): the part of the response that carries the physics, and half the 40 ms
  /// impact period, so consecutive windows never overlap.
  double post_s = 0.020;
  double min_post_s = 0.008;  ///< shorter windows (impact near the record end or a close neighbour) are dropped
};

struct ImpactWindow {
  std::uint64_t begin = 0, end = 0;  ///< samples [begin, end)
  double onset_s = 0.0;              ///< detected onset
  double mesh_hz = 0.0;              ///< z1 / local revolution period
  int predecessor = -1;              ///< index of the previous window if it is the previous revolution
};

struct Segmentation {
  double sample_rate_hz = 0.0;
  std::vector<ImpactWindow> windows;
  double noise_sd = 0.0;        ///< white-equivalent noise standard deviation of the samples
  bool noise_at_floor = false;  ///< no measurable noise: noise_sd is the 1e-6-of-peak floor
  double revolution_s = 0.0;    ///< median impact spacing
  std::vector<std::uint64_t> spikes;    ///< isolated outliers (masked)
  std::vector<std::uint64_t> dropouts;  ///< first samples of dropout runs (masked)
  std::uint64_t dropout_samples = 0;
  std::vector<double> weight;   ///< per sample: 0 masked, 1 used
  double peak = 0.0;            ///< max |y| over the windows
};

/// Throws std::invalid_argument when the rig/rate make detection impossible.
Segmentation segment_recording(std::span<const double> y, double sample_rate_hz, const model::RigParameters& rig,
                               const SegmentationOptions& options = {});

}  // namespace ridgewatch::diagnosis

namespace ridgewatch::diagnosis {

/// At most `max_windows` windows (rounded down to a multiple of 4, at least 4): runs of 4 consecutive
/// impacts spread evenly over the record, so that each run carries its predecessors' tails and slow
/// changes are still seen. Returns `seg` unchanged when it has no more windows than that.
Segmentation subset_windows(const Segmentation& seg, std::size_t max_windows);

}  // namespace ridgewatch::diagnosis
