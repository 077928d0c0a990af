// `ridgewatch analyze FILE [--config F] [--channel N] [--rate HZ]`: the streaming pipeline
// (core/pipeline/stream_processor.hpp, the same code ridgewatchd runs) over a file as fast as possible.
// stdout: one JSON line per impact event (cli/event_json.hpp), nothing else. stderr: a summary line.
#include <array>
#include <cmath>
#include <ostream>
#include <stdexcept>
#include <vector>

#include "cli/args.hpp"
#include "cli/commands.hpp"
#include "cli/replay_flags.hpp"
#include "cli/config_yaml.hpp"
#include "cli/event_json.hpp"
#include "core/pipeline/stream_processor.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::cli {

int run_analyze(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv, {"--config", "--channel", "--rate"}, {});
  const std::string& path = single_file(args);
  const drivers::ReplayOptions ropt = replay_options(args);

  pipeline::PipelineConfig cfg = default_config().pipeline;
  std::string cfg_name = "defaults";
  if (const auto file = args.value("--config")) {
    cfg = load_config_file(*file).pipeline;  // UsageError naming the file and YAML key
    cfg_name = *file;
  }

  auto source = drivers::open_replay(path, ropt);
  cfg.sample_rate_hz = source->info().sample_rate_hz;
  resolve_format_defaults(cfg, source->info().full_scale);  // clip_level from the file's format
  try {
    pipeline::validate(cfg);
  } catch (const std::invalid_argument& e) {
    // Only reachable through the sample rate of the file (the config loader checks each key alone):
    // name both the key and the file.
    throw UsageError(cfg_name + ": pipeline." + e.what() + " with the sample rate of " + path + " (" +
                     std::to_string(cfg.sample_rate_hz) + " Hz)");
  }
  pipeline::StreamProcessor processor(cfg);

  constexpr std::size_t kBlock = 4096;
  std::vector<float> block(kBlock);
  std::vector<pipeline::ImpactEvent> events;
  events.reserve(64);
  std::uint64_t index = 0;
  auto emit = [&] {
    for (const auto& e : events) out << event_json(e, path) << "\n";
    events.clear();
  };
  for (;;) {
    // Single precision straight from the decoder, as ridgewatchd reads it; InputError (exit 3) names
    // the file.
    const std::size_t n = source->read_float(block);
    if (n == 0) break;
    processor.process(std::span<const float>(block.data(), n), index, events);
    index += n;
    emit();
  }
  processor.flush(events);
  emit();
  out.flush();
  err << "analyze: " << path << ": " << index << " samples, " << processor.impacts_detected() << " impacts, "
      << processor.spikes_seen() << " spikes\n";
  if (processor.impacts_detected() == 0 && index > 0)
    err << "analyze: no impacts in the band watched, " << cfg.detector.band_lo_hz << "-" << cfg.detector.band_hi_hz
        << " Hz (pipeline.detector.band_lo_hz/band_hi_hz of " << cfg_name << ", f_expected_hz "
        << cfg.analyzer.f_expected_hz << "); if this rig's impacts ring elsewhere, `ridgewatch survey " << path
        << " --write-config OUT.yaml` finds their band and proposes a configuration\n";
  return kExitOk;
}

}  // namespace ridgewatch::cli
