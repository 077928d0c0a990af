// Writes the paper's Table-1 test signal (Eq. 20 with the Table 1 parameters; 10 kHz, 1 s, white noise
// at SNR 20 dB over the record) as a float32 WAV: the bundled replay-data/paper-table1.wav.
// usage: make_table1_signal OUT.wav [SEED] [SNR_DB]
#include <cstdio>
#include <cstdlib>
#include <exception>

#include "core/dsp/synthetic.hpp"
#include "drivers/wav_writer.hpp"

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: make_table1_signal OUT.wav [SEED] [SNR_DB]\n");
    return 2;
  }
  const auto seed = argc > 2 ? std::strtoull(argv[2], nullptr, 10) : 1ULL;
  const double snr_db = argc > 3 ? std::atof(argv[3]) : 20.0;
  const double fs = 10000.0;
  auto x = ridgewatch::dsp::damped_sum(ridgewatch::dsp::paper_table1_components(), fs, 10000);
  ridgewatch::dsp::add_white_noise(x, snr_db, seed);
  try {
    ridgewatch::drivers::write_wav(argv[1], x, fs, 1);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "make_table1_signal: %s\n", e.what());
    return 1;
  }
  return 0;
}
