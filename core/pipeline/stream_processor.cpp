// StreamProcessor: glue between the sample stream, the impact detector, the impact analyzer and the
// trend monitor. Samples reach the detector in runs that end exactly where something can happen (the
// detector's next processing run, the next window becoming final), so the events and their order are
// those of one sample at a time and do not depend on how the stream is cut into blocks
// (bit-identical for any block size; tested).
//
// An impact's window [onset - pretrigger, onset + window) is analysed as soon as it is final: when
// the next onset is known and cuts it, or when enough samples past its end have arrived that no
// later trigger can be refined to an onset inside it (the detector's report_delay_samples():
// look-back plus decision delay, 11.1-11.3 ms at the defaults). That is the event latency after the
// end of the decay window.
#include "core/pipeline/stream_processor.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <limits>
#include <numbers>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

#include "core/pipeline/impact_analyzer.hpp"
#include "core/pipeline/impact_detector.hpp"

namespace ridgewatch::pipeline {

namespace {

std::string num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

[[noreturn]] void fail(const std::string& field, const std::string& rule, double got) {
  throw std::invalid_argument(field + ": " + rule + " (got " + num(got) + ")");
}

void require(bool ok, const char* field, const std::string& rule, double got) {
  if (!ok) fail(field, rule, got);
}

}  // namespace

void validate(const PipelineConfig& c) {
  const double fs = c.sample_rate_hz;
  require(std::isfinite(fs) && fs > 0, "sample_rate_hz", "must be > 0", fs);
  const double nyq = fs / 2;
  const ImpactDetectorConfig& d = c.detector;
  require(std::isfinite(d.band_lo_hz) && d.band_lo_hz > 0, "detector.band_lo_hz", "must be > 0", d.band_lo_hz);
  // At least 2 Hz wide: the detector's start-up tables span 3 / (half the width) seconds (1.5 s at
  // 2 Hz), and an impact's envelope rises through the band's low-pass in about that time anyway.
  require(std::isfinite(d.band_hi_hz) && d.band_hi_hz >= d.band_lo_hz + 2.0, "detector.band_hi_hz",
          "must be >= detector.band_lo_hz + 2 Hz = " + num(d.band_lo_hz + 2.0), d.band_hi_hz);
  require(d.band_hi_hz < nyq, "detector.band_hi_hz", "must be < sample_rate_hz / 2 = " + num(nyq), d.band_hi_hz);
  require(std::isfinite(d.sta_s) && d.sta_s * fs >= 2, "detector.sta_s",
          "must be >= 2 samples (" + num(2 / fs) + " s)", d.sta_s);
  require(std::isfinite(d.lta_s) && d.lta_s > d.sta_s && d.lta_s <= 3600, "detector.lta_s",
          "must be > detector.sta_s = " + num(d.sta_s) + " and <= 3600", d.lta_s);
  require(std::isfinite(d.trigger_ratio) && d.trigger_ratio > 1, "detector.trigger_ratio", "must be > 1", d.trigger_ratio);
  require(std::isfinite(d.trigger_noise_ratio) && d.trigger_noise_ratio >= 0, "detector.trigger_noise_ratio", "must be >= 0 (0: off)",
          d.trigger_noise_ratio);
  require(std::isfinite(d.holdoff_s) && d.holdoff_s >= 0 && d.holdoff_s <= 60, "detector.holdoff_s",
          "must be in [0, 60]", d.holdoff_s);
  require(std::isfinite(d.spike_mad) && d.spike_mad > 0, "detector.spike_mad", "must be > 0", d.spike_mad);
  const ImpactAnalyzerConfig& a = c.analyzer;
  require(std::isfinite(a.f_expected_hz) && a.f_expected_hz > 0, "analyzer.f_expected_hz", "must be > 0", a.f_expected_hz);
  require(std::isfinite(a.band_rel) && a.band_rel > 0 && a.band_rel < 0.9, "analyzer.band_rel",
          "must be in (0, 0.9)", a.band_rel);
  require(a.f_expected_hz * (1 + a.band_rel) < nyq, "analyzer.f_expected_hz",
          "f_expected_hz * (1 + band_rel) must be < sample_rate_hz / 2 = " + num(nyq), a.f_expected_hz);
  require(std::isfinite(a.eta0) && a.eta0 >= 5 && a.eta0 <= 50, "analyzer.eta0", "must be in [5, 50]", a.eta0);
  require(std::isfinite(a.pretrigger_s) && a.pretrigger_s >= 0 && a.pretrigger_s <= 1, "analyzer.pretrigger_s",
          "must be in [0, 1]", a.pretrigger_s);
  require(std::isfinite(a.window_s) && a.window_s > 0, "analyzer.window_s", "must be > 0", a.window_s);
  require(a.window_s <= 10, "analyzer.window_s", "must be <= 10", a.window_s);
  // The decay window must hold the CWT's edge skips (4 kernel widths each side) plus the minimum fit
  // window (2 widths): 10 kernel widths s = eta0 / (2 pi f) at the expected frequency.
  const double min_window = 10.0 * a.eta0 / (2.0 * 3.141592653589793 * a.f_expected_hz);
  require(a.window_s >= min_window, "analyzer.window_s",
          "must be >= 10 Morlet kernel widths at f_expected_hz (" + num(min_window) + " s)", a.window_s);
  require(a.window_s * fs >= 80, "analyzer.window_s", "must span >= 80 samples", a.window_s);
  require(std::isfinite(a.min_snr_db), "analyzer.min_snr_db", "must be finite", a.min_snr_db);
  require(std::isfinite(a.max_ci_ratio) && a.max_ci_ratio > 1, "analyzer.max_ci_ratio", "must be > 1", a.max_ci_ratio);
  require(std::isnan(a.clip_level) || (std::isfinite(a.clip_level) && a.clip_level > 0), "analyzer.clip_level",
          "must be > 0 or null (no clipping check)", a.clip_level);
  require(std::isfinite(a.ml_band_rel) && a.ml_band_rel > 0 && a.ml_band_rel <= a.band_rel, "analyzer.ml_band_rel",
          "must be in (0, analyzer.band_rel = " + num(a.band_rel) + "]", a.ml_band_rel);
  try {
    trend::validate(c.trend);
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    if (what.rfind("trend.", 0) == 0) throw;
    throw std::invalid_argument("trend." + what);
  }
}

struct StreamProcessor::Impl {
  static constexpr std::size_t kMaxPending = 32;
  static constexpr std::size_t kNoiseHistory = 8;

  PipelineConfig cfg;
  double fs;
  // Analyzers for decay windows of window_s, window_s / sqrt(2), window_s / 2, ... down to the shortest
  // window the analysis accepts (ascending): each window goes to the shortest one that holds it, so a
  // short decay costs what it did with a short fixed window (the CWT's FFT and the ML segments are
  // sized by the analyzer's maximum) and window_s can be a generous maximum. Made with their sizes
  // only; each is prepared by its first window (ImpactAnalyzer::prepare(): the buffers and ML fitters
  // of all of them were 76 ms of start-up and 26 MB at 51.2 kHz for window_s = 1 s, while a steady
  // stream's decays use one or two).
  std::vector<std::unique_ptr<ImpactAnalyzer>> ladder;
  ImpactAnalyzer& analyzer;  // the longest (window_s)
  ImpactDetector detector;
  trend::TrendMonitor trend_monitor;

  std::vector<float> raw;  // raw samples by absolute index & mask
  std::uint64_t mask = 0;
  std::vector<float> window_buf;  // a window that wraps around the ring's end, made contiguous
  bool started = false, flushed = false;
  std::uint64_t seg_start = 0, next = 0;
  std::size_t wait_after = 0;    // samples past a window's end before it is final
  std::size_t cut_guard = 0;     // window ends this far before the next onset
  std::size_t noise_span = 0;    // pre-trigger samples used for the noise estimate
  std::size_t noise_guard = 0;   // ... ending this far before the onset

  static constexpr std::size_t kMaxLadder = 16;
  std::size_t max_win = 0;      // window_s in samples: the longest decay window
  std::size_t decay_step = 0;   // samples per decay-following step
  std::size_t decay_first = 0;  // first step end after the onset
  std::size_t peak_at = 0;      // the trigger band's envelope peak after an onset (detector model)

  struct Pending {
    std::uint64_t onset;
    double noise_var;              // from the band power between impacts: the decay-following floor
    bool noise_measured = false;   // noise_var from pre-trigger samples (else the LTA's stand-in)
    double innovation_noise_var;   // the noise without the ringing (NaN before any measurement)
    std::uint64_t checked = 0;     // end of the next step to check (0: not started)
    double peak_power = NAN;       // trigger-band power at the envelope's peak
    std::uint64_t decay_end = 0;   // where the decay reached the floor (0: not yet)
    bool exhausted = false;        // followed to the window's end (or the cut) without reaching it
  };
  std::array<Pending, kMaxPending> pending{};
  std::size_t p_head = 0, p_count = 0;
  // The last kNoiseHistory pre-trigger powers and their median.
  struct NoiseHistory {
    std::array<double, kNoiseHistory> v{};
    std::size_t head = 0, count = 0;
    void add(double p) {
      v[head] = p;
      head = (head + 1) % kNoiseHistory;
      count = std::min(count + 1, kNoiseHistory);
    }
    double median() const {
      std::array<double, kNoiseHistory> tmp = v;
      const std::size_t mid = count / 2;
      std::nth_element(tmp.begin(), tmp.begin() + static_cast<std::ptrdiff_t>(mid),
                       tmp.begin() + static_cast<std::ptrdiff_t>(count));
      return tmp[mid];
    }
  };
  NoiseHistory noise_hist;   // band power
  NoiseHistory innov_hist;   // the noise power without the ringing (innovation_noise_for())
  NoiseHistory mode_f_hist, mode_zeta_hist;  // f and zeta of the last analysed impacts (energy mode)
  double mode_f = NAN, mode_zeta = NAN;       // ... their medians
  bool noise_measured = false;  // the last noise_for() had pre-trigger measurements

  std::uint64_t samples = 0, impacts = 0, gaps = 0;
  // First sample index at which front_ready() can turn true (recomputed whenever the pending queue
  // changes), so that the per-sample loop compares one number instead of evaluating front_ready().
  std::uint64_t ready_at = std::numeric_limits<std::uint64_t>::max();

  explicit Impl(const PipelineConfig& c)
      : cfg((validate(c), c)),
        fs(c.sample_rate_hz),
        ladder(make_ladder(c)),
        analyzer(*ladder.back()),
        detector(c.detector, c.sample_rate_hz,
                 analyzer.max_samples() + static_cast<std::size_t>(std::ceil(0.002 * c.sample_rate_hz))),
        trend_monitor(c.trend) {
    wait_after = detector.lookback_samples() + detector.decision_delay_samples() + 1;
    cut_guard = static_cast<std::size_t>(std::ceil(0.0005 * fs));
    noise_guard = static_cast<std::size_t>(std::ceil(0.00025 * fs));
    noise_span = std::max(analyzer.pretrigger_samples(), static_cast<std::size_t>(std::ceil(0.001 * fs)));
    const std::uint64_t ring = std::bit_ceil(2 * (analyzer.max_samples() + wait_after + noise_span + 64));
    raw.assign(ring, 0.0f);
    mask = ring - 1;
    window_buf.assign(analyzer.max_samples(), 0.0f);
    // Decay following (follow_decay()): band powers over steps of one correlation time of the trigger
    // band's envelope, 1 / (band_hi - band_lo) (4 ms at the defaults), from past the envelope's peak
    // and the analysis' minimum window (10 kernel widths) on.
    const ImpactDetectorConfig& d = c.detector;
    max_win = std::min<std::size_t>(static_cast<std::size_t>(std::llround(c.analyzer.window_s * fs)),
                                    analyzer.window_samples());
    decay_step = static_cast<std::size_t>(std::ceil(fs / (d.band_hi_hz - d.band_lo_hz)));
    decay_step = std::max<std::size_t>(decay_step, 16);
    peak_at = static_cast<std::size_t>(std::llround(detector.peak_samples()));
    const double kernel_s = c.analyzer.eta0 / (2.0 * 3.141592653589793 * c.analyzer.f_expected_hz);
    // The earliest decay end: 12 kernel widths (the analysis' minimum plus margin), past the envelope's
    // peak, and long enough for 9 DFT bins across the ML band, 9 / (2 ml_band_rel f_expected) (44 ms
    // at the defaults; the fit then keeps its two residual terms). A decay that drowns in lines and
    // noise sooner still gets that much data (measured on the 51.2 kHz nuisance records of
    // test_pipeline_indep: ending at the floor after ~20 ms left 4 bins and doubled the spread).
    const double ml_bins_s = 9.0 / (2.0 * c.analyzer.ml_band_rel * c.analyzer.f_expected_hz);
    decay_first = std::max<std::size_t>({static_cast<std::size_t>(std::ceil(12.0 * kernel_s * fs)),
                                         static_cast<std::size_t>(std::ceil(ml_bins_s * fs)), peak_at + 2 * decay_step});
  }

  static std::vector<std::unique_ptr<ImpactAnalyzer>> make_ladder(const PipelineConfig& c) {
    validate(c);
    const ImpactAnalyzerConfig& a = c.analyzer;
    const double kernel_s = a.eta0 / (2.0 * 3.141592653589793 * a.f_expected_hz);
    const double shortest = std::max(10.0 * kernel_s, 80.0 / c.sample_rate_hz);  // validate()'s minimum
    std::vector<double> windows{a.window_s};
    // Steps of sqrt(2): a window uses at most 41 % more FFT length than it needs (the per-impact cost
    // is mostly the CWT's FFTs over the analyzer's maximum), and the analyzer's ML segments (k/8 of
    // its maximum) stay close to the window. Measured (`ridgewatch analyze`, 60 s at 51.2 kHz, 1500
    // impacts 40 ms apart, task-clock): start-up 82 ms, then 40 ms; steps of 2: 51 + 37 ms, but the
    // 40 ms windows then fit only 31 ms segments and sim-tacho's median |zeta error| went 0.2 -> 3 %
    // (the fixed 35 ms window before: 6 + 32 ms).
    while (windows.size() < kMaxLadder && windows.back() / std::numbers::sqrt2 >= shortest)
      windows.push_back(windows.back() / std::numbers::sqrt2);
    std::vector<std::unique_ptr<ImpactAnalyzer>> out;
    for (auto it = windows.rbegin(); it != windows.rend(); ++it) {
      ImpactAnalyzerConfig ac = a;
      ac.window_s = *it;
      auto an = std::make_unique<ImpactAnalyzer>(ac, c.sample_rate_hz);
      // Where the rate allows the half-rate analysis (ImpactAnalyzer step 0) but this maximum does not
      // get it (an odd window length: the copy would not keep the full-rate DFT bins), one sample
      // longer usually does (every rung at 51.2 kHz; at 25.6 kHz the CWT's odd decimation rules it out
      // anyway and the rungs stay as they are). Measured (impacts 40 ms apart, windows in the 44.2 ms
      // rung): `ridgewatch analyze` of 60 s processed in 34 ms instead of 42, the daemon 8 % faster.
      if (ImpactAnalyzer::decimates(ac, c.sample_rate_hz) && an->input_decimation() == 1) {
        ImpactAnalyzerConfig longer = ac;
        longer.window_s = static_cast<double>(std::llround(*it * c.sample_rate_hz) + 1) / c.sample_rate_hz;
        auto an2 = std::make_unique<ImpactAnalyzer>(longer, c.sample_rate_hz);
        if (an2->input_decimation() == 2) {
          ac = longer;
          an = std::move(an2);
        }
      }
      // A maximum whose CWT FFT has an odd length (FFTW's odd real transform allocates on every
      // execution) is lengthened by 1 % steps until it is even (windows still end at window_s:
      // max_win).
      const double base = ac.window_s;
      for (int k = 1; k <= 16 && an->fft_length() % 2 != 0; ++k) {
        ac.window_s = base * (1.0 + 0.01 * k);
        an = std::make_unique<ImpactAnalyzer>(ac, c.sample_rate_hz);
      }
      out.push_back(std::move(an));
    }
    return out;
  }

  // The shortest analyzer whose window holds `len` samples after the onset.
  ImpactAnalyzer& analyzer_for(std::size_t len) {
    for (auto& a : ladder)
      if (a->window_samples() >= len) return *a;
    return analyzer;
  }

  Pending& pending_at(std::size_t k) { return pending[(p_head + k) % kMaxPending]; }

  // In-band power between impacts: median of the last 8 pre-trigger estimates (each ~4 degrees of
  // freedom at 2 ms and a 1 kHz band, so the median is good to ~20 %), converted to the white-noise
  // variance of the samples with the band-pass's noise gain.
  double noise_for(std::uint64_t onset) {
    std::uint64_t begin = 0, end = 0;
    noise_span_before(onset, begin, end);
    // Only measured pre-trigger powers enter the history. Without any (an impact in the first samples of
    // a segment) the LTA stands in for this impact alone: at a segment start it is the white-noise power
    // implied by the spike stage's scale, which strong high modes (a real hammer hit's) inflate by
    // 20-30 dB, and as one of two history values it used to set the second impact's floor as well.
    const double p = detector.band_power(begin, end);
    if (std::isfinite(p)) noise_hist.add(p);
    noise_measured = noise_hist.count > 0;
    if (noise_hist.count == 0) {
      const double lta = detector.lta();
      return std::isfinite(lta) ? lta / detector.band_noise_gain() : NAN;
    }
    return noise_hist.median() / detector.band_noise_gain();
  }

  // The pre-trigger span of the noise estimates: noise_span samples ending noise_guard before the onset.
  void noise_span_before(std::uint64_t onset, std::uint64_t& begin, std::uint64_t& end) const {
    end = onset > noise_guard ? onset - noise_guard : 0;
    begin = std::max(end > noise_span ? end - noise_span : 0, seg_start);
  }

  // Innovation mode (decays that overlap the next impact): the noise over the same pre-trigger span
  // without the previous impact's ringing, which the band power between impacts holds (12-16 dB over
  // the noise at 854 Hz, 25 / s, zeta 0.002): the innovation's power there
  // (ImpactDetector::innovation_noise_power), median of the last 8 like noise_for(), as a white-noise
  // variance. NaN before any measurement. The analyzer decides whether to use it
  // (ImpactWindow::innovation_noise_var).
  //
  // Energy mode (decays that overlap less, e.g. 11 % left at 854 Hz, 25 / s, zeta 0.01, where the band
  // power between impacts still held the ringing 13-15 dB over the noise and made every event
  // low_snr): the same span's power without the ringing of the mode the earlier impacts were analysed
  // at (ImpactDetector::ringing_free_noise_power; the medians of the last 8 estimates' f and zeta), NaN
  // before any.
  double innovation_noise_for(std::uint64_t onset) {
    std::uint64_t begin = 0, end = 0;
    noise_span_before(onset, begin, end);
    double p = NAN;
    if (detector.innovation_mode()) p = detector.innovation_noise_power(begin, end);
    else if (std::isfinite(mode_f)) p = detector.ringing_free_noise_power(begin, end, mode_f, mode_zeta);
    else return NAN;
    if (std::isfinite(p)) innov_hist.add(p);
    return innov_hist.count > 0 ? innov_hist.median() / detector.band_noise_gain() : NAN;
  }

  void take_onsets(std::vector<ImpactEvent>& events) {
    while (detector.has_onset()) {
      const std::uint64_t o = detector.pop_onset();
      ++impacts;
      if (p_count == kMaxPending) analyze_front(events);  // cannot happen with sane configs
      const double nv = noise_for(o);
      pending_at(p_count) = Pending{o, nv, noise_measured, innovation_noise_for(o)};
      ++p_count;
    }
  }

  // The front window's hard end: the maximum (onset + window_s) or, when the next onset comes before
  // it, cut_guard before that onset.
  std::uint64_t hard_end(bool& cut) {
    const std::uint64_t o = pending_at(0).onset;
    const std::uint64_t end = o + max_win;
    cut = p_count > 1 && pending_at(1).onset < end + cut_guard;
    if (!cut) return end;
    const std::uint64_t nx = pending_at(1).onset;
    return std::max(nx > cut_guard ? nx - cut_guard : 0, o);
  }

  // Decay window (the analysis window ends with the decay, window_s is the maximum): steps of
  // decay_step samples after the onset, from decay_first on, each checked once its trigger-band
  // powers are final (wait_after samples later, or at the segment end: `final_data`). The decay has
  // reached the floor at the end of the first step whose mean trigger-band power is at most twice the
  // noise floor between impacts (the in-band power of the pre-trigger samples, lines included), or
  // 40 dB below the power at the envelope's peak (what follows adds little: the Fisher information
  // about sigma in a decay's power beyond u = ln 1e4 = 9.2 is e^-u (1 + u + u^2 / 2) = 0.5 % of it).
  void follow_decay(Pending& p, std::uint64_t end, bool final_data) {
    if (p.decay_end != 0 || p.exhausted) return;
    const std::uint64_t o = p.onset;
    if (p.checked == 0) p.checked = o + decay_first;
    const std::uint64_t limit = final_data ? next : (next > wait_after ? next - wait_after : 0);
    // Without a measured floor (the LTA's stand-in) only the 40 dB rule ends the decay.
    const double floor =
        p.noise_measured && std::isfinite(p.noise_var) ? 2.0 * p.noise_var * detector.band_noise_gain() : 0.0;
    while (p.checked <= limit) {
      if (p.checked > end) {
        p.exhausted = true;
        return;
      }
      if (!(p.peak_power > 0)) {
        const std::uint64_t a = o + peak_at, h = decay_step / 2;
        p.peak_power = detector.band_power(a > h ? a - h : 0, a + h);
      }
      const double pw = detector.band_power(p.checked - decay_step, p.checked);
      // At a segment start the band's fill-up hides the envelope's peak: the largest step stands in.
      if (std::isfinite(pw) && !(pw <= p.peak_power)) p.peak_power = pw;
      if (std::isfinite(pw) && (pw <= floor || (p.peak_power > 0 && pw <= 1e-4 * p.peak_power))) {
        p.decay_end = p.checked;
        return;
      }
      p.checked += decay_step;
    }
    if (final_data) p.exhausted = true;
  }

  // First sample index at which the front window is final (0: now), after following its decay with
  // the data seen so far.
  std::uint64_t front_ready_at(bool final_data = false) {
    if (p_count == 0) return std::numeric_limits<std::uint64_t>::max();
    Pending& p = pending_at(0);
    bool cut = false;
    const std::uint64_t end = hard_end(cut);
    follow_decay(p, end, final_data);
    // A decay that ended before the next onset: final once no onset can lie in it (known when the
    // next onset is).
    if (p.decay_end != 0) return cut ? 0 : p.decay_end + wait_after;
    if (p.exhausted) return cut ? 0 : end + wait_after;
    return p.checked + wait_after;  // the next step's powers are final then
  }

  bool front_ready() { return front_ready_at() <= next; }

  // Analyses every final window, then recomputes ready_at.
  void analyze_ready(std::vector<ImpactEvent>& events) {
    while (front_ready()) analyze_front(events);
    ready_at = front_ready_at();
  }

  void analyze_front(std::vector<ImpactEvent>& events) {
    const Pending p = pending_at(0);
    p_head = (p_head + 1) % kMaxPending;
    --p_count;
    const std::uint64_t o = p.onset;
    const std::uint64_t w0 = std::max(o > analyzer.pretrigger_samples() ? o - analyzer.pretrigger_samples() : 0, seg_start);
    std::uint64_t end = o + max_win;
    WindowEnd kind = WindowEnd::complete;
    if (p.decay_end != 0 && p.decay_end <= end) {
      end = p.decay_end;
      kind = WindowEnd::decayed;
    }
    if (p_count > 0 && pending_at(0).onset < end + cut_guard) {
      const std::uint64_t nx = pending_at(0).onset;
      end = std::max(nx > cut_guard ? nx - cut_guard : 0, o);
      kind = WindowEnd::next_impact;
    }
    if (end > next) {
      end = next;
      kind = WindowEnd::gap;
    }
    const std::size_t n = static_cast<std::size_t>(end - w0);
    // The window in place in the ring when it is one contiguous piece there (nothing writes the ring
    // while analyze() runs); a window that wraps around the ring's end is copied out (two pieces: a
    // masked index per sample does not vectorise). With the 8192-sample ring at 51.2 kHz about three
    // windows in four are contiguous (measured on rw60.wav, `ridgewatch analyze`: memmove 2.2-2.7 ->
    // 1.5-2.4 % of the samples in perf, memcpy 6.7M -> 5.9M instructions in callgrind).
    const auto slot = static_cast<std::size_t>(w0 & mask);
    const float* contiguous = raw.data() + slot;
    if (n > raw.size() - slot) {
      const std::size_t first = raw.size() - slot;
      std::copy(raw.begin() + static_cast<std::ptrdiff_t>(slot), raw.end(), window_buf.begin());
      std::copy(raw.begin(), raw.begin() + static_cast<std::ptrdiff_t>(n - first),
                window_buf.begin() + static_cast<std::ptrdiff_t>(first));
      contiguous = window_buf.data();
    }
    ImpactWindow win;
    win.samples = std::span<const float>(contiguous, n);
    win.onset_offset = static_cast<std::size_t>(o - w0);
    win.end = kind;
    win.noise_var = p.noise_var;
    win.innovation_noise_var = p.innovation_noise_var;
    win.spike = detector.spike_in(w0, end);
    win.onset_index = o;
    ImpactEvent ev = analyzer_for(static_cast<std::size_t>(end - o)).analyze(win);
    ev.window_end_index = end;
    if (std::isfinite(ev.f_hz) && ev.zeta > 0 && ev.zeta < 0.5) {
      mode_f_hist.add(ev.f_hz);
      mode_zeta_hist.add(ev.zeta);
      mode_f = mode_f_hist.median();
      mode_zeta = mode_zeta_hist.median();
    }
    ev.alarm = trend_monitor.update(ev.zeta, ev.status == ImpactStatus::ok);
    events.push_back(ev);
  }

  void end_segment(std::vector<ImpactEvent>& events) {
    detector.finish();
    take_onsets(events);
    while (p_count > 0) {
      front_ready_at(true);  // follow the front decay with all the data there is
      analyze_front(events);
    }
    ready_at = std::numeric_limits<std::uint64_t>::max();
  }

  void start_segment(std::uint64_t first) {
    seg_start = next = first;
    detector.restart(first);
  }
};

StreamProcessor::StreamProcessor(const PipelineConfig& config) : impl_(std::make_unique<Impl>(config)) {}
StreamProcessor::~StreamProcessor() = default;

void StreamProcessor::process(std::span<const float> block, std::uint64_t first_index, std::vector<ImpactEvent>& events) {
  Impl& im = *impl_;
  if (!im.started || im.flushed) {
    if (im.started && first_index < im.next)
      throw std::invalid_argument("StreamProcessor::process: first_index went backwards");
    im.started = true;
    im.flushed = false;
    im.start_segment(first_index);
  } else if (first_index < im.next) {
    throw std::invalid_argument("StreamProcessor::process: first_index " + std::to_string(first_index) +
                                " went backwards (expected " + std::to_string(im.next) + ")");
  } else if (first_index > im.next) {
    im.end_segment(events);
    ++im.gaps;
    im.start_segment(first_index);
  }
  // Samples enter the raw ring a chunk ahead of the detector (bulk copies); a chunk is at most half
  // the ring, which holds twice the history any pending window needs, so nothing still needed is
  // overwritten. Events are the same for any block size (tested).
  const std::size_t chunk_max = std::min<std::size_t>(1024, im.raw.size() / 2);
  for (std::size_t begin = 0; begin < block.size(); begin += chunk_max) {
    const std::size_t len = std::min(chunk_max, block.size() - begin);
    const std::size_t slot = static_cast<std::size_t>(im.next & im.mask);
    const std::size_t first = std::min(len, im.raw.size() - slot);
    std::copy(block.begin() + static_cast<std::ptrdiff_t>(begin),
              block.begin() + static_cast<std::ptrdiff_t>(begin + first), im.raw.begin() + static_cast<std::ptrdiff_t>(slot));
    std::copy(block.begin() + static_cast<std::ptrdiff_t>(begin + first),
              block.begin() + static_cast<std::ptrdiff_t>(begin + len), im.raw.begin());
    // The detector in runs that end where something can happen: where its next block runs (only that
    // push can report onsets) or where the front window becomes ready (next == ready_at; analyze_ready()
    // leaves ready_at > next). Same order of events as one sample at a time.
    for (std::size_t i = begin; i < begin + len;) {
      std::size_t n = std::min(begin + len - i, im.detector.until_block());
      n = im.ready_at > im.next ? static_cast<std::size_t>(std::min<std::uint64_t>(n, im.ready_at - im.next)) : 1;
      im.detector.push(block.subspan(i, n));
      i += n;
      im.next += n;
      if (im.detector.has_onset()) {
        im.take_onsets(events);
        im.ready_at = 0;  // re-evaluate the queue below
      }
      if (im.next >= im.ready_at) im.analyze_ready(events);
    }
  }
  im.samples += block.size();
}

void StreamProcessor::flush(std::vector<ImpactEvent>& events) {
  Impl& im = *impl_;
  if (!im.started || im.flushed) return;
  im.end_segment(events);
  im.flushed = true;
}

std::uint64_t StreamProcessor::samples_seen() const { return impl_->samples; }
std::uint64_t StreamProcessor::impacts_detected() const { return impl_->impacts; }
std::uint64_t StreamProcessor::spikes_seen() const { return impl_->detector.spikes_seen(); }
std::uint64_t StreamProcessor::gaps_seen() const { return impl_->gaps; }
trend::TrendMonitor& StreamProcessor::trend() { return impl_->trend_monitor; }
const PipelineConfig& StreamProcessor::config() const { return impl_->cfg; }

}  // namespace ridgewatch::pipeline
