// Strict YAML reading shared by the rig files and the daemon configuration: every problem is a
// UsageError (exit 2) "<file>: <yaml.path>: <what is wrong>", unknown keys are errors that list the
// known ones, numbers must be finite.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <set>
#include <sstream>
#include <string>

#include "app/args.hpp"

namespace ridgewatch::app {

class YamlReader {
 public:
  explicit YamlReader(std::string name) : name_(std::move(name)) {}

  const std::string& name() const { return name_; }

  [[noreturn]] void fail(const std::string& path, const std::string& message) const {
    throw UsageError(name_ + ": " + (path.empty() ? "" : path + ": ") + message);
  }

  /// Parses text; syntax errors name the file and line.
  YAML::Node parse(const std::string& text) const {
    try {
      return YAML::Load(text);
    } catch (const YAML::Exception& e) {
      fail("", std::string("not valid YAML: ") + e.what());
    }
  }

  /// `node` must be a mapping whose keys are all in `allowed`.
  void check_map(const YAML::Node& node, const std::string& path, const std::set<std::string>& allowed) const {
    if (!node.IsMap()) fail(path.empty() ? "(top level)" : path, "must be a mapping");
    for (const auto& kv : node) {
      if (!kv.first.IsScalar()) fail(path.empty() ? "(top level)" : path, "keys must be plain names");
      const std::string key = kv.first.Scalar();
      if (!allowed.count(key)) {
        std::string known;
        for (const auto& k : allowed) known += (known.empty() ? "" : ", ") + k;
        fail(join(path, key), "unknown key (known: " + known + ")");
      }
    }
  }

  static std::string join(const std::string& path, const std::string& key) {
    return path.empty() ? key : path + "." + key;
  }

  static std::string format(double x) {
    std::ostringstream os;
    os << x;
    return os.str();
  }

  double number(const YAML::Node& node, const std::string& path) const {
    if (!node.IsScalar()) fail(path, "must be a number");
    double x = 0.0;
    try {
      x = node.as<double>();
    } catch (const YAML::Exception&) {
      fail(path, "must be a number (got '" + node.Scalar() + "')");
    }
    if (!std::isfinite(x)) fail(path, "must be a finite number (got " + node.Scalar() + ")");
    return x;
  }

  /// Required number with a rule: "positive", "non-negative" or "any".
  double required(const YAML::Node& parent, const std::string& path, const std::string& key,
                  const std::string& rule) const {
    const YAML::Node n = child(parent, path, key);
    if (!n) fail(join(path, key), "missing (required)");
    return checked(n, join(path, key), rule);
  }

  double optional(const YAML::Node& parent, const std::string& path, const std::string& key,
                  const std::string& rule, double fallback) const {
    const YAML::Node n = child(parent, path, key);
    if (!n) return fallback;
    return checked(n, join(path, key), rule);
  }

  /// Required whole positive count (e.g. teeth), at most 100000.
  int required_count(const YAML::Node& parent, const std::string& path, const std::string& key) const {
    const double x = required(parent, path, key, "positive");
    if (x != std::floor(x) || x > 100000) fail(join(path, key), "must be a whole number (got " + format(x) + ")");
    return static_cast<int>(x);
  }

  // Overlay readers: leave `field` unchanged when the key is absent.
  void read(const YAML::Node& parent, const std::string& path, const std::string& key, double& field) const {
    if (const YAML::Node n = child(parent, path, key)) field = number(n, join(path, key));
  }
  void read(const YAML::Node& parent, const std::string& path, const std::string& key, bool& field) const {
    const YAML::Node n = child(parent, path, key);
    if (!n) return;
    try {
      if (!n.IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
      field = n.as<bool>();
    } catch (const YAML::Exception&) {
      fail(join(path, key), "must be true or false");
    }
  }
  void read(const YAML::Node& parent, const std::string& path, const std::string& key, std::string& field) const {
    const YAML::Node n = child(parent, path, key);
    if (!n) return;
    if (!n.IsScalar()) fail(join(path, key), "must be a string");
    field = n.Scalar();
  }
  template <typename Int>
  void read_count(const YAML::Node& parent, const std::string& path, const std::string& key, Int& field,
                  long long lo, long long hi) const {
    const YAML::Node n = child(parent, path, key);
    if (!n) return;
    const double x = number(n, join(path, key));
    if (x != std::floor(x) || x < static_cast<double>(lo) || x > static_cast<double>(hi))
      fail(join(path, key), "must be a whole number in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                                "] (got " + n.Scalar() + ")");
    field = static_cast<Int>(x);
  }

 private:
  /// parent[key], or a UsageError naming `path` when parent is a scalar or sequence (yaml-cpp would
  /// throw its own BadSubscript, which is no message for a user).
  YAML::Node child(const YAML::Node& parent, const std::string& path, const std::string& key) const {
    if (parent && !parent.IsNull() && !parent.IsMap()) fail(path.empty() ? "(top level)" : path, "must be a mapping");
    return parent[key];
  }

  double checked(const YAML::Node& n, const std::string& path, const std::string& rule) const {
    const double x = number(n, path);
    if (rule == "positive" && !(x > 0)) fail(path, "must be > 0 (got " + format(x) + ")");
    if (rule == "non-negative" && x < 0) fail(path, "must be >= 0 (got " + format(x) + ")");
    return x;
  }

  std::string name_;
};

}  // namespace ridgewatch::app
