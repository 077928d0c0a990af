// The fleet example (examples/fleet): run.sh with one mosquitto and three daemons on loopback delivers
// every event of every rig exactly once (fleet_check's verdict, exit 0), the Prometheus scrape
// configuration passes promtool, and every metric the Grafana dashboard queries exists.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>

#include "cli_runner.hpp"
#include "daemon/metrics.hpp"
#include "net_test_support.hpp"

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {
const fs::path kFleet = fs::path(RIDGEWATCH_SOURCE_DIR) / "examples" / "fleet";

// Three consecutive free loopback ports for the rigs' HTTP listeners.
int free_port_run(int count) {
  for (int attempt = 0; attempt < 20; ++attempt) {
    const int p = ridgewatch::test::free_loopback_port();
    bool ok = p + count < 65536;
    for (int i = 1; ok && i < count; ++i) ok = !ridgewatch::test::port_accepts(p + i);
    if (ok) return p;
  }
  return 0;
}
}  // namespace

TEST(FleetExample, EveryEventOfEveryRigArrivesExactlyOnce) {
  const fs::path build = fs::path(RIDGEWATCHD_PATH).parent_path().parent_path();
  if (!fs::exists(build / "examples" / "fleet" / "fleet_check")) GTEST_SKIP() << "fleet_check not built";
  const auto work = fs::temp_directory_path() / ("ridgewatch-fleet-test-" + std::to_string(::getpid()));
  fs::remove_all(work);
  const int http = free_port_run(3);
  ASSERT_NE(http, 0);
  const std::string cmd = ridgewatch::test::shell_quote((kFleet / "run.sh").string()) + " --build " +
                          ridgewatch::test::shell_quote(build.string()) + " --speed max --port " +
                          std::to_string(ridgewatch::test::free_loopback_port()) + " --http-base " + std::to_string(http) +
                          " --workdir " + work.string() + " > " + (work.string() + ".out") + " 2>&1";
  const int rc = std::system(cmd.c_str());
  const std::string out = ridgewatch::test::slurp(work.string() + ".out");
  ASSERT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 0) << out;
  EXPECT_NE(out.find("every event of every rig arrived exactly once"), std::string::npos) << out;
  for (const std::string rig : {"rig-a", "rig-b", "rig-c"}) {
    // Independent of fleet_check: the rig's log has events, and its spool was fully acknowledged.
    std::ifstream log(work / (rig + ".jsonl"));
    const auto lines = std::count(std::istreambuf_iterator<char>(log), std::istreambuf_iterator<char>(), '\n');
    EXPECT_GE(lines, 40) << rig;
    std::ifstream state(work / (rig + "-spool") / "state");
    std::string key;
    long acked = -1;
    state >> key >> acked;
    EXPECT_EQ(acked, lines) << rig;
  }
  fs::remove_all(work);
}

TEST(FleetExample, PrometheusConfigPassesPromtool) {
  if (std::system("command -v promtool >/dev/null 2>&1") != 0) GTEST_SKIP() << "promtool not installed";
  const auto r = std::system(("promtool check config " + (kFleet / "prometheus.yml").string() + " >/dev/null 2>&1").c_str());
  EXPECT_EQ(r, 0);
}

TEST(FleetExample, DashboardQueriesOnlyExportedMetrics) {
  std::ifstream f(kFleet / "grafana-dashboard.json");
  const json d = json::parse(f);
  ridgewatch::daemon::Telemetry t("rig", "1", ridgewatch::trend::TrendConfig{}, 51200.0);
  const std::string exposed = t.prometheus_text();
  std::set<std::string> names;
  std::istringstream in(exposed);
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("# TYPE ", 0) == 0) names.insert(line.substr(7, line.find(' ', 7) - 7));
  std::size_t queries = 0;
  const std::regex metric("ridgewatch_[a-z_]+");
  for (const auto& panel : d.at("panels"))
    for (const auto& target : panel.at("targets")) {
      const std::string expr = target.at("expr");
      for (std::sregex_iterator it(expr.begin(), expr.end(), metric), end; it != end; ++it) {
        std::string name = it->str();
        for (const std::string suffix : {"_bucket", "_sum", "_count"})
          if (!names.count(name) && name.size() > suffix.size() && name.ends_with(suffix))
            name = name.substr(0, name.size() - suffix.size());
        EXPECT_TRUE(names.count(name)) << it->str() << " in panel " << panel.at("title");
        ++queries;
      }
    }
  EXPECT_GE(queries, 10u);
}

// The network drop-in loads cleanly on top of the unit (systemd reads it: the offline security
// review then reports the host network), and keeps every address but loopback denied.
TEST(FleetExample, NetworkDropInVerifiesWithTheUnit) {
  if (std::system("command -v systemd-analyze >/dev/null 2>&1") != 0) GTEST_SKIP() << "systemd-analyze not installed";
  const auto dir = fs::temp_directory_path() / ("ridgewatch-unit-net-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "ridgewatchd.service.d");
  std::string unit = ridgewatch::test::slurp(fs::path(RIDGEWATCH_SOURCE_DIR) / "systemd" / "ridgewatchd.service");
  const std::string from = "/usr/local/sbin/ridgewatchd";
  for (std::size_t p; (p = unit.find(from)) != std::string::npos;) unit.replace(p, from.size(), RIDGEWATCHD_PATH);
  std::ofstream(dir / "ridgewatchd.service") << unit;
  const std::string dropin = ridgewatch::test::slurp(fs::path(RIDGEWATCH_SOURCE_DIR) / "systemd" / "ridgewatchd.service.d" / "20-network.conf");
  EXPECT_EQ(dropin.find("\nIPAddressDeny="), std::string::npos);  // the unit's IPAddressDeny=any stays
  std::ofstream(dir / "ridgewatchd.service.d" / "20-network.conf") << dropin;
  const std::string env = "SYSTEMD_UNIT_PATH=" + dir.string() + ": ";
  EXPECT_EQ(std::system((env + "systemd-analyze verify ridgewatchd.service > " + (dir / "verify.log").string() + " 2>&1").c_str()), 0);
  EXPECT_EQ(ridgewatch::test::slurp(dir / "verify.log"), "");  // no ignored or invalid assignments
  std::system((env + "systemd-analyze security --offline=true ridgewatchd.service > " + (dir / "sec.log").string() + " 2>&1").c_str());
  const std::string sec = ridgewatch::test::slurp(dir / "sec.log");
  EXPECT_NE(sec.find("Service has access to the host's network"), std::string::npos) << sec;
  EXPECT_NE(sec.find("allow list with only localhost entries"), std::string::npos) << sec;
  fs::remove_all(dir);
}
