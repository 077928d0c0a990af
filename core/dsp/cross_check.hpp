// Cross-check of two estimates of one mode (an ML fit against the ridge least squares, or any two of
// the estimators in core/dsp/damping.hpp): do they agree within their combined standard
// uncertainties? When they do not, the damped-sinusoid model does not describe the mode (close modes,
// non-viscous damping, a line in the band) and the caller marks the estimate `inconsistent`.
//
//   z_zeta = |ln(zeta_a / zeta_b)| / hypot(sd_a / zeta_a, sd_b / zeta_b, zeta_allowance)
//   z_f    = |f_a - f_b| / hypot(f_sd_a, f_sd_b, f_allowance f_a)
// agree when z_zeta <= max_zeta_sds and z_f <= max_f_sds (a NaN z fails). The allowances (1 % in
// ln zeta, 1e-4 of f) give room for the envelope method's small deterministic biases, which matter
// only when the noise is negligible.
//
// The two callers keep the rules they had when the check was written twice (so that the goldens and
// the accuracy tables do not move): the impact analyzer (kAnalyzerRule: 4 sds on both, a missing
// ridge-ls frequency uncertainty skips the frequency test) and `ridgewatch modes` (kModesRule: 3.5 sds
// on ln zeta, 4 on f, a missing frequency uncertainty counts as 0; modes.cpp says why 3.5).
#pragma once

#include "core/dsp/damping.hpp"

namespace ridgewatch::dsp {

struct AgreementRule {
  double max_zeta_sds = 4.0;         ///< combined standard uncertainties allowed on ln zeta (> 0)
  double max_f_sds = 4.0;            ///< ... on the damped frequency (> 0)
  double zeta_allowance = 0.01;      ///< relative allowance on zeta (added in quadrature), >= 0
  double f_allowance_rel = 1e-4;     ///< allowance on f as a fraction of f_a (added in quadrature), >= 0
  /// How an f_sd_hz that is not finite enters the frequency test.
  enum class MissingFrequencySd {
    skip_when_b_missing,  ///< b's missing: no frequency test; a's missing: the test fails (NaN)
    as_zero,              ///< either missing counts as 0
  } missing_f_sd = MissingFrequencySd::skip_when_b_missing;
};

/// The impact analyzer's rule (ml against ridge-ls, a = ml).
inline constexpr AgreementRule kAnalyzerRule{4.0, 4.0, 0.01, 1e-4,
                                             AgreementRule::MissingFrequencySd::skip_when_b_missing};
/// identify_modes' rule (`ridgewatch modes`).
inline constexpr AgreementRule kModesRule{3.5, 4.0, 0.01, 1e-4, AgreementRule::MissingFrequencySd::as_zero};

/// Whether a and b agree under `rule` (both should be status ok with finite zeta and zeta_sd).
bool estimates_agree(const DampingEstimate& a, const DampingEstimate& b, const AgreementRule& rule);

}  // namespace ridgewatch::dsp
