// An independent gear-rig record generator for diagnose/compare acceptance (issue 14). It shares no
// code with core/model or core/diagnosis: its own state (total mesh deflection q, not the dynamic
// deflection), its own integrator (adaptive Dormand–Prince 5(4) with step rejection, no event
// location: kinks are resolved by step-size control), its own impact pulse (a Hann pulse sin²(πt/τ)
// with the impulse of the rig's half-sine, not a half-sine), dry friction as a steep tanh instead of
// exact stick/slip, its own random numbers and its own noise convention (1 % of the largest clean
// sample, not of an RMS). One hidden effect per record; several are outside ridgewatch's catalogue.
//
// Physics (paper Eq. A1 on the line of action, q = total mesh deflection):
//   m q̈ = W + F_imp(t) - F_mesh(q, q̇, θ, t) - F_extra(q, q̇) ,   W = M1 / r_b1 ,
//   F_mesh = k(θ, t) q + d q̇ for the linear mesh (k = c0 at rest, d = 2 ζ sqrt(c0 m)),
//   sensor = s · (q̇ + ṗ)  (velocity, as the paper's vibrometer); p a second mode if present.
// Header-only, test support; plain C++20 and the standard library.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <string>
#include <vector>

namespace ridgewatch::testsupport::indep {

enum class Hidden {
  kNone,
  kCoulomb,            ///< dry friction of `size` N (tanh(v / 1e-6 m/s) regularisation)
  kQuadraticDamping,   ///< size N s²/m² on q̇|q̇|
  kSecondMode,         ///< second mode: f2 = size Hz (ζ2 = size2, participation = size3)
  kHardening,          ///< cubic stiffness on the dynamic deflection: κ = size at x_ref = 2 µm
  kMeshVariationNoLines,  ///< paper's c1..c3 × size acting on the dynamic deflection only (no static-load lines)
  kMeshVariation,      ///< paper's c1..c3 × size on the whole deflection (lines at k f_z under load)
  kContactLoss,        ///< no mesh force while q < 0 (light load; size ignored)
  kDampingDrift,       ///< ζ(t) = ζ + size · t
  kCubicDamping,       ///< out of catalogue: size N s³/m³ on q̇³
  kDeadZone,           ///< out of catalogue: the restoring force ignores |x| < size m (x = q - q_s)
  kFrequencyDrift,     ///< out of catalogue: c0(t) = c0 (1 + size · t) (temperature)
  kTransmissionError,  ///< displacement excitation e(θ) = size sin(θ + φ) + size2 sin(2(θ + φ)) m, φ = 0.4 rad
  kDampingStep,        ///< ζ + size from record time size2 s on (a step; step-size control finds it)
};

struct Settings {
  Hidden hidden = Hidden::kNone;
  double size = 0.0, size2 = 0.0, size3 = 0.0;
  double sample_rate_hz = 51200.0;
  double duration_s = 1.0;
  double noise_rel = 0.01;        ///< noise sd / largest |clean sample|
  double load_torque_n_m = 200.0; ///< 20 for the light-load (contact-loss) rig
  std::uint64_t seed = 1;
  bool half_sine_pulse = false;   ///< the rig's half-sine pulse instead of the Hann pulse (diagnostics)
};

struct Record {
  std::vector<double> y;
  std::vector<double> impact_times_s;
};

namespace detail {

struct Gear {
  // The paper's rig (Appendix B): J1, J2, base radii, c0, ζ, 22 pinion teeth, 1500 rpm.
  double m = 0.0, c0 = 8.04e8, zeta = 0.024, d = 0.0, w_load = 0.0, qs = 0.0;
  double mesh_hz = 22.0 * 25.0, rev_s = 1.0 / 25.0;
  double pulse_s = 1.5e-4, pulse_peak = 0.0;  // Hann peak with the half-sine's impulse
  double crack_angle = 1.0;                   // pinion angle of the impact after angle 0
  double sensitivity = 50.0;
  Gear(double load) {
    const double J1 = 0.093, J2 = 0.272, r1 = 0.03046, r2 = 0.08466;
    m = 1.0 / (r1 * r1 / J1 + r2 * r2 / J2);  // the same reduced mass as J1 J2 / (J1 r2² + J2 r1²)
    d = 2.0 * zeta * std::sqrt(c0 * m);
    w_load = load / r1;
    qs = w_load / c0;
    // Half-sine of peak 2000 N over τ has impulse 2 F τ / π; a Hann pulse of peak P has P τ / 2.
    pulse_peak = 4.0 / std::numbers::pi * 2000.0;
  }
};

}  // namespace detail

/// Generates one record: the clean response from rest at static equilibrium, 0.1 s lead-in dropped,
/// then noise. Impacts once per revolution with 10 % (Gaussian) amplitude jitter.
inline Record generate(const Settings& st) {
  using detail::Gear;
  const Gear g(st.load_torque_n_m);
  const double two_pi = 2.0 * std::numbers::pi;
  std::mt19937_64 rng(st.seed * 0x9E3779B97F4A7C15ull + 12345u);
  std::normal_distribution<double> normal(0.0, 1.0);
  const double lead = 0.1;
  const double t_total = lead + st.duration_s;
  // Impact times and amplitudes.
  std::vector<double> imp_t, imp_a;
  for (double t = g.crack_angle / two_pi * g.rev_s; t < t_total; t += g.rev_s) {
    imp_t.push_back(t);
    imp_a.push_back(std::max(0.2, 1.0 + 0.1 * normal(rng)));
  }
  // Paper's Eq. B1 terms (c_k, γ_k).
  const double ck[3] = {0.304e8, 0.185e8, 0.050e8}, gk[3] = {1.02, -0.72, -0.93};
  const double w2 = two_pi * (st.hidden == Hidden::kSecondMode ? st.size : 1.0);
  const double xref = 2e-6;

  auto pulse = [&](double t) {
    // Impacts are 40 ms apart and last 0.15 ms: at most one is active.
    const double rev = std::floor((t - imp_t[0]) / g.rev_s + 0.5);
    if (rev < 0 || rev >= static_cast<double>(imp_t.size())) return 0.0;
    const double u = (t - imp_t[static_cast<std::size_t>(rev)]) / g.pulse_s;
    if (u < 0.0 || u > 1.0) return 0.0;
    const double s = std::sin(std::numbers::pi * u);
    if (st.half_sine_pulse) return 2000.0 * imp_a[static_cast<std::size_t>(rev)] * s;
    return g.pulse_peak * imp_a[static_cast<std::size_t>(rev)] * s * s;
  };
  // Mesh angle θ = z1 × pinion angle = 2π f_z t (constant speed).
  auto rhs = [&](double t, const double* s, double* ds) {
    const double q = s[0], v = s[1];
    const double x = q - g.qs;
    const double th = two_pi * g.mesh_hz * t;
    double k = g.c0, zeta = g.zeta;
    double f_mesh = 0.0, f_extra = 0.0;
    switch (st.hidden) {
      case Hidden::kMeshVariation:
      case Hidden::kMeshVariationNoLines: {
        double dk = 0.0;
        for (int j = 0; j < 3; ++j) dk += st.size * ck[j] * std::cos((j + 1) * th + gk[j]);
        // Without static-load lines the variation acts on the dynamic deflection only (a tooth profile
        // relieved for the nominal load: no static transmission error).
        f_mesh = g.c0 * q + dk * (st.hidden == Hidden::kMeshVariation ? q : x) + g.d * v;
        break;
      }
      case Hidden::kFrequencyDrift:
        k = g.c0 * (1.0 + st.size * t);
        // The static deflection follows the stiffness (equilibrium q_s(t) = W / k(t)).
        f_mesh = k * q + g.d * v;
        break;
      case Hidden::kDampingStep:
        zeta = g.zeta + (t - lead >= st.size2 ? st.size : 0.0);
        f_mesh = k * q + 2.0 * zeta * std::sqrt(g.c0 * g.m) * v;
        break;
      case Hidden::kDampingDrift:
        zeta = g.zeta + st.size * t;
        f_mesh = k * q + 2.0 * zeta * std::sqrt(g.c0 * g.m) * v;
        break;
      case Hidden::kContactLoss:
        f_mesh = q > 0.0 ? k * q + g.d * v : 0.0;
        break;
      case Hidden::kTransmissionError: {
        // The mesh spring and damper act on the deflection relative to the unloaded transmission
        // error e(θ) (lines at k f_z whether or not an impact rings); own phase offset φ = 0.4 rad.
        constexpr double phi = 0.4;
        const double e = st.size * std::sin(th + phi) + st.size2 * std::sin(2.0 * (th + phi));
        const double de = two_pi * g.mesh_hz * (st.size * std::cos(th + phi) + 2.0 * st.size2 * std::cos(2.0 * (th + phi)));
        f_mesh = k * (q - e) + g.d * (v - de);
        break;
      }
      case Hidden::kDeadZone: {
        const double xd = std::abs(x) > st.size ? x - std::copysign(st.size, x) : 0.0;
        f_mesh = g.w_load + g.c0 * xd + g.d * v;
        break;
      }
      default: f_mesh = k * q + g.d * v;
    }
    switch (st.hidden) {
      case Hidden::kCoulomb: f_extra = st.size * std::tanh(v / 1e-6); break;
      case Hidden::kQuadraticDamping: f_extra = st.size * v * std::abs(v); break;
      case Hidden::kCubicDamping: f_extra = st.size * v * v * v; break;
      case Hidden::kHardening: f_extra = st.size * g.c0 / (xref * xref) * x * x * x; break;
      default: break;
    }
    const double fi = pulse(t);
    ds[0] = v;
    ds[1] = (g.w_load + fi - f_mesh - f_extra) / g.m;
    // Second mode (modal coordinate p, mass-normalised like the gear mode).
    ds[2] = s[3];
    ds[3] = st.hidden == Hidden::kSecondMode
                ? st.size3 * fi / g.m - 2.0 * st.size2 * w2 * s[3] - w2 * w2 * s[2]
                : 0.0;
  };

  // Dormand–Prince 5(4) coefficients.
  static constexpr double c2 = 1.0 / 5, c3 = 3.0 / 10, c4 = 4.0 / 5, c5 = 8.0 / 9;
  static constexpr double a21 = 1.0 / 5;
  static constexpr double a31 = 3.0 / 40, a32 = 9.0 / 40;
  static constexpr double a41 = 44.0 / 45, a42 = -56.0 / 15, a43 = 32.0 / 9;
  static constexpr double a51 = 19372.0 / 6561, a52 = -25360.0 / 2187, a53 = 64448.0 / 6561, a54 = -212.0 / 729;
  static constexpr double a61 = 9017.0 / 3168, a62 = -355.0 / 33, a63 = 46732.0 / 5247, a64 = 49.0 / 176,
                          a65 = -5103.0 / 18656;
  static constexpr double b1 = 35.0 / 384, b3 = 500.0 / 1113, b4 = 125.0 / 192, b5 = -2187.0 / 6784, b6 = 11.0 / 84;
  static constexpr double e1 = 71.0 / 57600, e3 = -71.0 / 16695, e4 = 71.0 / 1920, e5 = -17253.0 / 339200,
                          e6 = 22.0 / 525, e7 = -1.0 / 40;
  // Error scales: 1e-9 of the typical deflection (1 µm) and velocity (6 mm/s) per unit, absolute.
  const double scale[4] = {1e-15, 1e-11, 1e-15, 1e-11};

  double s[4] = {g.qs, 0.0, 0.0, 0.0};
  double t = 0.0;
  double h = 1e-6;
  const double fs = st.sample_rate_hz;
  const auto n_total = static_cast<std::size_t>(t_total * fs);
  const auto n_lead = static_cast<std::size_t>(lead * fs);
  std::vector<double> clean;
  clean.reserve(n_total - n_lead);
  double k1[4], k2[4], k3[4], k4[4], k5[4], k6[4], k7[4], tmp[4], y5[4];
  rhs(t, s, k1);
  for (std::size_t i = 0; i < n_total; ++i) {
    const double t_target = static_cast<double>(i) / fs;
    while (t < t_target - 1e-15) {
      // Steps never cross a pulse edge (the pulse and its derivative switch there).
      double hh = std::min(h, t_target - t);
      const double rev = std::floor((t - imp_t[0]) / g.rev_s + 0.5);
      if (rev >= 0 && rev < static_cast<double>(imp_t.size())) {
        const double on = imp_t[static_cast<std::size_t>(rev)], off = on + g.pulse_s;
        if (t < on - 1e-15 && t + hh > on) hh = on - t;
        else if (t < off - 1e-15 && t + hh > off) hh = off - t;
      }
      for (int j = 0; j < 4; ++j) tmp[j] = s[j] + hh * a21 * k1[j];
      rhs(t + c2 * hh, tmp, k2);
      for (int j = 0; j < 4; ++j) tmp[j] = s[j] + hh * (a31 * k1[j] + a32 * k2[j]);
      rhs(t + c3 * hh, tmp, k3);
      for (int j = 0; j < 4; ++j) tmp[j] = s[j] + hh * (a41 * k1[j] + a42 * k2[j] + a43 * k3[j]);
      rhs(t + c4 * hh, tmp, k4);
      for (int j = 0; j < 4; ++j) tmp[j] = s[j] + hh * (a51 * k1[j] + a52 * k2[j] + a53 * k3[j] + a54 * k4[j]);
      rhs(t + c5 * hh, tmp, k5);
      for (int j = 0; j < 4; ++j)
        tmp[j] = s[j] + hh * (a61 * k1[j] + a62 * k2[j] + a63 * k3[j] + a64 * k4[j] + a65 * k5[j]);
      rhs(t + hh, tmp, k6);
      for (int j = 0; j < 4; ++j) y5[j] = s[j] + hh * (b1 * k1[j] + b3 * k3[j] + b4 * k4[j] + b5 * k5[j] + b6 * k6[j]);
      rhs(t + hh, y5, k7);
      double err = 0.0;
      for (int j = 0; j < 4; ++j) {
        const double e = hh * (e1 * k1[j] + e3 * k3[j] + e4 * k4[j] + e5 * k5[j] + e6 * k6[j] + e7 * k7[j]);
        err = std::max(err, std::abs(e) / scale[j]);
      }
      if (err <= 1.0 || hh < 1e-10) {
        t += hh;
        for (int j = 0; j < 4; ++j) {
          s[j] = y5[j];
          k1[j] = k7[j];  // first-same-as-last
        }
      }
      const double factor = err > 0.0 ? 0.9 * std::pow(err, -0.2) : 5.0;
      h = std::clamp(hh * std::clamp(factor, 0.2, 5.0), 1e-10, 2e-5);
    }
    if (i >= n_lead) clean.push_back(g.sensitivity * (s[1] + s[3]));
  }
  double peak = 0.0;
  for (double v : clean) peak = std::max(peak, std::abs(v));
  Record r;
  r.y.resize(clean.size());
  for (std::size_t i = 0; i < clean.size(); ++i) r.y[i] = clean[i] + st.noise_rel * peak * normal(rng);
  for (double ti : imp_t)
    if (ti >= lead) r.impact_times_s.push_back(ti - lead);
  return r;
}

/// The tests' short record: 16 impacts (0.64 s at 1500 rpm) at 25.6 kHz, 1 % noise.
inline Settings short_test_record(Hidden h, double size, std::uint64_t seed) {
  Settings s;
  s.hidden = h;
  s.size = size;
  s.sample_rate_hz = 25600.0;
  s.duration_s = 0.64;
  s.noise_rel = 0.01;
  s.seed = seed;
  return s;
}

/// A named sweep case at the sizes of the README's diagnose sweep (and out-of-catalogue effects).
struct Case {
  std::string name;         ///< the hidden effect's catalogue name, "none", or an out-of-catalogue label
  Settings settings;
  bool in_catalogue = true;
};

inline std::vector<Case> sweep_cases() {
  auto mk = [](std::string n, Hidden h, double a, double b = 0.0, double c = 0.0, double load = 200.0, bool cat = true) {
    Case k;
    k.name = std::move(n);
    k.settings.hidden = h;
    k.settings.size = a;
    k.settings.size2 = b;
    k.settings.size3 = c;
    k.settings.load_torque_n_m = load;
    k.in_catalogue = cat;
    return k;
  };
  return {
      mk("none", Hidden::kNone, 0.0),
      mk("coulomb_friction", Hidden::kCoulomb, 30.0),
      mk("quadratic_damping", Hidden::kQuadraticDamping, 2e6),
      mk("second_mode", Hidden::kSecondMode, 1300.0, 0.015, 0.3),
      mk("stiffness_nonlinearity", Hidden::kHardening, 0.5),
      mk("mesh_stiffness_variation", Hidden::kMeshVariationNoLines, 1.5),
      mk("mesh_stiffness_variation+lines", Hidden::kMeshVariation, 1.5),
      mk("contact_loss", Hidden::kContactLoss, 1.0, 0.0, 0.0, 20.0),
      mk("damping_drift", Hidden::kDampingDrift, 0.008),
      // ζ 0.024 -> 0.032 at 0.32 s (the middle of a 0.64 s record): right only as damping_drift with a
      // step between the two fitted impacts around 0.32 s.
      mk("damping_step", Hidden::kDampingStep, 0.008, 0.32),
      mk("transmission_error", Hidden::kTransmissionError, 0.3e-6, 0.1e-6),
      // Out of catalogue. Cubic damping: ζ_eq(A) grows with A², 2e9 N s³/m³ doubles the damping
      // force at 6 mm/s. Dead zone of 0.1 µm (10 % of the typical 1 µm response). f0 drift 0.4 %/s.
      mk("cubic_damping", Hidden::kCubicDamping, 2e9, 0.0, 0.0, 200.0, false),
      mk("dead_zone", Hidden::kDeadZone, 1e-7, 0.0, 0.0, 200.0, false),
      mk("frequency_drift", Hidden::kFrequencyDrift, 0.004, 0.0, 0.0, 200.0, false),
  };
}

}  // namespace ridgewatch::testsupport::indep
