// Where the model fails: residual analyses of a fit on the held-out impacts (issue 5 "compare").
// All residuals are in units of the noise sd σ, so 1 is the noise floor. Pure computation.
#pragma once

#include <string>
#include <vector>

#include "core/diagnosis/model_fit.hpp"

namespace ridgewatch::diagnosis {

struct SpectrumPeak {
  double f_hz = 0.0;
  double level = 0.0;     ///< mean periodogram / σ² (1 = white noise floor)
  std::string marker;     ///< nearest marker ("f0+1fz", "2fz", ...) within the resolution, else ""
};

struct Backbone {
  std::vector<double> amplitude_rel;  ///< bin centres: cycle amplitude / largest cycle amplitude
  std::vector<double> zeta;           ///< equivalent damping ln(A_k/A_k+1)/2π per bin (NaN if empty)
  std::vector<double> f_hz;           ///< zero-crossing frequency per bin (NaN if empty)
  double amplitude_max = 0.0;         ///< the cycle amplitude amplitude_rel = 1 stands for, sensor units
};

struct ResidualReport {
  double f0_hz = 0.0, fz_hz = 0.0;
  double dt_ms = 1.0;
  std::vector<double> excess_vs_time;     ///< held-out excess per dt_ms bin after the onset
  std::vector<double> impact_time_s;      ///< held-out impacts: time
  std::vector<double> impact_amplitude;   ///< held-out impacts: fitted peak force / nominal
  std::vector<double> impact_excess;      ///< held-out impacts: excess
  std::vector<double> spectrum_f_hz, spectrum_level;  ///< mean residual periodogram / σ²
  std::vector<SpectrumPeak> peaks;        ///< structured lines, strongest first
  std::vector<std::pair<std::string, double>> markers;  ///< name, frequency
  double ljung_box_q = 0.0;               ///< lags 1..10 of the held-out residual
  double ljung_box_limit = 0.0;           ///< χ²(10) 99.9 % point
  bool white = true;
  Backbone measured, model;
  std::size_t beating_windows = 0;        ///< held-out windows left out of the backbones (beating)
  std::size_t far_windows = 0;            ///< of those, windows whose first cycles are > 25 % off f0
  /// Residual spectrum level (σ² units, 1 = white) at 2 f0 and 3 f0 (NaN beyond the spectrum): an
  /// asymmetric nonlinearity (contact loss) puts its first harmonic at 2 f0, a symmetric one
  /// (cubic stiffness) at 3 f0.
  double level_2f0 = 0.0, level_3f0 = 0.0;
  std::size_t spikes = 0, dropouts = 0;
};

ResidualReport analyse_residual(const ModelFitter& fitter, const FitResult& fit);

}  // namespace ridgewatch::diagnosis
