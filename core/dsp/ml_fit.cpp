#include "core/dsp/ml_fit.hpp"

#include <fftw3.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <cstring>
#include <numbers>
#include <stdexcept>
#include <type_traits>
#include <unsupported/Eigen/NonLinearOptimization>

#include "core/dsp/fftw_planner.hpp"
#include "core/dsp/kernels/goertzel.hpp"
#include "core/dsp/kernels/mode_bin.hpp"
#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp {

namespace {

using cd = std::complex<double>;
constexpr double kTwoPi = 2.0 * std::numbers::pi;

using kernels::half_sum;
using kernels::inv;
using kernels::mul;
using kernels::smul;
using kernels::Split;
using simd::f64x2;

// Stores the complex number (v[0], v[1]) with one 16-byte store (kernels::store_complex).
inline void store_pair(cd* to, f64x2 v) { kernels::store_complex(to, v); }

// t_{0.975, nu}, nu = 1..30 (standard tables, e.g. Abramowitz & Stegun Table 26.10).
constexpr double kT95[30] = {12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622, 2.2281,
                             2.2010,  2.1788, 2.1604, 2.1448, 2.1314, 2.1199, 2.1098, 2.1009, 2.0930, 2.0860,
                             2.0796,  2.0739, 2.0687, 2.0639, 2.0595, 2.0555, 2.0518, 2.0484, 2.0452, 2.0423};

// Parameter layout per mode: [f_hz, ln zeta, Re C, Im C]; then residual terms [Re b, Im b] each.
constexpr int kPerMode = 4;

struct Problem {
  double fs = 0.0;
  double n_samples = 0.0;
  // Per fit, reused across fits (reserved for every bin in the constructor, so clear() + push_back
  // never reallocates).
  std::vector<cd> data;    // X_k for the bins used
  std::vector<cd> w;       // e^{-2 pi i k / N}
  std::vector<double> u;   // bin position in the band, scaled to [-1, 1] (residual polynomial)
  std::vector<double> basis;  // u^b for each bin and residual term b (row-major), made once per fit
  int modes = 0;
  int residual_terms = 0;
  bool reference = false;  // the plain scalar kernels (SpectralModeFitter::use_reference_kernels)

  int params() const { return kPerMode * modes + 2 * residual_terms; }
  int values() const { return 2 * static_cast<int>(data.size()); }

  // The kernel's terms (z, 1 - z^N, z^(N-1), C, C dz/df, C dz/du and their lane pairs) and the rest
  // of a mode's state.
  struct ModeState : kernels::ModeBinState {
    cd zn, dz_df, dz_du;
    // The f and ln zeta the members above except the C terms were computed for (valid: at all).
    double key_f = 0.0, key_ln_zeta = 0.0;
    bool valid = false;
  };
  mutable std::vector<ModeState> states;  // one per mode, filled by for_each_bin

  // Mode j's state at x into m. Everything but the C terms depends only on f and ln zeta (an exp and
  // three complex exps): m keeps those from its previous update when f and ln zeta are bit for bit
  // the same (the start's linear pass and the first LM evaluation: one set of exps per fit fewer).
  template <typename V>
  void update_mode_state(ModeState& m, const V& x, int j) const {
    const double f = x[kPerMode * j];
    const double ln_zeta = x[kPerMode * j + 1];
    if (reference || !(m.valid && std::memcmp(&f, &m.key_f, sizeof f) == 0 &&
                       std::memcmp(&ln_zeta, &m.key_ln_zeta, sizeof ln_zeta) == 0)) {
      const double zeta = std::exp(ln_zeta);
      const double omega = kTwoPi * f;
      const double root = std::sqrt(std::max(1.0 - zeta * zeta, 1e-12));
      const double sigma = zeta * omega / root;
      const cd exponent(-sigma / fs, omega / fs);
      m.z = std::exp(exponent);
      m.zn = std::exp(n_samples * exponent);
      const double dsigma_df = kTwoPi * zeta / root;
      const double dsigma_du = zeta * omega / (root * root * root);  // zeta * d sigma / d zeta
      m.dz_df = m.z * cd(-dsigma_df, kTwoPi) / fs;
      m.dz_du = m.z * cd(-dsigma_du, 0.0) / fs;
      m.one_minus_zn = 1.0 - m.zn;
      m.zn1 = std::exp((n_samples - 1.0) * exponent);
      m.z2 = kernels::with_conj(m.z);
      m.one_minus_zn2 = kernels::with_conj(m.one_minus_zn);
      m.n_zn1_2 = kernels::with_conj(n_samples * m.zn1);  // n_samples * conj(zn1) = conj(n_samples * zn1) exactly
      m.key_f = f;
      m.key_ln_zeta = ln_zeta;
      m.valid = true;
    }
    m.c = cd(x[kPerMode * j + 2], x[kPerMode * j + 3]);
    m.c_dz_df = m.c * m.dz_df;
    m.c_dz_du = m.c * m.dz_du;
    m.c2 = kernels::with_conj(m.c);
    m.c_dz_df2 = kernels::with_conj(m.c_dz_df);
    m.c_dz_du2 = kernels::with_conj(m.c_dz_du);
  }

  // Calls sink(k, X_model_k, jrow) for every bin k; when jrow != nullptr it first receives
  // dX_model_k / dparams (complex, params() entries).
  template <typename V, typename Sink>
  void for_each_bin(const V& x, cd* jrow, Sink&& sink) const {
    states.resize(static_cast<std::size_t>(modes));
    for (int j = 0; j < modes; ++j) update_mode_state(states[static_cast<std::size_t>(j)], x, j);
    const int lin0 = kPerMode * modes;
    for (std::size_t k = 0; k < data.size(); ++k) {
      cd out(0.0, 0.0);
      const Split wk = kernels::both(w[k]);
      for (int j = 0; j < modes; ++j) {
        const ModeState& m = states[static_cast<std::size_t>(j)];
        cd* col = jrow ? jrow + kPerMode * j : nullptr;
        out += reference ? kernels::mode_bin_generic(m, w[k], n_samples, col) : kernels::mode_bin(m, wk, col);
      }
      for (int b = 0; b < residual_terms; ++b) {
        const double ub = basis[k * static_cast<std::size_t>(residual_terms) + static_cast<std::size_t>(b)];
        out += cd(x[lin0 + 2 * b], x[lin0 + 2 * b + 1]) * ub;
        if (jrow) {
          store_pair(jrow + lin0 + 2 * b, f64x2{ub, 0.0});
          store_pair(jrow + lin0 + 2 * b + 1, f64x2{0.0, ub});
        }
      }
      sink(k, out, jrow);
    }
  }

  // Model X_k and, when jac != nullptr, dX_k/dparams (complex, one column per parameter).
  void model(const Eigen::VectorXd& x, std::vector<cd>& out, Eigen::MatrixXcd* jac) const {
    out.resize(data.size());
    std::vector<cd> jrow(jac ? static_cast<std::size_t>(params()) : 0);
    if (jac) jac->resize(static_cast<Eigen::Index>(data.size()), params());
    for_each_bin(x, jac ? jrow.data() : nullptr, [&](std::size_t k, cd v, const cd* jr) {
      out[k] = v;
      if (jr)
        for (int c = 0; c < params(); ++c) (*jac)(static_cast<Eigen::Index>(k), c) = jr[c];
    });
  }
};

// Functor in the form Eigen's MINPACK-style LevenbergMarquardt expects.
struct LmFunctor {
  using Scalar = double;
  enum { InputsAtCompileTime = Eigen::Dynamic, ValuesAtCompileTime = Eigen::Dynamic };
  using InputType = Eigen::VectorXd;
  using ValueType = Eigen::VectorXd;
  using JacobianType = Eigen::MatrixXd;

  const Problem* problem;
  mutable std::vector<cd> model_buf;
  mutable Eigen::MatrixXcd jac_buf;

  int inputs() const { return problem->params(); }
  int values() const { return problem->values(); }

  int operator()(const Eigen::VectorXd& x, Eigen::VectorXd& fvec) const {
    problem->model(x, model_buf, nullptr);
    for (std::size_t k = 0; k < model_buf.size(); ++k) {
      const cd r = problem->data[k] - model_buf[k];
      fvec[static_cast<Eigen::Index>(2 * k)] = r.real();
      fvec[static_cast<Eigen::Index>(2 * k + 1)] = r.imag();
    }
    return 0;
  }
  int df(const Eigen::VectorXd& x, Eigen::MatrixXd& fjac) const {
    problem->model(x, model_buf, &jac_buf);
    for (Eigen::Index k = 0; k < jac_buf.rows(); ++k) {
      fjac.row(2 * k) = -jac_buf.row(k).real();
      fjac.row(2 * k + 1) = -jac_buf.row(k).imag();
    }
    return 0;
  }
};

Eigen::MatrixXd real_jacobian(const Eigen::MatrixXcd& jc) {
  Eigen::MatrixXd j(2 * jc.rows(), jc.cols());
  for (Eigen::Index k = 0; k < jc.rows(); ++k) {
    j.row(2 * k) = jc.row(k).real();
    j.row(2 * k + 1) = jc.row(k).imag();
  }
  return j;
}

// DFT bins X_k = sum_n x[n] e^{-2 pi i k n / N}, k = k_lo .. k_lo + count - 1, of the real x[0..N) by a
// polyphase Goertzel: with n = P m + j (x zero-padded to P M samples, M = ceil(N / P)),
//   X_k = sum_j W^{k j} e^{-i t (M-1)} Y_j,   Y_j = sum_m x[P m + j] e^{i t (M-1-m)},  t = 2 pi k P / N,
// and each Y_j is the Goertzel recursion s[m] = x[P m + j] + 2 cos(t) s[m-1] - s[m-2] read out as
// s[M-1] - e^{-i t} s[M-2]. The P = 8 phases are independent recursions (the latency of one recursion
// step is hidden; 3 flops per sample and bin against ~10 instructions for a direct sum with table
// twiddles). Round-off grows like M^2 eps / sin(t) (M = 221, t ~ 0.8 at the pipeline's 1766-sample
// segments: ~1e-11 of sum |x|; test_damping checks a fit on these bins against one on FFT bins).
// tw holds e^{-2 pi i m / N}, interleaved. The recursions: kernels::goertzel_recursions.
constexpr std::size_t kPhases = kernels::kGoertzelPhases;

void goertzel_bins(const double* x, std::size_t n, const double* tw, std::size_t k_lo, std::size_t count,
                   fftw_complex* out) {
  const std::size_t m_count = (n + kPhases - 1) / kPhases;
  const std::size_t m_full = n / kPhases;
  double tail[kPhases] = {};
  std::copy(x + kPhases * m_full, x + n, tail);
  const double* tail_row = m_full < m_count ? tail : nullptr;
  auto coef = [&](std::size_t k) { return 2.0 * tw[2 * ((k * kPhases) % n)]; };
  // X_k from the bin's s[M-1] (s1) and s[M-2] (s2). Table indices advance by addition (no integer
  // division per twiddle).
  auto combine = [&](std::size_t k, const double* s1, const double* s2) {
    const std::size_t kp = (k * kPhases) % n;
    const cd e(tw[2 * kp], tw[2 * kp + 1]);
    const std::size_t r = kp * (m_count - 1) % n;
    const cd rot(tw[2 * r], tw[2 * r + 1]);
    const std::size_t step = k % n;
    cd acc(0.0, 0.0);
    std::size_t kj = 0;  // k j mod n
    for (std::size_t j = 0; j < kPhases; ++j) {
      acc += (s1[j] - e * s2[j]) * cd(tw[2 * kj], tw[2 * kj + 1]);
      kj += step;
      if (kj >= n) kj -= n;
    }
    acc *= rot;
    out[k][0] = acc.real();
    out[k][1] = acc.imag();
  };
  double s[4 * kPhases];
  std::size_t k = k_lo;
  for (; k + 1 < k_lo + count; k += 2) {
    const double c2[2] = {coef(k), coef(k + 1)};
    kernels::goertzel_recursions(x, m_full, tail_row, c2, 2, s);
    combine(k, s, s + kPhases);
    combine(k + 1, s + 2 * kPhases, s + 3 * kPhases);
  }
  if (k < k_lo + count) {
    const double c1 = coef(k);
    kernels::goertzel_recursions(x, m_full, tail_row, &c1, 1, s);
    combine(k, s, s + kPhases);
  }
}

// Small problems (the pipeline's single mode: 6-8 parameters on ~7 bins; at most kMaxSmall
// parameters) take a Levenberg-Marquardt on the normal equations with fixed-capacity matrices: no
// heap allocation, and no values x params Jacobian (A = Re(J^H J) and g = Re(J^H r) are accumulated bin
// by bin). Forming J^T J squares the condition number; the Marquardt scaling D = sqrt(diag A) (the
// columns scaled to unit norm, as MINPACK does) keeps the scaled system's condition that of the
// parameters' correlations, which for one mode plus a low-order residual polynomial is modest.
constexpr int kMaxSmall = 12;
using SmallMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::ColMajor, kMaxSmall, kMaxSmall>;
using SmallVec = Eigen::Matrix<double, Eigen::Dynamic, 1, Eigen::ColMajor, kMaxSmall, 1>;

// Solves M y = b for a symmetric positive definite M (n <= kMaxSmall, upper triangle read) by an
// unpivoted L D L^T factorisation on fixed arrays; false when M is not numerically positive definite
// (the caller then takes Eigen's pivoted LDLT or QR). The systems here are Jacobi-scaled (unit
// diagonal, plus lambda in the LM steps), where the factorisation needs no pivoting. Cheaper than
// Eigen's dynamic-size LDLT and its solves: one reciprocal per column and no square roots keep the
// dependency chain short.
bool cholesky_solve(const SmallMat& m, int n, const double* b, double* y) {
  double l[kMaxSmall][kMaxSmall], dg[kMaxSmall], inv_d[kMaxSmall];
  for (int j = 0; j < n; ++j) {
    double w[kMaxSmall];  // w[k] = l[j][k] d[k]
    double djj = m(j, j);
    for (int k = 0; k < j; ++k) {
      w[k] = l[j][k] * dg[k];
      djj -= l[j][k] * w[k];
    }
    if (!(djj > 0) || !std::isfinite(djj)) return false;
    dg[j] = djj;
    inv_d[j] = 1.0 / djj;
    for (int i = j + 1; i < n; ++i) {
      double v = m(j, i);
      for (int k = 0; k < j; ++k) v -= l[i][k] * w[k];
      l[i][j] = v * inv_d[j];
    }
  }
  for (int i = 0; i < n; ++i) {  // L z = b
    double v = b[i];
    for (int k = 0; k < i; ++k) v -= l[i][k] * y[k];
    y[i] = v;
  }
  for (int i = 0; i < n; ++i) y[i] *= inv_d[i];  // D
  for (int i = n - 1; i >= 0; --i) {  // L^T y = z
    double v = y[i];
    for (int k = i + 1; k < n; ++k) v -= l[k][i] * y[k];
    y[i] = v;
  }
  return true;
}

// Sums over the bins of Re(conj(J_a) J_b) (upper triangle) and Re(conj(J_a) r), bin by bin in bin
// order. N > 0 (even): the column count as a compile-time constant, the sums in f64x2 pairs of columns
// (b, b + 1) with each lane's operations the scalar ones (the pair holding the diagonal of an odd row
// also forms the entry left of it, unused). N = 0: scalar, n at run time. The same values either way.
template <int N>
struct NormalSums {
  static_assert(N % 2 == 0);
  static constexpr int kP = N / 2;
  f64x2 acc[N][kP] = {};
  f64x2 acc_g[kP] = {};
  void add(int, const double* jre, const double* jim, cd r) {
    f64x2 re[kP], im[kP];
    for (int c = 0; c < kP; ++c) {
      re[c] = simd::load(jre + 2 * c);
      im[c] = simd::load(jim + 2 * c);
    }
    const f64x2 r_re{r.real(), r.real()}, r_im{r.imag(), r.imag()};
    for (int c = 0; c < kP; ++c) acc_g[c] += re[c] * r_re + im[c] * r_im;
    for (int a = 0; a < N; ++a) {
      const f64x2 a_re{jre[a], jre[a]}, a_im{jim[a], jim[a]};
      for (int c = a / 2; c < kP; ++c) acc[a][c] += a_re * re[c] + a_im * im[c];
    }
  }
  void store(int, SmallMat& A, SmallVec& g) const {
    A.resize(N, N);
    g.resize(N);
    for (int a = 0; a < N; ++a) {
      g[a] = acc_g[a / 2][a % 2];
      for (int b = a; b < N; ++b) A(a, b) = A(b, a) = acc[a][b / 2][b % 2];
    }
  }
};
template <>
struct NormalSums<0> {
  double acc[kMaxSmall][kMaxSmall] = {};
  double acc_g[kMaxSmall] = {};
  void add(int n, const double* jre, const double* jim, cd r) {
    for (int a = 0; a < n; ++a) {
      acc_g[a] += jre[a] * r.real() + jim[a] * r.imag();
      for (int b = a; b < n; ++b) acc[a][b] += jre[a] * jre[b] + jim[a] * jim[b];
    }
  }
  void store(int n, SmallMat& A, SmallVec& g) const {
    A.resize(n, n);
    g.resize(n);
    for (int a = 0; a < n; ++a) {
      g[a] = acc_g[a];
      for (int b = a; b < n; ++b) A(a, b) = A(b, a) = acc[a][b];
    }
  }
};

// RSS = sum_k |X_k - model_k|^2 and, when A != nullptr, the normal equations A = Re(J^H J),
// g = Re(J^H r) with r = X - model.
// N > 0: the parameter count as a compile-time constant (the pipeline's 6 and 8), so that the
// accumulation loops unroll and vectorise; N = 0: p.params() at run time. Same arithmetic either way.
template <int N>
double normal_equations_n(const Problem& p, const SmallVec& x, SmallMat* A, SmallVec* g) {
  const int n = N > 0 ? N : p.params();
  cd jrow[kMaxSmall];
  alignas(16) double jre[kMaxSmall], jim[kMaxSmall];
  NormalSums<N> sums;
  double rss = 0.0;
  p.for_each_bin(x, A ? jrow : nullptr, [&](std::size_t k, cd v, const cd* jr) {
    const cd r = p.data[k] - v;
    rss += std::norm(r);
    if (!jr) return;
    for (int a = 0; a < n; ++a) {
      jre[a] = jr[a].real();
      jim[a] = jr[a].imag();
    }
    sums.add(n, jre, jim, r);
  });
  if (A) sums.store(n, *A, *g);
  return rss;
}

// The start's linear least squares: at given frequencies and dampings with all linear parameters
// (amplitudes, residual terms) zero, the residual is the data and the normal equations restricted to
// the linear parameters are those of the linear problem. This computes only that block (the
// derivatives in f and ln zeta, which normal_equations would also form, are not needed), with the
// same arithmetic per entry as normal_equations (the result is identical). Row/column order: each
// mode's Re C, Im C, then each residual term's Re b, Im b. N as in normal_equations_n (the pipeline's
// one mode and one residual term: 4).
template <int N>
void linear_normal_equations_n(const Problem& p, const SmallVec& x, SmallMat& a, SmallVec& g) {
  const int n = N > 0 ? N : 2 * p.modes + 2 * p.residual_terms;
  alignas(16) double jre[kMaxSmall], jim[kMaxSmall];
  NormalSums<N> sums;
  p.states.resize(static_cast<std::size_t>(p.modes));
  for (int j = 0; j < p.modes; ++j) p.update_mode_state(p.states[static_cast<std::size_t>(j)], x, j);
  for (std::size_t k = 0; k < p.data.size(); ++k) {
    const Split wk = kernels::both(p.w[k]);
    for (int j = 0; j < p.modes; ++j) {
      const Problem::ModeState& m = p.states[static_cast<std::size_t>(j)];
      // Jacobian entries d/d Re C and d/d Im C, as Problem::mode_bin (_reference) forms them.
      cd c2, diff;
      if (p.reference) {
        const cd g1 = mul(m.one_minus_zn, inv(1.0 - mul(m.z, p.w[k])));
        const cd g2 = mul(std::conj(m.one_minus_zn), inv(1.0 - mul(std::conj(m.z), p.w[k])));
        c2 = 0.5 * (g1 + g2);
        diff = g1 - g2;
      } else {
        const Split zw = smul(m.z2, wk);
        const f64x2 d_re = f64x2{1.0, 1.0} - zw.re, d_im = -zw.im;
        const f64x2 nrm = d_re * d_re + d_im * d_im;
        const Split g12 = smul(m.one_minus_zn2, {d_re / nrm, -d_im / nrm});
        c2 = half_sum(g12);
        diff = cd(g12.re[0] - g12.re[1], g12.im[0] - g12.im[1]);
      }
      const cd c3(-0.5 * diff.imag(), 0.5 * diff.real());
      jre[2 * j] = c2.real();
      jim[2 * j] = c2.imag();
      jre[2 * j + 1] = c3.real();
      jim[2 * j + 1] = c3.imag();
    }
    for (int b = 0; b < p.residual_terms; ++b) {
      const double ub = p.basis[k * static_cast<std::size_t>(p.residual_terms) + static_cast<std::size_t>(b)];
      const int c = 2 * p.modes + 2 * b;
      jre[c] = ub;
      jim[c] = 0.0;
      jre[c + 1] = 0.0;
      jim[c + 1] = ub;
    }
    sums.add(n, jre, jim, p.data[k]);
  }
  sums.store(n, a, g);
}

void linear_normal_equations(const Problem& p, const SmallVec& x, SmallMat& a, SmallVec& g) {
  if (!p.reference && p.modes == 1 && p.residual_terms == 1)
    linear_normal_equations_n<4>(p, x, a, g);
  else
    linear_normal_equations_n<0>(p, x, a, g);
}

double normal_equations(const Problem& p, const SmallVec& x, SmallMat* A, SmallVec* g) {
  if (p.reference) return normal_equations_n<0>(p, x, A, g);
  switch (p.params()) {
    case 6: return normal_equations_n<6>(p, x, A, g);
    case 8: return normal_equations_n<8>(p, x, A, g);
    default: return normal_equations_n<0>(p, x, A, g);
  }
}

// Minimises the RSS from x (updated in place). Stops when the next step would change every mode's
// frequency by less than 1e-9 and its zeta by less than 1e-7 (relative; or the scaled parameters by
// less than 1e-12 of their norm), or an accepted step reduced the RSS by less than 1e-12 of itself
// (MINPACK's ftol; the general path uses 1e-12 for ftol and xtol), or no damping makes a step reduce
// the RSS (the minimum to rounding). On return A holds the normal matrix at x and
// rss the RSS there. Returns false when max_evaluations ran out first.
bool minimise_small(const Problem& p, SmallVec& x, int max_evaluations, SmallMat& A, double& rss) {
  const int n = p.params();
  SmallVec g(n), d(n), step(n), trial(n), g_trial(n);
  SmallMat m(n, n), a_trial(n, n);
  rss = normal_equations(p, x, &A, &g);
  int evaluations = 1;
  double lambda = 1e-4;
  for (;;) {
    for (int i = 0; i < n; ++i) d[i] = A(i, i) > 0 ? std::sqrt(A(i, i)) : 1.0;
    const double x_norm = x.cwiseProduct(d).norm();
    double rss_trial = rss;
    for (;;) {
      // (D^-1 A D^-1 + lambda I) (D step) = D^-1 g
      for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) m(i, j) = A(i, j) / (d[i] * d[j]);
      m.diagonal().array() += lambda;
      double rhs[kMaxSmall] = {}, y[kMaxSmall] = {};
      for (int i = 0; i < n; ++i) rhs[i] = g[i] / d[i];
      if (cholesky_solve(m, n, rhs, y)) {
        for (int i = 0; i < n; ++i) step[i] = y[i] / d[i];
      } else {
        const Eigen::LDLT<SmallMat> ldlt(m);
        step = ldlt.solve(g.cwiseQuotient(d)).cwiseQuotient(d);
      }
      // Converged: the Gauss-Newton step (lambda is tiny by now) changes f by < 1e-9 relative and
      // zeta by < 1e-7 relative. Convergence is quadratic there, so the step is taken without
      // another evaluation: x + step is within ~(1e-7)^2 of the minimum (A and rss stay those of x,
      // which the covariance does not notice at this distance).
      bool small = step.allFinite();
      for (int j = 0; j < p.modes && small; ++j)
        small = std::abs(step[kPerMode * j]) <= 1e-9 * std::abs(x[kPerMode * j]) &&
                std::abs(step[kPerMode * j + 1]) <= 1e-7;
      if (small || !(step.cwiseProduct(d).norm() > 1e-12 * x_norm)) {
        if (step.allFinite()) x += step;
        return step.allFinite();
      }
      // The trial point's normal equations come with its RSS: steps are nearly always accepted here
      // (good starts, small lambda), so this saves a separate RSS-only evaluation per iteration.
      trial = x + step;
      rss_trial = normal_equations(p, trial, &a_trial, &g_trial);
      if (++evaluations >= max_evaluations) return false;
      if (rss_trial < rss) break;
      lambda *= 4.0;
      if (lambda > 1e8) return true;  // no reduction along the gradient either: at the minimum
    }
    lambda = std::max(lambda / 4.0, 1e-10);
    const double reduction = rss - rss_trial;
    x = trial;
    rss = rss_trial;
    A = a_trial;
    g = g_trial;
    if (reduction <= 1e-12 * rss) return true;
  }
}

}  // namespace

namespace {

// The needed diagonal entries of (J^T J)^-1 at the solution, from an LDLT of the Jacobi-scaled matrix
// (unit diagonal: the factorisation loses nothing to the parameters' different units), and whether
// the problem is well posed. Parameters marked in `held` (an undamped component's ln zeta, see
// report_fit) are decoupled: their rows and columns of the scaled matrix are those of the identity.
template <typename Info>
class NormalInverse {
 public:
  using Vec = Eigen::Matrix<double, Eigen::Dynamic, 1, Eigen::ColMajor, Info::MaxRowsAtCompileTime, 1>;

  NormalInverse(const Info& info, const std::array<bool, 64>& held, int n_par)
      : n_(n_par), d_(n_par), rhs_(n_par), inv_diag_(n_par) {
    auto is_held = [&](int i) { return i < 64 && held[static_cast<std::size_t>(i)]; };
    Info scaled(n_par, n_par);
    for (int i = 0; i < n_par; ++i) d_[i] = info(i, i) > 0 ? std::sqrt(info(i, i)) : 1.0;
    for (int i = 0; i < n_par; ++i)
      for (int k = 0; k < n_par; ++k)
        scaled(i, k) = is_held(i) || is_held(k) ? (i == k ? 1.0 : 0.0) : info(i, k) / (d_[i] * d_[k]);
    ldlt_.compute(scaled);
    well_posed_ = bounds_decide(info);
    if (!well_posed_) {
      const Eigen::SelfAdjointEigenSolver<Info> eig(info, Eigen::EigenvaluesOnly);
      well_posed_ = eig.info() == Eigen::Success &&
                    eig.eigenvalues().minCoeff() > 1e-12 * eig.eigenvalues().maxCoeff();
    }
  }

  /// The smallest eigenvalue of J^T J above 1e-12 of the largest.
  bool well_posed() const { return well_posed_; }

  /// (A^-1)_ii: from the well-posedness bounds when they completed, else by a solve.
  double inverse_diagonal(int i) {
    if (have_inv_diag_) return inv_diag_[i];
    rhs_.setZero();
    rhs_[i] = 1.0;
    const Vec col = ldlt_.solve(rhs_);
    return col[i] / (d_[i] * d_[i]);
  }

 private:
  int n_ = 0;
  Vec d_, rhs_, inv_diag_;  // the Jacobi scale sqrt(A_ii), a solve's right side, (A^-1)_ii
  Eigen::LDLT<Info> ldlt_;
  bool have_inv_diag_ = false, well_posed_ = false;

  // Bounds decide the clear cases without an eigensolver: for a positive definite A,
  // lambda_min >= 1 / trace(A^-1) and lambda_max <= max_i sum_k |A_ik| (Gershgorin). A factor 2
  // margin keeps the bounds' rounding from deciding a borderline case; those go to the solver
  // (false here). With scaled = P^T L D L^T P: (A^-1)_ii = sum_k (L^-1 P e_i)_k^2 / D_k / d_i^2.
  bool bounds_decide(const Info& info) {
    if (!(ldlt_.info() == Eigen::Success && ldlt_.isPositive())) return false;
    const int n_par = n_;
    const auto& lu = ldlt_.matrixLDLT();  // strictly lower part: L (unit diagonal)
    const auto dvec = ldlt_.vectorD();
    // idx = P (0, 1, ..., n-1): (P x)_j = x_{idx_j} (P applies its transpositions in order).
    Vec idx(n_par), y(n_par);
    for (int i = 0; i < n_par; ++i) idx[i] = i;
    const auto& tr = ldlt_.transpositionsP();
    for (int k = 0; k < n_par; ++k) std::swap(idx[k], idx[static_cast<int>(tr.coeff(k))]);
    double trace_inv = 0.0, row_max = 0.0;
    bool finite = true;
    for (int j = 0; j < n_par && finite; ++j) {
      // y = L^-1 e_j (forward substitution), contributing to (A^-1)_ii with i = idx_j.
      y.setZero();
      y[j] = 1.0;
      double diag = 1.0 / dvec[j];
      for (int k = j + 1; k < n_par; ++k) {
        double v = 0.0;
        for (int m = j; m < k; ++m) v -= lu(k, m) * y[m];
        y[k] = v;
        diag += v * v / dvec[k];
      }
      const int i = static_cast<int>(idx[j]);
      inv_diag_[i] = diag / (d_[i] * d_[i]);
      trace_inv += inv_diag_[i];
      finite = dvec[j] > 0 && std::isfinite(diag);
    }
    have_inv_diag_ = finite;
    for (int i = 0; i < n_par; ++i) {
      double row = 0.0;
      for (int k = 0; k < n_par; ++k) row += std::abs(info(i, k));
      row_max = std::max(row_max, row);
    }
    return finite && std::isfinite(trace_inv) && std::isfinite(row_max) && trace_inv > 0 &&
           1.0 / trace_inv > 2e-12 * row_max;
  }
};

}  // namespace

double student_t95(int dof) {
  if (dof < 1) return NAN;
  if (dof <= 30) return kT95[dof - 1];
  // Cornish-Fisher expansion about the normal quantile z (Abramowitz & Stegun 26.7.5), to 1 / nu^4:
  // below 1e-5 of the exact value for nu > 30.
  const double z = 1.959963984540054, z2 = z * z, nu = static_cast<double>(dof);
  const double g1 = (z2 + 1.0) * z / 4.0;
  const double g2 = ((5.0 * z2 + 16.0) * z2 + 3.0) * z / 96.0;
  const double g3 = (((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) * z / 384.0;
  const double g4 = ((((79.0 * z2 + 776.0) * z2 + 1482.0) * z2 - 1920.0) * z2 - 945.0) * z / 92160.0;
  return z + (g1 + (g2 + (g3 + g4 / nu) / nu) / nu) / nu;
}

namespace {

// Estimates from the solution x, its RSS and the normal matrix info = J^T J there, into result
// (seg_s: the segment's duration, s).
template <typename X, typename Info>
void report_fit(const Problem& p, const X& x, double rss, const Info& info, bool converged, double seg_s,
                const MlFitOptions& options, MlFitResult& result) {
  const int n_par = p.params();
  result.converged = converged;
  // Covariance s^2 (J^T J)^-1 at the solution, s^2 = RSS / (values - params); the 95 % interval of
  // ln zeta is +-t sd with t Student's for those degrees of freedom (s^2 is estimated).
  const double s2 = rss / static_cast<double>(p.values() - n_par);
  const double t95 = student_t95(p.values() - n_par);
  result.noise_sd = std::sqrt(2.0 * s2 / p.n_samples);  // bin component variance = N sigma^2 / 2
  // A component that does not decay within the segment (sigma T < 1e-6: a steady line fitted as a
  // mode, whose ln zeta ran off towards -infinity where the RSS no longer depends on it) has no
  // determined damping; the covariance of the other parameters is taken with it held at zero (its
  // row and column decoupled), and its own interval is null (status fit_failed).
  std::array<bool, 64> undamped{};
  for (int j = 0; j < p.modes && kPerMode * j + 1 < 64; ++j) {
    const double zeta = std::exp(x[kPerMode * j + 1]);
    undamped[static_cast<std::size_t>(kPerMode * j + 1)] = kTwoPi * x[kPerMode * j] * zeta * seg_s < 1e-6;
  }
  auto held = [&](int i) { return i < 64 && undamped[static_cast<std::size_t>(i)]; };
  NormalInverse<Info> inverse(info, undamped, n_par);
  const bool well_posed = inverse.well_posed();
  for (int j = 0; j < p.modes; ++j) {
    double var_f = NAN, var_u = NAN;
    if (well_posed) {
      var_f = s2 * inverse.inverse_diagonal(kPerMode * j);
      var_u = s2 * inverse.inverse_diagonal(kPerMode * j + 1);
    }
    DampingEstimate e;
    e.method = DampingMethod::ml;
    e.window_start_s = 0.0;
    e.window_end_s = seg_s;
    e.points = p.data.size();
    e.f_hz = x[kPerMode * j];
    e.zeta = std::exp(x[kPerMode * j + 1]);
    e.f_sd_hz = std::sqrt(var_f);
    const double sd_u = held(kPerMode * j + 1) ? NAN : std::sqrt(var_u);  // sd of ln zeta
    e.zeta_sd = e.zeta * sd_u;
    e.zeta_ci95_lo = e.zeta * std::exp(-t95 * sd_u);
    e.zeta_ci95_hi = e.zeta * std::exp(t95 * sd_u);
    e.amplitude = std::abs(cd(x[kPerMode * j + 2], x[kPerMode * j + 3]));
    const bool sane = std::isfinite(e.f_hz) && std::isfinite(e.zeta) && e.zeta < 1.0 &&
                      e.f_hz >= options.f_lo_hz && e.f_hz <= options.f_hi_hz && std::isfinite(sd_u);
    e.status = (result.converged && well_posed && sane) ? EstimateStatus::ok : EstimateStatus::fit_failed;
    result.modes.push_back(e);
  }
}

// Small problems (at most kMaxSmall parameters): the start, nonlinear parameters from the guesses
// and linear ones (amplitudes, residual terms) from linear least squares at those frequencies and
// dampings, then minimise_small.
void fit_small(Problem& p, std::span<const ModeGuess> guesses, const MlFitOptions& options, double seg_s,
               MlFitResult& result) {
  const int n_par = p.params();
  SmallVec x = SmallVec::Zero(n_par);
  for (int j = 0; j < p.modes; ++j) {
    x[kPerMode * j] = guesses[static_cast<std::size_t>(j)].f_hz;
    x[kPerMode * j + 1] = std::log(guesses[static_cast<std::size_t>(j)].zeta);
  }
  SmallMat a(n_par, n_par);
  // With the linear parameters at 0 the residual is the data, and the model is linear in them: the
  // linear least-squares solution solves the normal equations restricted to their rows and columns.
  SmallMat al(n_par, n_par);
  SmallVec gl(n_par);
  linear_normal_equations(p, x, al, gl);
  int lin[kMaxSmall];
  int n_lin = 0;
  for (int j = 0; j < p.modes; ++j) {
    lin[n_lin++] = kPerMode * j + 2;
    lin[n_lin++] = kPerMode * j + 3;
  }
  for (int b = 0; b < p.residual_terms; ++b) {
    lin[n_lin++] = kPerMode * p.modes + 2 * b;
    lin[n_lin++] = kPerMode * p.modes + 2 * b + 1;
  }
  // Jacobi-scaled Cholesky (QR with column pivoting when that matrix is not positive definite).
  SmallVec sol(n_lin);
  {
    double dl[kMaxSmall] = {}, rhs[kMaxSmall] = {}, y[kMaxSmall] = {};
    SmallMat als(n_lin, n_lin);
    for (int r = 0; r < n_lin; ++r) dl[r] = al(r, r) > 0 ? std::sqrt(al(r, r)) : 1.0;
    for (int r = 0; r < n_lin; ++r) {
      rhs[r] = gl[r] / dl[r];
      for (int c = 0; c < n_lin; ++c) als(r, c) = al(r, c) / (dl[r] * dl[c]);
    }
    if (cholesky_solve(als, n_lin, rhs, y)) {
      for (int r = 0; r < n_lin; ++r) sol[r] = y[r] / dl[r];
    } else {
      sol = al.colPivHouseholderQr().solve(gl);
    }
  }
  for (int r = 0; r < n_lin; ++r) x[lin[r]] = sol[r];
  double rss = 0.0;
  const bool converged = minimise_small(p, x, options.max_evaluations, a, rss);
  report_fit(p, x, rss, a, converged, seg_s, options, result);
}

// General problems (`ridgewatch modes`: several modes, thousands of bins): Eigen's MINPACK
// Levenberg-Marquardt on the full Jacobian (QR, no squared condition number).
void fit_general(Problem& p, std::span<const ModeGuess> guesses, const MlFitOptions& options, double seg_s,
                 MlFitResult& result) {
  const int n_par = p.params();
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n_par);
  for (int j = 0; j < p.modes; ++j) {
    const ModeGuess& g = guesses[static_cast<std::size_t>(j)];
    x[kPerMode * j] = g.f_hz;
    x[kPerMode * j + 1] = std::log(g.zeta);
  }
  {
    std::vector<cd> model_buf;
    Eigen::MatrixXcd jc;
    p.model(x, model_buf, &jc);
    std::vector<Eigen::Index> linear_cols;
    for (int j = 0; j < p.modes; ++j) {
      linear_cols.push_back(kPerMode * j + 2);
      linear_cols.push_back(kPerMode * j + 3);
    }
    for (int b = 0; b < p.residual_terms; ++b) {
      linear_cols.push_back(kPerMode * p.modes + 2 * b);
      linear_cols.push_back(kPerMode * p.modes + 2 * b + 1);
    }
    const Eigen::MatrixXd jr = real_jacobian(jc);
    Eigen::MatrixXd a(jr.rows(), static_cast<Eigen::Index>(linear_cols.size()));
    for (std::size_t i = 0; i < linear_cols.size(); ++i)
      a.col(static_cast<Eigen::Index>(i)) = jr.col(linear_cols[i]);
    Eigen::VectorXd y(jr.rows());
    for (std::size_t k = 0; k < p.data.size(); ++k) {
      y[static_cast<Eigen::Index>(2 * k)] = p.data[k].real();
      y[static_cast<Eigen::Index>(2 * k + 1)] = p.data[k].imag();
    }
    const Eigen::VectorXd lin = a.colPivHouseholderQr().solve(y);
    for (std::size_t i = 0; i < linear_cols.size(); ++i) x[linear_cols[i]] = lin[static_cast<Eigen::Index>(i)];
  }

  LmFunctor functor{&p, {}, {}};
  Eigen::LevenbergMarquardt<LmFunctor> lm(functor);
  lm.parameters.maxfev = options.max_evaluations;
  lm.parameters.xtol = 1e-12;
  lm.parameters.ftol = 1e-12;
  const auto status = lm.minimize(x);
  using Space = Eigen::LevenbergMarquardtSpace::Status;
  const bool converged = status != Space::ImproperInputParameters &&
                         status != Space::TooManyFunctionEvaluation && status != Space::UserAsked;

  std::vector<cd> model_buf;
  Eigen::MatrixXcd jc;
  p.model(x, model_buf, &jc);
  double rss = 0.0;
  for (std::size_t k = 0; k < p.data.size(); ++k) rss += std::norm(p.data[k] - model_buf[k]);
  const Eigen::MatrixXd jr = real_jacobian(jc);
  const Eigen::MatrixXd info = jr.transpose() * jr;
  report_fit(p, x, rss, info, converged, seg_s, options, result);
}

}  // namespace

struct SpectralModeFitter::Impl {
  std::size_t n = 0;
  double fs = 0.0;
  double* in = nullptr;
  fftw_complex* out = nullptr;
  fftw_plan plan = nullptr;
  std::vector<double> tw;  // e^{-2 pi i m / N}, interleaved re, im (Goertzel bins)
  Problem p;               // per-fit bins and model, storage reused
  bool reference = false;  // use_reference_kernels

  // DFT bins k_lo .. k_lo + count - 1 of x[0..n) into out[k] (the Goertzel bins for few of them).
  void evaluate_bins(const double* x, std::size_t k_lo, std::size_t count);

  ~Impl() {
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    if (plan) fftw_destroy_plan(plan);
    fftw_free(in);
    fftw_free(out);
  }
};

namespace {
// fit(): this many bins or fewer are evaluated by the Goertzel recursion, more by the FFT.
bool goertzel_is_cheaper(std::size_t bins, std::size_t n) {
  return static_cast<double>(bins) <= 2.0 * std::log2(static_cast<double>(n));
}
}  // namespace

void SpectralModeFitter::Impl::evaluate_bins(const double* x, std::size_t k_lo, std::size_t count) {
  if (goertzel_is_cheaper(count, n) || !plan) {
    goertzel_bins(x, n, tw.data(), k_lo, count, out);
  } else {
    std::copy(x, x + n, in);
    fftw_execute(plan);
  }
}

SpectralModeFitter::SpectralModeFitter(std::size_t segment_samples, double sample_rate_hz, std::size_t max_bins,
                                       std::size_t fit_bins)
    : impl_(std::make_unique<Impl>()) {
  if (segment_samples < 16 || segment_samples > (std::size_t{1} << 28))
    throw std::invalid_argument("SpectralModeFitter: segment_samples must be in [16, 2^28]");
  if (!(sample_rate_hz > 0) || !std::isfinite(sample_rate_hz))
    throw std::invalid_argument("SpectralModeFitter: sample_rate_hz must be > 0");
  impl_->n = segment_samples;
  impl_->fs = sample_rate_hz;
  {
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    impl_->out = fftw_alloc_complex(segment_samples / 2 + 1);  // also the Goertzel bins' output
    if (!impl_->out) throw std::bad_alloc();
    if (max_bins == 0 || !goertzel_is_cheaper(max_bins, segment_samples)) {
      impl_->in = fftw_alloc_real(segment_samples);
      if (!impl_->in) throw std::bad_alloc();
      impl_->plan = fftw_plan_dft_r2c_1d(static_cast<int>(segment_samples), impl_->in, impl_->out,
                                         FFTW_ESTIMATE);
      if (!impl_->plan) throw std::runtime_error("SpectralModeFitter: FFTW could not make a plan");
    }
  }
  impl_->tw.resize(2 * segment_samples);
  for (std::size_t m = 0; m < segment_samples; ++m) {
    const cd t = std::polar(1.0, -kTwoPi * static_cast<double>(m) / static_cast<double>(segment_samples));
    impl_->tw[2 * m] = t.real();
    impl_->tw[2 * m + 1] = t.imag();
  }
  // Room for every bin a fit can use (fit_bins or max_bins when the caller bounds it, else all), so
  // that fits never reallocate (real-time callers).
  const std::size_t bound = fit_bins > 0 ? fit_bins : max_bins;
  const std::size_t all_bins = bound > 0 ? std::min(bound, segment_samples / 2 + 1) : segment_samples / 2 + 1;
  Problem& p = impl_->p;
  p.data.reserve(all_bins);
  p.w.reserve(all_bins);
  p.u.reserve(all_bins);
  p.basis.reserve(4 * all_bins);
  p.states.reserve(kMaxSmall / kPerMode);
}

SpectralModeFitter::~SpectralModeFitter() = default;

void SpectralModeFitter::dft_bins(std::span<const double> segment, std::size_t k_lo,
                                  std::span<std::complex<double>> bins) {
  Impl& im = *impl_;
  if (segment.size() != im.n) throw std::invalid_argument("SpectralModeFitter::dft_bins: wrong segment length");
  if (bins.empty()) return;
  if (k_lo < 1 || k_lo + bins.size() - 1 > (im.n - 1) / 2)
    throw std::invalid_argument("SpectralModeFitter::dft_bins: bins must lie in [1, (N - 1) / 2]");
  im.evaluate_bins(segment.data(), k_lo, bins.size());
  for (std::size_t i = 0; i < bins.size(); ++i) bins[i] = cd(im.out[k_lo + i][0], im.out[k_lo + i][1]);
}

void SpectralModeFitter::use_reference_kernels(bool on) { impl_->reference = on; }

MlFitResult SpectralModeFitter::fit(std::span<const double> segment,
                                    std::span<const ModeGuess> guesses, const MlFitOptions& options) {
  MlFitResult result;
  fit(segment, guesses, options, result);
  return result;
}

void SpectralModeFitter::fit(std::span<const double> segment, std::span<const ModeGuess> guesses,
                             const MlFitOptions& options, MlFitResult& result) {
  Impl& im = *impl_;
  if (segment.size() != im.n) throw std::invalid_argument("SpectralModeFitter::fit: wrong segment length");
  if (!(options.f_lo_hz > 0 && options.f_hi_hz > options.f_lo_hz && options.f_hi_hz <= im.fs / 2))
    throw std::invalid_argument("SpectralModeFitter::fit: band must satisfy 0 < f_lo < f_hi <= fs/2");
  if (options.residual_terms < 0 || options.residual_terms > 4)
    throw std::invalid_argument("SpectralModeFitter::fit: residual_terms must be in [0, 4]");

  result.modes.clear();
  result.noise_sd = 0.0;
  result.converged = false;
  result.bins = 0;
  const double seg_s = static_cast<double>(im.n) / im.fs;
  auto fail_all = [&](EstimateStatus status) {
    result.modes.clear();
    for (const ModeGuess& g : guesses) {
      DampingEstimate e;
      e.method = DampingMethod::ml;
      e.status = status;
      e.f_hz = g.f_hz;
      e.window_start_s = 0.0;
      e.window_end_s = seg_s;
      result.modes.push_back(e);
    }
  };
  if (guesses.empty()) return;

  Problem& p = im.p;
  p.fs = im.fs;
  p.n_samples = static_cast<double>(im.n);
  p.modes = static_cast<int>(guesses.size());
  p.residual_terms = options.residual_terms;
  p.reference = im.reference;
  p.data.clear();
  p.states.clear();  // no mode state carries over from the previous fit
  p.w.clear();
  p.u.clear();
  p.basis.clear();
  const double bin_hz = im.fs / static_cast<double>(im.n);
  const auto k_lo = static_cast<std::size_t>(std::max(1.0, std::ceil(options.f_lo_hz / bin_hz)));
  const auto k_hi = std::min(static_cast<std::size_t>(std::floor(options.f_hi_hz / bin_hz)),
                             (im.n - 1) / 2);  // exclude Nyquist (real-valued bin)
  if (k_hi <= k_lo) return fail_all(EstimateStatus::too_short);
  // Only the bins in [k_lo, k_hi] are used. A few of them (the pipeline's single mode in f_d +- 12 %:
  // ~7 bins of a 1766-sample segment) are cheaper by the Goertzel recursion than by a full FFT of an
  // awkward length (1766 = 2 * 883); many bins
  // (`ridgewatch modes`: thousands) go through the FFT.
  const std::size_t n_bins = k_hi - k_lo + 1;
  im.evaluate_bins(segment.data(), k_lo, n_bins);
  const double k_mid = 0.5 * static_cast<double>(k_lo + k_hi);
  const double k_half = std::max(0.5 * static_cast<double>(k_hi - k_lo), 1.0);
  for (std::size_t k = k_lo; k <= k_hi; ++k) {
    p.data.emplace_back(im.out[k][0], im.out[k][1]);
    p.w.emplace_back(im.tw[2 * k], im.tw[2 * k + 1]);  // e^{-2 pi i k / N}, the same polar() value
    p.u.push_back((static_cast<double>(k) - k_mid) / k_half);
  }
  for (const double uk : p.u) {
    double power = 1.0;
    for (int b = 0; b < p.residual_terms; ++b, power *= uk) p.basis.push_back(power);
  }
  result.bins = p.data.size();
  const int n_par = p.params();
  if (p.values() <= n_par + 2) return fail_all(EstimateStatus::too_short);
  for (const ModeGuess& g : guesses)
    if (!(g.f_hz > 0 && g.zeta > 0 && g.zeta < 1)) return fail_all(EstimateStatus::fit_failed);

  if (n_par <= kMaxSmall)
    fit_small(p, guesses, options, seg_s, result);
  else
    fit_general(p, guesses, options, seg_s, result);
}

}  // namespace ridgewatch::dsp
