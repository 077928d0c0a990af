// Independent test-signal generator: closed-form free decays, impact trains with rig nuisances, and a
// WAV writer of its own. It shares no code with core/model (the gear-pair simulator) or drivers/, so
// acceptance tests built on it do not only prove that ridgewatch agrees with itself.
//
// Conventions (deliberately different from core/model): a mode is written as
//   x(t) = A(t) · sin(φ(t)),  φ(t) = φ0 + 2π ∫ f(A(τ)) dτ,   t ≥ 0 from the impact,
// with the envelope following the averaged (first-order harmonic-balance) equation
//   dA/dt = −a·A − b − c·A²,   a = ζ·2π·f   (viscous),  b ≥ 0 (dry friction),  c ≥ 0 (quadratic),
// solved in closed form (one of b, c non-zero at a time). The equivalent viscous damping ratio at
// amplitude A is then ζ_eq(A) = (a + b/A + c·A) / (2π f): dry friction raises it as A falls,
// quadratic damping lowers it. The frequency may depend on amplitude, f(A) = f0·(1 + κ·A²)
// (κ > 0 hardening, κ < 0 softening); the phase is then integrated sample by sample.
//
// Everything is seeded and reproducible on one platform (std::mt19937_64 and our own Box–Muller).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace indep {

inline constexpr double kTwoPi = 6.283185307179586476925286766559;

/// Gaussian and uniform numbers from a seeded 64-bit Mersenne Twister (Box–Muller, our own, so the
/// sequence does not depend on the standard library's distribution implementations).
class Rng {
 public:
  explicit Rng(std::uint64_t seed) : engine_(seed) {}
  double uniform() { return (static_cast<double>(engine_() >> 11) + 0.5) * 0x1.0p-53; }  // (0, 1)
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  double gauss() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double r = std::sqrt(-2.0 * std::log(uniform()));
    const double phi = kTwoPi * uniform();
    spare_ = r * std::sin(phi);
    has_spare_ = true;
    return r * std::cos(phi);
  }

 private:
  std::mt19937_64 engine_;
  double spare_ = 0.0;
  bool has_spare_ = false;
};

/// One free-decay mode. Units: f_hz in Hz, amplitude in signal units, coulomb in signal units per
/// second, quadratic in 1/(signal unit · s), hardening κ in 1/(signal unit)².
struct Mode {
  double f_hz = 854.0;
  double zeta = 0.024;           ///< viscous part, 0 ≤ ζ < 1
  double amplitude = 1.0;        ///< A(0)
  double phase_rad = 0.0;        ///< φ0
  double coulomb = 0.0;          ///< b of dA/dt = −aA − b − cA²
  double quadratic = 0.0;        ///< c of dA/dt = −aA − b − cA²
  double hardening = 0.0;        ///< κ of f(A) = f0 (1 + κ A²)

  double a_per_s() const { return zeta * kTwoPi * f_hz; }

  /// Closed-form envelope A(t), t ≥ 0 (0 once a dry-friction decay has stopped).
  double envelope(double t_s) const {
    const double a = a_per_s();
    const double A0 = amplitude;
    if (coulomb > 0.0 && quadratic > 0.0) throw std::invalid_argument("indep::Mode: coulomb and quadratic together");
    if (coulomb > 0.0) {
      // A(t) = (A0 + b/a) e^{−at} − b/a; with a = 0 the linear A0 − b t.
      const double A = a > 0.0 ? (A0 + coulomb / a) * std::exp(-a * t_s) - coulomb / a : A0 - coulomb * t_s;
      return std::max(A, 0.0);
    }
    if (quadratic > 0.0) {
      // Riccati with b = 0: A(t) = a A0 e^{−at} / (a + c A0 (1 − e^{−at})); a = 0: A0 / (1 + c A0 t).
      if (a <= 0.0) return A0 / (1.0 + quadratic * A0 * t_s);
      const double e = std::exp(-a * t_s);
      return a * A0 * e / (a + quadratic * A0 * (1.0 - e));
    }
    return A0 * std::exp(-a * t_s);
  }

  /// Equivalent viscous damping ratio at envelope amplitude A (the backbone truth).
  double zeta_at(double A) const {
    const double f = f_at(A);
    return (a_per_s() + (A > 0.0 ? coulomb / A : 0.0) + quadratic * A) / (kTwoPi * f);
  }
  double f_at(double A) const { return f_hz * (1.0 + hardening * A * A); }
};

/// Adds the free decay of `m`, starting at fractional time `onset_s`, to x (sampled at fs_hz),
/// up to `max_len_s` after the onset (the whole record when ≤ 0).
inline void add_decay(std::vector<double>& x, double fs_hz, double onset_s, const Mode& m, double max_len_s = 0.0) {
  const double dt = 1.0 / fs_hz;
  std::size_t first = static_cast<std::size_t>(std::ceil(onset_s * fs_hz));
  if (first >= x.size()) return;
  std::size_t last = x.size();
  if (max_len_s > 0.0) last = std::min(last, first + static_cast<std::size_t>(max_len_s * fs_hz));
  const bool chirp = m.hardening != 0.0;
  double phase = m.phase_rad;
  double t_prev = 0.0;
  for (std::size_t n = first; n < last; ++n) {
    const double t = static_cast<double>(n) * dt - onset_s;
    const double A = m.envelope(t);
    if (chirp) {
      // Trapezoid on f(A(t)) from the previous sample (the first step starts at the onset itself).
      const double f_prev = m.f_at(m.envelope(t_prev));
      phase += kTwoPi * 0.5 * (f_prev + m.f_at(A)) * (t - t_prev);
      t_prev = t;
    } else {
      phase = m.phase_rad + kTwoPi * m.f_hz * t;
    }
    if (A <= 0.0 && m.coulomb > 0.0) break;
    x[n] += A * std::sin(phase);
  }
}

/// A record of repeated impacts on a rotating machine with the usual nuisances. Shaft speed may ramp
/// and wobble; impacts fall once per revolution at a fixed shaft angle (plus onset jitter); mesh
/// lines are phase-locked to the shaft angle (teeth · revolutions), so a speed ramp sweeps them.
struct RigSpec {
  double fs_hz = 51200.0;
  double duration_s = 10.0;
  double rev_hz = 25.0;              ///< shaft speed at t = 0, revolutions per second (impact rate)
  double ramp_rel = 0.0;             ///< speed changes linearly by this fraction over the record
  double wobble_rel = 0.0;           ///< sinusoidal speed variation, fraction of rev_hz
  double wobble_period_s = 2.0;
  int teeth = 22;                    ///< mesh frequency = teeth · shaft speed
  std::vector<double> mesh_amp;      ///< amplitude of mesh harmonic k = 1, 2, … (0 = none)
  double hum_hz = 50.0;
  std::vector<double> hum_amp;       ///< amplitude of hum harmonic k = 1, 2, …
  double noise_sd = 0.0;             ///< white Gaussian noise, signal units
  double spike_rate_hz = 0.0;        ///< isolated one-sample spikes per second (Poisson)
  double spike_amp = 0.0;            ///< spike height (random sign), signal units
  Mode response;                     ///< the mode every impact excites (amplitude = mean impact size)
  std::vector<Mode> extra_modes;     ///< further modes excited by each impact (amplitudes scale alike)
  double amp_jitter_rel = 0.1;       ///< impact size varies by this fraction (uniform ±)
  double onset_jitter_s = 0.0;       ///< uniform ± jitter of each impact time
  double first_impact_s = 0.02;      ///< time of the first impact
  std::uint64_t seed = 1;
};

struct RigRecord {
  std::vector<double> x;                 ///< samples, signal units
  std::vector<double> onset_s;           ///< true impact times (start of each free decay)
  std::vector<double> zeta;              ///< true viscous ζ of each impact's response mode
  std::vector<double> f_hz;              ///< true frequency of each impact's response mode
  std::vector<std::size_t> spike_index;  ///< samples that carry a spike
  double fs_hz = 0.0;
};

inline RigRecord make_rig_record(const RigSpec& s) {
  Rng rng(s.seed);
  RigRecord r;
  r.fs_hz = s.fs_hz;
  const std::size_t n = static_cast<std::size_t>(s.duration_s * s.fs_hz);
  r.x.assign(n, 0.0);
  const double dt = 1.0 / s.fs_hz;
  // Shaft angle in revolutions, integrated sample by sample from the speed law.
  std::vector<double> rev(n);
  double angle = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) * dt;
    rev[i] = angle;
    const double speed = s.rev_hz * (1.0 + s.ramp_rel * t / s.duration_s +
                                     s.wobble_rel * std::sin(kTwoPi * t / s.wobble_period_s));
    angle += speed * dt;
  }
  // Mesh and hum lines.
  std::vector<double> mesh_phase(s.mesh_amp.size()), hum_phase(s.hum_amp.size());
  for (double& p : mesh_phase) p = rng.uniform(0.0, kTwoPi);
  for (double& p : hum_phase) p = rng.uniform(0.0, kTwoPi);
  for (std::size_t i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) * dt;
    double v = 0.0;
    for (std::size_t k = 0; k < s.mesh_amp.size(); ++k)
      v += s.mesh_amp[k] * std::sin(kTwoPi * static_cast<double>((k + 1) * s.teeth) * rev[i] + mesh_phase[k]);
    for (std::size_t k = 0; k < s.hum_amp.size(); ++k)
      v += s.hum_amp[k] * std::sin(kTwoPi * static_cast<double>(k + 1) * s.hum_hz * t + hum_phase[k]);
    r.x[i] = v;
  }
  // Impacts: the shaft angle at the first impact, then every whole revolution after it.
  const double angle0 = s.first_impact_s * s.rev_hz;
  double next = angle0;
  for (std::size_t i = 1; i < n; ++i) {
    if (rev[i] < next) continue;
    // Linear interpolation of the crossing between samples i−1 and i.
    const double frac = (next - rev[i - 1]) / (rev[i] - rev[i - 1]);
    double t0 = (static_cast<double>(i - 1) + frac) * dt;
    if (s.onset_jitter_s > 0.0) t0 += rng.uniform(-s.onset_jitter_s, s.onset_jitter_s);
    next += 1.0;
    if (t0 <= 0.0) continue;
    const double size = 1.0 + (s.amp_jitter_rel > 0.0 ? rng.uniform(-s.amp_jitter_rel, s.amp_jitter_rel) : 0.0);
    Mode m = s.response;
    m.amplitude *= size;
    add_decay(r.x, s.fs_hz, t0, m);
    for (Mode e : s.extra_modes) {
      e.amplitude *= size;
      add_decay(r.x, s.fs_hz, t0, e);
    }
    r.onset_s.push_back(t0);
    r.zeta.push_back(m.zeta);
    r.f_hz.push_back(m.f_hz);
  }
  if (s.noise_sd > 0.0)
    for (double& v : r.x) v += s.noise_sd * rng.gauss();
  if (s.spike_rate_hz > 0.0) {
    double t = 0.0;
    for (;;) {
      t += -std::log(rng.uniform()) / s.spike_rate_hz;
      const auto i = static_cast<std::size_t>(t * s.fs_hz);
      if (i >= n) break;
      r.x[i] += (rng.uniform() < 0.5 ? -1.0 : 1.0) * s.spike_amp;
      r.spike_index.push_back(i);
    }
  }
  return r;
}

/// Repeats a record `count` times with `gap_s` of zeros (plus optional noise) between copies.
inline std::vector<double> repeat_with_gaps(const std::vector<double>& x, double fs_hz, int count, double gap_s,
                                            double gap_noise_sd = 0.0, std::uint64_t seed = 1) {
  Rng rng(seed);
  std::vector<double> out;
  const auto gap = static_cast<std::size_t>(gap_s * fs_hz);
  for (int c = 0; c < count; ++c) {
    out.insert(out.end(), x.begin(), x.end());
    for (std::size_t i = 0; i < gap; ++i) out.push_back(gap_noise_sd > 0.0 ? gap_noise_sd * rng.gauss() : 0.0);
  }
  return out;
}

enum class SampleFormat { pcm16, pcm24, float32 };

/// Writes interleaved frames (`channels` values per frame) as a canonical RIFF/WAVE file: integer
/// PCM scaled so that ±full_scale maps to the format's full range (values beyond are clipped, as a
/// sound card would), or IEEE float32 unscaled (physical units). Throws std::runtime_error on I/O.
inline void write_wav(const std::string& path, const std::vector<double>& interleaved, double fs_hz, int channels,
                      SampleFormat format, double full_scale = 1.0) {
  const int bytes = format == SampleFormat::pcm16 ? 2 : format == SampleFormat::pcm24 ? 3 : 4;
  const std::uint32_t data_bytes = static_cast<std::uint32_t>(interleaved.size() * static_cast<std::size_t>(bytes));
  const bool is_float = format == SampleFormat::float32;
  // A float WAV carries a fact chunk (frame count), as the format requires for non-PCM data.
  const std::uint32_t fact_bytes = is_float ? 12u : 0u;
  std::vector<unsigned char> out;
  out.reserve(44u + fact_bytes + data_bytes);
  auto u16 = [&](unsigned v) { out.push_back(static_cast<unsigned char>(v & 0xff)); out.push_back(static_cast<unsigned char>((v >> 8) & 0xff)); };
  auto u32 = [&](std::uint32_t v) { for (int k = 0; k < 4; ++k) out.push_back(static_cast<unsigned char>((v >> (8 * k)) & 0xff)); };
  // A chunk id, byte by byte (a 4-byte range insert here made GCC 12 at -O2 report a false
  // -Wstringop-overflow in every translation unit that included this header).
  auto tag = [&](const char (&t)[5]) { for (int k = 0; k < 4; ++k) out.push_back(static_cast<unsigned char>(t[k])); };
  const auto rate = static_cast<std::uint32_t>(std::lround(fs_hz));
  tag("RIFF");
  u32(4 + 24 + fact_bytes + 8 + data_bytes);
  tag("WAVE");
  tag("fmt ");
  u32(16);
  u16(is_float ? 3u : 1u);
  u16(static_cast<unsigned>(channels));
  u32(rate);
  u32(rate * static_cast<std::uint32_t>(channels * bytes));
  u16(static_cast<unsigned>(channels * bytes));
  u16(static_cast<unsigned>(8 * bytes));
  if (is_float) {
    tag("fact");
    u32(4);
    u32(static_cast<std::uint32_t>(interleaved.size() / static_cast<std::size_t>(channels)));
  }
  tag("data");
  u32(data_bytes);
  for (double v : interleaved) {
    if (is_float) {
      const float f = static_cast<float>(v);
      std::uint32_t b;
      static_assert(sizeof b == sizeof f);
      std::memcpy(&b, &f, sizeof b);
      u32(b);
      continue;
    }
    const double max_code = format == SampleFormat::pcm16 ? 32767.0 : 8388607.0;
    const double code = std::clamp(std::round(v / full_scale * max_code), -max_code - 1.0, max_code);
    const auto c = static_cast<std::int32_t>(code);
    const auto uc = static_cast<std::uint32_t>(c);
    out.push_back(static_cast<unsigned char>(uc & 0xff));
    out.push_back(static_cast<unsigned char>((uc >> 8) & 0xff));
    if (bytes == 3) out.push_back(static_cast<unsigned char>((uc >> 16) & 0xff));
  }
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) throw std::runtime_error("indep::write_wav: cannot open " + path);
  const bool ok = std::fwrite(out.data(), 1, out.size(), f) == out.size();
  if (std::fclose(f) != 0 || !ok) throw std::runtime_error("indep::write_wav: cannot write " + path);
}

/// Mono convenience overload.
inline void write_wav_mono(const std::string& path, const std::vector<double>& x, double fs_hz, SampleFormat format,
                           double full_scale = 1.0) {
  write_wav(path, x, fs_hz, 1, format, full_scale);
}

}  // namespace indep
