#include "core/dsp/ml_fit.hpp"

#include <fftw3.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <complex>
#include <numbers>
#include <stdexcept>
#include <unsupported/Eigen/NonLinearOptimization>

#include "core/dsp/fftw_planner.hpp"

namespace ridgewatch::dsp {

namespace {

using cd = std::complex<double>;
constexpr double kTwoPi = 2.0 * std::numbers::pi;

// Parameter layout per mode: [f_hz, ln zeta, Re C, Im C]; then residual terms [Re b, Im b] each.
constexpr int kPerMode = 4;

struct Problem {
  double fs = 0.0;
  double n_samples = 0.0;
  std::vector<cd> data;    // X_k for the bins used
  std::vector<cd> w;       // e^{-2 pi i k / N}
  std::vector<double> u;   // bin position in the band, scaled to [-1, 1] (residual polynomial)
  std::vector<double> basis;  // u^b for each bin and residual term b (row-major), made once per fit
  int modes = 0;
  int residual_terms = 0;

  int params() const { return kPerMode * modes + 2 * residual_terms; }
  int values() const { return 2 * static_cast<int>(data.size()); }

  struct ModeState {
    cd z, zn, dz_df, dz_du;
    cd c;
  };

  ModeState mode_state(const Eigen::VectorXd& x, int j) const {
    const double f = x[kPerMode * j];
    const double zeta = std::exp(x[kPerMode * j + 1]);
    const double omega = kTwoPi * f;
    const double root = std::sqrt(std::max(1.0 - zeta * zeta, 1e-12));
    const double sigma = zeta * omega / root;
    ModeState m;
    const cd exponent(-sigma / fs, omega / fs);
    m.z = std::exp(exponent);
    m.zn = std::exp(n_samples * exponent);
    const double dsigma_df = kTwoPi * zeta / root;
    const double dsigma_du = zeta * omega / (root * root * root);  // zeta * d sigma / d zeta
    m.dz_df = m.z * cd(-dsigma_df, kTwoPi) / fs;
    m.dz_du = m.z * cd(-dsigma_du, 0.0) / fs;
    m.c = cd(x[kPerMode * j + 2], x[kPerMode * j + 3]);
    return m;
  }

  // Model X_k and, when jac != nullptr, dX_k/dparams (complex, one column per parameter).
  void model(const Eigen::VectorXd& x, std::vector<cd>& out, Eigen::MatrixXcd* jac) const {
    const std::size_t k_count = data.size();
    out.assign(k_count, cd(0.0, 0.0));
    if (jac) jac->setZero(static_cast<Eigen::Index>(k_count), params());
    for (int j = 0; j < modes; ++j) {
      const ModeState m = mode_state(x, j);
      const cd zc = std::conj(m.z), znc = std::conj(m.zn);
      for (std::size_t k = 0; k < k_count; ++k) {
        const cd d1 = 1.0 - m.z * w[k];
        const cd d2 = 1.0 - zc * w[k];
        const cd g1 = (1.0 - m.zn) / d1;
        const cd g2 = (1.0 - znc) / d2;
        out[k] += 0.5 * (m.c * g1 + std::conj(m.c) * g2);
        if (!jac) continue;
        // G'(z) = (-N z^(N-1) (1 - z w) + (1 - z^N) w) / (1 - z w)^2
        const cd gp1 = (-n_samples * m.zn / m.z * d1 + (1.0 - m.zn) * w[k]) / (d1 * d1);
        const cd gp2 = (-n_samples * znc / zc * d2 + (1.0 - znc) * w[k]) / (d2 * d2);
        const auto row = static_cast<Eigen::Index>(k);
        const int col = kPerMode * j;
        (*jac)(row, col) = 0.5 * (m.c * gp1 * m.dz_df + std::conj(m.c) * gp2 * std::conj(m.dz_df));
        (*jac)(row, col + 1) =
            0.5 * (m.c * gp1 * m.dz_du + std::conj(m.c) * gp2 * std::conj(m.dz_du));
        (*jac)(row, col + 2) = 0.5 * (g1 + g2);
        (*jac)(row, col + 3) = 0.5 * cd(0.0, 1.0) * (g1 - g2);
      }
    }
    for (int b = 0; b < residual_terms; ++b) {
      const int col = kPerMode * modes + 2 * b;
      const cd coef(x[col], x[col + 1]);
      for (std::size_t k = 0; k < k_count; ++k) {
        const double ub = basis[k * static_cast<std::size_t>(residual_terms) + static_cast<std::size_t>(b)];
        out[k] += coef * ub;
        if (jac) {
          (*jac)(static_cast<Eigen::Index>(k), col) = ub;
          (*jac)(static_cast<Eigen::Index>(k), col + 1) = cd(0.0, ub);
        }
      }
    }
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

// DFT of the real x[0..n) at the single bin k, X_k = sum_n x[n] e^{-2 pi i k n / N}, with the exact
// twiddles tw (interleaved cos, -sin of 2 pi m / N, m = 0..N-1) indexed by k n mod N (no recurrence,
// so no rounding drift). Two interleaved accumulator pairs hide the add latency.
cd direct_bin(const double* x, std::size_t n, const double* tw, std::size_t k) {
  const std::size_t step = k % n;
  std::size_t m0 = 0, m1 = step;
  const std::size_t step2 = (2 * step) % n;
  double re0 = 0.0, im0 = 0.0, re1 = 0.0, im1 = 0.0;
  std::size_t i = 0;
  for (; i + 1 < n; i += 2) {
    re0 += x[i] * tw[2 * m0];
    im0 += x[i] * tw[2 * m0 + 1];
    re1 += x[i + 1] * tw[2 * m1];
    im1 += x[i + 1] * tw[2 * m1 + 1];
    m0 += step2;
    if (m0 >= n) m0 -= n;
    m1 += step2;
    if (m1 >= n) m1 -= n;
  }
  if (i < n) {
    re0 += x[i] * tw[2 * m0];
    im0 += x[i] * tw[2 * m0 + 1];
  }
  return {re0 + re1, im0 + im1};
}

}  // namespace

struct SpectralModeFitter::Impl {
  std::size_t n = 0;
  double fs = 0.0;
  double* in = nullptr;
  fftw_complex* out = nullptr;
  fftw_plan plan = nullptr;
  std::vector<double> tw;  // e^{-2 pi i m / N}, interleaved re, im (direct DFT of a few bins)

  ~Impl() {
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    if (plan) fftw_destroy_plan(plan);
    fftw_free(in);
    fftw_free(out);
  }
};

SpectralModeFitter::SpectralModeFitter(std::size_t segment_samples, double sample_rate_hz)
    : impl_(std::make_unique<Impl>()) {
  if (segment_samples < 16 || segment_samples > (std::size_t{1} << 28))
    throw std::invalid_argument("SpectralModeFitter: segment_samples must be in [16, 2^28]");
  if (!(sample_rate_hz > 0) || !std::isfinite(sample_rate_hz))
    throw std::invalid_argument("SpectralModeFitter: sample_rate_hz must be > 0");
  impl_->n = segment_samples;
  impl_->fs = sample_rate_hz;
  std::lock_guard<std::mutex> lock(fftw_planner_mutex());
  impl_->in = fftw_alloc_real(segment_samples);
  impl_->out = fftw_alloc_complex(segment_samples / 2 + 1);
  if (!impl_->in || !impl_->out) throw std::bad_alloc();
  impl_->plan = fftw_plan_dft_r2c_1d(static_cast<int>(segment_samples), impl_->in, impl_->out,
                                     FFTW_ESTIMATE);
  if (!impl_->plan) throw std::runtime_error("SpectralModeFitter: FFTW could not make a plan");
  impl_->tw.resize(2 * segment_samples);
  for (std::size_t m = 0; m < segment_samples; ++m) {
    const cd t = std::polar(1.0, -kTwoPi * static_cast<double>(m) / static_cast<double>(segment_samples));
    impl_->tw[2 * m] = t.real();
    impl_->tw[2 * m + 1] = t.imag();
  }
}

SpectralModeFitter::~SpectralModeFitter() = default;

MlFitResult SpectralModeFitter::fit(std::span<const double> segment,
                                    std::span<const ModeGuess> guesses, const MlFitOptions& options) {
  Impl& im = *impl_;
  if (segment.size() != im.n) throw std::invalid_argument("SpectralModeFitter::fit: wrong segment length");
  if (!(options.f_lo_hz > 0 && options.f_hi_hz > options.f_lo_hz && options.f_hi_hz <= im.fs / 2))
    throw std::invalid_argument("SpectralModeFitter::fit: band must satisfy 0 < f_lo < f_hi <= fs/2");
  if (options.residual_terms < 0 || options.residual_terms > 4)
    throw std::invalid_argument("SpectralModeFitter::fit: residual_terms must be in [0, 4]");

  MlFitResult result;
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
    return result;
  };
  if (guesses.empty()) return result;

  Problem p;
  p.fs = im.fs;
  p.n_samples = static_cast<double>(im.n);
  p.modes = static_cast<int>(guesses.size());
  p.residual_terms = options.residual_terms;
  const double bin_hz = im.fs / static_cast<double>(im.n);
  const auto k_lo = static_cast<std::size_t>(std::max(1.0, std::ceil(options.f_lo_hz / bin_hz)));
  const auto k_hi = std::min(static_cast<std::size_t>(std::floor(options.f_hi_hz / bin_hz)),
                             (im.n - 1) / 2);  // exclude Nyquist (real-valued bin)
  if (k_hi <= k_lo) return fail_all(EstimateStatus::too_short);
  // Only the bins in [k_lo, k_hi] are used. A few of them (the pipeline's single mode in f_d +- 12 %:
  // ~7 bins of a 1766-sample segment) are cheaper as direct sums than as a full FFT of an awkward
  // length (1766 = 2 * 883; measured: 209k instructions per FFTW ESTIMATE transform vs ~25k for the
  // direct bins); many bins (`ridgewatch modes`: thousands) go through the FFT.
  const std::size_t n_bins = k_hi - k_lo + 1;
  const bool direct = static_cast<double>(n_bins) <= 2.0 * std::log2(static_cast<double>(im.n));
  if (direct) {
    for (std::size_t k = k_lo; k <= k_hi; ++k) {
      const cd v = direct_bin(segment.data(), im.n, im.tw.data(), k);
      im.out[k][0] = v.real();
      im.out[k][1] = v.imag();
    }
  } else {
    std::copy(segment.begin(), segment.end(), im.in);
    fftw_execute(im.plan);
  }
  const double k_mid = 0.5 * static_cast<double>(k_lo + k_hi);
  const double k_half = std::max(0.5 * static_cast<double>(k_hi - k_lo), 1.0);
  for (std::size_t k = k_lo; k <= k_hi; ++k) {
    p.data.emplace_back(im.out[k][0], im.out[k][1]);
    p.w.push_back(std::polar(1.0, -kTwoPi * static_cast<double>(k) / p.n_samples));
    p.u.push_back((static_cast<double>(k) - k_mid) / k_half);
  }
  p.basis.reserve(p.u.size() * static_cast<std::size_t>(p.residual_terms));
  for (const double uk : p.u)
    for (int b = 0; b < p.residual_terms; ++b) p.basis.push_back(std::pow(uk, b));
  result.bins = p.data.size();
  const int n_par = p.params();
  if (p.values() <= n_par + 2) return fail_all(EstimateStatus::too_short);

  // Start: nonlinear parameters from the guesses, linear ones (amplitudes, residual terms) from
  // linear least squares at those frequencies and dampings.
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n_par);
  for (int j = 0; j < p.modes; ++j) {
    const ModeGuess& g = guesses[static_cast<std::size_t>(j)];
    if (!(g.f_hz > 0 && g.zeta > 0 && g.zeta < 1)) return fail_all(EstimateStatus::fit_failed);
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
  result.converged = status != Space::ImproperInputParameters &&
                     status != Space::TooManyFunctionEvaluation && status != Space::UserAsked;

  // Covariance s^2 (J^T J)^-1 at the solution, s^2 = RSS / (values - params).
  std::vector<cd> model_buf;
  Eigen::MatrixXcd jc;
  p.model(x, model_buf, &jc);
  double rss = 0.0;
  for (std::size_t k = 0; k < p.data.size(); ++k) rss += std::norm(p.data[k] - model_buf[k]);
  const double s2 = rss / static_cast<double>(p.values() - n_par);
  result.noise_sd = std::sqrt(2.0 * s2 / p.n_samples);  // bin component variance = N sigma^2 / 2
  const Eigen::MatrixXd jr = real_jacobian(jc);
  const Eigen::MatrixXd info = jr.transpose() * jr;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(info);
  const Eigen::VectorXd ev = eig.eigenvalues();
  const bool well_posed = eig.info() == Eigen::Success && ev.minCoeff() > 1e-12 * ev.maxCoeff();
  Eigen::MatrixXd cov = Eigen::MatrixXd::Constant(n_par, n_par, NAN);
  if (well_posed)
    cov = s2 * eig.eigenvectors() * ev.cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();

  for (int j = 0; j < p.modes; ++j) {
    DampingEstimate e;
    e.method = DampingMethod::ml;
    e.window_start_s = 0.0;
    e.window_end_s = seg_s;
    e.points = p.data.size();
    e.f_hz = x[kPerMode * j];
    e.zeta = std::exp(x[kPerMode * j + 1]);
    const double var_f = cov(kPerMode * j, kPerMode * j);
    const double var_u = cov(kPerMode * j + 1, kPerMode * j + 1);
    e.f_sd_hz = std::sqrt(var_f);
    const double sd_u = std::sqrt(var_u);  // sd of ln zeta
    e.zeta_sd = e.zeta * sd_u;
    e.zeta_ci95_lo = e.zeta * std::exp(-1.959963984540054 * sd_u);
    e.zeta_ci95_hi = e.zeta * std::exp(1.959963984540054 * sd_u);
    e.amplitude = std::abs(cd(x[kPerMode * j + 2], x[kPerMode * j + 3]));
    const bool sane = std::isfinite(e.f_hz) && std::isfinite(e.zeta) && e.zeta < 1.0 &&
                      e.f_hz >= options.f_lo_hz && e.f_hz <= options.f_hi_hz && std::isfinite(sd_u);
    e.status = (result.converged && well_posed && sane) ? EstimateStatus::ok : EstimateStatus::fit_failed;
    result.modes.push_back(e);
  }
  return result;
}

}  // namespace ridgewatch::dsp
