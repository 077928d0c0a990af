#include "core/model/rig_parameters.hpp"

#include <cmath>
#include <numbers>
#include <sstream>
#include <stdexcept>

namespace ridgewatch::model {

namespace {

[[noreturn]] void fail(const std::string& field, const std::string& rule, double got) {
  std::ostringstream os;
  os << field << ": must be " << rule << " (got " << got << ")";
  throw std::invalid_argument(os.str());
}

void require_positive(const std::string& field, double v) {
  if (!std::isfinite(v) || !(v > 0.0)) fail(field, "> 0", v);
}

void require_non_negative(const std::string& field, double v) {
  if (!std::isfinite(v) || v < 0.0) fail(field, ">= 0", v);
}

}  // namespace

void RigParameters::validate() const {
  require_positive("J1", pinion_inertia_kg_m2);
  require_positive("J2", wheel_inertia_kg_m2);
  require_positive("rb1", pinion_base_radius_m);
  require_positive("rb2", wheel_base_radius_m);
  if (pinion_teeth < 1) fail("pinion_teeth", ">= 1", pinion_teeth);
  if (wheel_teeth < 1) fail("wheel_teeth", ">= 1", wheel_teeth);
  require_positive("c0", mean_mesh_stiffness_n_per_m);
  double sum_ck = 0.0;
  for (std::size_t k = 0; k < stiffness_harmonics.size(); ++k) {
    const std::string name = "c" + std::to_string(k + 1);
    require_non_negative(name, stiffness_harmonics[k].amplitude_n_per_m);
    if (!std::isfinite(stiffness_harmonics[k].phase_rad))
      fail("gamma" + std::to_string(k + 1), "finite", stiffness_harmonics[k].phase_rad);
    sum_ck += stiffness_harmonics[k].amplitude_n_per_m;
  }
  // Eq. B1 must keep c_z(t) > 0 for every mesh angle; sum |c_k| < c0 is the sufficient condition.
  if (sum_ck >= mean_mesh_stiffness_n_per_m) fail("c1+c2+...", "< c0", sum_ck);
  if (!std::isfinite(damping_ratio) || damping_ratio < 0.0 || damping_ratio >= 1.0)
    fail("damping_ratio", "in [0, 1)", damping_ratio);
  require_positive("pinion_speed_rpm", pinion_speed_rpm);
  require_non_negative("load_torque_n_m", load_torque_n_m);
  require_non_negative("impact_force_n", impact_force_n);
  require_positive("impact_duration_s", impact_duration_s);
  // The pulse must be short against one revolution so that impacts do not overlap.
  if (impact_duration_s >= 0.5 / pinion_speed_hz())
    fail("impact_duration_s", "< half a revolution", impact_duration_s);
  if (!std::isfinite(impact_jitter_rel) || impact_jitter_rel < 0.0 || impact_jitter_rel >= 1.0)
    fail("impact_jitter_rel", "in [0, 1)", impact_jitter_rel);
  if (!std::isfinite(crack_angle_rad)) fail("crack_angle_rad", "finite", crack_angle_rad);
  require_positive("sensitivity", sensor_sensitivity);
}

double RigParameters::reduced_mass_kg() const {
  const double j1 = pinion_inertia_kg_m2, j2 = wheel_inertia_kg_m2;
  const double r1 = pinion_base_radius_m, r2 = wheel_base_radius_m;
  return j1 * j2 / (j1 * r2 * r2 + j2 * r1 * r1);  // Eq. A1
}

double RigParameters::natural_angular_frequency_rad_per_s() const {
  return std::sqrt(mean_mesh_stiffness_n_per_m / reduced_mass_kg());
}

double RigParameters::natural_frequency_hz() const {
  return natural_angular_frequency_rad_per_s() / (2.0 * std::numbers::pi);
}

double RigParameters::damped_frequency_hz() const {
  return natural_frequency_hz() * std::sqrt(1.0 - damping_ratio * damping_ratio);
}

double RigParameters::mesh_damping_n_s_per_m() const {
  return 2.0 * damping_ratio * std::sqrt(mean_mesh_stiffness_n_per_m * reduced_mass_kg());
}

double RigParameters::pinion_speed_hz() const { return pinion_speed_rpm / 60.0; }

double RigParameters::mesh_frequency_hz() const { return pinion_teeth * pinion_speed_hz(); }

double RigParameters::static_mesh_force_n() const { return load_torque_n_m / pinion_base_radius_m; }

double RigParameters::static_deflection_m() const {
  return static_mesh_force_n() / mean_mesh_stiffness_n_per_m;
}

}  // namespace ridgewatch::model
