// The estimator cross-check shared by the impact analyzer and `ridgewatch modes`
// (core/dsp/cross_check.hpp): the two callers' rules on estimates built by hand, where z_zeta and
// z_f follow from the formula in the header.
#include <gtest/gtest.h>

#include <cmath>

#include "core/dsp/cross_check.hpp"

namespace {

using namespace ridgewatch::dsp;

DampingEstimate estimate(double f, double f_sd, double zeta, double zeta_sd) {
  DampingEstimate e;
  e.status = EstimateStatus::ok;
  e.f_hz = f;
  e.f_sd_hz = f_sd;
  e.zeta = zeta;
  e.zeta_sd = zeta_sd;
  return e;
}

// b's zeta with |ln(zeta_a / zeta_b)| = z times the combined relative uncertainty of a and b (5 %
// each, plus the 1 % allowance).
double zeta_at(double zeta_a, double z) {
  const double combined = std::hypot(std::hypot(0.05, 0.05), 0.01);
  return zeta_a * std::exp(z * combined);
}

TEST(CrossCheck, ZetaLimitsDifferBetweenTheCallers) {
  const DampingEstimate a = estimate(860.0, 0.1, 0.02, 0.001);
  for (const double z : {3.0, 3.7, 4.3}) {
    const double zb = zeta_at(0.02, z);
    const DampingEstimate b = estimate(860.0, 0.1, zb, 0.05 * zb);
    EXPECT_EQ(estimates_agree(a, b, kAnalyzerRule), z <= 4.0) << z;
    EXPECT_EQ(estimates_agree(a, b, kModesRule), z <= 3.5) << z;
  }
}

TEST(CrossCheck, FrequencyTestAndMissingUncertainties) {
  // z_f = 3 and 5 with f_sd 0.1 Hz each (allowance 1e-4 * 860 = 0.086 Hz in quadrature).
  const double combined = std::hypot(std::hypot(0.1, 0.1), 1e-4 * 860.0);
  const DampingEstimate a = estimate(860.0, 0.1, 0.02, 0.001);
  EXPECT_TRUE(estimates_agree(a, estimate(860.0 + 3.0 * combined, 0.1, 0.02, 0.001), kAnalyzerRule));
  EXPECT_FALSE(estimates_agree(a, estimate(860.0 + 5.0 * combined, 0.1, 0.02, 0.001), kAnalyzerRule));
  EXPECT_FALSE(estimates_agree(a, estimate(860.0 + 5.0 * combined, 0.1, 0.02, 0.001), kModesRule));
  // b without a frequency uncertainty: the analyzer skips the frequency test, modes counts it as 0
  // (a 1 Hz difference is then 1 / hypot(0.1, 0.086) = 7.6 sds).
  const DampingEstimate b_nan = estimate(861.0, NAN, 0.02, 0.001);
  EXPECT_TRUE(estimates_agree(a, b_nan, kAnalyzerRule));
  EXPECT_FALSE(estimates_agree(a, b_nan, kModesRule));
  // a without one: the analyzer's frequency test fails (NaN), modes counts it as 0.
  const DampingEstimate a_nan = estimate(860.0, NAN, 0.02, 0.001);
  EXPECT_FALSE(estimates_agree(a_nan, estimate(860.0, 0.1, 0.02, 0.001), kAnalyzerRule));
  EXPECT_TRUE(estimates_agree(a_nan, estimate(860.0, 0.1, 0.02, 0.001), kModesRule));
  // A NaN zeta uncertainty fails both.
  EXPECT_FALSE(estimates_agree(a, estimate(860.0, 0.1, 0.02, NAN), kAnalyzerRule));
  EXPECT_FALSE(estimates_agree(a, estimate(860.0, 0.1, 0.02, NAN), kModesRule));
}

}  // namespace
