#include "core/model/custom_effect.hpp"

#include <muParser.h>

#include <cctype>
#include <cmath>
#include <memory>
#include <set>
#include <sstream>

#include "core/model/effect_registry.hpp"

namespace ridgewatch::model {

const std::vector<std::string>& custom_effect_variables() {
  static const std::vector<std::string> vars = {"x", "v", "theta", "t", "t_abs"};
  return vars;
}

namespace {

bool is_identifier(const std::string& s) {
  if (s.empty() || !(std::islower(static_cast<unsigned char>(s[0])) || s[0] == '_')) return false;
  for (char c : s)
    if (!(std::islower(static_cast<unsigned char>(c)) || std::isdigit(static_cast<unsigned char>(c)) || c == '_')) return false;
  return true;
}

std::string num(double v) {
  std::ostringstream o;
  o << v;
  return o.str();
}

/// A compiled expression with its variables bound to members (muparser keeps their addresses: the
/// object is never copied or moved once compiled). Eval runs muparser's byte code: the text is parsed
/// once, on the first evaluation.
class Expression {
 public:
  Expression(const std::string& text, const std::vector<EffectParameter>& params, const EffectValues& values)
      : params_(params.size()) {
    parser_.DefineVar("x", &x_);
    parser_.DefineVar("v", &v_);
    parser_.DefineVar("theta", &theta_);
    parser_.DefineVar("t", &t_);
    parser_.DefineVar("t_abs", &t_abs_);
    for (std::size_t i = 0; i < params.size(); ++i) {
      params_[i] = values.at(params[i].key);
      parser_.DefineVar(params[i].key, &params_[i]);
    }
    parser_.SetExpr(text);
  }
  Expression(const Expression&) = delete;
  Expression& operator=(const Expression&) = delete;

  double eval(double x, double v, double theta, double t, double t_abs) const {
    x_ = x;
    v_ = v;
    theta_ = theta;
    t_ = t;
    t_abs_ = t_abs;
    return parser_.Eval();
  }

 private:
  mutable double x_ = 0.0, v_ = 0.0, theta_ = 0.0, t_ = 0.0, t_abs_ = 0.0;
  std::vector<double> params_;  // sized once: the addresses stay valid
  mu::Parser parser_;
};

class CustomForce final : public Effect {
 public:
  CustomForce(std::string name, const std::string& text, const std::vector<std::string>& kinks,
              const std::vector<EffectParameter>& params, const EffectValues& values)
      : name_(std::move(name)), expr_(text, params, values) {
    for (const auto& k : kinks) kinks_.push_back(std::make_unique<Expression>(k, params, values));
  }
  // The user's force is added to the mesh force; the simulator subtracts resisting forces.
  double resisting_force_n(const MeshState& s, int) const override {
    const double f = expr_.eval(s.x_m, s.v_m_per_s, s.mesh_angle_rad, s.t_since_impact_s, s.t_s);
    if (!std::isfinite(f)) {
      std::ostringstream o;
      o << "effect " << name_ << ": force is not finite (" << f << ") at x = " << s.x_m << " m, v = " << s.v_m_per_s
        << " m/s, theta = " << s.mesh_angle_rad << " rad, t = " << s.t_since_impact_s << " s";
      throw std::domain_error(o.str());
    }
    return -f;
  }
  StepHooks step_hooks() const override { return {true, false}; }
  bool has_switching() const override { return !kinks_.empty(); }
  // One switching function for all kinks: the product of their signs times the smallest magnitude.
  // Its sign changes whenever one of them changes sign (one at a time), and near that zero it equals
  // ± that function, smooth within a regime, as the integrator's regula falsi needs.
  double switching_function(const MeshState& s) const override {
    double sign = 1.0, smallest = INFINITY;
    for (const auto& k : kinks_) {
      const double g = k->eval(s.x_m, s.v_m_per_s, s.mesh_angle_rad, s.t_since_impact_s, s.t_s);
      if (g < 0.0) sign = -sign;
      smallest = std::min(smallest, std::abs(g));
    }
    return sign * smallest;
  }

 private:
  std::string name_;
  Expression expr_;
  std::vector<std::unique_ptr<Expression>> kinks_;  // Expression is not movable: held by pointer
};

/// Compiles `text` (the force or a kink's switching function) with each parameter set and evaluates it
/// on a grid of states spanning a typical free response of the paper's rig (x up to 1e-5 m, v up to
/// 0.05 m/s, both signs and zero, two mesh angles, two times). Throws through `fail(where, what, col)`.
template <typename Fail>
void check_expression(const std::string& text, const std::string& where, const std::vector<EffectParameter>& params,
                      const std::vector<EffectValues>& sets, const Fail& fail) {
  if (text.find_first_not_of(" \t\n") == std::string::npos) fail(where, "empty expression", 0);
  for (const auto& values : sets) {
    try {
      const Expression e(text, params, values);
      for (double x : {-1e-5, 0.0, 1e-5})
        for (double v : {-0.05, 0.0, 0.05})
          for (double th : {0.0, 2.0})
            for (double t : {0.0, 0.01}) {
              const double f = e.eval(x, v, th, t, t + 1.0);
              if (!std::isfinite(f)) {
                std::ostringstream o;
                o << "'" << text << "' is not finite (" << f << ") at x = " << x << ", v = " << v << ", theta = " << th
                  << ", t = " << t << " with";
                for (const auto& [k, val] : values) o << " " << k << " = " << val;
                fail(where, o.str(), 0);
              }
            }
    } catch (const mu::Parser::exception_type& e) {
      // muparser's positions are 0-based character offsets into the expression.
      const int col = e.GetPos() >= 0 ? e.GetPos() + 1 : 0;
      std::ostringstream o;
      o << "'" << text << "'";
      if (col > 0) o << " at column " << col;
      if (!e.GetToken().empty()) o << " ('" << e.GetToken() << "')";
      o << ": " << e.GetMsg();
      if (e.GetCode() == mu::ecUNASSIGNABLE_TOKEN) {
        o << " (variables: x, v, theta, t, t_abs; parameters:";
        for (const auto& p : params) o << " " << p.key;
        o << ")";
      }
      fail(where, o.str(), col);
    }
  }
}

}  // namespace

EffectDescriptor make_custom_effect(const CustomEffectDefinition& def) {
  const std::string who = "effect " + (def.name.empty() ? std::string("(unnamed)") : def.name);
  auto fail = [&](const std::string& where, const std::string& what, int pos = 0) {
    throw CustomEffectError(who + ": " + where + ": " + what, where, pos);
  };
  if (!is_identifier(def.name)) fail("name", "'" + def.name + "' must be lower case letters, digits and _ (starting with a letter or _)");
  if (find_catalogue_effect(def.name) != nullptr)
    fail("name", "'" + def.name + "' is a catalogue effect; choose another name");
  std::set<std::string> keys;
  for (const auto& p : def.parameters) {
    const std::string where = "parameters." + p.key;
    if (!is_identifier(p.key)) fail(where, "'" + p.key + "' must be lower case letters, digits and _ (starting with a letter or _)");
    for (const auto& v : custom_effect_variables())
      if (p.key == v) fail(where, "'" + p.key + "' is a variable of the expression; choose another name");
    if (p.key.rfind("_", 0) == 0) fail(where, "names starting with _ are muparser's constants");
    if (!keys.insert(p.key).second) fail(where, "given twice");
    if (!std::isfinite(p.min_value) || !std::isfinite(p.max_value) || !(p.min_value <= p.max_value))
      fail(where, "min must be <= max, both finite (got " + num(p.min_value) + ", " + num(p.max_value) + ")");
    if (!(p.default_value >= p.min_value && p.default_value <= p.max_value))
      fail(where, "default " + num(p.default_value) + " is outside [" + num(p.min_value) + ", " + num(p.max_value) + "]");
    if (p.null_value && !(*p.null_value >= p.min_value && *p.null_value <= p.max_value))
      fail(where, "null " + num(*p.null_value) + " is outside [" + num(p.min_value) + ", " + num(p.max_value) + "]");
  }
  for (const auto& [key, value] : def.starts) {
    const EffectParameter* p = nullptr;
    for (const auto& q : def.parameters)
      if (q.key == key) p = &q;
    if (p == nullptr) fail("parameters." + key, "start given for an unknown parameter");
    if (!(value >= p->min_value && value <= p->max_value))
      fail("parameters." + key, "start " + num(value) + " is outside [" + num(p->min_value) + ", " + num(p->max_value) + "]");
  }
  // Compile and evaluate on a grid of states: the parameters at their defaults, then all at their
  // minima, then all at their maxima.
  std::vector<EffectValues> sets(3);
  for (const auto& p : def.parameters) {
    sets[0][p.key] = p.default_value;
    sets[1][p.key] = p.min_value;
    sets[2][p.key] = p.max_value;
  }
  check_expression(def.force, "force", def.parameters, sets, fail);
  for (std::size_t k = 0; k < def.kinks.size(); ++k)
    check_expression(def.kinks[k], "kinks[" + std::to_string(k) + "]", def.parameters, sets, fail);

  EffectDescriptor d;
  d.name = def.name;
  d.kind = EffectKind::kDynamics;
  d.explanation = "user-defined force on the mesh coordinate: " + def.force + " (N)";
  for (const auto& k : def.kinks) d.explanation += "; kink where " + k + " = 0";
  d.signature = "defined by its expression";
  d.parameters = def.parameters;
  const std::string name = def.name, text = def.force;
  const std::vector<std::string> kinks = def.kinks;
  const std::vector<EffectParameter> params = def.parameters;
  d.create = [name, text, kinks, params](const EffectValues& values, const RigParameters&) -> std::unique_ptr<Effect> {
    return std::make_unique<CustomForce>(name, text, kinks, params, values);
  };
  return d;
}

}  // namespace ridgewatch::model
