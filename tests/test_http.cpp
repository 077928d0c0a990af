// The HTTP listener: /metrics checked by `promtool check metrics` (Prometheus' own parser and linter)
// with counters equal to the events the daemon wrote, label escaping, loopback-only by default, and
// the live page in a real headless Chromium (shows the replayed events and the alarm state, updates
// as new events arrive; a phone-sized screenshot is kept in test-artifacts/).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <thread>

#include "app/config_yaml.hpp"
#include "cli_runner.hpp"
#include "daemon/daemon.hpp"
#include "daemon/http_server.hpp"
#include "daemon/metrics.hpp"
#include "net_test_support.hpp"
#include "process_runner.hpp"
#include "support/indep_signals.hpp"

using ridgewatch::test::ChildProcess;
using ridgewatch::test::http_get;
using ridgewatch::test::read_jsonl;
using ridgewatch::test::temp_dir;
using ridgewatch::test::wait_for;
namespace fs = std::filesystem;
using json = nlohmann::json;
using namespace std::chrono_literals;

namespace {

const std::string kReplay = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/sim-noise.wav";

// An independent record (no code shared with core/model) whose damping steps up half-way, so that
// the trend goes learning -> normal -> alert/danger: 4 s + 4 s at 25 impacts/s (the daemon learns
// its baseline from 50 events).
std::pair<std::string, std::size_t> stepped_record(const fs::path& dir) {
  namespace ind = indep;
  ind::RigSpec s;
  s.duration_s = 4.0;
  s.response.amplitude = 0.4;
  s.response.zeta = 0.02;
  s.noise_sd = 0.002;
  s.seed = 7;
  auto a = ind::make_rig_record(s);
  s.response.zeta = 0.035;  // +75 %: far beyond the danger limit of a 1-2 % spread
  s.seed = 8;
  const auto b = ind::make_rig_record(s);
  a.x.insert(a.x.end(), b.x.begin(), b.x.end());
  const std::string path = (dir / "stepped.wav").string();
  ind::write_wav_mono(path, a.x, a.fs_hz, ind::SampleFormat::pcm16);
  return {path, a.x.size()};
}

// Samples of the exposition text: "name{labels}" -> value (independent of the code under test).
std::map<std::string, double> parse_samples(const std::string& text) {
  std::map<std::string, double> out;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    const auto sp = line.rfind(' ');
    const std::string v = line.substr(sp + 1);
    out[line.substr(0, sp)] = v == "NaN" ? NAN : v == "+Inf" ? INFINITY : std::stod(v);
  }
  return out;
}

// Headless Chromium with a throw-away profile in `dir`, a phone-sized window.
std::string chromium_command(const fs::path& dir) {
  return "chromium --headless --no-sandbox --disable-gpu --no-first-run --disable-extensions "
         "--disable-background-networking --disable-sync --user-data-dir=" + (dir / "profile").string() +
         " --window-size=412,1400 ";
}

int promtool_check(const fs::path& file, std::string* output) {
  const auto out = file.string() + ".promtool";
  const int rc = std::system(("promtool check metrics < " + file.string() + " > " + out + " 2>&1").c_str());
  *output = ridgewatch::test::slurp(out);
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

// The exposition text passes `promtool check metrics` without lint warnings (kept in dir/metrics.txt).
void expect_promtool_clean(const fs::path& dir, const std::string& metrics) {
  std::ofstream(dir / "metrics.txt") << metrics;
  std::string lint;
  EXPECT_EQ(promtool_check(dir / "metrics.txt", &lint), 0) << lint << metrics;
  EXPECT_TRUE(lint.empty()) << lint;
}

}  // namespace

// Acceptance: /metrics passes promtool, and its counters equal the events written to the log.
TEST(Metrics, PromtoolAcceptsThemAndCountersEqualTheEventLog) {
  if (std::system("command -v promtool >/dev/null 2>&1") != 0) GTEST_SKIP() << "promtool (package prometheus) not installed";
  const auto dir = temp_dir("http-metrics");
  const auto [file, samples] = stepped_record(dir);
  ridgewatch::daemon::DaemonOptions options;
  options.config = ridgewatch::app::default_config();
  options.config.source.replay.path = file;
  options.config.source.replay.speed = 0.0;
  options.config.pipeline.trend.baseline_events = 50;
  options.config.output.events = (dir / "ev.jsonl").string();
  options.config.http.listen = "127.0.0.1:0";  // any free port
  std::string metrics, state, page;
  int page_status = 0;
  options.before_network_stop = [&](int port) {
    metrics = http_get(port, "/metrics");
    state = http_get(port, "/api/state");
    page = http_get(port, "/", &page_status);
  };
  ridgewatch::daemon::Daemon::clear_requests();
  ridgewatch::daemon::Daemon daemon(options);
  ASSERT_EQ(daemon.run(), 0);

  ASSERT_FALSE(metrics.empty());
  expect_promtool_clean(dir, metrics);

  const auto events = read_jsonl(dir / "ev.jsonl");
  ASSERT_GT(events.size(), 190u);  // 8 s at 25 impacts/s
  std::map<std::string, double> by_status;
  for (const auto& e : events) by_status[e["status"].get<std::string>()] += 1;
  const auto m = parse_samples(metrics);
  double sum = 0;
  for (const auto& [k, v] : m)
    if (k.rfind("ridgewatch_events_total{", 0) == 0) sum += v;
  EXPECT_EQ(sum, static_cast<double>(events.size()));
  for (const auto& [status, n] : by_status) EXPECT_EQ(m.at("ridgewatch_events_total{status=\"" + status + "\"}"), n) << status;
  EXPECT_EQ(m.at("ridgewatch_impacts_detected_total"), static_cast<double>(events.size()));
  EXPECT_EQ(m.at("ridgewatch_samples_total"), static_cast<double>(samples));
  // Current trend values = those of the last event (the exposition prints 17 significant digits).
  const json& last = events.back();
  const std::map<std::string, double> level = {{"learning", 0}, {"normal", 1}, {"alert", 2}, {"danger", 3}};
  EXPECT_EQ(m.at("ridgewatch_alarm_level"), level.at(last["alarm"].get<std::string>()));
  EXPECT_EQ(last["alarm"], "danger");  // the step up was seen
  EXPECT_NEAR(m.at("ridgewatch_damping_ewma_ratio"), std::exp(last["alarm_detail"]["ewma_ln_zeta"].get<double>()), 1e-15);
  EXPECT_NEAR(m.at("ridgewatch_damping_baseline_ratio"), last["alarm_detail"]["baseline_zeta"].get<double>(), 1e-15);
  EXPECT_EQ(m.at("ridgewatch_cusum{direction=\"up\"}"), last["alarm_detail"]["cusum_up"].get<double>());
  double transitions = 0;
  for (const auto& e : events) transitions += e["alarm_detail"]["transition"].get<bool>();
  EXPECT_EQ(m.at("ridgewatch_alarm_transitions_total"), transitions);
  // As fast as possible: no latency is measured, the histogram is empty but well-formed.
  EXPECT_EQ(m.at("ridgewatch_event_latency_seconds_count"), 0.0);
  EXPECT_EQ(m.at("ridgewatch_mqtt_enabled"), 0.0);
  EXPECT_NE(metrics.find("ridgewatch_build_info{version=\""), std::string::npos);

  // The page's data agrees too, and the page itself is served.
  const json s = json::parse(state);
  EXPECT_EQ(s["events"], events.size());
  EXPECT_EQ(s["alarm"]["level"], "danger");
  // Its recent events are the newest logged ones, value for value (both writers print the shortest
  // text that reads back as the same double, and null where there is no value).
  const json& recent = s["recent"];
  ASSERT_EQ(recent.size(), std::min<std::size_t>(events.size(), 300));
  const std::size_t off = events.size() - recent.size();
  for (std::size_t i = 0; i < recent.size(); ++i) {
    const json& e = events[off + i];
    EXPECT_EQ(recent[i]["n"], off + i + 1) << i;
    EXPECT_EQ(recent[i]["t_s"], e["t_s"]) << i;
    EXPECT_EQ(recent[i]["zeta"], e["zeta"]) << i;
    EXPECT_EQ(recent[i]["lo"], e["zeta_ci95"][0]) << i;
    EXPECT_EQ(recent[i]["hi"], e["zeta_ci95"][1]) << i;
    EXPECT_EQ(recent[i]["status"], e["status"]) << i;
    EXPECT_EQ(recent[i]["alarm"], e["alarm"]) << i;
  }
  ASSERT_GE(s["envelopes"].size(), 1u);  // the first event's window at least
  for (const json& env : s["envelopes"]) {
    EXPECT_TRUE(env["zeta"].is_number() || env["zeta"].is_null());
    ASSERT_FALSE(env["envelope"].empty());
    EXPECT_LE(env["envelope"].size(), 160u);
    for (const json& v : env["envelope"]) EXPECT_GE(v.get<double>(), 0.0);  // peak |x|
  }
  EXPECT_EQ(page_status, 200);
  EXPECT_NE(page.find("<title>ridgewatch</title>"), std::string::npos);
  EXPECT_EQ(page.find("src=\"http"), std::string::npos);  // nothing loaded from elsewhere
}

// Several streams, one listener: every /metrics sample carries its stream's label, each family's
// header appears once (promtool), each stream's counters equal its own events in the log, and the
// page data and the page (in headless Chromium) show the stream asked for.
TEST(Metrics, SeveralStreamsShareOneListenerWithAStreamLabel) {
  if (std::system("command -v promtool >/dev/null 2>&1") != 0) GTEST_SKIP() << "promtool (package prometheus) not installed";
  const auto dir = temp_dir("http-streams");
  // Three independent rigs (no code shared with core/model) at different impact rates, so that the
  // streams' counts differ and a mix-up shows.
  const std::vector<std::string> names = {"a", "b", "c"};
  const double fs = 25600.0, duration_s = 3.0;
  const auto n = static_cast<std::size_t>(fs * duration_s);
  std::vector<double> frames(names.size() * n);
  for (std::size_t ch = 0; ch < names.size(); ++ch) {
    indep::RigSpec r;
    r.fs_hz = fs;
    r.duration_s = duration_s;
    r.rev_hz = 15.0 + 10.0 * static_cast<double>(ch);
    r.response.amplitude = 0.3;
    r.noise_sd = 0.001;
    r.seed = 40 + ch;
    const auto rec = indep::make_rig_record(r);
    for (std::size_t i = 0; i < n; ++i) frames[names.size() * i + ch] = rec.x[i];
  }
  const std::string wav = (dir / "three.wav").string();
  indep::write_wav(wav, frames, fs, static_cast<int>(names.size()), indep::SampleFormat::pcm24);
  std::string yaml = "streams:\n";
  for (std::size_t ch = 0; ch < names.size(); ++ch)
    yaml += "  - name: " + names[ch] + "\n    channel: " + std::to_string(ch) + "\n";
  ridgewatch::daemon::DaemonOptions options;
  options.config = ridgewatch::app::parse_config(yaml, "streams.yaml");
  options.config.source.replay.path = wav;
  options.config.source.replay.speed = 0.0;
  options.config.output.events = (dir / "ev.jsonl").string();
  options.config.http.listen = "127.0.0.1:0";  // any free port (the configuration file wants a fixed one)
  std::string metrics, list, state_b, state_default, dom;
  int unknown_status = 0;
  const bool browser = std::system("command -v chromium >/dev/null 2>&1") == 0;
  options.before_network_stop = [&](int port) {
    metrics = http_get(port, "/metrics");
    list = http_get(port, "/api/streams");
    state_b = http_get(port, "/api/state?stream=b");
    state_default = http_get(port, "/api/state");
    http_get(port, "/api/state?stream=zz", &unknown_status);
    if (!browser) return;
    const std::string dom_file = (dir / "dom.html").string();
    std::system((chromium_command(dir) + "--virtual-time-budget=2000 --dump-dom 'http://127.0.0.1:" + std::to_string(port) +
                 "/?stream=b' > " + dom_file + " 2>/dev/null").c_str());
    dom = ridgewatch::test::slurp(dom_file);
  };
  ridgewatch::daemon::Daemon::clear_requests();
  ridgewatch::daemon::Daemon daemon(options);
  ASSERT_EQ(daemon.run(), 0);

  ASSERT_FALSE(metrics.empty());
  expect_promtool_clean(dir, metrics);
  // One header per family, however many streams.
  std::size_t helps = 0;
  for (std::size_t at = 0; (at = metrics.find("# HELP ridgewatch_events_total ", at)) != std::string::npos; ++at) ++helps;
  EXPECT_EQ(helps, 1u);

  std::map<std::string, std::map<std::string, double>> logged;  // stream -> status -> events
  for (const auto& e : read_jsonl(dir / "ev.jsonl")) logged[e["stream"].get<std::string>()][e["status"].get<std::string>()] += 1;
  ASSERT_EQ(logged.size(), names.size());
  const auto m = parse_samples(metrics);
  for (const auto& [key, v] : m) EXPECT_NE(key.find("{stream=\""), std::string::npos) << "sample without a stream label: " << key;
  std::map<std::string, double> totals;
  for (const auto& name : names) {
    const std::string label = "stream=\"" + name + "\"";
    double events = 0;
    for (const auto& [status, count] : logged[name]) {
      EXPECT_EQ(m.at("ridgewatch_events_total{" + label + ",status=\"" + status + "\"}"), count) << name << " " << status;
      events += count;
    }
    double exposed = 0;
    for (const auto& [key, v] : m)
      if (key.rfind("ridgewatch_events_total{" + label + ",", 0) == 0) exposed += v;
    EXPECT_EQ(exposed, events) << name;
    EXPECT_EQ(m.at("ridgewatch_impacts_detected_total{" + label + "}"), events) << name;
    EXPECT_EQ(m.at("ridgewatch_samples_total{" + label + "}"), static_cast<double>(n)) << name;
    totals[name] = events;
  }
  // 15, 25 and 35 impacts per second for 3 s: the counts must differ, or a mix-up would not show.
  EXPECT_LT(totals["a"], totals["b"]);
  EXPECT_LT(totals["b"], totals["c"]);

  EXPECT_EQ(json::parse(list), json(names));
  const json b = json::parse(state_b);
  EXPECT_EQ(b["stream"], "b");
  EXPECT_EQ(b["events"], totals["b"]);
  EXPECT_EQ(json::parse(state_default)["stream"], "a");  // the first stream without ?stream=
  EXPECT_EQ(unknown_status, 404);
  if (!browser) GTEST_SKIP() << "chromium not installed: the page itself not checked";
  std::smatch match;
  ASSERT_TRUE(std::regex_search(dom, match, std::regex("data-stream=\"([a-z]+)\""))) << dom.substr(0, 2000);
  EXPECT_EQ(match[1].str(), "b");
  ASSERT_TRUE(std::regex_search(dom, match, std::regex("data-events=\"([0-9]+)\"")));
  EXPECT_EQ(std::stod(match[1]), totals["b"]);
  // One link per stream, the shown one marked.
  EXPECT_NE(dom.find("<a href=\"?stream=a\">a</a>"), std::string::npos) << dom.substr(0, 3000);
  EXPECT_NE(dom.find("<a href=\"?stream=b\" class=\"here\">b</a>"), std::string::npos);
  EXPECT_NE(dom.find("<a href=\"?stream=c\">c</a>"), std::string::npos);
}

// Label values with quotes, backslashes and newlines are escaped as the text format requires.
TEST(Metrics, LabelValuesAreEscaped) {
  if (std::system("command -v promtool >/dev/null 2>&1") != 0) GTEST_SKIP() << "promtool (package prometheus) not installed";
  EXPECT_EQ(ridgewatch::daemon::prometheus_escape("a\"b\\c\nd"), "a\\\"b\\\\c\\nd");
  ridgewatch::daemon::Telemetry t("rig \"7\" C:\\data\nline2", "1.0", ridgewatch::trend::TrendConfig{}, 51200.0);
  const std::string text = t.prometheus_text();
  EXPECT_NE(text.find("source=\"rig \\\"7\\\" C:\\\\data\\nline2\""), std::string::npos) << text;
  const auto dir = temp_dir("http-escape");
  std::ofstream(dir / "m.txt") << text;
  std::string lint;
  EXPECT_EQ(promtool_check(dir / "m.txt", &lint), 0) << lint;
}

// A bad or taken listen address is a configuration error naming http.listen (exit 2).
TEST(Metrics, ListenErrorsNameTheKey) {
  const auto dir = temp_dir("http-listen");
  {
    std::ofstream(dir / "bad.yaml") << "http:\n  listen: \"localhost\"\n";
    ChildProcess d({RIDGEWATCHD_PATH, "--check-config", (dir / "bad.yaml").string()}, {}, (dir / "o").string(),
                   (dir / "e").string());
    EXPECT_EQ(d.wait(10s), 2);
    EXPECT_NE(ridgewatch::test::slurp(dir / "e").find("http.listen"), std::string::npos);
  }
  // The port is taken by another listener.
  const int port = ridgewatch::test::free_loopback_port();
  ridgewatch::daemon::Telemetry t("x", "1", ridgewatch::trend::TrendConfig{}, 51200.0);
  ridgewatch::daemon::HttpServer first("127.0.0.1:" + std::to_string(port), t);
  std::ofstream(dir / "taken.yaml") << "http:\n  listen: \"127.0.0.1:" << port << "\"\n";
  ChildProcess d({RIDGEWATCHD_PATH, "--config", (dir / "taken.yaml").string(), "--replay", kReplay, "--events",
                  (dir / "ev").string()},
                 {}, (dir / "o2").string(), (dir / "e2").string());
  EXPECT_EQ(d.wait(10s), 2);
  EXPECT_NE(ridgewatch::test::slurp(dir / "e2").find("http.listen"), std::string::npos) << ridgewatch::test::slurp(dir / "e2");
}

// Acceptance: the live page in a real headless Chromium shows the replayed events and the alarm
// state, and updates by itself as new events arrive.
TEST(LivePage, HeadlessChromiumShowsEventsAndAlarmAndUpdates) {
  if (std::system("command -v chromium >/dev/null 2>&1") != 0) GTEST_SKIP() << "chromium not installed";
  const auto dir = temp_dir("http-page");
  const int port = ridgewatch::test::free_loopback_port();
  std::ofstream(dir / "c.yaml") << "http:\n  listen: \"127.0.0.1:" << port << "\"\noutput:\n  source_name: \"rig-page\"\n";
  // 2x real time, looping: ~50 new events per second while the browser watches.
  ChildProcess d({RIDGEWATCHD_PATH, "--config", (dir / "c.yaml").string(), "--replay", kReplay, "--speed", "2", "--loop",
                  "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "o").string(), (dir / "e").string());
  ASSERT_TRUE(wait_for([&] { return read_jsonl(dir / "ev.jsonl").size() >= 30; }, 20s)) << ridgewatch::test::slurp(dir / "e");
  const std::string url = "http://127.0.0.1:" + std::to_string(port) + "/";
  const std::string chrome = chromium_command(dir);
  // Virtual time runs the page's 1 s polling timer; fetches to the daemon take real time, during
  // which the daemon keeps replaying, so later polls show more events.
  const std::string dom_file = (dir / "dom.html").string();
  ASSERT_EQ(std::system((chrome + "--virtual-time-budget=6000 --dump-dom " + url + " > " + dom_file + " 2>" +
                         (dir / "chromium.err").string()).c_str()), 0)
      << ridgewatch::test::slurp(dir / "chromium.err");
  const std::string dom = ridgewatch::test::slurp(dom_file);
  std::smatch m;
  ASSERT_TRUE(std::regex_search(dom, m, std::regex("data-events=\"([0-9]+)\""))) << dom.substr(0, 2000);
  const std::size_t shown = std::stoul(m[1]);
  ASSERT_TRUE(std::regex_search(dom, m, std::regex("data-first-events=\"([0-9]+)\"")));
  const std::size_t first_shown = std::stoul(m[1]);
  EXPECT_GT(shown, first_shown) << "the page did not update while new events arrived";
  EXPECT_GE(first_shown, 30u);
  // The newest event the page lists is one the daemon wrote: same number, same time, same zeta.
  const auto logged = read_jsonl(dir / "ev.jsonl");
  ASSERT_GE(logged.size(), shown);
  const json& newest = logged[shown - 1];
  ASSERT_TRUE(std::regex_search(dom, m, std::regex("<tr class=\"ev\"><td>([0-9]+)</td><td>([0-9.]+)</td>")));
  EXPECT_EQ(std::stoul(m[1]), shown);
  char t_text[32];
  std::snprintf(t_text, sizeof t_text, "%.3f", newest["t_s"].get<double>());
  EXPECT_EQ(m[2].str(), t_text);
  // The alarm badge shows the level of the newest event.
  ASSERT_TRUE(std::regex_search(dom, m, std::regex("<span id=\"alarm\" class=\"([a-z]+)\">([a-z]+)</span>")));
  EXPECT_EQ(m[2].str(), newest["alarm"].get<std::string>());
  EXPECT_NE(dom.find("<circle"), std::string::npos);  // the trend was drawn
  // A phone-sized screenshot for people to look at (test-artifacts/ in the test's working directory).
  fs::create_directories("test-artifacts");
  const std::string shot = (fs::current_path() / "test-artifacts" / "live-page.png").string();
  std::system((chrome + "--virtual-time-budget=3000 --hide-scrollbars --screenshot=" + shot + " " + url + " >/dev/null 2>&1").c_str());
  EXPECT_GT(fs::exists(shot) ? fs::file_size(shot) : 0, 10000u);
  d.signal(SIGTERM);
  EXPECT_EQ(d.wait(10s), 0);
}
