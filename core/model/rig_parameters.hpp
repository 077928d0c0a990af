// Gear-pair rig description (paper Appendix A/B) and the quantities derived from it.
// Pure value type: validate() throws std::invalid_argument naming the field; nothing here does I/O.
#pragma once

#include <string>
#include <vector>

namespace ridgewatch::model {

/// One Fourier term of the mesh stiffness, Eq. B1: c_k cos(k ω_z t + γ_k) (here on the mesh angle).
struct StiffnessHarmonic {
  double amplitude_n_per_m = 0.0;  ///< c_k, N/m, >= 0
  double phase_rad = 0.0;          ///< γ_k, rad
};

/// What the simulated sensor measures. The paper's laser vibrometer measures q̇ (Sec. 5).
enum class SensorQuantity { kVelocity, kDisplacement, kAcceleration };

struct RigParameters {
  // Gear pair (Appendix B).
  double pinion_inertia_kg_m2 = 0.093;    ///< J1, > 0
  double wheel_inertia_kg_m2 = 0.272;     ///< J2, > 0
  double pinion_base_radius_m = 0.03046;  ///< r_b1, > 0
  double wheel_base_radius_m = 0.08466;   ///< r_b2, > 0
  int pinion_teeth = 22;                  ///< z1 >= 1 (the paper gives none; 22/60 at module 3 mm fits r_b)
  int wheel_teeth = 60;                   ///< z2 >= 1

  // Mesh (Eq. A1, B1).
  double mean_mesh_stiffness_n_per_m = 8.04e8;    ///< c0, > 0
  std::vector<StiffnessHarmonic> stiffness_harmonics = {
      {0.304e8, 1.02}, {0.185e8, -0.72}, {0.050e8, -0.93}};  ///< c_k, γ_k of Eq. B1
  double damping_ratio = 0.024;  ///< ζ = d_z / (2 sqrt(c0 m_red)), Eq. A2; 0 <= ζ < 1

  // Operation.
  double pinion_speed_rpm = 1500.0;  ///< mean pinion shaft speed, > 0
  double load_torque_n_m = 200.0;    ///< pinion torque M1 transmitted by the mesh, >= 0 (not in the paper)

  // Cracked-tooth excitation: a half-sine force pulse once per pinion revolution.
  double impact_force_n = 2000.0;        ///< peak force of the pulse, >= 0
  double impact_duration_s = 1.5e-4;     ///< pulse length, > 0 and well below the period 1/f0
  double impact_jitter_rel = 0.1;        ///< std of the relative amplitude jitter, in [0, 1)
  double crack_angle_rad = 0.0;          ///< pinion angle of the cracked tooth; tacho marks angle 0

  // Sensor.
  SensorQuantity sensor_quantity = SensorQuantity::kVelocity;
  double sensor_sensitivity = 50.0;  ///< output units per m/s (or per m, per m/s^2), > 0

  /// Throws std::invalid_argument("<field>: must be ... (got x)") on the first bad field.
  void validate() const;

  // Derived quantities.
  /// m_red = J1 J2 / (J1 r_b2^2 + J2 r_b1^2), Eq. A1 (kg).
  double reduced_mass_kg() const;
  /// ω0 = sqrt(c0 / m_red), Appendix B (rad/s); ≈ 5397 s^-1 in the paper.
  double natural_angular_frequency_rad_per_s() const;
  /// f0 = ω0 / 2π (Hz); ≈ 859 Hz in the paper.
  double natural_frequency_hz() const;
  /// Damped natural frequency f_d = f0 sqrt(1 - ζ^2) (Hz).
  double damped_frequency_hz() const;
  /// d_z = 2 ζ sqrt(c0 m_red), Eq. A2 (N s/m).
  double mesh_damping_n_s_per_m() const;
  double pinion_speed_hz() const;  ///< shaft rotation frequency (Hz)
  /// f_z = z1 × pinion shaft frequency (Hz), the ω_z / 2π of Eq. B1.
  double mesh_frequency_hz() const;
  /// Static tooth force W = M1 / r_b1 (N); with F of Eq. A1 at steady state, F = W.
  double static_mesh_force_n() const;
  /// Static mesh deflection q_s = W / c0 (m).
  double static_deflection_m() const;
};

}  // namespace ridgewatch::model
