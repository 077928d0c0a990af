// merge_channels OUT.wav IN1.wav IN2.wav ...: channel 0 of each input as one channel of OUT (float32
// WAV, interleaved), cut to the shortest input. For scripts/bench-streams.sh (16 simulated rigs in one
// 16-channel recording). All inputs must have the same sample rate.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <stdexcept>
#include <exception>
#include <string>
#include <vector>

#include "drivers/replay_file.hpp"
#include "drivers/wav_writer.hpp"

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: merge_channels OUT.wav IN.wav...\n");
    return 2;
  }
  try {
    std::vector<std::vector<double>> in;
    double fs = 0.0;
    std::size_t n = SIZE_MAX;
    for (int i = 2; i < argc; ++i) {
      auto src = ridgewatch::drivers::open_replay(argv[i], {});
      if (fs != 0.0 && src->info().sample_rate_hz != fs) throw std::runtime_error(std::string(argv[i]) + ": other sample rate");
      fs = src->info().sample_rate_hz;
      in.push_back(ridgewatch::drivers::read_all(*src));
      n = std::min(n, in.back().size());
    }
    std::vector<double> frames(n * in.size());
    for (std::size_t k = 0; k < n; ++k)
      for (std::size_t c = 0; c < in.size(); ++c) frames[k * in.size() + c] = in[c][k];
    ridgewatch::drivers::write_wav(argv[1], frames, fs, in.size());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "merge_channels: %s\n", e.what());
    return 3;
  }
  return 0;
}
