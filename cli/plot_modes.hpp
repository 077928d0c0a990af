// The plot files of `ridgewatch modes --plots DIR`, drawn with cli/plot_svg.hpp and written with
// plot_diagnosis.hpp's write_all (same SVG/HTML style as `diagnose --plots`):
//   scalogram.svg  |W(t, f)| in dB over the noise floor (eta0 = 7, linear frequency axis) with each
//                  mode's ridge drawn over the time window its envelope estimate used
//   envelopes.svg  per mode: ln |W(t, f_d)| at the mode's own eta0 against time, with the ridge-ls and
//                  ml decays A exp(-sigma t) and the row's noise level
//   backbones.svg  per mode: zeta and f of each backbone segment against the envelope amplitude
#pragma once

#include <span>
#include <vector>

#include "cli/plot_diagnosis.hpp"
#include "core/dsp/modes.hpp"

namespace ridgewatch::cli::plots {

std::vector<PlotFile> mode_plots(std::span<const double> signal, double sample_rate_hz, const dsp::ModeSearchResult& result);

}  // namespace ridgewatch::cli::plots
