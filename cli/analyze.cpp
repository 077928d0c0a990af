// `ridgewatch analyze FILE [--config F] [--rig R] [--channel N | --all-channels] [--rate HZ]`: the
// streaming pipeline (core/pipeline/stream_processor.hpp, the same code ridgewatchd runs) over a file
// as fast as possible. stdout: one JSON line per impact event (app/event_json.hpp), nothing else.
// stderr: a summary line per stream (and, with a rig, the measured f against the model's f_d).
//
// Streams: one channel (--channel, default 0); a derived channel (source.combine of --config: a linear
// combination of channels, e.g. the mesh coordinate q̇ = r_b1 φ̇1 + r_b2 φ̇2); or --all-channels, one
// stream per channel with the same pipeline configuration, events carrying "stream": "ch<N>" (N 0-based)
// and printed in time order (sample_index, then channel) once the file is done.
//
// --summary FILE...: the paper's Figure 9 as numbers. Instead of the events, one JSON object: per file
// and stream the count of events and of `ok` events, the mean ζ of the ok events, their standard
// deviation (spread) and the 95 % interval of the mean (Student t), the mean and spread of f; and the
// same over all ok events of all files pooled. With --plots DIR also DIR/summary.svg (cli/plot_summary.hpp)
// and DIR/index.html.
#include <algorithm>
#include <array>
#include <atomic>
#include <exception>
#include <cmath>
#include <filesystem>
#include <memory>
#include <optional>
#include <ostream>
#include <stdexcept>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "app/args.hpp"
#include "cli/commands.hpp"
#include "cli/plot_summary.hpp"
#include "cli/replay_flags.hpp"
#include "app/config_yaml.hpp"
#include "app/event_json.hpp"
#include "app/rig_defaults.hpp"
#include "core/pipeline/stream_processor.hpp"
#include "drivers/combined_source.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::cli {

namespace {

struct Stream {
  std::string name;  // "ch<N>" with --all-channels, else empty (no stream key in the events)
  std::unique_ptr<drivers::SampleSource> source;
  std::unique_ptr<pipeline::StreamProcessor> processor;
  std::uint64_t index = 0;
};

/// Two-sided 95 % quantile of Student's t with nu degrees of freedom: exact to 3 decimals from tables for
/// nu <= 5, beyond by the Cornish-Fisher expansion in 1/nu (error < 5e-4 at nu = 6, falling as nu^-4).
double t975(std::size_t nu) {
  static constexpr double table[] = {0, 12.706, 4.303, 3.182, 2.776, 2.571};
  if (nu <= 5) return table[nu];
  const double z = 1.959963984540054, v = static_cast<double>(nu);
  const double z3 = z * z * z, z5 = z3 * z * z, z7 = z5 * z * z;
  return z + (z3 + z) / (4 * v) + (5 * z5 + 16 * z3 + 3 * z) / (96 * v * v) +
         (3 * z7 + 19 * z5 + 17 * z3 - 15 * z) / (384 * v * v * v);
}

/// Per-stream figures of --summary: the ok events' ζ and f (kept, for a two-pass standard deviation:
/// the sum-of-squares formula cancels to 0 for a spread of 1e-8 around 0.024).
struct Tally {
  std::uint64_t events = 0;
  std::vector<double> zeta, f;
  void add(const pipeline::ImpactEvent& e) {
    ++events;
    if (e.status != pipeline::ImpactStatus::ok || !std::isfinite(e.zeta) || !std::isfinite(e.f_hz)) return;
    zeta.push_back(e.zeta);
    f.push_back(e.f_hz);
  }
  void add(const Tally& t) {
    events += t.events;
    zeta.insert(zeta.end(), t.zeta.begin(), t.zeta.end());
    f.insert(f.end(), t.f.begin(), t.f.end());
  }
  static double mean(const std::vector<double>& x) {
    double s = 0;
    for (double v : x) s += v;
    return x.empty() ? NAN : s / static_cast<double>(x.size());
  }
  static double sd(const std::vector<double>& x) {
    if (x.size() < 2) return NAN;
    const double m = mean(x);
    double s = 0;
    for (double v : x) s += (v - m) * (v - m);
    return std::sqrt(s / static_cast<double>(x.size() - 1));
  }
  /// Half-width of the 95 % interval of the mean ζ (Student t, ok - 1 degrees of freedom); NaN below 2.
  double half_ci95() const {
    const std::size_t ok = zeta.size();
    return ok >= 2 ? t975(ok - 1) * sd(zeta) / std::sqrt(static_cast<double>(ok)) : NAN;
  }
  /// Adds the figures to `j` (after any keys it has).
  void put(nlohmann::ordered_json& j) const {
    auto num = [](double x) { return std::isfinite(x) ? nlohmann::ordered_json(x) : nlohmann::ordered_json(nullptr); };
    const double zm = mean(zeta), half = half_ci95();
    j["events"] = events;
    j["ok"] = zeta.size();
    j["zeta_mean"] = num(zm);
    j["zeta_sd"] = num(sd(zeta));
    j["zeta_mean_ci95"] = {num(zm - half), num(zm + half)};
    j["f_mean_hz"] = num(mean(f));
    j["f_sd_hz"] = num(sd(f));
  }
  /// The figures --plots draws for this tally.
  plots::SummaryGroup group(std::string label) const {
    const double m = mean(zeta), half = half_ci95();
    return {std::move(label), zeta, m, m - half, m + half};
  }
};

}  // namespace

int run_analyze(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv, {"--config", "--channel", "--rate", "--rig", "--jobs", "--plots"}, {"--all-channels", "--summary"});
  const auto jobs = static_cast<std::size_t>(args.integer("--jobs", 1, 1, 256));
  const bool summary = args.has("--summary");
  if (!summary) single_file(args);  // exactly one FILE unless --summary
  if (args.positional().empty()) throw UsageError("expects FILE (--summary: one or more)");
  if (args.has("--plots") && !summary) throw UsageError("--plots: only with --summary (the plot shows the summary)");
  std::filesystem::path plot_dir;
  if (const auto d = args.value("--plots")) plot_dir = plots::prepare_dir(*d);  // before any work
  const drivers::ReplayOptions ropt = replay_options(args);
  const bool all_channels = args.has("--all-channels");
  if (all_channels && args.has("--channel")) throw UsageError("--all-channels: not with --channel");

  RidgewatchConfig full = default_config();
  std::string cfg_name = "defaults";
  if (const auto file = args.value("--config")) {
    full = load_config_file(*file);  // UsageError naming the file and YAML key
    cfg_name = *file;
  }
  // --rig replaces the configuration's `rig`; keys the configuration gives still win.
  if (const auto rig = args.value("--rig")) apply_rig_defaults(full, *rig, "--rig");
  const RigModelInfo& model = full.rig_model;
  if (!model.note.empty()) err << "analyze: warning: " << model.path << ": " << model.note << "\n";
  const CombineConfig& combine = full.source.combine;
  const bool combined = combine.type != "none";
  if (combined && (all_channels || args.has("--channel")))
    throw UsageError(std::string(all_channels ? "--all-channels" : "--channel") + ": not with source.combine of " +
                     cfg_name + " (the combination names its channels)");

  nlohmann::ordered_json per_stream = nlohmann::ordered_json::array();
  std::vector<plots::SummaryGroup> groups;  // for --plots
  Tally overall;
  for (const std::string& path : args.positional()) {
    pipeline::PipelineConfig cfg = full.pipeline;  // per file: rate and clip level come from the file
    std::vector<Stream> streams;
    if (combined) {
      const std::size_t available = drivers::open_replay(path, ropt)->info().channels;
      const std::vector<double> gains = combine_gains(full, cfg_name, available);  // UsageError naming the key
      if (combine.type == "mesh_velocity" && !model.radius_note.empty())
        err << "analyze: warning: " << model.path << ": " << model.radius_note << "\n";
      streams.push_back({"", drivers::open_combined_replay(path, combine.channels, gains, ropt.csv_rate_hz), nullptr});
    } else {
      streams.push_back({"", drivers::open_replay(path, ropt), nullptr});
      if (all_channels) {
        const std::size_t n = streams.front().source->info().channels;
        streams.front().name = "ch0";
        for (std::size_t ch = 1; ch < n; ++ch) {
          drivers::ReplayOptions o = ropt;
          o.channel = ch;
          streams.push_back({"ch" + std::to_string(ch), drivers::open_replay(path, o), nullptr});
        }
      }
    }
    const drivers::SourceInfo& info = streams.front().source->info();
    cfg.sample_rate_hz = info.sample_rate_hz;
    resolve_format_defaults(cfg, info.full_scale);  // clip_level from the file's format
    try {
      pipeline::validate(cfg);
    } catch (const std::invalid_argument& e) {
      // Only reachable through the sample rate of the file (the config loader checks each key alone):
      // name both the key and the file.
      throw UsageError(cfg_name + ": pipeline." + e.what() + " with the sample rate of " + path + " (" +
                       std::to_string(cfg.sample_rate_hz) + " Hz)");
    }
    if (combined && std::isnan(cfg.analyzer.clip_level))
      err << "analyze: note: the derived channel has no full scale; the clipping check is off unless "
             "pipeline.analyzer.clip_level is set (in the combination's units)\n";
    for (Stream& s : streams) s.processor = std::make_unique<pipeline::StreamProcessor>(cfg);

    constexpr std::size_t kBlock = 4096;
    std::optional<ModelGap> gap;
    if (!model.path.empty()) gap.emplace(model.f_d_hz);
    std::vector<Tally> tallies(streams.size());
    auto account = [&](std::size_t s, const pipeline::ImpactEvent& e) {
      if (gap && e.status == pipeline::ImpactStatus::ok) gap->add_ok(e.f_hz);
      if (summary) tallies[s].add(e);
    };
    // One stream: its events are printed block by block as they complete. Several: each stream runs to
    // its end on one of --jobs threads (streams share nothing but the file; their processors, FFT plans
    // included, are made above on this thread), and the events are printed in time order at the end (an
    // event is final only when its decay window is, up to window_s after its onset, so streams finish
    // events at different moments).
    const bool print_as_we_go = streams.size() == 1 && !summary;
    std::vector<std::vector<pipeline::ImpactEvent>> sinks(streams.size());
    auto run_stream = [&](std::size_t s) {
      Stream& st = streams[s];
      std::vector<float> block(kBlock);
      std::vector<pipeline::ImpactEvent>& events = sinks[s];
      events.reserve(64);
      for (bool more = true; more;) {
        // Single precision straight from the decoder, as ridgewatchd reads it; InputError (exit 3)
        // names the file.
        const std::size_t n = st.source->read_float(block);
        if (n == 0) {
          st.processor->flush(events);
          more = false;
        } else {
          st.processor->process(std::span<const float>(block.data(), n), st.index, events);
          st.index += n;
        }
        if (print_as_we_go) {
          for (const auto& e : events) {
            account(s, e);
            out << event_json(e, path) << "\n";
          }
          events.clear();
        }
      }
    };
    if (streams.size() == 1) {
      run_stream(0);
    } else {
      std::atomic<std::size_t> next{0};
      std::vector<std::exception_ptr> failures(streams.size());
      auto worker = [&] {
        for (std::size_t s; (s = next.fetch_add(1)) < streams.size();) {
          try {
            run_stream(s);
          } catch (...) {
            failures[s] = std::current_exception();
          }
        }
      };
      std::vector<std::thread> pool;
      for (std::size_t j = 1; j < std::min<std::size_t>(jobs, streams.size()); ++j) pool.emplace_back(worker);
      worker();
      for (auto& t : pool) t.join();
      for (const auto& f : failures)
        if (f) std::rethrow_exception(f);  // the first stream's error, as the serial order would give
    }
    struct Held {
      pipeline::ImpactEvent e;
      std::size_t stream;
    };
    std::vector<Held> held;
    for (std::size_t s = 0; s < streams.size(); ++s)
      for (const auto& e : sinks[s]) {
        account(s, e);
        if (!summary) held.push_back({e, s});
      }
    std::stable_sort(held.begin(), held.end(), [](const Held& a, const Held& b) {
      return a.e.sample_index != b.e.sample_index ? a.e.sample_index < b.e.sample_index : a.stream < b.stream;
    });
    for (const Held& h : held) out << event_json(h.e, path, {}, streams[h.stream].name) << "\n";
    if (!summary) out.flush();
    for (std::size_t k = 0; k < streams.size() && summary; ++k) {
      nlohmann::ordered_json j;
      j["source"] = path;
      if (!streams[k].name.empty()) j["stream"] = streams[k].name;
      tallies[k].put(j);
      per_stream.push_back(j);
      overall.add(tallies[k]);
      const std::string label = std::filesystem::path(path).filename().string();
      groups.push_back(tallies[k].group(streams[k].name.empty() ? label : label + " " + streams[k].name));
    }
    std::uint64_t impacts = 0;
    for (const Stream& st : streams) {
      const auto& p = *st.processor;
      impacts += p.impacts_detected();
      err << "analyze: " << (combined ? st.source->info().name : path) << (st.name.empty() ? "" : " " + st.name) << ": "
          << st.index << " samples, " << p.impacts_detected() << " impacts, " << p.spikes_seen() << " spikes\n";
    }
    if (gap)
      err << "analyze: rig " << model.path << ": " << gap->text() << " (f_expected_hz "
          << (model.f_expected ? "from the rig" : "from " + cfg_name) << ", detector band "
          << std::round(10 * cfg.detector.band_lo_hz) / 10 << "-" << std::round(10 * cfg.detector.band_hi_hz) / 10 << " Hz "
          << (model.band ? "from the rig" : "from " + cfg_name) << ")\n";
    if (impacts == 0 && streams.front().index > 0)
      err << "analyze: no impacts in the band watched, " << cfg.detector.band_lo_hz << "-" << cfg.detector.band_hi_hz
          << " Hz (pipeline.detector.band_lo_hz/band_hi_hz of " << cfg_name << ", f_expected_hz "
          << cfg.analyzer.f_expected_hz << "); if this rig's impacts ring elsewhere, `ridgewatch survey " << path
          << " --write-config OUT.yaml` finds their band and proposes a configuration\n";
  }
  if (summary) {
    nlohmann::ordered_json o;
    overall.put(o);
    o["files"] = args.positional().size();
    o["streams"] = per_stream.size();
    nlohmann::ordered_json doc;
    doc["summary"] = per_stream;
    doc["overall"] = o;
    out << doc.dump() << "\n";
    out.flush();
    if (!plot_dir.empty())
      plots::write_all(plot_dir, "ridgewatch analyze --summary", doc.dump(2), {plots::summary_plot(groups, overall.group(""))});
  }
  return kExitOk;
}

}  // namespace ridgewatch::cli
