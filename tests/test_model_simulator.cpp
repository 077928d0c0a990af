// Gear-pair simulator against analytic solutions of Eq. A2, energy balance, impacts, determinism,
// and the null value of every catalogue effect.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <stdexcept>

#include "core/model/effect_registry.hpp"
#include "core/model/simulator.hpp"

namespace rm = ridgewatch::model;

namespace {

constexpr double kPi = std::numbers::pi;

/// Free response of Eq. A2 with constant c0 and ζ from x(0) = 0, q̇(0) = v0: velocity.
double analytic_velocity(const rm::RigParameters& rig, double v0, double t_s) {
  const double w0 = rig.natural_angular_frequency_rad_per_s();
  const double z = rig.damping_ratio;
  const double wd = w0 * std::sqrt(1 - z * z);
  return v0 * std::exp(-z * w0 * t_s) * (std::cos(wd * t_s) - z / std::sqrt(1 - z * z) * std::sin(wd * t_s));
}

rm::SimulationSettings free_decay(double duration_s, double v0) {
  rm::SimulationSettings s;
  s.duration_s = duration_s;
  s.impacts = false;
  s.initial_velocity_m_per_s = v0;
  return s;
}

double max_abs_error_vs_analytic(const rm::RigParameters& rig, const rm::SimulationResult& r, double v0) {
  double err = 0.0;
  for (std::size_t i = 0; i < r.output.size(); ++i) {
    const double t = static_cast<double>(i) / r.sample_rate_hz;
    err = std::max(err, std::abs(r.output[i] / rig.sensor_sensitivity - analytic_velocity(rig, v0, t)));
  }
  return err;
}

}  // namespace

TEST(Simulator, ConstantStiffnessIsADampedSinusoid) {
  const rm::RigParameters rig;
  const double v0 = 0.01;
  const auto r = rm::simulate(rig, {}, free_decay(0.1, v0));
  ASSERT_EQ(r.output.size(), 5120u);
  EXPECT_EQ(r.substeps_per_sample, 4);  // 51.2 kHz × 4 = 204.8 kHz >= 200 kHz
  // RK4 local error for the linear oscillator is |z|^5/120 per step with z = ω0 h = 5404/204800 =
  // 0.0264: 1.1e-10 relative; over 20480 steps at most 2.2e-6 relative. Allow 1e-5.
  EXPECT_LT(max_abs_error_vs_analytic(rig, r, v0), 1e-5 * v0);
}

TEST(Simulator, Rk4ErrorShrinksWithTheFourthPowerOfTheStep) {
  const rm::RigParameters rig;
  const double v0 = 0.01;
  auto coarse = free_decay(0.1, v0);
  coarse.min_internal_rate_hz = 51200.0;  // 1 step per sample
  auto fine = free_decay(0.1, v0);
  fine.min_internal_rate_hz = 102400.0;  // 2 steps per sample
  const double e1 = max_abs_error_vs_analytic(rig, rm::simulate(rig, {}, coarse), v0);
  const double e2 = max_abs_error_vs_analytic(rig, rm::simulate(rig, {}, fine), v0);
  // Global error ∝ h^4: halving h divides it by 16; accept 12..20 (higher-order terms at z = 0.1).
  EXPECT_GT(e1 / e2, 12.0);
  EXPECT_LT(e1 / e2, 20.0);
}

TEST(Simulator, EnergyDecaysByTheViscousWork) {
  rm::RigParameters rig;
  const double v0 = 0.01;
  const auto rv = rm::simulate(rig, {}, free_decay(0.05, v0));
  rig.sensor_quantity = rm::SensorQuantity::kDisplacement;
  const auto rx = rm::simulate(rig, {}, free_decay(0.05, v0));
  const double m = rig.reduced_mass_kg(), c = rig.mean_mesh_stiffness_n_per_m;
  const double d = rig.mesh_damping_n_s_per_m();
  const double k = rig.sensor_sensitivity;
  const double dt = 1.0 / rv.sample_rate_hz;
  const double e0 = 0.5 * m * v0 * v0;
  // E(t) + ∫ d q̇² dt = E(0). Trapezoid integral of an oscillation at 2 f_d = 1718 Hz sampled at
  // 51.2 kHz: relative error ~ (2π·1718/51200)^2/12 ≈ 4e-3 per cycle, but it alternates sign and
  // cancels over cycles; measured energy residuals stay below 2e-4 E0, allow 5e-4.
  double work = 0.0;
  for (std::size_t i = 1; i < rv.output.size(); ++i) {
    const double a = rv.output[i - 1] / k, b = rv.output[i] / k;
    work += 0.5 * d * (a * a + b * b) * dt;
    const double v = b, x = rx.output[i] / k;
    const double energy = 0.5 * m * v * v + 0.5 * c * x * x;
    ASSERT_NEAR(energy + work, e0, 5e-4 * e0) << "sample " << i;
  }
  // And the energy really decays: after 0.05 s, E/E0 ≈ exp(-2ζω0 t) = exp(-12.97) = 2.3e-6.
  const double v = rv.output.back() / k, x = rx.output.back() / k;
  EXPECT_LT(0.5 * m * v * v + 0.5 * c * x * x, 1e-5 * e0);
}

TEST(Simulator, ImpactsOncePerRevolutionWithTachoMarks) {
  rm::RigParameters rig;
  rig.impact_jitter_rel = 0.0;
  rm::SimulationSettings s;
  s.duration_s = 1.0;
  const auto r = rm::simulate(rig, {}, s);
  // 25 Hz shaft: marks at 0, 40, 80 ms..., impacts at crack angle 1 rad later (6.366 ms).
  ASSERT_EQ(r.revolution_times_s.size(), 25u);
  ASSERT_EQ(r.impacts.size(), 25u);
  const double offset_s = rig.crack_angle_rad / (2 * kPi * 25.0);
  for (std::size_t k = 0; k < 25; ++k) {
    // Crossings are interpolated linearly inside a 4.9 µs step of an exactly linear angle: 1e-9 s.
    EXPECT_NEAR(r.revolution_times_s[k], 0.04 * static_cast<double>(k), 1e-9);
    EXPECT_NEAR(r.impacts[k].t_s, 0.04 * static_cast<double>(k) + offset_s, 1e-9);
    EXPECT_DOUBLE_EQ(r.impacts[k].peak_force_n, rig.impact_force_n);
  }
  // Tacho high for 0.5 ms after each mark.
  EXPECT_EQ(r.tacho[0], 1.0);
  EXPECT_EQ(r.tacho[25], 1.0);   // 0.488 ms
  EXPECT_EQ(r.tacho[26], 0.0);   // 0.508 ms
  EXPECT_EQ(r.tacho[2050], 1.0); // 40.04 ms
  EXPECT_EQ(r.truth.size(), 100u);
  EXPECT_DOUBLE_EQ(r.truth[10].damping_ratio, 0.024);
  EXPECT_NEAR(r.truth[10].f0_hz, rig.natural_frequency_hz(), 1e-12);
}

TEST(Simulator, ImpactResponseIsTheConvolutionOfThePulse) {
  rm::RigParameters rig;
  rig.impact_jitter_rel = 0.0;
  rm::SimulationSettings s;
  s.duration_s = 0.03;  // one impact at 6.366 ms
  const auto r = rm::simulate(rig, {}, s);
  ASSERT_EQ(r.impacts.size(), 1u);
  const double t0 = r.impacts[0].t_s, tau = rig.impact_duration_s, f = rig.impact_force_n;
  const double m = rig.reduced_mass_kg(), w0 = rig.natural_angular_frequency_rad_per_s(), z = rig.damping_ratio;
  const double wd = w0 * std::sqrt(1 - z * z);
  // q̇(t) = ∫ F(s) ḣ(t - s) ds with h the unit impulse response of Eq. A2; Simpson with 4000 panels
  // (error ~ (τ/4000)^4 × max|(Fḣ)''''| ≪ 1e-9 of the peak).
  auto velocity = [&](double t) {
    const int n = 4000;
    const double end = std::min(t - t0, tau);
    if (end <= 0) return 0.0;
    const double ds = end / n;
    double sum = 0.0;
    for (int i = 0; i <= n; ++i) {
      const double u = i * ds, lag = t - t0 - u;
      const double force = f * std::sin(kPi * u / tau);
      const double hdot = std::exp(-z * w0 * lag) * (std::cos(wd * lag) - z * w0 / wd * std::sin(wd * lag)) / m;
      sum += (i == 0 || i == n ? 1.0 : (i % 2 ? 4.0 : 2.0)) * force * hdot;
    }
    return sum * ds / 3.0;
  };
  double peak = 0.0, err = 0.0;
  for (std::size_t i = 0; i < r.output.size(); ++i) {
    const double t = static_cast<double>(i) / r.sample_rate_hz;
    const double expected = velocity(t);
    peak = std::max(peak, std::abs(expected));
    err = std::max(err, std::abs(r.output[i] / rig.sensor_sensitivity - expected));
  }
  // After the pulse the amplitude is impulse/m × 0.985 (half-sine spectrum at ω0τ = 0.81). The
  // positive maximum falls inside the pulse (t0 + τ/2), so the largest |q̇| is the negative half
  // cycle, T_d/2 later: × exp(-ζ ω0 T_d/2) = 0.928. Sampling (60 samples/cycle) costs < 0.2 %.
  EXPECT_NEAR(peak, 2 * f * tau / kPi / m * 0.985 * std::exp(-z * w0 * kPi / wd), 0.01 * peak);
  // Steps split at the pulse ends, so RK4's h^4 error holds: 1e-5 as in the free decay.
  EXPECT_LT(err, 1e-5 * peak);
}

TEST(Simulator, SameSeedSameOutputOtherSeedDifferent) {
  const rm::RigParameters rig;
  rm::SimulationSettings s;
  s.duration_s = 0.3;
  const std::vector<rm::EffectSpec> effects = {{"noise", {}}, {"spikes", {{"rate_per_s", 20.0}}}};
  const auto a = rm::simulate(rig, effects, s);
  const auto b = rm::simulate(rig, effects, s);
  EXPECT_EQ(a.output, b.output);
  s.seed = 2;
  const auto c = rm::simulate(rig, effects, s);
  EXPECT_NE(a.output, c.output);
  EXPECT_NE(a.impacts[0].peak_force_n, c.impacts[0].peak_force_n);  // jitter follows the seed
}

TEST(Simulator, EveryEffectVanishesAtItsNullValues) {
  rm::RigParameters rig;
  rig.load_torque_n_m = 20.0;  // light load: the impacts exceed the static deflection (contact loss)
  rm::SimulationSettings s;
  s.duration_s = 0.1;
  const auto baseline = rm::simulate(rig, {}, s);
  for (const auto& d : rm::effect_catalogue()) {
    SCOPED_TRACE(d.name);
    bool has_null = false;
    for (const auto& p : d.parameters) {
      has_null = has_null || p.null_value.has_value();
      EXPECT_GE(p.default_value, p.min_value);
      EXPECT_LE(p.default_value, p.max_value);
      EXPECT_FALSE(p.unit.empty());
    }
    EXPECT_TRUE(has_null);
    EXPECT_FALSE(d.explanation.empty());
    EXPECT_FALSE(d.signature.empty());
    const auto r = rm::simulate(rig, {{d.name, rm::null_values(d)}}, s);
    // Located events split steps differently from the baseline, which changes the RK4 truncation
    // error (<= 1.1e-10 relative per step, see ConstantStiffnessIsADampedSinusoid): allow 1e-7.
    double diff = 0.0;
    for (std::size_t i = 0; i < r.output.size(); ++i) diff = std::max(diff, std::abs(r.output[i] - baseline.output[i]));
    EXPECT_LT(diff, 1e-7 * baseline.clean_peak);
    // ... and at its defaults it does change something.
    const auto on = rm::simulate(rig, {{d.name, {}}}, s);
    double change = 0.0;
    for (std::size_t i = 0; i < on.output.size(); ++i) change = std::max(change, std::abs(on.output[i] - baseline.output[i]));
    // damping_drift's default rate changes ζ by only 2e-4 in 0.1 s; it has its own test.
    if (d.name != "damping_drift") {
      EXPECT_GT(change, 1e-3 * baseline.clean_peak);
    }
  }
}

TEST(Simulator, RejectsBadEffectsNamingThem) {
  const rm::RigParameters rig;
  const rm::SimulationSettings s;
  try {
    rm::simulate(rig, {{"coulomb_friction", {{"force_n", -1.0}}}}, s);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("coulomb_friction: force_n"), std::string::npos) << e.what();
  }
  EXPECT_THROW(rm::simulate(rig, {{"no_such_effect", {}}}, s), std::invalid_argument);
  EXPECT_THROW(rm::simulate(rig, {{"noise", {{"sigma", 1.0}}}}, s), std::invalid_argument);
  EXPECT_THROW(rm::simulate(rig, {{"noise", {}}, {"noise", {}}}, s), std::invalid_argument);
}

TEST(EffectSpec, ParsesCommandLineForm) {
  const auto a = rm::parse_effect_spec("coulomb_friction:force_n=20");
  EXPECT_EQ(a.name, "coulomb_friction");
  EXPECT_THROW(rm::parse_effect_spec("x:force_n"), std::invalid_argument);
  const auto b = rm::parse_effect_spec("hum:amplitude_rel=0.1,frequency_hz=60");
  EXPECT_EQ(b.name, "hum");
  EXPECT_DOUBLE_EQ(b.values.at("frequency_hz"), 60.0);
  EXPECT_EQ(rm::parse_effect_spec("noise").values.size(), 0u);
  EXPECT_THROW(rm::parse_effect_spec("noise:std_rel=abc"), std::invalid_argument);
  EXPECT_THROW(rm::parse_effect_spec(":a=1"), std::invalid_argument);
}

TEST(Simulator, AccelerationAndDisplacementSensorsAreConsistentWithVelocity) {
  rm::RigParameters rig;
  rm::SimulationSettings s;
  s.duration_s = 0.03;
  const auto v = rm::simulate(rig, {}, s);
  rig.sensor_quantity = rm::SensorQuantity::kAcceleration;
  const auto a = rm::simulate(rig, {}, s);
  rig.sensor_quantity = rm::SensorQuantity::kDisplacement;
  const auto x = rm::simulate(rig, {}, s);
  const double dt = 1.0 / v.sample_rate_hz;
  double amax = 0.0, aerr = 0.0, vmax = 0.0, verr = 0.0;
  for (std::size_t i = 1; i + 1 < v.output.size(); ++i) {
    // Central differences at 60 samples per cycle: relative error (ω dt)²/6 = 1.8e-3 of the peak.
    const double a_fd = (v.output[i + 1] - v.output[i - 1]) / (2 * dt);
    const double v_fd = (x.output[i + 1] - x.output[i - 1]) / (2 * dt);
    amax = std::max(amax, std::abs(a.output[i]));
    vmax = std::max(vmax, std::abs(v.output[i]));
    // Skip the impact pulse itself (the force has kinks there, so differences are poor).
    const double t = static_cast<double>(i) * dt;
    if (t > v.impacts[0].t_s - 2 * dt && t < v.impacts[0].t_s + 1.5e-4 + 2 * dt) continue;
    aerr = std::max(aerr, std::abs(a.output[i] - a_fd));
    verr = std::max(verr, std::abs(v.output[i] - v_fd));
  }
  EXPECT_LT(aerr, 3e-3 * amax);
  EXPECT_LT(verr, 3e-3 * vmax);
  EXPECT_GT(amax, 1000 * vmax);  // ω0 = 5404 s⁻¹ (velocity peak → acceleration peak)
}
