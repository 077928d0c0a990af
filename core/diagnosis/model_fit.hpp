// Output-error fit of the gear-pair model (Eq. A1/A2, B1 and catalogue effects) to the measured free
// responses of a recording, with global physics shared by all impacts and per-impact nuisances, and
// judged on held-out impacts with the physics frozen.
//
// Parameters (optimiser space u, bounded by reparametrisation, see Transform):
//   globals  ln(c0 / c0_nominal), ln ζ, the free parameters of each effect in the model
//            (core/diagnosis/impact_model.hpp candidate_table), and the mesh phase φ_z when a
//            mesh-periodic effect is present;
//   per impact  ln(F / F_nominal) (pulse peak force) and the onset shift (samples) from the detector.
// Residual rows: (y - model) / σ over each window's unmasked samples, σ = the noise floor between
// impacts. Optimiser: Eigen's Levenberg–Marquardt (unsupported/Eigen/NonLinearOptimization) with a
// forward-difference Jacobian that exploits the structure (a nuisance moves only its own window and
// the next one's carried tail), and one more stop for a fit with a global parameter at a bound of
// its range (run_lm in the .cpp). Uncertainties: s² (JᵀJ)⁻¹ at the optimum, s² = RSS / (n - p); with
// dry friction plus the propagated systematic term of each window without a predecessor, whose start
// the model takes at rest at x = 0 while in a record that begins mid-run the mesh is held anywhere in
// the friction band ±F_c / c0 (training_statistics in the .cpp).
//
// Folds: windows alternate training (even index) / held-out (odd). Training fit: globals and the
// training nuisances on training rows (held-out nuisances stay at their initial values; they reach the
// training rows only through the small carried tail; with dry friction that tail is an offset in the
// friction band, as large as a few % of the response, and the held-out nuisances are fitted too,
// through the training rows only). Held-out: globals frozen, all nuisances refitted
// window by window in time order (each on its own rows, with its predecessor's final tail carried in),
// the error reported on held-out rows only.
#pragma once

#include <Eigen/Dense>
#include <map>
#include <span>
#include <string>
#include <vector>

#include "core/diagnosis/impact_model.hpp"
#include "core/diagnosis/segmentation.hpp"
#include "core/model/rig_parameters.hpp"

namespace ridgewatch::diagnosis {

struct FitProblem;

struct GlobalParameter {
  std::string name;    ///< "c0_n_per_m", "zeta", "mesh_phase_rad" or "<effect>.<key>"
  std::string effect;  ///< empty for c0, ζ, φ_z
  std::string key;
  Transform transform = Transform::kLog;
  double lo = 0.0, hi = 0.0;
};

struct FitParams {
  Eigen::VectorXd u;               ///< globals in optimiser space (layout order)
  std::vector<double> ln_force;    ///< per window: ln(F / F_nominal)
  std::vector<double> shift;       ///< per window: onset - detected onset, samples
  double polarity = 1.0;
  /// Per window (empty: all zero): a static offset (m) of the mesh deflection at the start of a window
  /// without a predecessor, where the window model otherwise starts at rest at x = 0. Never fitted:
  /// set only to propagate the unknown held offset of dry friction into the intervals (the
  /// uncertainties above).
  std::vector<double> start_offset_m;
  /// Impact pulse shape (not fitted by LM: a choice, ModelFitter::set_pulse_shape and
  /// fit_pulse_shapes below).
  model::PulseShape pulse_shape = model::PulseShape::kHalfSine;
};

struct ParameterEstimate {
  std::string name;
  double value = 0.0;
  double sd = 0.0;               ///< delta-method standard deviation of the value
  /// Part of sd² (value units²) from the unknown held start offset of dry friction (the uncertainties
  /// above); 0 without dry friction. sd² - offset_var is the s² (JᵀJ)⁻¹ part alone.
  double offset_var = 0.0;
  double ci95_lo = 0.0, ci95_hi = 0.0;  ///< u ± 1.96 sd_u mapped back (asymmetric for ln parameters)
  bool at_bound = false;         ///< within 1e-3 of the transform's range of a bound
};

struct FitResult {
  std::vector<std::string> effects;
  std::vector<GlobalParameter> layout;
  FitParams params;
  std::vector<ParameterEstimate> estimates;   ///< one per global parameter, layout order
  Eigen::MatrixXd correlation;                ///< of the global parameters
  bool converged = false;
  // Training fold.
  double train_chi2 = 0.0;   ///< Σ r², r in σ units
  double train_n = 0.0;      ///< residual samples used
  int free_parameters = 0;   ///< globals + training nuisances
  double bic = 0.0;          ///< n ln(RSS/n) + k ln n on the training rows
  // Held-out fold (physics frozen).
  double heldout_excess = 0.0;     ///< held-out residual power / noise power - 1
  double heldout_n = 0.0;
  double fit_percent = 0.0;        ///< 100 (1 - ||y - model|| / ||y - mean y||) on held-out rows
  std::vector<double> impact_power;  ///< per window: residual power / σ² (all windows, after held-out refit)
  std::vector<std::vector<double>> model;  ///< per window, the model output (after held-out refit)
};

class ModelFitter {
 public:
  /// `y` must outlive the fitter. Throws std::invalid_argument if there are fewer than 4 windows.
  ModelFitter(std::span<const double> y, const Segmentation& seg, const model::RigParameters& rig);

  std::vector<GlobalParameter> layout(const std::vector<std::string>& effects, bool pulse_with_mesh = false) const;

  /// A parameter value given by the user (`--with NAME:key=value`, `key=value!`): a start for the
  /// optimiser, or fixed (left out of the fit; the effect keeps that value in every model).
  struct ParameterSetting {
    double value = 0.0;
    bool fixed = false;
    /// Chosen from the data, not given by the user (diagnose's scan of damping_drift's step time over
    /// the gaps between impacts, damping_step.hpp): counted as a free parameter in the BIC of every
    /// model that contains its effect.
    bool chosen_from_data = false;
  };
  /// Settings by "<effect>.<key>". Throws std::invalid_argument for an effect that is not a
  /// candidate, an unknown key or a value outside the fit range. A fixed setting belongs to every
  /// model fitted afterwards that contains its effect; an effect the model lacks is added with it only
  /// when the settings fix all of its parameters (a fully fixed effect, e.g. the starting model's).
  void set_parameter_settings(const std::map<std::string, ParameterSetting>& settings);

  const std::map<std::string, ParameterSetting>& parameter_settings() const { return settings_; }
  /// Dry friction: the training fit also fits the held-out windows' nuisances (through the carried
  /// stuck offset only, see fit()); without it force_n and ζ come out ~5 sd off. On by default;
  /// diagnose screens its candidates with it off (a friction fit costs about twice as much with it,
  /// the choice of effects does not depend on it) and refits its final model with it on.
  void set_friction_carry_fit(bool on) { friction_carry_fit_ = on; }
  /// Whether fit() frees the held-out nuisances for the model of `f` (it has dry friction).
  bool frees_heldout_nuisances(const FitResult& f) const;
  /// The impact pulse shape of the fits that follow (half-sine by default); a fit keeps its own in
  /// FitParams, so its later evaluations do not depend on this setting. fit_pulse_shapes() chooses.
  void set_pulse_shape(model::PulseShape shape) { pulse_shape_ = shape; }
  model::PulseShape pulse_shape() const { return pulse_shape_; }

  /// Fits a model. `warm` (optional): a previous result whose global values (by name) and nuisances
  /// start this fit. `start_overrides`: starting values by global name (e.g. a second mode's
  /// frequency from the residual spectrum). Throws std::invalid_argument for an unknown effect.
  /// `pulse_with_mesh`: fit the impact pulse length also when the model has a mesh-periodic effect
  /// (left out there by default, see layout() in model_fit.cpp; diagnose frees it only from a
  /// converged fit of that model).
  FitResult fit(const std::vector<std::string>& effects, const FitResult* warm = nullptr,
                const std::vector<std::pair<std::string, double>>& start_overrides = {},
                bool pulse_with_mesh = false) const;

  bool is_heldout(std::size_t window) const { return window % 2 == 1; }
  const Segmentation& segmentation() const { return seg_; }
  std::span<const double> data() const { return y_; }
  const model::RigParameters& rig() const { return rig_; }

  /// Physical values for a parameter vector (the simulator's input; the half-sine pulse).
  PhysicsValues physics(const std::vector<GlobalParameter>& layout, const Eigen::VectorXd& u) const;
  /// The same with the pulse shape of `p`.
  PhysicsValues physics(const std::vector<GlobalParameter>& layout, const FitParams& p) const;

  struct Chain {
    std::vector<std::vector<double>> out;
    std::vector<WindowSimulator::End> end;
  };
  /// Model output of every window for the given parameters.
  Chain evaluate(const std::vector<GlobalParameter>& layout, const FitParams& p) const;

  /// What term discovery (term_discovery.hpp) needs from a fit, per window: the model's mesh state at
  /// every sample (`states`) and the derivatives of the model output (sensor units) with respect to
  /// the window's two nuisances, ln F (`d_ln_force`) and the onset shift in samples (`d_shift`), by
  /// forward differences with the fit's own steps.
  struct Linearisation {
    std::vector<std::vector<TraceSample>> states;
    std::vector<std::vector<double>> d_ln_force, d_shift;
  };
  Linearisation linearise(const FitResult& fit) const;

 private:
  friend struct FitProblem;
  friend struct WindowProblem;
  WindowSimulator::Impact impact(std::size_t w, const FitParams& p) const;
  ModelState carry(const WindowSimulator& sim, std::size_t w, const Chain& c) const;
  void simulate_window(const WindowSimulator& sim, std::size_t w, const FitParams& p, const Chain& c,
                       std::vector<double>& out, WindowSimulator::End& end,
                       std::vector<TraceSample>* trace = nullptr) const;
  /// The same from the transient `carried` into window w (carry(sim, w, c)): callers that simulate
  /// one window many times over the same chain compute it once (with dry friction it is an
  /// integration of the whole gap).
  void simulate_window(const WindowSimulator& sim, std::size_t w, const FitParams& p, const ModelState& carried,
                       std::vector<double>& out, WindowSimulator::End& end,
                       std::vector<TraceSample>* trace = nullptr) const;
  void initialise_nuisances(FitParams& p, const std::vector<GlobalParameter>& layout) const;
  // The steps of fit(): start values (returns whether the mesh phase came from `warm`), restarts of
  // training windows in a wrong onset basin, training statistics and parameter estimates, the
  // held-out refit of the nuisances with the physics frozen, and the held-out statistics.
  bool start_values(const std::vector<GlobalParameter>& layout, const FitResult* warm,
                    const std::vector<std::pair<std::string, double>>& start_overrides, FitParams& p) const;
  void restart_bad_windows(FitProblem& train, FitParams& p, int budget, FitResult& res) const;
  void training_statistics(const FitProblem& train, const FitParams& p, FitResult& res) const;
  /// Returns the chain at the refitted nuisances (every window).
  Chain heldout_refit(const std::vector<GlobalParameter>& layout, FitParams& p) const;
  void heldout_statistics(const FitParams& p, const Chain& c, FitResult& res) const;
  /// Best onset shift (grid) and force (projection) of window w at the given physics and tail.
  bool onset_grid(const WindowSimulator& sim, std::size_t w, const FitParams& p, const ModelState& carried,
                  double& ln_force, double& shift) const;

  std::span<const double> y_;
  Segmentation seg_;
  model::RigParameters rig_;
  std::map<std::string, ParameterSetting> settings_;
  bool friction_carry_fit_ = true;
  model::PulseShape pulse_shape_ = model::PulseShape::kHalfSine;
};

/// The impact pulse shape as a nuisance chosen by the training fit. No real impact is an exact
/// half-sine: a tooth contact that loads and unloads smoothly is closer to a raised cosine. The fitted
/// pulse length absorbs the shape where the model is linear (a Hann pulse of length τ acts as a
/// half-sine of 0.83 τ to second order in ωτ), not where the response during the pulse is nonlinear
/// (a dead zone the impact drives the mesh through). Fits `effects` (as fitter.fit, same arguments)
/// with each shape of model::PulseShape and returns the fit with the lower training χ² (the same
/// parameters and rows, so χ² compares them; a tie keeps the half-sine). Twice the cost of one fit.
FitResult fit_pulse_shapes(const ModelFitter& fitter, const std::vector<std::string>& effects,
                           const FitResult* warm = nullptr,
                           const std::vector<std::pair<std::string, double>>& start_overrides = {},
                           bool pulse_with_mesh = false);

}  // namespace ridgewatch::diagnosis
