// Small command-line flag parser shared by the subcommands. Every error is a UsageError whose message
// names the flag and what is wrong; main() maps it to exit code 2.
#pragma once

#include <map>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace ridgewatch::app {

inline constexpr int kExitOk = 0;
inline constexpr int kExitUsage = 2;     ///< bad usage or configuration; the message names the flag/key
inline constexpr int kExitBadInput = 3;  ///< bad input data; the message names the file and the problem

class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Thrown by Args when "--help" is among the arguments (and the command does not parse --help
/// itself): main() prints the command's help from app/usage.cpp and exits 0. Carries the flags the
/// command's Args accepts, so tests can compare them with the usage table.
class HelpRequested : public std::exception {
 public:
  HelpRequested(std::set<std::string> valued_flags, std::set<std::string> switch_flags)
      : valued(std::move(valued_flags)), switches(std::move(switch_flags)) {}
  const char* what() const noexcept override { return "--help"; }
  std::set<std::string> valued, switches;
};

class Args {
 public:
  /// `valued`: flags that take a value (`--rate 10000` or `--rate=10000`), may repeat.
  /// `switches`: flags without a value. Anything else starting with "--" is an error, except
  /// "--help", which throws HelpRequested unless it is one of `switches`.
  Args(const std::vector<std::string>& argv, std::set<std::string> valued, std::set<std::string> switches);

  bool has(const std::string& flag) const;
  std::optional<std::string> value(const std::string& flag) const;  ///< last occurrence
  std::vector<std::string> values(const std::string& flag) const;   ///< all occurrences
  const std::vector<std::string>& positional() const { return positional_; }

  /// Value of a numeric flag, checked to lie in [lo, hi]; `fallback` when absent.
  double number(const std::string& flag, double fallback, double lo, double hi) const;
  long long integer(const std::string& flag, long long fallback, long long lo, long long hi) const;
  std::optional<double> optional_number(const std::string& flag, double lo, double hi) const;

 private:
  std::set<std::string> valued_, switches_;
  std::map<std::string, std::vector<std::string>> seen_;
  std::vector<std::string> positional_;
};

}  // namespace ridgewatch::app
