// `ridgewatch survey` benchmark and acceptance sweep (README "First run on your own rig").
//   bench_survey time            survey of 60 s at 51.2 kHz (one thread), wall and CPU time
//   bench_survey sweep [SEEDS]   the issue-19 acceptance grid through `survey --write-config` and
//                                `analyze --config` (bench/survey_cases.hpp), one line per record,
//                                then the controls without impacts (20 seeds) and a summary
//   bench_survey sweep SEEDS F [RATE [ZETA]]   only the grid's records with that f (rate, zeta; 0 =
//                                any), numbered as in the full sweep; no controls
//   bench_survey controls        only the 20 controls
//   bench_survey case FS F RATE ZETA SNR SEED [float] [wobble] [teeth=N]   one record, verbose (teeth:
//                                the gear's, default 22; sets the mesh lines at N x the impact rate)
//   bench_survey hammer HIT.wav  the real hammer hit repeated 5x with gaps (tests/test_survey.cpp):
//                                the survey's report, then analyze's events with the proposal
#include <chrono>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <string>

#include <unistd.h>

#include "bench/survey_cases.hpp"
#include "core/pipeline/impact_detector.hpp"
#include "core/survey/band_envelope.hpp"
#include "core/survey/survey.hpp"

namespace {

double cpu_s() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

int time_mode() {
  survey_cases::Case c;
  c.duration_s = 60;
  c.fs_hz = 51200;
  const auto r = survey_cases::make_record(c);
  for (int rep = 0; rep < 3; ++rep) {
    const auto w0 = std::chrono::steady_clock::now();
    const double c0 = cpu_s();
    const auto s = ridgewatch::survey::run_survey(r.x, c.fs_hz);
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
    std::printf("survey 60 s at 51.2 kHz: wall %.2f s, cpu %.2f s (proposal %s, f %.1f Hz)\n", wall, cpu_s() - c0,
                s.proposal ? "yes" : "no", s.modes.empty() ? NAN : s.modes[0].f_hz);
  }
  return 0;
}

void print(const survey_cases::Case& c, const survey_cases::Outcome& o) {
  const double f_err = (o.f_expected_hz / c.f_hz - 1) * 100;
  std::printf("%-75s | proposal %-3s f_err %+7.3f %% | found %3zu/%-3zu false %zu ok %3zu median|dzeta| %6.2f %%\n",
              survey_cases::describe(c).c_str(), o.proposal ? "yes" : "no", f_err, o.found, o.truth, o.false_events, o.ok,
              100 * o.median_zeta_err);
  std::fflush(stdout);
}

// filter: only the records whose f / rate / zeta match the given values (<= 0: any); the other
// records keep their numbering (seed, sample rate, format), so a subset reproduces the full sweep's lines.
struct SweepFilter {
  double f = 0, rate = 0, zeta = 0;
  bool controls = true;
  bool match(double f_, double r_, double z_) const {
    return (f <= 0 || f == f_) && (rate <= 0 || rate == r_) && (zeta <= 0 || zeta == z_);
  }
};

int sweep_mode(int seeds, const SweepFilter& filter) {
  const std::string dir = std::filesystem::temp_directory_path() / ("bench_survey-" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const double rates_fs[] = {25600, 44100, 48000, 51200};
  const double fns[] = {300, 854, 2500, 8000};
  const double rates[] = {5, 25, 120};
  const double zetas[] = {0.002, 0.01, 0.05};
  const double snrs[] = {10, 25, 40};
  int n = 0, run = 0, pass = 0, feasible = 0, feasible_pass = 0;
  for (double f : fns)
    for (double rate : rates)
      for (double z : zetas)
        for (int s = 0; s < seeds; ++s) {
          const survey_cases::Case c = survey_cases::sweep_case(f, rate, z, s, n);
          ++n;
          if (!filter.match(f, rate, z)) continue;
          ++run;
          // Per-impact damping is measurable when the decay falls below 30 % of its start before the
          // next impact comes and the period holds the analyzer's minimum window (10 kernel widths at
          // its lowest eta0, 5, to which the survey may lower it).
          const double left = std::exp(-2 * 3.141592653589793 * f * z / (rate * 1.05));
          const bool ok_case = left < 0.3 && 10 * 5 / (2 * 3.141592653589793 * f) < 0.9 / (rate * 1.05) - 0.002;
          const auto o = survey_cases::run_case(c, dir);
          print(c, o);
          const bool good = o.proposal && std::fabs(o.f_expected_hz / f - 1) <= 0.01 && static_cast<double>(o.found) >= 0.97 * static_cast<double>(o.truth) &&
                            o.false_events == 0 && o.median_zeta_err <= 0.02;
          pass += good;
          feasible += ok_case;
          feasible_pass += ok_case && good;
          if (!ok_case) std::printf("    (decays overlap: %.0f %% left at the next impact, or the period is below the minimum window)\n", 100 * left);
        }
  int proposals = 0;
  for (int s = 0; s < (filter.controls ? 20 : 0); ++s) {
    survey_cases::Case c;
    c.impacts = false;
    c.seed = static_cast<std::uint64_t>(1000 + s);
    c.fs_hz = rates_fs[s % 4];
    c.rate_hz = 5 + 6 * s;
    c.snr_db = snrs[s % 3];
    c.float32 = s % 2;
    c.wobble = (s / 2) % 2;
    const auto o = survey_cases::run_case(c, dir);
    print(c, o);
    proposals += o.proposal;
  }
  std::printf("summary: %d/%d records meet every acceptance figure; of the %d with measurable decays %d; controls "
              "without impacts: %d proposals in 20\n",
              pass, run, feasible, feasible_pass, proposals);
  return 0;
}

int hammer_mode(const std::string& hit) {
  const std::string dir = std::filesystem::temp_directory_path() / ("bench_survey-" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const auto h = survey_cases::write_hammer_record(hit, dir);
  std::ostringstream out, err;
  ridgewatch::cli::run_survey({h.wav, "--write-config", dir + "/hammer5.yaml"}, out, err);
  std::cout << out.str() << err.str();
  if (!std::filesystem::exists(dir + "/hammer5.yaml")) return 0;
  std::ostringstream aout, aerr;
  ridgewatch::cli::run_analyze({h.wav, "--config", dir + "/hammer5.yaml"}, aout, aerr);
  std::cout << aout.str() << aerr.str();
  const auto o = survey_cases::survey_then_analyze(h.wav, dir + "/hammer5.yaml", h.onsets, h.zetas, 0.2);
  std::printf("hammer: proposal %s f %.1f Hz, found %zu/%zu, false %zu, ok %zu (files in %s)\n", o.proposal ? "yes" : "no",
              o.f_expected_hz, o.found, o.truth, o.false_events, o.ok, dir.c_str());
  return 0;
}

// `case`: the analyze events of the record that match no impact within the sweep's tolerance and the
// impacts no event matches, each with its nearest counterpart (what a false or missed onset is).
void print_unmatched(const survey_cases::Case& c, const std::string& dir) {
  const auto truth = survey_cases::make_record(c).onset_s;
  std::ostringstream out, err;
  ridgewatch::cli::run_analyze({dir + "/survey-case.wav", "--config", dir + "/survey-case.yaml"}, out, err);
  std::vector<double> events;
  for (const auto& e : survey_cases::json_lines(out.str())) events.push_back(e["t_s"].get<double>());
  const double tol = std::min(0.002, 0.25 / c.rate_hz);
  auto nearest = [](const std::vector<double>& v, double t) {
    double best = NAN;
    for (double u : v)
      if (!(std::fabs(u - t) >= std::fabs(best - t))) best = u;
    return best;
  };
  for (double t : events)
    if (!(std::fabs(nearest(truth, t) - t) <= tol))
      std::printf("unmatched event at %.4f s: nearest impact %.4f s (%+.2f ms)\n", t, nearest(truth, t), 1e3 * (t - nearest(truth, t)));
  for (double t : truth)
    if (!(std::fabs(nearest(events, t) - t) <= tol))
      std::printf("missed impact at %.4f s: nearest event %.4f s (%+.2f ms)\n", t, nearest(events, t), 1e3 * (nearest(events, t) - t));
}

// `noise`: the detector's own band energy (ImpactDetector with the survey's proposed detector block)
// on the survey's noise-only stretches (as noise_trigger_level in core/survey/survey.cpp: from 10
// decay time constants after each impact to 15 ms before the next, and before the first impact):
// its mean over the white-noise band power the spike stage implies, the share of band samples
// above 3x / 5x / 8x the stretch's mean (exponential: e^-r), and the largest min(STA, 2 ms mean)
// over max(mean, 8 ms before), as noise_trigger_level reads the survey's FFT envelope.
void noise_mode(const survey_cases::Case& c) {
  const auto r = survey_cases::make_record(c);
  const auto s = ridgewatch::survey::run_survey(r.x, c.fs_hz);
  if (!s.proposal || s.modes.empty()) {
    std::printf("no proposal\n");
    return;
  }
  auto d = s.proposal->detector;
  ridgewatch::pipeline::ImpactDetector det(d, c.fs_hz, r.x.size() + 16);
  for (double v : r.x) det.push(static_cast<float>(v));
  const std::size_t D = det.decimation();
  const double fs_d = c.fs_hz / static_cast<double>(D);
  std::vector<double> e;  // one value per band sample: the band power over its D input samples
  for (std::size_t n = 0; n + D + 8 < r.x.size(); n += D) e.push_back(det.band_power(n, n + std::max<std::size_t>(D, 8)));
  const double tau = 1.0 / (2 * 3.141592653589793 * s.modes[0].f_hz * s.modes[0].zeta);
  const auto& t = s.impact_times_s;
  std::vector<std::pair<double, double>> st{{0.010, t.empty() ? 0.0 : t[0] - 0.015}};
  for (std::size_t i = 0; i + 1 < t.size(); ++i) st.emplace_back(t[i] + 10 * tau, t[i + 1] - 0.015);
  const auto sta_n = std::max<std::size_t>(1, static_cast<std::size_t>(std::lround(d.sta_s * fs_d)));
  const auto conf_n = 4 * sta_n;
  const auto pre_n = static_cast<std::size_t>(std::ceil(fs_d / (0.5 * (d.band_hi_hz - d.band_lo_hz))));
  double level = 0, level_t = NAN, sum = 0;
  std::size_t count = 0, over3 = 0, over5 = 0, over8 = 0;
  for (const auto& [a_s, b_s] : st) {
    const auto a = static_cast<std::size_t>(std::max(0.0, a_s) * fs_d);
    const auto b = std::min(e.size(), static_cast<std::size_t>(std::max(0.0, b_s) * fs_d));
    if (b < a + pre_n + conf_n + sta_n + 2) continue;
    double mean = 0;
    for (std::size_t i = a; i < b; ++i) mean += e[i];
    mean /= static_cast<double>(b - a);
    for (std::size_t i = a; i < b; ++i) {
      sum += e[i] / mean;
      ++count;
      over3 += e[i] > 3 * mean;
      over5 += e[i] > 5 * mean;
      over8 += e[i] > 8 * mean;
    }
    for (std::size_t i = a + pre_n + sta_n; i + conf_n < b; ++i) {
      double sta = 0, pre = 0, conf = 0;
      for (std::size_t k = i + 1 - sta_n; k <= i; ++k) sta += e[k];
      for (std::size_t k = i + 1 - sta_n - pre_n; k < i + 1 - sta_n; ++k) pre += e[k];
      for (std::size_t k = i + 1; k <= i + conf_n; ++k) conf += e[k];
      const double lv = std::min(sta / static_cast<double>(sta_n), conf / static_cast<double>(conf_n)) / std::max(mean, pre / static_cast<double>(pre_n));
      if (lv > level) {
        level = lv;
        level_t = static_cast<double>(i) / fs_d;
      }
    }
  }
  // The white-noise band power the spike stage implies: E[e] = noise_sd^2 x the chain's noise gain.
  const double sd = 0.25 * std::pow(10.0, -c.snr_db / 20.0);
  std::printf("detector band %.1f-%.1f Hz ratio %.2f, D %zu: noise-only band samples %zu, lta %.3g (white %.3g)\n",
              d.band_lo_hz, d.band_hi_hz, d.trigger_ratio, D, count, det.lta(), sd * sd * det.band_noise_gain());
  std::printf("share above 3x/5x/8x the stretch mean: %.2e %.2e %.2e (exponential %.2e %.2e %.2e)\n",
              static_cast<double>(over3) / static_cast<double>(count), static_cast<double>(over5) / static_cast<double>(count),
              static_cast<double>(over8) / static_cast<double>(count),
              std::exp(-3.0), std::exp(-5.0), std::exp(-8.0));
  std::printf("detector's band energy: noise alone reaches %.2fx its reference (at %.4f s); survey's FFT measure %.2fx\n", level,
              level_t, s.noise_trigger_level);
  (void)sum;
  // The survey's FFT band envelope (brick-wall band, core/survey/band_envelope.hpp) on the same
  // stretches: its mean energy against white noise's, bins x N x sd^2 (E|X[k]|^2 = N sd^2 per bin).
  const ridgewatch::survey::RecordSpectrum spec(r.x, c.fs_hz);
  double fe = 0;
  const auto env = spec.envelope(d.band_lo_hz, d.band_hi_hz, 4.0, fe);
  const double bins = std::ceil(d.band_hi_hz / spec.bin_hz()) - std::ceil(d.band_lo_hz / spec.bin_hz());
  double fsum = 0;
  std::size_t fn = 0;
  for (const auto& [a_s, b_s] : st)
    for (auto i = static_cast<std::size_t>(std::max(0.0, a_s) * fe); i < std::min(env.size(), static_cast<std::size_t>(std::max(0.0, b_s) * fe)); ++i) {
      fsum += std::norm(env[i]);
      ++fn;
    }
  std::printf("FFT band envelope on the same stretches: mean energy %.2fx white noise's (detector: %.2fx)\n",
              fsum / static_cast<double>(fn) / (bins * static_cast<double>(r.x.size()) * sd * sd),
              det.lta() / (sd * sd * det.band_noise_gain()));
}

}  // namespace

int main(int argc, char** argv) {
  const std::string mode = argc > 1 ? argv[1] : "time";
  if (mode == "time") return time_mode();
  if (mode == "sweep") {
    SweepFilter filter;
    if (argc > 3) filter.f = std::atof(argv[3]);
    if (argc > 4) filter.rate = std::atof(argv[4]);
    if (argc > 5) filter.zeta = std::atof(argv[5]);
    filter.controls = argc <= 3;
    return sweep_mode(argc > 2 ? std::atoi(argv[2]) : 3, filter);
  }
  if (mode == "controls") {
    return sweep_mode(0, SweepFilter{});  // no seeds per cell: only the 20 controls
  }
  if (mode == "noise" && argc >= 8) {
    noise_mode(survey_cases::case_from_args(argc, argv));
    return 0;
  }
  if (mode == "hammer" && argc >= 3) return hammer_mode(argv[2]);
  if (mode == "case" && argc >= 8) {
    const survey_cases::Case c = survey_cases::case_from_args(argc, argv);
    const std::string dir = std::filesystem::temp_directory_path() / ("bench_survey-" + std::to_string(getpid()));
    std::filesystem::create_directories(dir);
    const auto o = survey_cases::run_case(c, dir);
    std::cout << o.survey_text.substr(0, 0);
    std::ostringstream out, err;
    ridgewatch::cli::run_survey({dir + "/survey-case.wav"}, out, err);
    std::cout << out.str();
    print(c, o);
    const auto s = ridgewatch::survey::run_survey(survey_cases::make_record(c).x, c.fs_hz);
    std::printf("trigger: impacts' STA and confirmation %.2fx the detector's reference, band noise alone %.2fx its reference\n",
                s.trigger_headroom, s.noise_trigger_level);
    std::cout << o.analyze_err;
    if (o.proposal) print_unmatched(c, dir);
    return 0;
  }
  std::cerr << "usage: bench_survey time | sweep [SEEDS [F [RATE [ZETA]]]] | controls | case FS F RATE ZETA SNR SEED [float] [wobble] [none] [teeth=N] | hammer HIT.wav\n";
  return 2;
}
