#include "app/rig_defaults.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "app/args.hpp"
#include "app/rig_yaml.hpp"

namespace ridgewatch::app {

namespace {
constexpr double kHalfWidthRel = 0.15;     // the shipped default band, 854 Hz +- 15 %
constexpr double kMinHalfWidthRel = 0.05;  // narrower bands lose the impact's own spectral width
constexpr double kLineClearance = 1.776;   // 99^(1/8): |H| = -20 dB at df = 1.776 B (8th order)

std::string fixed(double x, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", digits, x);
  return buf;
}
}  // namespace

RigBand rig_band(const model::RigParameters& rig) {
  RigBand b;
  b.f_d_hz = rig.damped_frequency_hz();
  b.mesh_hz = rig.mesh_frequency_hz();
  const double below = std::floor(b.f_d_hz / b.mesh_hz) * b.mesh_hz;  // mesh line k f_z <= f_d (0 if k = 0)
  const double above = below + b.mesh_hz;                             // (k + 1) f_z > f_d
  double half = kHalfWidthRel * b.f_d_hz;
  if (below > 0) half = std::min(half, (b.f_d_hz - below) / kLineClearance);
  half = std::min(half, (above - b.f_d_hz) / kLineClearance);
  if (half < kMinHalfWidthRel * b.f_d_hz) {
    const double nearest = (b.f_d_hz - below < above - b.f_d_hz && below > 0) ? below : above;
    b.note = "model f_d " + fixed(b.f_d_hz, 1) + " Hz lies " + fixed(std::abs(b.f_d_hz - nearest), 1) +
             " Hz from the mesh line at " + fixed(nearest, 1) +
             " Hz: the trigger band cannot keep that line 20 dB down (impacts may be missed or mesh "
             "bursts trigger); check the rig's speed and teeth, or set pipeline.detector.band_lo_hz/band_hi_hz";
    half = kMinHalfWidthRel * b.f_d_hz;
  }
  b.lo_hz = b.f_d_hz - half;
  b.hi_hz = b.f_d_hz + half;
  return b;
}

void apply_rig_defaults(RidgewatchConfig& c, const std::string& rig_path, const std::string& key) {
  RigConfig rig;
  std::error_code ec;
  if (std::filesystem::exists(rig_path, ec) && !std::filesystem::is_regular_file(rig_path, ec))
    throw UsageError(key + ": " + rig_path + ": not a regular file");  // e.g. a device that never ends
  try {
    rig = load_rig_yaml(rig_path);
  } catch (const UsageError& e) {
    throw UsageError(key + ": " + e.what());
  }
  const RigBand b = rig_band(rig.rig);
  c.rig_model = {};
  c.rig_model.path = rig_path;
  c.rig_model.f_d_hz = b.f_d_hz;
  c.rig_model.mesh_hz = b.mesh_hz;
  c.rig_model.rb1_m = rig.rig.pinion_base_radius_m;
  c.rig_model.rb2_m = rig.rig.wheel_base_radius_m;
  c.rig_model.note = b.note;
  const model::RigParameters& g = rig.rig;
  const double radius_ratio = g.pinion_base_radius_m / g.wheel_base_radius_m;
  const double teeth_ratio = static_cast<double>(g.pinion_teeth) / g.wheel_teeth;
  // 5 %: the paper rig's radii and the 22/60 teeth chosen for it agree within 1.9 %.
  if (std::abs(radius_ratio / teeth_ratio - 1.0) > 0.05)
    c.rig_model.radius_note = "gear.rb1/rb2 = " + fixed(radius_ratio, 4) + " differs from pinion_teeth/wheel_teeth = " +
                              fixed(teeth_ratio, 4) + " by " + fixed(100.0 * std::abs(radius_ratio / teeth_ratio - 1.0), 1) +
                              " %: a wrong base radius leaves the shafts' common rotation in q̇ = rb1 φ̇1 + rb2 φ̇2";
  if (!c.given.count("pipeline.analyzer.f_expected_hz")) {
    c.pipeline.analyzer.f_expected_hz = b.f_d_hz;
    c.rig_model.f_expected = true;
  }
  if (!c.given.count("pipeline.detector.band_lo_hz") && !c.given.count("pipeline.detector.band_hi_hz")) {
    c.pipeline.detector.band_lo_hz = b.lo_hz;
    c.pipeline.detector.band_hi_hz = b.hi_hz;
    c.rig_model.band = true;
  }
}

std::string ModelGap::text() const {
  std::string t = "model f_d " + fixed(model_, 1) + " Hz";
  if (n_ == 0) return t + ", no ok event measured yet";
  double gap = 100.0 * gap_rel();
  if (std::abs(gap) < 0.005) gap = 0.0;  // no "-0.00 %"
  return t + ", measured f " + fixed(mean_hz(), 1) + " Hz (mean of " + std::to_string(n_) + " ok events), gap " +
         (gap >= 0 ? "+" : "") + fixed(gap, 2) + " %";
}

}  // namespace ridgewatch::app
