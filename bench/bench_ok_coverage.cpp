// Does `ok` keep its promise on records the pipeline did not make? Records of
// tests/support/indep_signals.hpp (bench/survey_cases.hpp: one mode, mesh lines, hum, noise, speed
// ramp or wobble), configured by `ridgewatch survey --write-config` (the proposal unchanged, as a new
// user would run it), analysed by `ridgewatch analyze`, every event scored against the generator's
// truth: how many are ok, how far the ok values are off and whether their 95 % intervals cover the
// true zeta (README "Per-impact accuracy").
//
//   bench_ok_coverage case FS F RATE ZETA SNR SEED [float] [wobble] [-v]   one record (-v: every event)
//   bench_ok_coverage tail [SEEDS]    decays that fill the interval: 854 Hz, 25/40/60 per second,
//                                     zeta 0.002/0.005/0.01, SNR 10/25/40 dB rotating
//   bench_ok_coverage sweep [SEEDS [F [RATE [ZETA]]]]   the survey sweep's records (bench_survey
//                                     sweep numbering; F, RATE, ZETA: only that cell's, 0 = any)
// Records and proposals are kept in $TMPDIR/bench_ok_coverage/ and a proposal found there is reused,
// so that two builds of the analyzer can be compared on the same configurations.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "bench/survey_cases.hpp"

namespace {

struct Score {
  std::size_t truth = 0, events = 0, found = 0, false_events = 0, ok = 0, ok_miss = 0;
  std::vector<double> ok_err;       // |zeta / truth - 1| of ok events
  std::map<std::string, int> status;
  bool proposal = false;
};

Score run_record(const survey_cases::Case& c, const std::string& tag, bool verbose) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / "bench_ok_coverage";
  fs::create_directories(dir);
  const std::string wav = (dir / (tag + ".wav")).string(), cfg = (dir / (tag + ".yaml")).string();
  const indep::RigRecord r = survey_cases::make_record(c);
  indep::write_wav_mono(wav, r.x, c.fs_hz, c.float32 ? indep::SampleFormat::float32 : indep::SampleFormat::pcm16);
  Score s;
  s.truth = r.onset_s.size();
  if (!fs::exists(cfg)) {
    std::ostringstream out, err;
    ridgewatch::cli::run_survey({wav, "--write-config", cfg}, out, err);
  }
  s.proposal = fs::exists(cfg);
  if (!s.proposal) return s;
  std::ostringstream out, err;
  ridgewatch::cli::run_analyze({wav, "--config", cfg}, out, err);
  const double tol = std::min(0.002, 0.25 / c.rate_hz);
  std::vector<char> matched(r.onset_s.size(), 0);
  for (const auto& e : survey_cases::json_lines(out.str())) {
    ++s.events;
    const double t = e["t_s"].get<double>();
    const auto it = std::lower_bound(r.onset_s.begin(), r.onset_s.end(), t - tol);
    const long k = it != r.onset_s.end() && std::fabs(*it - t) <= tol ? it - r.onset_s.begin() : -1;
    const std::string st = e["status"].get<std::string>();
    ++s.status[st];
    if (k < 0 || matched[static_cast<std::size_t>(k)]) {
      ++s.false_events;
      continue;
    }
    matched[static_cast<std::size_t>(k)] = 1;
    ++s.found;
    const double zt = r.zeta[static_cast<std::size_t>(k)];
    const bool has = !e["zeta"].is_null() && !e["zeta_ci95"][0].is_null();
    const double z = e["zeta"].is_null() ? NAN : e["zeta"].get<double>();
    const double lo = has ? e["zeta_ci95"][0].get<double>() : NAN, hi = has ? e["zeta_ci95"][1].get<double>() : NAN;
    if (verbose)
      std::printf("  t %8.4f  %-12s zeta %.5f [%.5f %.5f] err %+6.2f %% snr %5.1f win %.4f%s\n", t, st.c_str(), z, lo,
                  hi, 100 * (z / zt - 1), e["snr_db"].is_null() ? NAN : e["snr_db"].get<double>(),
                  e["window_s"].is_null() ? NAN : e["window_s"].get<double>(),
                  st == "ok" && !(lo <= zt && zt <= hi) ? "  <-- ok interval misses the truth" : "");
    if (st != "ok") continue;
    ++s.ok;
    s.ok_err.push_back(std::fabs(z / zt - 1));
    if (!(lo <= zt && zt <= hi)) ++s.ok_miss;
  }
  return s;
}

double median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

struct Totals {
  std::size_t ok = 0, ok_miss = 0, events = 0, found = 0, truth = 0, false_events = 0;
};

void print(const survey_cases::Case& c, const Score& s, Totals& t) {
  std::string st;
  for (const auto& [k, v] : s.status) st += k + " " + std::to_string(v) + ", ";
  const double mx = s.ok_err.empty() ? NAN : *std::max_element(s.ok_err.begin(), s.ok_err.end());
  std::printf("%-72s | %s found %3zu/%-3zu false %zu | ok %3zu (%5.1f %%) misses %zu | |err| med %5.2f max %5.2f %% | %s\n",
              survey_cases::describe(c).c_str(), s.proposal ? "   " : "(-)", s.found, s.truth, s.false_events, s.ok,
              s.events ? 100.0 * static_cast<double>(s.ok) / static_cast<double>(s.events) : 0.0, s.ok_miss,
              100 * median(s.ok_err), 100 * mx, st.c_str());
  std::fflush(stdout);
  t.ok += s.ok;
  t.ok_miss += s.ok_miss;
  t.events += s.events;
  t.found += s.found;
  t.truth += s.truth;
  t.false_events += s.false_events;
}

void summary(const Totals& t) {
  std::printf("total: %zu events (%zu of %zu impacts found, %zu false), %zu ok (%.1f %%), %zu ok intervals miss the "
              "truth (coverage %.1f %%)\n",
              t.events, t.found, t.truth, t.false_events, t.ok,
              t.events ? 100.0 * static_cast<double>(t.ok) / static_cast<double>(t.events) : 0.0, t.ok_miss,
              t.ok ? 100.0 * static_cast<double>(t.ok - t.ok_miss) / static_cast<double>(t.ok) : NAN);
}

std::string tag_of(const survey_cases::Case& c) {
  char b[160];
  std::snprintf(b, sizeof b, "fs%.0f-f%.0f-r%.0f-z%.4f-snr%.0f-s%llu%s%s", c.fs_hz, c.f_hz, c.rate_hz, c.zeta, c.snr_db,
                static_cast<unsigned long long>(c.seed), c.float32 ? "-float" : "", c.wobble ? "-wobble" : "");
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string mode = argc > 1 ? argv[1] : "";
  Totals t;
  if (mode == "case" && argc >= 8) {
    const survey_cases::Case c = survey_cases::case_from_args(argc, argv);
    bool verbose = false;
    for (int k = 8; k < argc; ++k) verbose |= std::string(argv[k]) == "-v";
    print(c, run_record(c, tag_of(c), verbose), t);
    return 0;
  }
  if (mode == "tail") {
    const int seeds = argc > 2 ? std::atoi(argv[2]) : 2;
    const double snrs[] = {10, 25, 40};
    int n = 0;
    for (double rate : {25.0, 40.0, 60.0})
      for (double z : {0.002, 0.005, 0.01})
        for (int s = 0; s < seeds; ++s, ++n) {
          survey_cases::Case c;
          c.fs_hz = 51200;
          c.f_hz = 854;
          c.rate_hz = rate;
          c.zeta = z;
          c.snr_db = snrs[n % 3];
          c.seed = static_cast<std::uint64_t>(500 + n);
          c.float32 = n % 2;
          c.wobble = (n / 2) % 2;
          print(c, run_record(c, tag_of(c), false), t);
        }
    summary(t);
    return 0;
  }
  if (mode == "sweep") {
    // The records of `bench_survey sweep SEEDS` (same numbering, seeds, rates and formats).
    const int seeds = argc > 2 ? std::atoi(argv[2]) : 3;
    const double only_f = argc > 3 ? std::atof(argv[3]) : 0, only_rate = argc > 4 ? std::atof(argv[4]) : 0,
                 only_zeta = argc > 5 ? std::atof(argv[5]) : 0;
    int n = 0;
    for (double f : {300.0, 854.0, 2500.0, 8000.0})
      for (double rate : {5.0, 25.0, 120.0})
        for (double z : {0.002, 0.01, 0.05})
          for (int s = 0; s < seeds; ++s) {
            const survey_cases::Case c = survey_cases::sweep_case(f, rate, z, s, n);
            ++n;
            if ((only_f > 0 && f != only_f) || (only_rate > 0 && rate != only_rate) || (only_zeta > 0 && z != only_zeta))
              continue;
            print(c, run_record(c, tag_of(c), false), t);
          }
    summary(t);
    return 0;
  }
  std::fprintf(stderr,
               "usage: bench_ok_coverage case FS F RATE ZETA SNR SEED [float] [wobble] [-v] | tail [SEEDS] | sweep [SEEDS [F [RATE [ZETA]]]]\n");
  return 2;
}
