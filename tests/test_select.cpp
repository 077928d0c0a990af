// dsp::select_kth_nonnegative (core/dsp/select.hpp) against std::nth_element. select_kth itself is
// tested in test_damping.cpp (SelectKth.EqualsNthElement).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <random>
#include <vector>

#include "core/dsp/select.hpp"

using namespace ridgewatch::dsp;

namespace {

// The same value as nth_element exactly (an order statistic is an element of the input), the input
// left unchanged, on every exit: the pivot itself, its neighbours in rank below and above, and the
// copied-out side below or above. Families: random rows, rows with ties (the neighbours then have
// multiplicities), zeros, monotone rows and the analyzer's shape (a short rise, then a decay on a
// noise floor), for every rank of short arrays and the tails of the pair loop (odd n).
TEST(SelectKthNonnegative, EqualsNthElement) {
  std::mt19937 rng(17);
  std::exponential_distribution<double> expo(1.0);
  std::uniform_int_distribution<int> small(0, 3);
  std::size_t exits[5] = {0, 0, 0, 0, 0};  // pivot, below max, above min, side below, side above
  auto check = [&](const std::vector<double>& v, std::size_t k) {
    std::vector<double> ref = v, tmp(2 * v.size(), -1.0);
    std::nth_element(ref.begin(), ref.begin() + static_cast<std::ptrdiff_t>(k), ref.end());
    const std::vector<double> before = v;
    EXPECT_EQ(select_kth_nonnegative(v.data(), tmp.data(), v.size(), k), ref[k]) << "n " << v.size() << " k " << k;
    EXPECT_EQ(v, before);
    // Which exit the call took (the pivot rule of select_kth: median of v[n/4], v[n/2], v[3n/4]).
    const std::size_t n = v.size();
    const double a = v[n / 4], b = v[n / 2], c = v[3 * n / 4];
    const double pivot = std::max(std::min(a, b), std::min(std::max(a, b), c));
    const auto below = static_cast<std::size_t>(std::count_if(v.begin(), v.end(), [&](double x) { return x < pivot; }));
    const auto at = static_cast<std::size_t>(std::count_if(v.begin(), v.end(), [&](double x) { return x <= pivot; }));
    ++exits[k >= below && k < at ? 0 : k + 1 == below ? 1 : k == at ? 2 : k < below ? 3 : 4];
  };
  for (std::size_t n : {1, 2, 3, 4, 5, 7, 8, 9, 16, 63, 64, 65, 200}) {
    for (int trial = 0; trial < 20; ++trial) {
      std::vector<double> random(n), ties(n), zeros(n, 0.0), decay(n);
      for (std::size_t i = 0; i < n; ++i) {
        random[i] = expo(rng);
        ties[i] = static_cast<double>(small(rng));
        const double t = static_cast<double>(i) - static_cast<double>(n / 10);
        decay[i] = (t < 0 ? std::exp(t) : std::exp(-0.1 * t)) + 1e-3 * expo(rng);
      }
      std::vector<double> rising = random;
      std::sort(rising.begin(), rising.end());
      std::vector<std::size_t> ranks = {0, n / 2, n - 1, static_cast<std::size_t>(trial) % n};
      if (n <= 9)
        for (std::size_t k = 0; k < n; ++k) ranks.push_back(k);
      for (std::size_t k : ranks) {
        check(random, k);
        check(ties, k);
        check(zeros, k);
        check(decay, k);
        check(rising, k);
        check(std::vector<double>(rising.rbegin(), rising.rend()), k);
      }
    }
  }
  for (std::size_t e = 0; e < 5; ++e) EXPECT_GT(exits[e], 20u) << "exit " << e << " hardly exercised";
}

}  // namespace
