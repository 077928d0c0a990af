// Property test of `identify_modes` on random multi-mode free decays that ridgewatch's simulator did
// not make (closed-form sums from tests/support/indep_signals.hpp): 1-8 modes in a random band,
// zeta log-uniform in 1e-4 .. 0.05, close pairs 0.4-3 % apart, one or two modes 40-60 dB stronger far
// above the band, white noise. Every trial is analysed with the band the "user" typed.
//
// What must hold (the contract of `modes`):
//  (a) every in-band mode that is resolvable is found (asserted as a rate >= 95 %: see the end). Resolvable (defined from the truth only):
//      - it lies inside the band with a margin of 3 half-power bandwidths and 1 %;
//      - it stands above the noise: energy in the record over the noise density E / N0 >= 30 dB
//        (E = A^2 (1 - e^{-2 sigma T}) / (4 sigma), N0 = noise_var / fs; a matched filter's SNR);
//      - it is separated from every other mode (in band or not) by at least 4 half-power bandwidths
//        of the wider of the two, and by 4 / T (the record's frequency resolution, with margin);
//      - its spectral peak stands 10 dB above the sum of all other modes' spectra at its frequency
//        (exact transforms of the causal decays, below).
//      Found: a reported mode within a quarter of the nearest other mode's distance and within
//      max(3 zeta f, 1e-3 f) of the true frequency.
//  (b) an `ok` ml estimate is right: |zeta - truth| <= 3 x its 95 % half-width + 1 % of zeta (3x the
//      half-width is > 5 sigma, so a correct estimator fails this about once in 10^6; the 1 % is the
//      cross-check's own allowance for the envelope's deterministic bias); |f - truth| <= 5 f_sd +
//      1e-4 f. This holds for every `ok`, also on a mode that is not "resolvable" by (a).
//  (c) pooled over the `ok` ml estimates of true modes whose relative zeta_sd is >= 0.5 % (the interval
//      is then statistics-limited; below, (b)'s 1 % bias allowance governs), the 95 % interval covers
//      the truth in >= 85 % (with ~40-70 intervals the binomial sd of the rate is 2.6-3.5 %, so 85 % is
//      about 3 sd below nominal).
//  (d) no mode (any status) is reported outside the band.
//  (e) no `ok` on a number that is no mode: every `ok` mode is within max(3 zeta f, 1e-3 f) of a true
//      mode.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "core/dsp/modes.hpp"
#include "support/indep_signals.hpp"

using namespace ridgewatch::dsp;

namespace {

#ifdef RIDGEWATCH_SANITIZED
constexpr int kTrials = 4;  // sanitizer builds: a representative subset (the first trials)
#else
constexpr int kTrials = 24;
#endif

struct Trial {
  double fs = 0.0, seconds = 1.0, f_lo = 0.0, f_hi = 0.0, noise_sd = 0.0;
  std::vector<indep::Mode> in_band;  // the modes of interest
  std::vector<indep::Mode> strong;   // far above the band, 40-60 dB stronger
  std::vector<double> x;
};

// The generator's zeta is sigma / omega_d; the estimator's is the usual sigma / omega_n.
double true_zeta(const indep::Mode& m) { return m.zeta / std::sqrt(1.0 + m.zeta * m.zeta); }
double sigma_of(const indep::Mode& m) { return m.zeta * indep::kTwoPi * m.f_hz; }
double half_power_bw_hz(const indep::Mode& m) { return sigma_of(m) / indep::kTwoPi; }  // half-width

Trial make_trial(int index) {
  indep::Rng rng(static_cast<std::uint64_t>(7919 * index + 17));
  Trial t;
  t.fs = index % 2 ? 25600.0 : 20000.0;
  t.f_lo = rng.uniform(150.0, 400.0);
  t.f_hi = std::min(t.f_lo * rng.uniform(4.0, 12.0), 0.25 * t.fs);
  const int k = 1 + static_cast<int>(rng.uniform() * 8.0);
  const double a0 = 100.0;  // physical units, far above 1
  auto draw_zeta = [&](double max_zeta) {
    return std::min(max_zeta, std::exp(rng.uniform(std::log(1e-4), std::log(0.05))));
  };
  while (static_cast<int>(t.in_band.size()) < k) {
    indep::Mode m;
    m.f_hz = std::exp(rng.uniform(std::log(t.f_lo * 1.05), std::log(t.f_hi / 1.05)));
    m.zeta = draw_zeta(0.05);
    m.amplitude = a0 * std::exp(rng.uniform(std::log(0.2), std::log(3.0)));
    m.phase_rad = rng.uniform(0.0, indep::kTwoPi);
    t.in_band.push_back(m);
    // A close partner (every third mode on average): 0.4-3 % away, damped lightly enough that the
    // pair is resolvable (4 bandwidths within the separation).
    if (static_cast<int>(t.in_band.size()) < k && rng.uniform() < 0.35) {
      indep::Mode p = m;
      const double sep = rng.uniform(0.004, 0.03);
      p.f_hz = m.f_hz * (1.0 + (rng.uniform() < 0.5 ? -sep : sep));
      const double zmax = sep / 8.0;  // 4 half-power bandwidths (zeta f each) within sep f
      t.in_band.back().zeta = std::min(t.in_band.back().zeta, zmax);
      p.zeta = draw_zeta(zmax);
      p.amplitude = a0 * std::exp(rng.uniform(std::log(0.2), std::log(3.0)));
      p.phase_rad = rng.uniform(0.0, indep::kTwoPi);
      t.in_band.push_back(p);
    }
  }
  const int n_strong = 1 + (rng.uniform() < 0.5);
  for (int i = 0; i < n_strong; ++i) {
    indep::Mode s;
    s.f_hz = rng.uniform(1.5 * t.f_hi, 0.42 * t.fs);
    s.zeta = std::exp(rng.uniform(std::log(3e-4), std::log(5e-3)));
    s.amplitude = a0 * std::pow(10.0, rng.uniform(40.0, 60.0) / 20.0);
    s.phase_rad = rng.uniform(0.0, indep::kTwoPi);
    t.strong.push_back(s);
  }
  // Noise 20-50 dB below a0 (so weak, heavily damped modes may sink into it: they are then not
  // resolvable by (a), but still must not be `ok` on a wrong number).
  t.noise_sd = a0 * std::pow(10.0, -rng.uniform(20.0, 50.0) / 20.0);
  t.x.assign(static_cast<std::size_t>(t.seconds * t.fs), 0.0);
  for (const auto& m : t.in_band) indep::add_decay(t.x, t.fs, 0.0, m);
  for (const auto& m : t.strong) indep::add_decay(t.x, t.fs, 0.0, m);
  for (double& v : t.x) v += t.noise_sd * rng.gauss();
  return t;
}

bool resolvable(const Trial& t, std::size_t i, std::string& why) {
  const indep::Mode& m = t.in_band[i];
  const double bw = half_power_bw_hz(m);
  if (m.f_hz - 3 * bw < t.f_lo * 1.01 || m.f_hz + 3 * bw > t.f_hi / 1.01) {
    why = "at the band edge";
    return false;
  }
  const double sg = sigma_of(m);
  const double energy = m.amplitude * m.amplitude * (1.0 - std::exp(-2.0 * sg * t.seconds)) / (4.0 * sg);
  const double n0 = t.noise_sd * t.noise_sd / t.fs;
  if (energy / n0 < 1000.0) {
    why = "E/N0 " + std::to_string(10 * std::log10(energy / n0)) + " dB";
    return false;
  }
  std::vector<const indep::Mode*> others;
  for (std::size_t j = 0; j < t.in_band.size(); ++j)
    if (j != i) others.push_back(&t.in_band[j]);
  for (const auto& s : t.strong) others.push_back(&s);
  // Spectra of the causal decays themselves: A e^{-sigma t} sin(w0 t + phi) for t >= 0 has the Fourier
  // transform A [w0 cos phi + (sigma + i w) sin phi] / ((sigma + i w)^2 + w0^2). (The one-pole
  // Lorentzian underestimates a strong mode's far skirt several times: the onset step adds a 1/f tail.)
  auto spectrum2 = [](const indep::Mode& o, double f) {
    const std::complex<double> s(sigma_of(o), indep::kTwoPi * f);
    const double w0 = indep::kTwoPi * o.f_hz;
    const std::complex<double> num = o.amplitude * (w0 * std::cos(o.phase_rad) + s * std::sin(o.phase_rad));
    return std::norm(num / (s * s + w0 * w0));
  };
  const double peak = spectrum2(m, m.f_hz);
  double skirt = 0.0;
  for (const indep::Mode* o : others) {
    const double df = std::abs(o->f_hz - m.f_hz);
    if (df < 4.0 * std::max(bw, half_power_bw_hz(*o)) || df < 4.0 / t.seconds) {
      why = "neighbour at " + std::to_string(o->f_hz) + " Hz";
      return false;
    }
    skirt += spectrum2(*o, m.f_hz);
  }
  if (peak < 10.0 * skirt) {
    why = "under a neighbour's skirt";
    return false;
  }
  return true;
}

double found_tolerance_hz(const Trial& t, std::size_t i) {
  const indep::Mode& m = t.in_band[i];
  double nearest = INFINITY;
  for (std::size_t j = 0; j < t.in_band.size(); ++j)
    if (j != i) nearest = std::min(nearest, std::abs(t.in_band[j].f_hz - m.f_hz));
  return std::min(0.25 * nearest, std::max(3.0 * half_power_bw_hz(m), 1e-3 * m.f_hz));
}

std::string describe(const Trial& t) {
  std::ostringstream s;
  s << "fs " << t.fs << " band " << t.f_lo << "-" << t.f_hi << " noise " << t.noise_sd << " modes";
  for (const auto& m : t.in_band) s << " [" << m.f_hz << " z " << m.zeta << " A " << m.amplitude << "]";
  s << " strong";
  for (const auto& m : t.strong) s << " [" << m.f_hz << " z " << m.zeta << " A " << m.amplitude << "]";
  return s.str();
}

int trial_count() {
  // RIDGEWATCH_MODES_TRIALS=N runs more trials (the README's measurement); the default keeps the test
  // within its time budget.
  if (const char* e = std::getenv("RIDGEWATCH_MODES_TRIALS")) return std::max(1, std::atoi(e));
  return kTrials;
}

}  // namespace

TEST(ModesProperty, RandomMultiModeDecaysInARandomBand) {
  int resolvable_modes = 0, resolvable_found = 0, found_modes = 0, ok_modes = 0, covered = 0, unresolvable = 0;
  int ok_stat = 0, covered_stat = 0;  // ok estimates whose interval is statistics-limited (zeta_sd >= 0.5 %)
  const int trials = trial_count();
  int first = 0;
  if (const char* e = std::getenv("RIDGEWATCH_MODES_FIRST")) first = std::max(0, std::atoi(e));
  for (int trial = first; trial < first + trials; ++trial) {
    const Trial t = make_trial(trial);
    SCOPED_TRACE("trial " + std::to_string(trial) + ": " + describe(t));
    ModeSearchOptions opt;
    opt.onset_s = 0.0;
    opt.f_min_hz = t.f_lo;
    opt.f_max_hz = t.f_hi;
    const ModeSearchResult r = identify_modes(t.x, t.fs, opt);
    std::ostringstream rep;
    for (const auto& m : r.modes)
      rep << " [" << m.selected.f_hz << " sd " << m.ml.f_sd_hz << " z " << m.ml.zeta << " " << to_string(m.ml.status) << " eta0 " << m.eta0 << " "
          << m.note << "]";
    rep << " peaks:";
    for (const auto& pk : r.peaks) rep << " " << pk.f_hz << "/" << pk.snr_db << "dB/" << pk.eta0;
    SCOPED_TRACE("reported:" + rep.str());
    // (d) nothing outside the band.
    for (const auto& m : r.modes) {
      EXPECT_GE(m.selected.f_hz, t.f_lo);
      EXPECT_LE(m.selected.f_hz, t.f_hi);
    }
    std::vector<bool> matched(r.modes.size(), false);
    for (std::size_t i = 0; i < t.in_band.size(); ++i) {
      const indep::Mode& truth = t.in_band[i];
      const double tol = found_tolerance_hz(t, i);
      const IdentifiedMode* got = nullptr;
      for (std::size_t q = 0; q < r.modes.size(); ++q) {
        const double d = std::abs(r.modes[q].selected.f_hz - truth.f_hz);
        if (d <= tol && (!got || d < std::abs(got->selected.f_hz - truth.f_hz))) {
          got = &r.modes[q];
          matched[q] = true;
        }
      }
      std::string why;
      if (resolvable(t, i, why)) {
        ++resolvable_modes;
        resolvable_found += got != nullptr;
        if (!got) std::printf("[property] trial %d: resolvable mode %.2f Hz zeta %.3g not found\n", trial, truth.f_hz, truth.zeta);
      } else {
        ++unresolvable;
      }
      if (!got) continue;
      ++found_modes;
      const DampingEstimate& e = got->ml;
      if (e.status != EstimateStatus::ok) continue;
      // (b) an ok number is right.
      ++ok_modes;
      const double z = true_zeta(truth);
      const double half = 0.5 * (e.zeta_ci95_hi - e.zeta_ci95_lo);
      EXPECT_NEAR(e.zeta, z, 3.0 * half + 0.01 * z) << truth.f_hz << " Hz: ok zeta " << e.zeta << " truth " << z;
      EXPECT_NEAR(e.f_hz, truth.f_hz, 5.0 * e.f_sd_hz + 1e-4 * truth.f_hz) << truth.f_hz << " Hz";
      const bool cov = e.zeta_ci95_lo <= z && z <= e.zeta_ci95_hi;
      covered += cov;
      if (e.zeta_sd >= 0.005 * e.zeta) {
        ++ok_stat;
        covered_stat += cov;
      }
      if (!cov && std::getenv("RIDGEWATCH_MODES_VERBOSE"))
        std::printf("[property] trial %d: %.2f Hz zeta %.3g truth %.3g sd %.2g (%.1f sd) eta0 %.0f %s\n", trial, truth.f_hz, e.zeta, z,
                    e.zeta_sd, (e.zeta - z) / e.zeta_sd, got->eta0, got->note.c_str());
    }
    // (e) every ok mode is a true mode.
    for (std::size_t q = 0; q < r.modes.size(); ++q) {
      if (r.modes[q].ml.status == EstimateStatus::ok) {
        EXPECT_TRUE(matched[q]) << "ok on no mode: " << r.modes[q].selected.f_hz;
      }
    }
  }
  std::printf("[property] %d trials: %d/%d resolvable modes found (%d further modes not resolvable), "
              "%d found in all, %d ok, CI95 covers %d/%d (%d/%d where zeta_sd >= 0.5 %%)\n",
              trials, resolvable_found, resolvable_modes, unresolvable, found_modes, ok_modes, covered, ok_modes, covered_stat, ok_stat);
  // (a) as a rate: measured 101 of 105 over 40 trials; every miss is one member of a pair 1-2 % apart
  // (README). 95 % with the default trials (at least ~60 resolvable modes) fails on 3 misses more.
  EXPECT_GE(static_cast<double>(resolvable_found), 0.95 * resolvable_modes);
  ASSERT_GT(ok_modes, trials);  // the test must look at many ok estimates (about 2 per trial)
  // (c) interval coverage near nominal, where the interval is statistics-limited. Below a relative
  // zeta_sd of 0.5 % a deterministic bias of up to ~1 % (strong out-of-band tails, the residual terms)
  // is larger than the interval: (b)'s 1 % allowance covers it, the interval does not (README).
  ASSERT_GT(ok_stat, trials / 2);
  EXPECT_GE(static_cast<double>(covered_stat), 0.85 * ok_stat);
}
