// The configuration file: documented defaults, round trip, and errors that name the YAML path.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "app/args.hpp"
#include "app/config_yaml.hpp"

using namespace ridgewatch::app;

namespace {

// Expects parse_config to fail with a message containing every needle.
void expect_error(const std::string& yaml, std::initializer_list<std::string> needles) {
  try {
    parse_config(yaml, "test.yaml");
    ADD_FAILURE() << "accepted:\n" << yaml;
  } catch (const UsageError& e) {
    const std::string msg = e.what();
    EXPECT_EQ(msg.rfind("test.yaml: ", 0), 0u) << msg;
    for (const auto& n : needles) EXPECT_NE(msg.find(n), std::string::npos) << "'" << n << "' not in: " << msg;
  }
}

}  // namespace

// config/ridgewatch.yaml documents every key with its default: parsing it must give exactly the
// compiled-in defaults (compared through the printer, which walks every key).
TEST(Config, DocumentedFileEqualsDefaults) {
  const std::string path = std::string(RIDGEWATCH_SOURCE_DIR) + "/config/ridgewatch.yaml";
  const RidgewatchConfig c = load_config_file(path);
  EXPECT_EQ(to_yaml(c), to_yaml(default_config()));
}

TEST(Config, PrintedDefaultsParseBack) {
  const std::string printed = to_yaml(default_config());
  EXPECT_NE(printed.find("ewma_lambda"), std::string::npos);
  const RidgewatchConfig c = parse_config(printed, "printed");
  EXPECT_EQ(to_yaml(c), printed);
}

TEST(Config, KeysOverrideDefaultsAndOthersStay) {
  const RidgewatchConfig c = parse_config(
      "pipeline:\n  analyzer:\n    method: ridge-ls\n    window_s: 0.03\n  trend:\n    baseline_zeta: 0.024\n"
      "output:\n  events: /tmp/x.jsonl\nsource:\n  replay:\n    speed: 0\n",
      "t");
  EXPECT_EQ(c.pipeline.analyzer.method, ridgewatch::dsp::DampingMethod::ridge_ls);
  EXPECT_DOUBLE_EQ(c.pipeline.analyzer.window_s, 0.03);
  EXPECT_DOUBLE_EQ(c.pipeline.trend.baseline_zeta, 0.024);
  EXPECT_EQ(c.output.events, "/tmp/x.jsonl");
  EXPECT_DOUBLE_EQ(c.source.replay.speed, 0.0);
  EXPECT_DOUBLE_EQ(c.pipeline.analyzer.f_expected_hz, default_config().pipeline.analyzer.f_expected_hz);
}

TEST(Config, EmptyFileMeansDefaults) {
  EXPECT_EQ(to_yaml(parse_config("", "empty")), to_yaml(default_config()));
}

TEST(Config, ErrorsNameTheYamlPath) {
  expect_error("pipeline:\n  analyser:\n    eta0: 7\n", {"pipeline.analyser", "unknown key", "analyzer"});
  expect_error("pipeline:\n  analyzer:\n    eta0: seven\n", {"pipeline.analyzer.eta0", "number"});
  expect_error("pipeline:\n  analyzer:\n    method: fastest\n", {"pipeline.analyzer.method", "ml"});
  expect_error("pipeline:\n  analyzer:\n    window_s: 0\n", {"window_s"});
  expect_error("pipeline:\n  trend:\n    ewma_lambda: 0\n", {"ewma_lambda"});
  expect_error("pipeline:\n  trend:\n    confirm_k: 2.5\n", {"pipeline.trend.confirm_k", "whole number"});
  expect_error("source:\n  type: usb\n", {"source.type", "replay or alsa"});
  expect_error("source:\n  alsa:\n    format: S24_3LE\n", {"source.alsa.format"});
  expect_error("source:\n  alsa:\n    channels: 2\n    channel: 2\n", {"source.alsa.channel"});
  expect_error("source:\n  replay:\n    loop: sometimes\n", {"source.replay.loop", "true or false"});
  expect_error("pipeline:\n  detector:\n    trigger_innovation: 2\n", {"pipeline.detector.trigger_innovation", "true or false"});
  expect_error("logging:\n  level: loud\n", {"logging.level"});
  expect_error("gpio: [1, 2]\n", {"gpio", "mapping"});
  expect_error("output:\n  events: [a]\n", {"output.events", "string"});
  expect_error("pipeline: {detector: {band_lo_hz: .nan}}\n", {"pipeline.detector.band_lo_hz", "finite"});
  expect_error("source: [\n", {"not valid YAML"});
  expect_error("bogus: 1\n", {"bogus", "unknown key"});
}

TEST(Config, MissingFileIsAUsageError) {
  EXPECT_THROW(load_config_file("/nonexistent/ridgewatch.yaml"), UsageError);
}
