// Flags every file-reading subcommand shares: exactly one FILE, --channel N and --rate HZ.
#pragma once

#include <string>

#include "cli/app_names.hpp"
#include "app/args.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::cli {

/// The single positional FILE argument (UsageError otherwise).
inline const std::string& single_file(const Args& args) {
  if (args.positional().size() != 1)
    throw UsageError("expects exactly one FILE (got " + std::to_string(args.positional().size()) + ")");
  return args.positional()[0];
}

/// --channel N (0-based) and --rate HZ (one-column CSV files) as replay options.
inline drivers::ReplayOptions replay_options(const Args& args) {
  drivers::ReplayOptions ropt;
  ropt.channel = static_cast<std::size_t>(args.integer("--channel", 0, 0, 1023));
  ropt.csv_rate_hz = args.optional_number("--rate", drivers::kMinReplayRateHz, drivers::kMaxReplayRateHz);
  return ropt;
}

}  // namespace ridgewatch::cli
