// Configuration of the impact detector (core/pipeline/impact_detector.hpp): its own header so that
// the detector does not include its composer (stream_processor.hpp), which includes this one.
#pragma once

namespace ridgewatch::pipeline {

struct ImpactDetectorConfig {
  /// Band whose energy triggers (around the natural frequency), Hz. The default, 854 Hz +- 15 %,
  /// lies between the paper rig's mesh harmonics at 550 and 1100 Hz (see impact_detector.hpp).
  double band_lo_hz = 730.0;
  double band_hi_hz = 980.0;     ///< band_lo < band_hi < fs/2
  double sta_s = 0.0005;         ///< short-term average window, s (> 0)
  double lta_s = 0.05;           ///< long-term average window, s (> sta_s)
  double trigger_ratio = 8.0;    ///< STA/LTA ratio that declares an impact (> 1)
  double holdoff_s = 0.015;      ///< no new trigger within this time after one, s (>= 0)
  /// Spikes: a sample whose cubic-interpolation residual exceeds spike_mad robust-MAD units (and a
  /// quarter of its neighbours' magnitude) while its neighbours' do not is an isolated outlier; it is
  /// replaced by the interpolation, never triggers and is reported (> 0).
  double spike_mad = 12.0;
  /// Trigger statistic. false: the band energy e = |z|^2 of the band's complex envelope z. true: the
  /// innovation energy |z[m] - p z[m - k]|^2, z against the continuation of its own free decay k band
  /// samples back (p fitted to the band's recent history); an impact on a still-ringing previous
  /// decay adds a phasor at random phase, which raises e only ~1.5-fold but makes an innovation of its
  /// own size. For decays that overlap the next impact (impact_detector.hpp, stage 3).
  bool trigger_innovation = false;
  /// Noise floor of the trigger (0 = off, >= 0): the STA and the confirmation mean must also exceed
  /// trigger_noise_ratio x the band power of white noise with the variance the spike stage measures
  /// (impact_detector.hpp, stage 4). For a trigger_ratio lowered below the level band noise alone
  /// reaches over its own mean (band envelope energy is exponentially distributed): stretches where the
  /// band holds noise only are then judged at this ratio, stretches filled with decays at trigger_ratio.
  double trigger_noise_ratio = 0.0;
};

}  // namespace ridgewatch::pipeline
