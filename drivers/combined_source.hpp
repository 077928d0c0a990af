// A derived channel: y[n] = sum_i gain_i x_i[n] over several channels of one recording, read in
// lockstep through the SampleSource interface (each input is its own source, e.g. one open_replay per
// channel). Used for the mesh coordinate of the paper's measurement, q̇ = r_b1 φ̇1 + r_b2 φ̇2 (Appendix A,
// q = r_b1 φ1 + r_b2 φ2), from two shaft-speed channels: the gains then are r_b_i / sensitivity_i.
// The sum is formed in double precision. The delivered stream has no full scale (SourceInfo::full_scale
// empty): a sum of full-scale inputs has none, so the clipping check of the pipeline is off unless
// pipeline.analyzer.clip_level is set in the derived channel's units.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "drivers/sample_source.hpp"

namespace ridgewatch::drivers {

class CombinedSource : public SampleSource {
 public:
  /// `inputs` and `gains` have the same non-zero length; every input has the same sample rate
  /// (std::invalid_argument otherwise). `name` stands for the stream in messages and events.
  CombinedSource(std::vector<std::unique_ptr<SampleSource>> inputs, std::vector<double> gains, std::string name);
  const SourceInfo& info() const override { return info_; }
  /// Reads the same number of samples from every input. An input that ends before the others is an
  /// InputError naming the stream (the channels of one recording cannot differ in length).
  std::size_t read(std::span<double> out) override;

 private:
  std::vector<std::unique_ptr<SampleSource>> inputs_;
  std::vector<double> gains_;
  std::vector<double> scratch_;
  SourceInfo info_;
};

/// One open_replay per channel of `path`, combined with `gains` (same length as `channels`).
/// InputError as open_replay (e.g. a channel beyond the file's).
std::unique_ptr<SampleSource> open_combined_replay(const std::string& path, const std::vector<std::size_t>& channels,
                                                   const std::vector<double>& gains,
                                                   std::optional<double> csv_rate_hz);

}  // namespace ridgewatch::drivers
