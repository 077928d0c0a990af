#include "core/dsp/cross_check.hpp"

#include <cmath>

namespace ridgewatch::dsp {

bool estimates_agree(const DampingEstimate& a, const DampingEstimate& b, const AgreementRule& rule) {
  const double z_zeta = std::abs(std::log(a.zeta / b.zeta)) /
                        std::hypot(std::hypot(a.zeta_sd / a.zeta, b.zeta_sd / b.zeta), rule.zeta_allowance);
  double z_f = 0.0;
  if (rule.missing_f_sd == AgreementRule::MissingFrequencySd::as_zero) {
    const double fa = std::isfinite(a.f_sd_hz) ? a.f_sd_hz : 0.0, fb = std::isfinite(b.f_sd_hz) ? b.f_sd_hz : 0.0;
    z_f = std::abs(a.f_hz - b.f_hz) / std::hypot(std::hypot(fa, fb), rule.f_allowance_rel * a.f_hz);
  } else if (std::isfinite(b.f_sd_hz)) {
    z_f = std::abs(a.f_hz - b.f_hz) / std::hypot(std::hypot(a.f_sd_hz, b.f_sd_hz), rule.f_allowance_rel * a.f_hz);
  }
  return z_zeta <= rule.max_zeta_sds && z_f <= rule.max_f_sds;
}

}  // namespace ridgewatch::dsp
