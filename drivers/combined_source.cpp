#include "drivers/combined_source.hpp"

#include <algorithm>
#include <stdexcept>

#include "drivers/replay_file.hpp"

namespace ridgewatch::drivers {

CombinedSource::CombinedSource(std::vector<std::unique_ptr<SampleSource>> inputs, std::vector<double> gains,
                               std::string name)
    : inputs_(std::move(inputs)), gains_(std::move(gains)) {
  if (inputs_.empty() || inputs_.size() != gains_.size())
    throw std::invalid_argument("combined source: need one gain per input (got " + std::to_string(gains_.size()) +
                                " gains, " + std::to_string(inputs_.size()) + " inputs)");
  info_ = inputs_.front()->info();
  for (const auto& in : inputs_)
    if (in->info().sample_rate_hz != info_.sample_rate_hz)
      throw std::invalid_argument("combined source: inputs differ in sample rate");
  info_.name = std::move(name);
  info_.full_scale.reset();  // see the header: a weighted sum has no converter full scale
}

std::size_t CombinedSource::read(std::span<double> out) {
  if (out.empty()) return 0;
  const std::size_t n = inputs_.front()->read(out);
  if (n == 0) {
    // The others must end here too.
    scratch_.resize(1);
    for (std::size_t i = 1; i < inputs_.size(); ++i)
      if (inputs_[i]->read(std::span<double>(scratch_.data(), 1)) != 0)
        throw InputError(info_.name + ": channels of the combination end at different sample counts");
    return 0;
  }
  for (std::size_t k = 0; k < n; ++k) out[k] *= gains_[0];
  scratch_.resize(n);
  for (std::size_t i = 1; i < inputs_.size(); ++i) {
    std::size_t got = 0;
    while (got < n) {
      const std::size_t m = inputs_[i]->read(std::span<double>(scratch_.data() + got, n - got));
      if (m == 0) throw InputError(info_.name + ": channels of the combination end at different sample counts");
      got += m;
    }
    const double g = gains_[i];
    for (std::size_t k = 0; k < n; ++k) out[k] += g * scratch_[k];
  }
  return n;
}

std::unique_ptr<SampleSource> open_combined_replay(const std::string& path, const std::vector<std::size_t>& channels,
                                                   const std::vector<double>& gains,
                                                   std::optional<double> csv_rate_hz) {
  std::vector<std::unique_ptr<SampleSource>> inputs;
  std::string name = path + " [";
  for (std::size_t i = 0; i < channels.size(); ++i) {
    ReplayOptions opt;
    opt.channel = channels[i];
    opt.csv_rate_hz = csv_rate_hz;
    inputs.push_back(open_replay(path, opt));
    name += (i ? "+" : "") + std::to_string(channels[i]);
  }
  return std::make_unique<CombinedSource>(std::move(inputs), gains, name + "]");
}

}  // namespace ridgewatch::drivers
