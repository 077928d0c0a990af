// The search for a step in the damping ratio (damping_drift's step, ζ(t) = ζ + rate t + step [t >= T])
// when the user gives no step time. Pure computation.
//
// Every T between two consecutive fitted impacts gives the same model (ζ is only seen during the
// impacts' free responses), so T is not fitted by LM: the gaps between impacts are scanned.
//  1. A cheap per-impact statistic from the drift-rate fit: each impact's own ζ correction, the
//     least-squares coefficient of its residual on the model's derivative with respect to ζ, beside
//     the derivatives with respect to its two nuisances (force and onset). A straight line in time plus
//     a step at each admissible gap is fitted to those per-impact ζ (weighted by their noise
//     variances); the step is searched further only when the best gap's F statistic (step against the
//     line alone, scaled by the scatter left around the step model) is above kStepFThreshold.
//  2. Full fits of the model with the step at the best gaps of the statistic (one per distinct
//     training split, at most kStepFits), the gap chosen by the training fit. The training impacts
//     alternate with held-out ones, so the two gaps beside a held-out impact split the training
//     impacts alike: between them the statistic decides (the held-out impact's own ζ).
//  3. The step model replaces the drift-rate-only one when its training BIC, which counts the step
//     time as a parameter (ModelFitter::ParameterSetting::chosen_from_data), is lower and the step is
//     significant (more than 2 sd from zero).
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "core/diagnosis/model_fit.hpp"

namespace ridgewatch::diagnosis {

/// A gap between two consecutive fitted impacts where the step may be.
struct StepGap {
  std::size_t before = 0;       ///< window index of the impact before the gap (the next one is before + 1)
  double after_impact_s = 0.0;  ///< onset of the impact before the gap
  double before_impact_s = 0.0; ///< onset of the impact after the gap
  double time_s = 0.0;          ///< where the model puts the step: the middle of the gap between the windows
  double zeta_start = 0.0, rate_start = 0.0;  ///< the statistic's ζ at t = 0 and rate, the full fit's starts
  double step_start = 0.0;      ///< the statistic's step size, the full fit's start
  double chi2 = 0.0;            ///< the statistic's weighted residual with the step at this gap
};

/// The statistic's gaps, best first, one per distinct training split, at most `max_gaps`; empty when
/// no step is visible (F at or below kStepFThreshold) or the fit has no drift rate. `f_statistic`
/// (optional) receives the best gap's F.
std::vector<StepGap> damping_step_gaps(const ModelFitter& fitter, const FitResult& rate_fit, std::size_t max_gaps,
                                       double* f_statistic = nullptr);

/// The model `with` (it contains damping_drift) refitted with a step at the best gap; nullopt when
/// the user set the step or its time, no step is visible, or the step model does not win (see the
/// top). `stepped` receives the fitter whose settings hold the chosen step time.
struct StepFit {
  FitResult fit;
  StepGap gap;
};
std::optional<StepFit> fit_damping_step(const ModelFitter& fitter, const std::vector<std::string>& with,
                                        const FitResult& rate_fit, ModelFitter& stepped);

/// The step time the fitter's settings hold when diagnose chose it (nullopt otherwise), as an
/// estimate: value the model's time, the interval the onsets of the two impacts that bracket it
/// (not a confidence interval: the time is anywhere in that gap), sd NaN.
std::optional<ParameterEstimate> chosen_step_time(const ModelFitter& fitter);

/// The settings without diagnose's chosen step time.
std::map<std::string, ModelFitter::ParameterSetting> without_chosen_step(const ModelFitter& fitter);

constexpr const char* kStepTimeKey = "damping_drift.step_time_s";
/// F(1, n - 3) above which the step is searched (see the .cpp).
constexpr double kStepFThreshold = 20.0;
/// Full fits per step search.
constexpr std::size_t kStepFits = 2;

}  // namespace ridgewatch::diagnosis
