// Term discovery (issue 14, item 3): when diagnose ends with structured residual that no catalogue
// effect explains, find the missing force as a sparse combination of a generic term library and
// propose it as a ready-to-paste user-defined effect (core/model/custom_effect.hpp). Pure computation.
//
// The residual force. The fitted model integrates Eq. A1 (paper Appendix A) per impact window,
//   m_red ẍ = W + F_imp(t) - (c0 + Δc(θ)) (q_s + x + e) - d ẋ - Σ effects ,  d = 2 ζ sqrt(c0 m_red),
// with c0 and ζ from Appendix B's rig refitted. A missing force F_res(x, ẋ, θ, t) adds to the right-hand
// side. Rather than forming F_res sample by sample from the record (m_red ẍ_meas minus the model's forces
// at the measured state: a second derivative of a 1 %-noise record, whose noise grows with f² and is
// no longer white), it is identified through the model's own response, output-error style like the
// fit itself: to first order in F_res, the measured-minus-model residual of window w is
//   r_w(t) ≈ (h * F_res)(t) + (∂y/∂ln F) δln F_w + (∂y/∂onset) δonset_w + noise ,
// where h is the impulse response of the fitted linear mesh oscillator m_red ẍ + d ẋ + c0 x = F
// (Eq. A1 with the effects' and the variation's terms left out) seen through the sensor, and F_res is
// evaluated on the model's trajectory (noise-free). With F_res = Σ_j ξ_j φ_j(x, v, θ, t) over the
// library terms φ_j the residual is linear in ξ: each column is the response h * φ_j, so least squares
// in σ units (white noise) estimates ξ in N per unit of each term. This is one Gauss–Newton step of the
// output-error fit with the term library added, from the fitted model; the per-window nuisances
// (impact force and onset) are refitted with it (their columns are eliminated window by window), and
// the linear terms x and v are always included: they are corrections of c0 and ζ, which the fit of
// the proposed effect adjusts anyway, and are not proposed.
//
// Sparsity and validation (SINDy's sequentially thresholded least squares, Brunton et al. 2016, with a
// scale-free threshold): fit all terms on the training impacts, drop the term with the smallest
// |coefficient / standard error| while it is below `t_threshold`, refit, repeat (one term per pass,
// because the library's odd terms in v are strongly correlated). Then every surviving term must earn
// its place on the held-out impacts: removed (weakest first) unless the held-out excess grows by more
// than `term_gate_se` (3) standard errors without it. The whole proposal must pass diagnose's gain
// gate (held-out excess lower by 3 standard errors). Held-out nuisances are refitted with the terms
// frozen, as in the fit's own held-out judgement. Being first order, the proposal is then refitted by
// the nonlinear fitter (verify_proposal) before diagnose reports it.
#pragma once

#include <limits>
#include <string>
#include <vector>

#include "core/diagnosis/model_fit.hpp"
#include "core/model/custom_effect.hpp"

namespace ridgewatch::diagnosis {

struct TermDiscoveryOptions {
  /// STLSQ threshold on |ξ / sd(ξ)|: 4 standard errors (p = 6e-5 per term under no effect; the
  /// library has 24 candidates with the dead-zone term of the best gap, so a false term survives this
  /// step with p ~ 1.5e-3, and then still has to improve the held-out impacts).
  double t_threshold = 4.0;
  /// At most this many proposed terms (the weakest are dropped first): a proposal is for a person to read.
  std::size_t max_terms = 5;
  /// A surviving term must gain this many standard errors of the held-out excess (sqrt(2/n)(1 + excess)):
  /// 3, diagnose's own gain gate, applied to every term (a smaller gate let terms that only fit the
  /// first-order approximation's own error survive: x², sign(v) beside v³ on cubic damping, measured).
  double term_gate_se = 3.0;
  /// Mesh orders k of the x·cos kθ, x·sin kθ, v·cos kθ, v·sin kθ terms.
  int mesh_orders = 3;
  /// diagnose fits the dead-zone family directly (fit_dead_zone) when the best description found
  /// leaves a held-out excess above this: the project's accuracy target, 0.1.
  double direct_dead_zone_above = 0.1;
  /// Name of the proposed user-defined effect.
  std::string effect_name = "discovered_force";
};

struct DiscoveredTerm {
  std::string term;       ///< the library term in muparser syntax, e.g. "v^3", "x*cos(2*theta)"
  std::string parameter;  ///< its coefficient's name in the proposed effect (a_v3, ...)
  std::string unit;       ///< unit of the coefficient (N per unit of the term)
  double coefficient = 0.0;  ///< fitted, signed: the force is coefficient · term (N)
  double sd = 0.0;           ///< standard error of the coefficient (training fit)
  double heldout_loss = 0.0; ///< held-out excess gained by this term (excess without it - with it)
  double linear_coefficient = 0.0;  ///< the first-order estimate (coefficient is replaced by a refit's value)
  /// Dead-zone term only (min(max(x, -b_dz), b_dz)): the gap's parameter name and value (m; from the
  /// grid, replaced by the refit's value). Empty / 0 for every other term.
  std::string gap_parameter;
  double gap = 0.0;
};

struct TermDiscoveryResult {
  bool proposed = false;          ///< terms survived and the proposal passes the held-out gain gate
  std::vector<DiscoveredTerm> terms;
  std::string force;              ///< muparser expression of the proposed force (empty if none)
  model::CustomEffectDefinition definition;  ///< the proposed effect (compiled and checked when proposed)
  /// Held-out excess of the linearised model with c0 and ζ corrected only (before) and with the terms
  /// (after), nuisances refitted; the gain and the gate it had to pass.
  double heldout_excess_before = 0.0, heldout_excess_after = 0.0;
  double heldout_gain = 0.0, required_gain = 0.0;
  std::vector<std::string> base_effects;  ///< the model the terms add to (the fit's effects)
  std::string note;               ///< why nothing is proposed, or remarks (words)
  /// Set by diagnose (verify_proposal): the held-out excess of the base model plus the proposed effect
  /// fitted by the nonlinear fitter (NaN when not verified).
  double verified_excess = std::numeric_limits<double>::quiet_NaN();
  /// Set by verify_proposal: that fit (base model plus the proposed effect; empty when not verified).
  FitResult verified_fit;
};

/// The library terms in muparser syntax, in the order they are tried (x and v first: always kept; the
/// dead-zone family last, once for its grid of gaps).
std::vector<std::string> term_library(int mesh_orders = 3);

/// Term discovery on a fit's held-out residual (see above). Throws nothing on bad data: an empty
/// proposal with a note.
TermDiscoveryResult discover_terms(const ModelFitter& fitter, const FitResult& fit,
                                   const TermDiscoveryOptions& options = {});

/// The proposal checked by the real (nonlinear) fitter: the proposed effect is registered as a
/// user-defined effect of this thread for the fit and removed again (the thread's user effects are
/// restored), the base model plus the effect fitted from `base_fit` and the linearised values, and
/// again cold (c0, ζ from the rig's, as compare starts a pasted block), the better training fit kept. Sets
/// verified_excess, replaces the coefficients by the fitted ones (and the definition's defaults, so
/// that a pasted block starts compare there), and withdraws the proposal (proposed = false, a note)
/// when the fit does not pass diagnose's gain gate against `base_fit`.
void verify_proposal(const ModelFitter& fitter, const FitResult& base_fit, TermDiscoveryResult& proposal);

/// The dead-zone proposal's definition: force a_dz · min(max(x, -b_dz), b_dz), kinks at x = ±b_dz,
/// a_dz (N/m) on [0, 100 c0] with default c0, b_dz (m) on [0, 100 x_rms] with default x_rms (both
/// fitted on a log scale).
model::CustomEffectDefinition dead_zone_definition(const std::string& name, double c0, double x_rms);

/// The dead-zone family fitted by the nonlinear fitter directly (no first-order step): when a gap
/// moves the record far from the linear model, one Gauss–Newton step from it picks the wrong gap and
/// coefficient. `base_fit`'s model plus a_dz · min(max(x, -b_dz), b_dz) (kinks at x = ±b_dz declared,
/// so the integrator locates them) is fitted from a_dz = the rig's c0 (no dynamic force inside the
/// gap) and each gap of the discovery grid b = x_rms · 2^-k, k = 0..4, cold (c0, ζ from the rig's, as
/// compare starts a pasted block); the fit with the lowest training χ² is refitted cold from its own
/// a_dz and b_dz with each impact pulse shape (fit_pulse_shapes, model_fit.hpp). Returns a verified
/// proposal (verified_excess, verified_fit set) or, when no fit passes diagnose's gain gate against
/// `base_fit`, proposed = false with a note. The thread's user effects are restored.
TermDiscoveryResult fit_dead_zone(const ModelFitter& fitter, const FitResult& base_fit,
                                  const TermDiscoveryOptions& options = {});

}  // namespace ridgewatch::diagnosis
