#include "app/args.hpp"

#include <charconv>
#include <cmath>
#include <system_error>

namespace ridgewatch::app {

Args::Args(const std::vector<std::string>& argv, std::set<std::string> valued,
           std::set<std::string> switches)
    : valued_(std::move(valued)), switches_(std::move(switches)) {
  if (!switches_.count("--help"))
    for (const auto& a : argv)
      if (a == "--help") throw HelpRequested(valued_, switches_);
  for (std::size_t i = 0; i < argv.size(); ++i) {
    const std::string& a = argv[i];
    if (a.size() > 2 && a.rfind("--", 0) == 0) {
      std::string name = a, val;
      bool inline_value = false;
      if (const auto eq = a.find('='); eq != std::string::npos) {
        name = a.substr(0, eq);
        val = a.substr(eq + 1);
        inline_value = true;
      }
      if (switches_.count(name)) {
        if (inline_value) throw UsageError(name + " takes no value");
        seen_[name].emplace_back();
      } else if (valued_.count(name)) {
        if (!inline_value) {
          if (i + 1 >= argv.size()) throw UsageError(name + " needs a value");
          val = argv[++i];
        }
        seen_[name].push_back(val);
      } else {
        throw UsageError("unknown flag " + name);
      }
    } else {
      positional_.push_back(a);
    }
  }
}

bool Args::has(const std::string& flag) const { return seen_.count(flag) > 0; }

std::optional<std::string> Args::value(const std::string& flag) const {
  auto it = seen_.find(flag);
  if (it == seen_.end() || it->second.empty()) return std::nullopt;
  return it->second.back();
}

std::vector<std::string> Args::values(const std::string& flag) const {
  auto it = seen_.find(flag);
  return it == seen_.end() ? std::vector<std::string>{} : it->second;
}

std::optional<double> Args::optional_number(const std::string& flag, double lo, double hi) const {
  const auto v = value(flag);
  if (!v) return std::nullopt;
  double x = 0.0;
  const char* first = v->data();
  const char* last = v->data() + v->size();
  const auto res = std::from_chars(first, last, x);
  if (v->empty() || res.ec != std::errc() || res.ptr != last || !std::isfinite(x))
    throw UsageError(flag + ": '" + *v + "' is not a number");
  if (x < lo || x > hi)
    throw UsageError(flag + ": " + *v + " is out of range [" + std::to_string(lo) + ", " +
                     std::to_string(hi) + "]");
  return x;
}

double Args::number(const std::string& flag, double fallback, double lo, double hi) const {
  return optional_number(flag, lo, hi).value_or(fallback);
}

long long Args::integer(const std::string& flag, long long fallback, long long lo, long long hi) const {
  const auto v = value(flag);
  if (!v) return fallback;
  long long x = 0;
  const char* last = v->data() + v->size();
  const auto res = std::from_chars(v->data(), last, x);
  if (v->empty() || res.ec != std::errc() || res.ptr != last)
    throw UsageError(flag + ": '" + *v + "' is not a whole number");
  if (x < lo || x > hi)
    throw UsageError(flag + ": " + *v + " is out of range [" + std::to_string(lo) + ", " +
                     std::to_string(hi) + "]");
  return x;
}

}  // namespace ridgewatch::app
