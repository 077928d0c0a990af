// ridgewatchd: the monitoring daemon. Usually started by systemd (systemd/ridgewatchd.service).
#include <signal.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <span>
#include <iostream>
#include <string>
#include <vector>

#include "app/args.hpp"
#include "app/config_yaml.hpp"
#include "app/usage.hpp"
#include "app/survey_report.hpp"
#include "daemon/daemon.hpp"
#include "daemon/relay_test.hpp"
#include "daemon/sources.hpp"
#include "drivers/replay_file.hpp"
#include "drivers/alsa_source.hpp"
#include "drivers/gpio.hpp"
#include "drivers/sample_source.hpp"
#include "ridgewatch_version.hpp"

namespace {

namespace app = ridgewatch::app;
using ridgewatch::daemon::Daemon;

extern "C" void on_signal(int sig) {
  switch (sig) {
    case SIGTERM:
    case SIGINT: Daemon::request_stop(); break;
    case SIGHUP: Daemon::request_reload(); break;
    case SIGUSR1: Daemon::request_latch_reset(); break;
    default: break;
  }
}

void install_signal_handlers() {
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;
  for (int sig : {SIGTERM, SIGINT, SIGHUP, SIGUSR1}) sigaction(sig, &sa, nullptr);
  signal(SIGPIPE, SIG_IGN);  // a closed stdout reader must not kill the daemon; writes report EPIPE
}

void setup_logging(const std::string& level) {
  auto logger = spdlog::stderr_logger_st("ridgewatchd");
  // Under systemd (JOURNAL_STREAM set) journald adds the timestamp itself.
  logger->set_pattern(std::getenv("JOURNAL_STREAM") ? "%l: %v" : "%Y-%m-%d %H:%M:%S.%e %l: %v");
  logger->set_level(spdlog::level::from_str(level));
  logger->flush_on(spdlog::level::trace);
  spdlog::set_default_logger(logger);
}

// --survey SECONDS: record that long from the configured source (nothing else is started: no event
// log, no relays, no notification) and print the survey report of app/survey_report.hpp; --write-config OUT merges
// the proposal into a copy of --config (or of the defaults).
int run_survey_mode(const app::Args& args, const app::RidgewatchConfig& config, const std::optional<std::string>& config_path) {
  const double seconds = args.number("--survey", 0.0, 0.5, 3600.0);
  app::SurveyOutput output;
  output.write_config = args.value("--write-config");
  output.base_config = config_path;
  app::check_survey_output(output);
  auto source = ridgewatch::daemon::open_source(config, config_path.value_or("configuration"));
  const double fs = source->info().sample_rate_hz;
  const auto want = static_cast<std::size_t>(std::llround(seconds * fs));
  std::vector<double> x;
  x.reserve(want);
  std::vector<double> block(4096);
  while (x.size() < want) {
    const std::size_t n = source->read(std::span<double>(block.data(), std::min(block.size(), want - x.size())));
    if (n == 0) break;
    x.insert(x.end(), block.begin(), block.begin() + static_cast<std::ptrdiff_t>(n));
  }
  if (x.size() < want)
    std::cerr << "ridgewatchd: survey: the source ended after " << static_cast<double>(x.size()) / fs << " s of the "
              << seconds << " s asked for\n";
  if (x.size() < 64) throw ridgewatch::drivers::InputError(source->info().name + ": too few samples for a survey");
  return app::survey_and_report(x, fs, source->info().name, {}, output, std::cout, std::cerr);
}

int run(const std::vector<std::string>& argv) {
  // The flags come from the usage table (app/usage.cpp), which also makes --help and the man page.
  const app::Args args = app::usage::parse(argv, app::usage::daemon());
  if (!args.positional().empty()) throw app::UsageError("unexpected argument '" + args.positional().front() + "'");
  if (args.has("--version")) {
    std::cout << "ridgewatchd " << RIDGEWATCH_VERSION << "\n";
    return app::kExitOk;
  }
  if (args.has("--print-defaults")) {
    std::cout << app::to_yaml(app::default_config());
    return app::kExitOk;
  }
  if (args.has("--list-devices")) {
    std::cout << "ALSA capture devices (source.alsa.device):\n"
              << ridgewatch::drivers::describe_alsa_capture_devices() << "\nGPIO chips and lines (gpio section):\n"
              << ridgewatch::drivers::describe_gpio_chips();
    return app::kExitOk;
  }
  if (const auto file = args.value("--check-config")) {
    const app::RidgewatchConfig checked = app::load_config_file(*file);  // throws UsageError naming the key
    app::combine_gains(checked, *file);  // the daemon has no --rig: mesh_velocity needs the rig key
    for (std::size_t i = 0; i < checked.streams.size(); ++i) {
      app::combine_gains(checked.streams[i], *file, "streams[" + std::to_string(i) + "].combine");  // needs its rig
      // A replayed file that is there already: its channels must exist (a missing file is not an
      // error of the configuration: --replay may name it at start).
      const std::string path = ridgewatch::daemon::stream_path(checked, i);
      std::error_code ec;
      if (checked.source.type == "replay" && !path.empty() && std::filesystem::is_regular_file(path, ec))
        app::check_stream_channels(checked, *file, i,
                                   ridgewatch::drivers::open_replay(path, {})->info().channels);
    }
    std::cout << *file << ": ok\n";
    return app::kExitOk;
  }

  const auto config_path = args.value("--config");
  // Command-line overrides, applied on top of the file at start and after every reload.
  auto overrides = [&args](app::RidgewatchConfig& c) {
    if (const auto f = args.value("--replay")) {
      c.source.type = "replay";
      c.source.replay.path = *f;
    }
    if (const auto s = args.value("--speed")) {
      if (*s == "max") {
        c.source.replay.speed = 0.0;
      } else {
        c.source.replay.speed = args.number("--speed", 1.0, 1e-3, 1e6);
      }
    }
    if (args.has("--loop")) c.source.replay.loop = true;
    if (args.has("--channel")) {
      const auto ch = static_cast<std::size_t>(args.integer("--channel", 0, 0, 1023));
      c.source.replay.channel = ch;
      c.source.alsa.channel = ch;
    }
    if (const auto e = args.value("--events")) c.output.events = *e;
    if (const auto e = args.value("--csv")) c.output.csv = *e;
    if (const auto e = args.value("--capture-dir")) c.output.capture.dir = *e;
    if (const auto e = args.value("--log-level")) c.logging.level = *e;
  };
  app::RidgewatchConfig config = config_path ? app::load_config_file(*config_path) : app::default_config();
  overrides(config);
  if (args.has("--test-relays")) {
    if (!config.gpio.enabled) throw app::UsageError("--test-relays: gpio.enabled is false in the configuration");
    ridgewatch::daemon::GpioLines lines = ridgewatch::daemon::open_gpio(config.gpio);  // GpioError: exit 3
    return ridgewatch::daemon::test_relays(lines, std::cin, std::cout, args.has("--yes"), std::chrono::seconds(2));
  }
  if (args.has("--yes")) throw app::UsageError("--yes goes with --test-relays");
  if (args.has("--channel") && !config.streams.empty())
    throw app::UsageError("--channel: not with streams in the configuration (each stream names its channel)");
  // The one stream, or any stream without its own path, reads source.replay.path.
  const bool needs_path = config.streams.empty() || std::any_of(config.streams.begin(), config.streams.end(),
                                                                [](const auto& s) { return s.path.empty(); });
  if (config.source.type == "replay" && config.source.replay.path.empty() && needs_path)
    throw app::UsageError("no input: set source.replay.path in the configuration or pass --replay FILE");
  if (const auto lvl = args.value("--log-level");
      lvl && *lvl != "trace" && *lvl != "debug" && *lvl != "info" && *lvl != "warn" && *lvl != "error")
    throw app::UsageError("--log-level: '" + *lvl + "' is not one of trace, debug, info, warn, error");

  if (args.has("--survey")) return run_survey_mode(args, config, config_path);
  if (args.has("--write-config")) throw app::UsageError("--write-config: only with --survey SECONDS");

  setup_logging(config.logging.level);
  install_signal_handlers();
  ridgewatch::daemon::DaemonOptions options;
  options.config = config;
  options.config_path = config_path.value_or("");
  options.overrides = overrides;
  options.max_samples = static_cast<std::uint64_t>(args.integer("--max-samples", 0, 0, 1LL << 50));
  Daemon daemon(std::move(options));
  return daemon.run();
}

}  // namespace

int main(int argc, char** argv) {
  ridgewatch::drivers::silence_alsa_lib_errors();  // the daemon names the device in its own messages
  try {
    return run(std::vector<std::string>(argv + 1, argv + argc));
  } catch (const app::UsageError& e) {
    std::cerr << "ridgewatchd: " << e.what() << "\n";
    return app::kExitUsage;
  } catch (const app::HelpRequested&) {
    std::cout << app::usage::command_help(app::usage::daemon(), "ridgewatchd");
    return app::kExitOk;
  } catch (const ridgewatch::drivers::InputError& e) {
    std::cerr << "ridgewatchd: " << e.what() << "\n";
    return app::kExitBadInput;
  } catch (const ridgewatch::drivers::GpioError& e) {
    std::cerr << "ridgewatchd: " << e.what() << "\n";
    return app::kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "ridgewatchd: internal error: " << e.what() << "\n";
    return 1;
  }
}
