// `ridgewatch survey`: look at a recording of an unknown rig and find (1) whether it holds repeated
// impacts and at what rate, (2) the band they ring in, (3) the ringing mode's frequency and a first
// damping ratio, and (4) a pipeline configuration (detector band, trigger, hold-off, expected
// frequency, ridge band, window) for `ridgewatch analyze` / ridgewatchd. Pure computation.
//
//  0. Despiking: isolated one-sample outliers (residual of the 4-neighbour cubic interpolation beyond
//     12 MAD while the neighbours, corrected for it, stay below) are replaced by the interpolation, so
//     a sensor's spikes do not masquerade as impulsive energy in every band.
//  1. Fast kurtogram (kurtogram.hpp): up to 8 candidate bands with z >= 8 in decreasing spectral
//     kurtosis, each from its own part of the spectrum; steps 2-3 run on each, and the first band whose
//     envelope forms a periodic impact train (the train tests of step 5) is kept, else the
//     largest-SK band.
//  2. Band envelope e = |c|^2 of that band (band_envelope.hpp), averaged into bins of ~0.25 ms:
//     its normalised autocorrelation r(tau) over lags 1/max_rate .. min(1/min_rate, T/2.5), the
//     highest peak of the envelope smoothed over 0.6 / max_rate (or its shortest sub-multiple standing
//     >= 40 % as high; when the train tests fail with it, the shortest sub-multiple of any order) is
//     the impact period;
//     the envelope spectrum (|DFT of e - mean|) shows the rate and its harmonics.
//  3. Impacts: maxima of e that dominate +-0.45 periods and exceed a fifth of the median such
//     maximum; when no candidate band forms a train so, a fifth of the typical impact's height, the
//     median of e's maxima over windows one period long (decays much shorter than the period leave
//     a noise maximum in every gap) (onset clicks vary 2-fold in amplitude with their position
//     between samples);
//     the median peak over the envelope median (the contrast). Intervals within 25 % of the period are
//     regular; the period is refined to their median, the speed variation is half their 5-95 %
//     spread in % of it.
//  4. Free responses: for up to 24 impacts spread over the record, the raw samples from 1/bw + 2 ms
//     before the band envelope's peak to just before the next impact go to dsp::identify_modes (the
//     modes command's analysis), with the onset at the first sample at half the segment's peak but
//     not before 0.5/bw ahead of the envelope's peak, and the end 10 decay time constants later (at
//     least 50 ms; tau from the record's power averaged over the impacts; the whole interval when
//     the decays fill it); the search over the whole range [f_min, f_max], not only the kurtogram band:
//     an impact's onset is a broadband click, so the sharpest bursts can lie well away from the
//     resonance, and the ringing mode is the decaying one). Modes of all segments are
//     clustered (+-1.5 % in f); the cluster found in the most segments with status ok is the
//     ringing mode: median f, median zeta and the zeta quartiles. Other clusters found in >= half
//     the segments are listed as further modes. When no cluster is ok in half of them, the search is
//     repeated for up to three candidates (modes detected whatever their status) in the candidate's
//     band f (1 +- 0.15), kept clear of stationary lines, with tau from that band's power and eta0
//     raised against the lines' leakage (focused_look in survey.cpp). When the train passes its tests
//     and still no mode is ok in enough free responses (a decay of 1-2 ms at 10 dB stands only 6-9 dB
//     over the noise in one), the mode is identified from quantities averaged over up to 24 impacts
//     (step 4''', averaged_response.hpp): the peak of the power just after the impacts over the
//     power just before them, with its own significance test (an F test on the N-averages at a
//     family-wise false-alarm probability of 1e-3), and zeta from the averaged band power's decay.
//  5. Decision "repeated impacts": all of SK z >= 8 (a burst band, not noise or lines), r(T) >= 0.2
//     (periodic bursts), contrast >= 10 (bursts stand 10 dB above the floor), >= 4 impacts with
//     >= 75 % of the intervals regular, and the ringing mode in >= half of the analysed segments (a
//     decaying free response after the bursts, which mesh lines, hum and noise are not). A record
//     that fails any is reported with every figure and the reasons, and gets no proposal. When the
//     kurtogram band's train fails but the mode is found, the train tests are repeated in the mode's
//     band f (1 +- 0.15), where the contrast may also be read against the envelope's median 0.4 .. 0.2
//     periods before each impact (decays that fill the interval make the record's median the ringing).
//  6. Proposal (current pipeline keys, core/pipeline/stream_processor.hpp):
//       detector band f (1 +- 0.15), each edge pulled in to halfway to the nearest stationary line
//         (peaks of the power spectrum of the quiet ends of the intervals, >= 10 dB over the local
//         floor, widened by the speed variation) within f (1 +- 0.3), at least f (1 +- 0.03);
//       trigger_ratio = min(8 (the default), half the impacts' median STA peak over the detector's
//         capped long-term mean in that band), at least 3; holdoff_s = 0.5 x the shortest regular
//         interval; trigger_innovation when the decays overlap (> 20 % of the amplitude left at the
//         next impact, exp(-2 pi f zeta T));
//       f_expected_hz = the mode's f; band_rel = 0.3, reduced to 0.6 x the relative distance of a
//         further mode inside it (so the ridge cannot jump to it); ml_band_rel = min(0.12, band_rel,
//         0.6 x the relative distance of the nearest line);
//       window_s = min(4.5 time constants 1/(2 pi f zeta) (the default's 35 ms at 854 Hz, zeta
//         0.024), 0.9 x the shortest interval - pretrigger), and at least the analyzer's minimum of
//         10 Morlet kernel widths and 80 samples (when that fits the interval); clip_level above
//         the record's peak when the samples exceed 1.0 (float files in physical units have no
//         full scale).
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "core/pipeline/stream_processor.hpp"
#include "core/survey/kurtogram.hpp"

namespace ridgewatch::survey {

struct SurveyOptions {
  double f_min_hz = 100;       ///< lowest band edge considered by the kurtogram and the mode search
  double f_max_hz = 0;         ///< highest; <= 0: fs / 2 (kurtogram), 0.45 fs (modes)
  double min_rate_hz = 0.2;    ///< slowest impact rate searched (lag up to 1/min_rate, and <= T / 2.5)
  double max_rate_hz = 150;    ///< fastest (also sets the envelope smoothing for the autocorrelation)
  std::size_t max_segments = 24;  ///< free responses analysed by identify_modes
  /// Shaft speed (Hz) of a rig description, for the order of the impact rate; <= 0: unknown.
  double shaft_hz = 0;
};

struct ModeCluster {
  double f_hz = NAN;           ///< median damped frequency of the cluster's members
  double zeta = NAN;           ///< median zeta
  double zeta_q1 = NAN, zeta_q3 = NAN;
  double amplitude = NAN;      ///< median amplitude at the segment start, signal units
  std::size_t segments = 0;    ///< segments with an ok mode in the cluster
  /// > 0: identified from the spectra and band power averaged over this many impacts (step 4''',
  /// core/survey/averaged_response.hpp), not in single free responses (then segments is 0,
  /// amplitude and the zeta quartiles NaN, and zeta a first value from the averaged decay).
  std::size_t averaged_over = 0;
  /// Morlet eta0 that reads this mode apart from the other modes listed (step 4'); may exceed the
  /// analyzer's maximum 50 (then the analyzer cannot separate them).
  double eta0_needed = NAN;
};

struct Proposal {
  pipeline::ImpactDetectorConfig detector;
  pipeline::ImpactAnalyzerConfig analyzer;
  std::vector<std::string> notes;  ///< why a value is what it is, when it is not the rule's plain value
};

struct SurveyResult {
  double sample_rate_hz = 0;
  std::size_t samples = 0;
  std::size_t spikes_removed = 0;
  double peak_abs = 0;          ///< max |x| of the record (after despiking)

  Kurtogram kurtogram;
  double band_lo_hz = NAN, band_hi_hz = NAN;  ///< the kurtogram's best band
  double band_kurtosis = NAN, band_z = NAN;

  // Envelope of the best band.
  double envelope_rate_hz = NAN;          ///< rate of the averaged envelope used below
  std::vector<double> acf;                ///< normalised autocorrelation, lag k / envelope_rate_hz
  std::vector<double> envelope_spectrum_hz, envelope_spectrum;  ///< |DFT(e - mean)|, normalised to max 1
  double acf_peak = NAN;                  ///< r(T)
  double period_s = NAN;                  ///< impact period (refined by the intervals when found)
  double rate_hz = NAN;
  double speed_variation_pct = NAN;       ///< half the 5-95 % spread of the regular intervals
  double regular_fraction = NAN;          ///< intervals within 25 % of the period
  double contrast = NAN;                  ///< median envelope peak / envelope median
  std::vector<double> impact_times_s;     ///< band-envelope peaks of the impacts found
  double shaft_order = NAN;               ///< rate / shaft speed when SurveyOptions::shaft_hz given

  // Free responses.
  std::size_t segments_analysed = 0;
  std::vector<ModeCluster> modes;         ///< modes[0] the ringing mode, then further ones
  double decay_per_period = NAN;          ///< envelope left at the next impact, exp(-2 pi f zeta T)
  /// Median over the impacts of the ratio both the detector's STA and its confirmation mean reach over
  /// its reference (max over t of min(STA, mean of the next 4 STA windows) / max(capped long-term
  /// mean, pre-window mean)) in the proposed band.
  double trigger_headroom = NAN;
  /// Largest level band noise alone reaches against the detector's reference in the proposed band
  /// (its noise-only stretches; NaN when there are none): the proposed trigger_ratio stays 1.25x over it
  /// where the impacts allow.
  double noise_trigger_level = NAN;
  /// Averaged band envelope after the impacts (aligned at the envelope peak), for the plot; time of
  /// sample k is k / envelope_rate_hz after the peak; normalised to 1 at the peak.
  std::vector<double> mean_envelope;
  std::vector<double> line_hz;            ///< stationary lines found near the mode

  bool impacts_found = false;
  std::vector<std::string> evidence;      ///< one line per test of step 5, passed or failed
  std::optional<Proposal> proposal;
};

/// Throws std::invalid_argument for fs <= 0, a record shorter than 64 samples or non-finite samples.
SurveyResult run_survey(std::span<const double> x, double sample_rate_hz, const SurveyOptions& options = {});

}  // namespace ridgewatch::survey
