// MQTT output: the on-disk spool (unit tests), and ridgewatchd against a real mosquitto broker that the
// test starts on 127.0.0.1 (events equal `ridgewatch analyze`, a broker outage and a SIGKILLed daemon
// lose nothing, retained status and Last Will, password authentication without the password in logs).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "cli_runner.hpp"
#include "app/args.hpp"
#include "app/config_yaml.hpp"
#include "daemon/mqtt_link.hpp"
#include "daemon/spool.hpp"
#include "net_test_support.hpp"
#include "process_runner.hpp"
#include "support/indep_signals.hpp"

using ridgewatch::daemon::Spool;
using ridgewatch::test::Broker;
using ridgewatch::test::ChildProcess;
using ridgewatch::test::run_cli;
using ridgewatch::test::Subscriber;
using ridgewatch::test::read_jsonl;
using ridgewatch::test::temp_dir;
using ridgewatch::test::wait_for;
namespace fs = std::filesystem;
using json = nlohmann::json;
using namespace std::chrono_literals;

namespace {

const std::string kReplay = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/sim-noise.wav";

std::vector<json> analyze_events(const std::string& file) {
  const auto r = run_cli({"analyze", file});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  std::vector<json> out;
  std::istringstream s(r.out);
  std::string line;
  while (std::getline(s, line)) out.push_back(json::parse(line));
  return out;
}

// A record made by the independent generator (no code shared with core/model): 4 s of impacts at
// 25 Hz (by default 4 s) on an 854 Hz mode with mesh lines, hum and noise.
std::string indep_record(const fs::path& dir, double duration_s = 4.0) {
  indep::RigSpec s;
  s.duration_s = duration_s;
  s.response.amplitude = 0.4;
  s.response.zeta = 0.02;
  s.mesh_amp = {0.01};
  s.hum_amp = {0.005};
  s.noise_sd = 0.002;
  s.seed = 15;
  const auto rec = indep::make_rig_record(s);
  const std::string path = (dir / "indep.wav").string();
  indep::write_wav_mono(path, rec.x, rec.fs_hz, indep::SampleFormat::pcm16);
  return path;
}

std::string mqtt_config(const fs::path& dir, int port, const std::string& extra = "") {
  const auto p = dir / "ridgewatch.yaml";
  std::ofstream(p) << "output:\n  source_name: \"rig-t\"\n  mqtt:\n    host: \"127.0.0.1\"\n    port: " << port
                   << "\n    topic_prefix: \"t/rig\"\n    spool_dir: \"" << (dir / "spool").string()
                   << "\"\n    keepalive_s: 5\n" << extra << "logging:\n  status_interval_s: 0.5\n";
  return p.string();
}

// Distinct seqs received on t/rig/events so far, read incrementally: each message is parsed once.
// (Re-parsing every message on every poll took seconds per poll in the sanitizer build once ~10 000
// had arrived, while the daemon's log kept growing: the two counts were then seconds apart.)
class SeqTally {
 public:
  std::size_t update(Subscriber& sub) {
    for (const auto& m : sub.messages_from(read_)) {
      ++read_;
      if (m.topic == "t/rig/events") seqs_.insert(json::parse(m.payload).at("seq").get<std::uint64_t>());
    }
    return seqs_.size();
  }

 private:
  std::size_t read_ = 0;
  std::set<std::uint64_t> seqs_;
};

// Complete lines of a growing file so far, read incrementally from where the last call stopped.
class LineTally {
 public:
  explicit LineTally(fs::path p) : path_(std::move(p)) {}
  std::size_t update() {
    std::ifstream in(path_, std::ios::binary);
    in.seekg(static_cast<std::streamoff>(offset_));
    char buf[1 << 16];
    while (in.read(buf, sizeof buf) || in.gcount() > 0) {
      const auto n = static_cast<std::size_t>(in.gcount());
      for (std::size_t i = 0; i < n; ++i) lines_ += buf[i] == '\n';
      offset_ += n;
    }
    return lines_;
  }

 private:
  fs::path path_;
  std::size_t offset_ = 0, lines_ = 0;
};

// Events received on t/rig/events, de-duplicated by seq. Checks that first occurrences arrive in
// ascending seq order and that a duplicate is byte-identical to the first copy.
std::vector<json> dedup_events(const std::vector<Subscriber::Msg>& msgs, std::size_t* duplicates = nullptr) {
  std::map<std::uint64_t, std::string> seen;
  std::vector<json> out;
  std::uint64_t last = 0;
  std::size_t dups = 0;
  for (const auto& m : msgs) {
    if (m.topic != "t/rig/events") continue;
    const json j = json::parse(m.payload);
    const std::uint64_t seq = j.at("seq").get<std::uint64_t>();
    if (const auto it = seen.find(seq); it != seen.end()) {
      EXPECT_EQ(it->second, m.payload) << "seq " << seq << " sent twice with different content";
      ++dups;
      continue;
    }
    EXPECT_GT(seq, last) << "seq out of order";
    last = seq;
    seen[seq] = m.payload;
    out.push_back(j);
  }
  if (duplicates) *duplicates = dups;
  return out;
}

json without_seq(json j) {
  j.erase("seq");
  return j;
}

std::string event_lines(std::size_t n, std::size_t first_index = 0) {
  std::string s;
  for (std::size_t i = 0; i < n; ++i)
    s += "{\"t_s\":" + std::to_string(i) + ".5,\"sample_index\":" + std::to_string(first_index + i) +
         ",\"status\":\"ok\",\"pad\":\"" + std::string(200, 'x') + "\"}\n";
  return s;
}

}  // namespace

// ---- Spool -------------------------------------------------------------------------------------

TEST(Spool, KeepsOrderAcrossSegmentsAndRestartsWhereTheAcknowledgementsEnded) {
  const auto dir = temp_dir("mqtt-spool-order");
  std::uint64_t last = 0;
  {
    Spool s((dir / "q").string(), 160 * 1024);  // 20 kB segments: the 75 kB below span four
    for (int b = 0; b < 60; ++b) {
      const std::uint64_t first = s.append(event_lines(5, 5 * b));
      ASSERT_EQ(first, 5u * b + 1);  // seqs 1, 2, ... consecutive
    }
    last = s.last_seq();
    ASSERT_EQ(last, 300u);
    EXPECT_GE(std::distance(fs::directory_iterator(dir / "q"), fs::directory_iterator{}), 3);
    std::vector<Spool::Message> got;
    while (s.read(got.empty() ? 0 : got.back().seq, 64, got) > 0) {
    }
    ASSERT_EQ(got.size(), 300u);
    for (std::size_t i = 0; i < got.size(); ++i) {
      ASSERT_EQ(got[i].seq, i + 1);
      const json j = json::parse(got[i].payload);
      EXPECT_EQ(j["seq"], i + 1);
      EXPECT_EQ(j["sample_index"], i);  // the event itself, unchanged behind the seq
      EXPECT_EQ(got[i].payload.rfind("{\"seq\":" + std::to_string(i + 1) + ",", 0), 0u);  // first key
    }
    s.ack_through(120);
    EXPECT_EQ(s.depth(), 180u);
  }
  // A new process: resends from 121, and new events continue the numbering.
  Spool s((dir / "q").string(), 160 * 1024);
  EXPECT_EQ(s.acked(), 120u);
  EXPECT_EQ(s.last_seq(), 300u);
  std::vector<Spool::Message> got;
  ASSERT_GT(s.read(0, 1000, got), 0u);
  EXPECT_EQ(got.front().seq, 121u);
  EXPECT_EQ(got.back().seq, 300u);
  EXPECT_EQ(s.append(event_lines(1)), 301u);
  s.ack_through(301);
  EXPECT_EQ(s.depth(), 0u);
  EXPECT_EQ(s.bytes(), 0u);  // fully acknowledged segments are deleted
}

TEST(Spool, APartialLineFromACrashIsRemovedAndItsSeqReused) {
  const auto dir = temp_dir("mqtt-spool-crash");
  {
    Spool s((dir / "q").string(), 1 << 20);
    s.append(event_lines(3));
  }
  fs::path seg;
  for (const auto& e : fs::directory_iterator(dir / "q"))
    if (e.path().filename().string().rfind("seg-", 0) == 0) seg = e.path();
  ASSERT_FALSE(seg.empty());
  std::ofstream(seg, std::ios::app) << "{\"seq\":4,\"t_s\":1.";  // killed in the middle of a write
  Spool s((dir / "q").string(), 1 << 20);
  EXPECT_EQ(s.last_seq(), 3u);
  std::vector<Spool::Message> got;
  EXPECT_EQ(s.read(0, 100, got), 3u);
  EXPECT_EQ(s.append(event_lines(1)), 4u);
  got.clear();
  s.read(3, 100, got);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_NO_THROW(json::parse(got[0].payload));
}

TEST(Spool, WhenFullDropsTheOldestAndCountsThem) {
  const auto dir = temp_dir("mqtt-spool-full");
  Spool s((dir / "q").string(), 32 * 1024);  // 4 kB segments (the minimum)
  for (int b = 0; b < 100; ++b) s.append(event_lines(10));
  // 1000 lines of ~250 bytes = 250 kB into a 32 kB bound.
  EXPECT_LE(s.bytes(), 32u * 1024);
  EXPECT_GT(s.dropped(), 800u);
  EXPECT_EQ(s.dropped() + s.depth(), 1000u);  // every event is either waiting or counted as dropped
  std::vector<Spool::Message> got;
  while (s.read(got.empty() ? 0 : got.back().seq, 100, got) > 0) {
  }
  ASSERT_EQ(got.size(), s.depth());
  EXPECT_EQ(got.front().seq, s.dropped() + 1);  // the oldest went first, the rest is contiguous
  EXPECT_EQ(got.back().seq, 1000u);
}

// ---- ridgewatchd against a real broker -----------------------------------------------------------

// Acceptance: a replayed file -> the events on <prefix>/events equal `ridgewatch analyze` on the same
// file, with seq 1..N; the retained status ends "offline" after the clean stop; alarm transitions
// arrive retained on <prefix>/alarm.
TEST(MqttBroker, ReplayedEventsEqualAnalyze) {
  const auto dir = temp_dir("mqtt-replay");
  const std::string file = indep_record(dir);
  const int port = ridgewatch::test::free_loopback_port();
  Broker broker(dir / "broker", port);
  Subscriber sub(port, "t/rig/#");
  const auto reference = analyze_events(file);
  ASSERT_GT(reference.size(), 80u);  // 4 s at 25 impacts/s
  ChildProcess d({RIDGEWATCHD_PATH, "--config", mqtt_config(dir, port), "--replay", file, "--speed", "max", "--events",
                  (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(60s), 0) << ridgewatch::test::slurp(dir / "err");
  ASSERT_TRUE(wait_for([&] { return dedup_events(sub.messages()).size() >= reference.size(); }, 10s));
  std::this_thread::sleep_for(200ms);  // anything beyond the reference would arrive now
  const auto msgs = sub.messages();
  const auto got = dedup_events(msgs);
  ASSERT_EQ(got.size(), reference.size());
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i]["seq"], i + 1);
    // Every key and value of the event-log contract, exactly (the source is the configured name).
    json ref = reference[i];
    ref["source"] = "rig-t";
    EXPECT_EQ(without_seq(got[i]), ref) << "event " << i;
  }
  // Status: retained, "online" while running, "offline" after the clean stop.
  std::vector<json> status;
  for (const auto& m : msgs)
    if (m.topic == "t/rig/status") status.push_back(json::parse(m.payload));
  ASSERT_GE(status.size(), 2u);
  EXPECT_EQ(status.front()["state"], "online");
  EXPECT_EQ(status.back()["state"], "offline");
  // A late subscriber gets the retained status and the last alarm transition.
  Subscriber late(port, "t/rig/+", "ridgewatch-test-late");
  ASSERT_TRUE(wait_for([&] { return late.count() >= 1; }, 5s));
  std::this_thread::sleep_for(200ms);
  bool status_seen = false;
  for (const auto& m : late.messages()) {
    EXPECT_TRUE(m.retained) << m.topic;
    if (m.topic == "t/rig/status") status_seen = json::parse(m.payload)["state"] == "offline";
    if (m.topic == "t/rig/alarm") {
      const json a = json::parse(m.payload);
      EXPECT_NE(a["level"], a["previous"]);
    }
  }
  EXPECT_TRUE(status_seen);
  // The spool is empty after a clean stop with the broker up.
  std::size_t segments = 0;
  for (const auto& e : fs::directory_iterator(dir / "spool")) segments += e.path().filename().string().rfind("seg-", 0) == 0;
  EXPECT_EQ(segments, 0u);
  if (!HasFailure()) fs::remove_all(dir);
}

// QoS 0 has no acknowledgement: a message counts as sent once libmosquitto has it. More events than
// the sender's in-flight window (256) all arrive and the spool ends empty (a sender that waited for
// PUBACKs that QoS 0 never brings would stop after 256 and leave every event in the spool).
TEST(MqttBroker, QosZeroDeliversEveryEventAndEmptiesTheSpool) {
  const auto dir = temp_dir("mqtt-qos0");
  const std::string file = indep_record(dir, 12.0);
  const int port = ridgewatch::test::free_loopback_port();
  Broker broker(dir / "broker", port);
  Subscriber sub(port, "t/rig/events");
  ChildProcess d({RIDGEWATCHD_PATH, "--config", mqtt_config(dir, port, "    qos: 0\n"), "--replay", file, "--speed", "max",
                  "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(60s), 0) << ridgewatch::test::slurp(dir / "err");
  const auto logged = read_jsonl(dir / "ev.jsonl");
  ASSERT_GT(logged.size(), 256u);  // 12 s at 25 impacts/s
  ASSERT_TRUE(wait_for([&] { return dedup_events(sub.messages()).size() >= logged.size(); }, 10s))
      << dedup_events(sub.messages()).size() << " of " << logged.size();
  const auto got = dedup_events(sub.messages());
  ASSERT_EQ(got.size(), logged.size());
  for (std::size_t i = 0; i < got.size(); ++i) EXPECT_EQ(got[i]["sample_index"], logged[i]["sample_index"]) << i;
  const Spool spool((dir / "spool").string(), 64u << 20);  // its state file, read back independently
  EXPECT_EQ(spool.last_seq(), logged.size());
  EXPECT_EQ(spool.depth(), 0u);
  if (!HasFailure()) fs::remove_all(dir);
}

// Acceptance: the broker is killed mid-run (with messages in flight) and comes back 10 s later; after
// de-duplication by seq every event of the daemon's own log arrives, in order, none lost.
TEST(MqttBroker, BrokerOutageLosesNothing) {
#ifdef RIDGEWATCH_SANITIZED
  const auto outage = 3s;  // the sanitizer run keeps a shorter variant
#else
  const auto outage = 10s;
#endif
  const auto dir = temp_dir("mqtt-outage");
  const int port = ridgewatch::test::free_loopback_port();
  Broker broker(dir / "broker", port);
  Subscriber sub(port, "t/rig/events");
  const auto subscribed_at = std::chrono::steady_clock::now();
  // Paced at 5x real time (~125 events/s) and looping, so events keep coming during the outage.
  ChildProcess d({RIDGEWATCHD_PATH, "--config", mqtt_config(dir, port), "--replay", kReplay, "--speed", "5", "--loop",
                  "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_TRUE(wait_for([&] { return sub.count() >= 20; }, 10s)) << ridgewatch::test::slurp(dir / "err");
  // The broker hangs for 0.5 s (the daemon keeps publishing, ~60 events stay unacknowledged in
  // flight) and is then killed: those must be resent from the spool after the restart.
  // The broker saves its persistence database after every change (autosave_on_changes): once it holds the
  // subscriber's session, a killed broker still queues for the subscriber after the restart.
  std::this_thread::sleep_until(subscribed_at + 1500ms);
  broker.freeze_and_kill(500ms);
  const std::size_t before = sub.count();
  std::this_thread::sleep_for(outage);
  broker.start(/*save_every_change=*/false);  // not killed again (see Broker::start)
  // The daemon retries with a backoff doubling from 0.5 s to at most 4 s: it is back within 4 s.
  const auto reconnected = [&] {
    const std::string err = ridgewatch::test::slurp(dir / "err");
    std::size_t n = 0;
    for (auto p = err.find("MQTT: connected"); p != std::string::npos; p = err.find("MQTT: connected", p + 1)) ++n;
    return n >= 2;
  };
  ASSERT_TRUE(wait_for(reconnected, 8s)) << ridgewatch::test::slurp(dir / "err");
  // The backlog of the outage (~1500 events) is sent before the stop: the daemon's drain at SIGTERM
  // is bounded in time and leaves what the broker has not acknowledged in the spool for the next start,
  // which this test does not make. On a loaded host the backlog took longer than that bound (758 of
  // 1753 events were still spooled at the stop). Caught up = the subscriber within ~1 s of events
  // (~125 at 5x real time) of the daemon's own log, which keeps growing while the replay loops.
  SeqTally received;
  LineTally logged_lines(dir / "ev.jsonl");
  const auto caught_up = [&] {
    std::this_thread::sleep_for(100ms);
    return received.update(sub) + 150 >= logged_lines.update();
  };
  ASSERT_TRUE(wait_for(caught_up, 60s)) << received.update(sub) << " received, " << logged_lines.update() << " logged\n"
                                        << ridgewatch::test::slurp(dir / "err");
  d.signal(SIGTERM);
  ASSERT_EQ(d.wait(20s), 0) << ridgewatch::test::slurp(dir / "err");
  const auto logged = read_jsonl(dir / "ev.jsonl");
  // Events were made during the outage: ~125 per second at 5x real time (at least half of that).
  ASSERT_GT(logged.size(), before + static_cast<std::size_t>(62 * std::chrono::duration<double>(outage).count()));
  ASSERT_TRUE(wait_for([&] { return received.update(sub) >= logged.size(); }, 15s))
      << received.update(sub) << " of " << logged.size() << "\n"
      << ridgewatch::test::slurp(dir / "err");
  const auto got = dedup_events(sub.messages());
  ASSERT_EQ(got.size(), logged.size());
  for (std::size_t i = 0; i < got.size(); ++i) {
    ASSERT_EQ(got[i]["seq"], i + 1);
    ASSERT_EQ(without_seq(got[i]), logged[i]) << "event " << i;
  }
  const std::string err = ridgewatch::test::slurp(dir / "err");
  EXPECT_NE(err.find("retrying in"), std::string::npos) << err;  // the outage was noticed and logged
  if (!HasFailure()) fs::remove_all(dir);
}

// Acceptance: the daemon is SIGKILLed while the broker is away (all its events unacknowledged) and
// started again: the spool resends them first, then the new run's events follow with seq continuing.
TEST(MqttBroker, DaemonKilledAndRestartedResendsTheSpool) {
  const auto dir = temp_dir("mqtt-kill");
  const int port = ridgewatch::test::free_loopback_port();
  const std::string cfg = mqtt_config(dir, port);
  {
    ChildProcess d1({RIDGEWATCHD_PATH, "--config", cfg, "--replay", kReplay, "--speed", "5", "--loop", "--events",
                     (dir / "ev1.jsonl").string()},
                    {}, (dir / "out1").string(), (dir / "err1").string());
    ASSERT_TRUE(wait_for([&] { return read_jsonl(dir / "ev1.jsonl").size() >= 40; }, 20s));
    d1.signal(SIGKILL);
    d1.wait(5s);
  }
  const auto run1 = read_jsonl(dir / "ev1.jsonl");
  Broker broker(dir / "broker", port);
  Subscriber sub(port, "t/rig/events");
  ChildProcess d2({RIDGEWATCHD_PATH, "--config", cfg, "--replay", kReplay, "--speed", "max", "--events",
                   (dir / "ev2.jsonl").string()},
                  {}, (dir / "out2").string(), (dir / "err2").string());
  ASSERT_EQ(d2.wait(30s), 0) << ridgewatch::test::slurp(dir / "err2");
  const auto run2 = read_jsonl(dir / "ev2.jsonl");
  ASSERT_TRUE(wait_for([&] { return dedup_events(sub.messages()).size() >= run1.size() + run2.size(); }, 10s));
  const auto got = dedup_events(sub.messages());
  // Seqs are contiguous from 1. The first run's spooled events come first: its event log is a prefix
  // of them (the spool is written before the log, so a kill between the two leaves at most one more
  // block in the spool than in the log).
  for (std::size_t i = 0; i < got.size(); ++i) ASSERT_EQ(got[i]["seq"], i + 1);
  ASSERT_GE(got.size(), run1.size() + run2.size());
  const std::size_t n1 = got.size() - run2.size();
  for (std::size_t i = 0; i < run1.size(); ++i) ASSERT_EQ(without_seq(got[i]), run1[i]) << "run 1 event " << i;
  for (std::size_t i = 0; i < run2.size(); ++i) ASSERT_EQ(without_seq(got[n1 + i]), run2[i]) << "run 2 event " << i;
  EXPECT_LE(n1 - run1.size(), 64u);  // at most one processing step's events more than the log
  if (!HasFailure()) fs::remove_all(dir);
}

// Authentication: the password comes from a file and never appears in the daemon's output; a wrong
// one is refused by the broker (and retried), a missing file is a configuration error naming the key.
TEST(MqttBroker, PasswordFromFileNeverLogged) {
  const auto dir = temp_dir("mqtt-auth");
  const int port = ridgewatch::test::free_loopback_port();
  const std::string secret = "s3cret-Pa55-word";
  const auto pwfile = dir / "broker-passwd";
  std::ofstream(pwfile) << "rig:" << secret << "\n";
  ASSERT_EQ(std::system(("/usr/bin/mosquitto_passwd -U " + pwfile.string() + " >/dev/null 2>&1").c_str()), 0);
  fs::create_directories(dir / "broker");
  // A broker that requires the user "rig".
  std::ofstream(dir / "broker" / "extra.conf") << "";
  {
    std::ofstream conf(dir / "auth.conf");
    conf << "listener " << port << " 127.0.0.1\nallow_anonymous false\npassword_file " << pwfile.string() << "\n";
  }
  ChildProcess broker({"/usr/sbin/mosquitto", "-c", (dir / "auth.conf").string()}, {}, (dir / "b.out").string(),
                      (dir / "b.err").string());
  ASSERT_TRUE(wait_for([&] { return ridgewatch::test::port_accepts(port); }, 10s));
  std::ofstream(dir / "rig.pass") << secret << "\n";
  const std::string cfg = mqtt_config(dir, port, "    username: \"rig\"\n    password_file: \"" + (dir / "rig.pass").string() + "\"\n");
  ChildProcess d({RIDGEWATCHD_PATH, "--config", cfg, "--replay", kReplay, "--speed", "max", "--log-level", "debug",
                  "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(30s), 0) << ridgewatch::test::slurp(dir / "err");
  const std::string err = ridgewatch::test::slurp(dir / "err");
  EXPECT_NE(err.find("MQTT: connected"), std::string::npos) << err;
  EXPECT_EQ(err.find(secret), std::string::npos);
  EXPECT_EQ(ridgewatch::test::slurp(dir / "out").find(secret), std::string::npos);
  // Nothing left in the spool: the broker accepted the credentials and acknowledged every event.
  std::size_t segments = 0;
  for (const auto& e : fs::directory_iterator(dir / "spool")) segments += e.path().filename().string().rfind("seg-", 0) == 0;
  EXPECT_EQ(segments, 0u);

  // Missing password file: exit 2 naming the key.
  const std::string bad = mqtt_config(dir, port, "    username: \"rig\"\n    password_file: \"/nonexistent/pw\"\n");
  ChildProcess d2({RIDGEWATCHD_PATH, "--config", bad, "--replay", kReplay, "--speed", "max", "--events",
                   (dir / "ev2.jsonl").string()},
                  {}, (dir / "out2").string(), (dir / "err2").string());
  EXPECT_EQ(d2.wait(10s), 2);
  EXPECT_NE(ridgewatch::test::slurp(dir / "err2").find("output.mqtt.password_file"), std::string::npos)
      << ridgewatch::test::slurp(dir / "err2");

  // A wrong password: the broker refuses the connection (logged with its reason, not the password)
  // and every event stays in the spool for a later connection.
  const std::string wrong = "Wr0ng-Pa55-word";
  std::ofstream(dir / "wrong.pass") << wrong << "\n";
  fs::remove_all(dir / "spool");
  const std::string cfg3 = mqtt_config(dir, port, "    username: \"rig\"\n    password_file: \"" + (dir / "wrong.pass").string() + "\"\n");
  ChildProcess d3({RIDGEWATCHD_PATH, "--config", cfg3, "--replay", kReplay, "--speed", "max", "--events",
                   (dir / "ev3.jsonl").string()},
                  {}, (dir / "out3").string(), (dir / "err3").string());
  ASSERT_EQ(d3.wait(30s), 0) << ridgewatch::test::slurp(dir / "err3");
  const std::string err3 = ridgewatch::test::slurp(dir / "err3");
  EXPECT_NE(err3.find("broker refused the connection"), std::string::npos) << err3;
  EXPECT_EQ(err3.find("MQTT: connected"), std::string::npos) << err3;
  EXPECT_EQ(err3.find(wrong), std::string::npos);
  std::size_t spooled = 0;
  for (const auto& e : fs::directory_iterator(dir / "spool"))
    if (e.path().filename().string().rfind("seg-", 0) == 0) spooled += read_jsonl(e.path()).size();
  const std::size_t logged = read_jsonl(dir / "ev3.jsonl").size();
  EXPECT_GT(logged, 0u);
  EXPECT_EQ(spooled, logged);
}

// TLS end to end (the libmosquitto link): openssl makes a test CA, a server certificate for
// 127.0.0.1 and a client certificate; mosquitto listens with TLS only and requires a client
// certificate, and the test's subscriber connects over TLS too. With the right CA and client pair
// every event of the daemon's log arrives and the spool ends empty; with a CA that did not sign the
// server certificate the daemon never connects (it must verify the broker), says why, and keeps every
// event spooled.
namespace {

// Writes ca.crt/ca.key, server.crt/key (CN and subjectAltName 127.0.0.1), client.crt/key signed by
// the CA, and other-ca.crt (an unrelated CA) into dir. EC P-256 keys: fast to make.
bool make_test_pki(const fs::path& dir) {
  std::ofstream(dir / "san.ext") << "subjectAltName=IP:127.0.0.1,DNS:127.0.0.1\n";
  const std::string d = dir.string();
  const std::string key = " -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes";
  const std::string script =
      "set -e; cd '" + d + "'\n" +
      "openssl req -x509" + key + " -keyout ca.key -out ca.crt -days 2 -subj /CN=ridgewatch-test-ca\n" +
      "openssl req -x509" + key + " -keyout other-ca.key -out other-ca.crt -days 2 -subj /CN=other-ca\n" +
      "openssl req" + key + " -keyout server.key -out server.csr -subj /CN=127.0.0.1\n" +
      "openssl x509 -req -in server.csr -CA ca.crt -CAkey ca.key -CAcreateserial -out server.crt -days 2 -extfile san.ext\n" +
      "openssl req" + key + " -keyout client.key -out client.csr -subj /CN=rig-t\n" +
      "openssl x509 -req -in client.csr -CA ca.crt -CAkey ca.key -CAcreateserial -out client.crt -days 2\n" +
      "chmod 644 *.key\n";
  std::ofstream(dir / "pki.sh") << script;
  return std::system(("bash '" + (dir / "pki.sh").string() + "' >'" + d + "/pki.log' 2>&1").c_str()) == 0;
}

std::size_t spooled_events(const fs::path& spool) {
  std::size_t n = 0;
  for (const auto& e : fs::directory_iterator(spool))
    if (e.path().filename().string().rfind("seg-", 0) == 0) n += read_jsonl(e.path()).size();
  return n;
}

std::string tls_keys(const fs::path& dir, const std::string& ca) {
  return "    tls:\n      ca_file: \"" + (dir / ca).string() + "\"\n      cert_file: \"" + (dir / "client.crt").string() +
         "\"\n      key_file: \"" + (dir / "client.key").string() + "\"\n";
}

}  // namespace

TEST(MqttBroker, TlsWithClientCertificateDeliversEverythingAndAnUnknownCaIsRefused) {
  if (!fs::exists("/usr/bin/openssl")) GTEST_SKIP() << "openssl not installed (scripts/install-deps.sh installs it)";
  const auto dir = temp_dir("mqtt-tls");
  ASSERT_TRUE(make_test_pki(dir)) << ridgewatch::test::slurp(dir / "pki.log");
  const int tls_port = ridgewatch::test::free_loopback_port();
  {
    std::ofstream conf(dir / "tls.conf");
    conf << "allow_anonymous true\nlistener " << tls_port << " 127.0.0.1\ncafile " << (dir / "ca.crt").string()
         << "\ncertfile " << (dir / "server.crt").string() << "\nkeyfile " << (dir / "server.key").string()
         << "\nrequire_certificate true\n" << (::geteuid() == 0 ? "user root\n" : "");
  }
  ChildProcess broker({"/usr/sbin/mosquitto", "-c", (dir / "tls.conf").string()}, {}, (dir / "b.out").string(),
                      (dir / "b.err").string());
  ASSERT_TRUE(wait_for([&] { return ridgewatch::test::port_accepts(tls_port); }, 10s)) << ridgewatch::test::slurp(dir / "b.err");
  const ridgewatch::test::TlsFiles client{(dir / "ca.crt").string(), (dir / "client.crt").string(), (dir / "client.key").string()};
  Subscriber sub(tls_port, "t/rig/events", "ridgewatch-test-sub", &client);
  ASSERT_TRUE(wait_for([&] { return ridgewatch::test::slurp(dir / "b.err").find("as ridgewatch-test-sub") != std::string::npos; }, 10s))
      << ridgewatch::test::slurp(dir / "b.err");

  ChildProcess d({RIDGEWATCHD_PATH, "--config", mqtt_config(dir, tls_port, tls_keys(dir, "ca.crt")), "--replay", kReplay,
                  "--speed", "max", "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(30s), 0) << ridgewatch::test::slurp(dir / "err");
  EXPECT_NE(ridgewatch::test::slurp(dir / "err").find("MQTT: connected"), std::string::npos)
      << ridgewatch::test::slurp(dir / "err");
  const auto logged = read_jsonl(dir / "ev.jsonl");
  ASSERT_GT(logged.size(), 0u);
  ASSERT_TRUE(wait_for([&] { return dedup_events(sub.messages()).size() >= logged.size(); }, 10s))
      << dedup_events(sub.messages()).size() << " of " << logged.size();
  const auto got = dedup_events(sub.messages());
  ASSERT_EQ(got.size(), logged.size());
  for (std::size_t i = 0; i < got.size(); ++i) EXPECT_EQ(got[i]["sample_index"], logged[i]["sample_index"]) << i;
  EXPECT_EQ(spooled_events(dir / "spool"), 0u);

  // The broker's certificate checked against a CA that did not sign it: no connection, nothing sent,
  // the reason in the log, every event kept in the spool.
  fs::remove_all(dir / "spool");
  const std::size_t before = sub.count();
  ChildProcess d2({RIDGEWATCHD_PATH, "--config", mqtt_config(dir, tls_port, tls_keys(dir, "other-ca.crt")), "--replay",
                   kReplay, "--speed", "max", "--events", (dir / "ev2.jsonl").string()},
                  {}, (dir / "out2").string(), (dir / "err2").string());
  ASSERT_EQ(d2.wait(30s), 0) << ridgewatch::test::slurp(dir / "err2");
  const std::string err2 = ridgewatch::test::slurp(dir / "err2");
  EXPECT_EQ(err2.find("MQTT: connected"), std::string::npos) << err2;
  EXPECT_NE(err2.find("TLS handshake failed"), std::string::npos) << err2;
  EXPECT_NE(err2.find("output.mqtt.tls.ca_file"), std::string::npos) << err2;
  EXPECT_EQ(sub.count(), before);
  const std::size_t logged2 = read_jsonl(dir / "ev2.jsonl").size();
  EXPECT_GT(logged2, 0u);
  EXPECT_EQ(spooled_events(dir / "spool"), logged2);
  if (!HasFailure()) fs::remove_all(dir);
}

// ---- configuration ------------------------------------------------------------------------------

TEST(MqttConfig, BadValuesNameTheKey) {
  using ridgewatch::app::parse_config;
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"output:\n  mqtt:\n    host: \"h\"\n    qos: 2\n", "output.mqtt.qos"},
      {"output:\n  mqtt:\n    host: \"h\"\n    keepalive_s: 1\n", "output.mqtt.keepalive_s"},
      {"output:\n  mqtt:\n    host: \"h\"\n    port: 70000\n", "output.mqtt.port"},
      {"output:\n  mqtt:\n    host: \"h\"\n    spool_max_mb: 0\n", "output.mqtt.spool_max_mb"},
      {"output:\n  mqtt:\n    host: \"h\"\n    tls:\n      ca_file: \"ca\"\n      cert_file: \"c\"\n", "output.mqtt.tls"},
      {"output:\n  mqtt:\n    host: \"h\"\n    password_file: \"p\"\n", "output.mqtt.username"},
      {"output:\n  mqtt:\n    host: \"h\"\n    topic_prefix: \"a/#\"\n", "output.mqtt.topic_prefix"},
      {"output:\n  mqtt:\n    hots: \"h\"\n", "output.mqtt.hots"},
      {"http:\n  listen: \"0.0.0.0\"\n", "http.listen"},
      {"http:\n  listen: \"127.0.0.1:99999\"\n", "http.listen"},
      {"http:\n  listen: \"127.0.0.1:x\"\n", "http.listen"},
  };
  for (const auto& [text, key] : cases) {
    try {
      parse_config(text, "t.yaml");
      ADD_FAILURE() << "accepted: " << text;
    } catch (const ridgewatch::app::UsageError& e) {
      EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
    }
  }
  // Good values round-trip through the printer (--print-defaults layout).
  const auto c = parse_config("output:\n  mqtt:\n    host: \"127.0.0.1\"\n    port: 8883\n    qos: 0\n    username: \"u\"\n"
                              "    password_file: \"/p\"\n    tls:\n      ca_file: \"/ca\"\n"
                              "http:\n  listen: \"[::1]:9420\"\n",
                              "t.yaml");
  EXPECT_EQ(c.output.mqtt.port, 8883u);
  EXPECT_EQ(c.output.mqtt.qos, 0u);
  EXPECT_EQ(c.output.mqtt.tls.ca_file, "/ca");
  EXPECT_EQ(c.http.listen, "[::1]:9420");
  EXPECT_EQ(ridgewatch::app::to_yaml(parse_config(ridgewatch::app::to_yaml(c), "again")), ridgewatch::app::to_yaml(c));
}

// ---- the plain-TCP MQTT 3.1.1 link against a scripted broker -----------------------------------

namespace {

// The test's side of one connection: reads exactly n bytes (or fewer when the peer closes).
std::string read_exact(int fd, std::size_t n) {
  std::string out;
  char buf[4096];
  while (out.size() < n) {
    const ssize_t got = ::recv(fd, buf, std::min(sizeof buf, n - out.size()), 0);
    if (got <= 0) break;
    out.append(buf, static_cast<std::size_t>(got));
  }
  return out;
}

// One control packet as the specification lays it out (2.2): type byte, remaining length (base 128,
// low digits first), body.
struct Packet {
  unsigned type = 0;
  std::string body;
};
Packet read_packet(int fd) {
  Packet p;
  const std::string t = read_exact(fd, 1);
  if (t.empty()) return p;
  p.type = static_cast<unsigned char>(t[0]);
  std::size_t len = 0, mult = 1;
  for (;;) {
    const std::string b = read_exact(fd, 1);
    if (b.empty()) return p;
    len += (static_cast<unsigned char>(b[0]) & 127u) * mult;
    mult *= 128;
    if ((static_cast<unsigned char>(b[0]) & 128u) == 0) break;
  }
  p.body = read_exact(fd, len);
  return p;
}

// A two-byte big-endian length followed by that many bytes (1.5.3), taken from the front of `s`.
std::string take_field(std::string& s) {
  if (s.size() < 2) return "<short>";
  const std::size_t n = static_cast<unsigned char>(s[0]) * 256u + static_cast<unsigned char>(s[1]);
  std::string f = s.substr(2, n);
  s.erase(0, 2 + n);
  return f;
}

struct Recorder : ridgewatch::daemon::MqttLink::Events {
  std::vector<int> connacks, acks;
  void on_connect(int rc) override { connacks.push_back(rc); }
  void on_publish(int mid) override { acks.push_back(mid); }
};

void send_bytes(int fd, const std::string& s) { ASSERT_EQ(::send(fd, s.data(), s.size(), MSG_NOSIGNAL), static_cast<ssize_t>(s.size())); }

}  // namespace

// The link writes CONNECT and PUBLISH as MQTT 3.1.1 specifies them (decoded here independently),
// reports a CONNACK and PUBACKs that arrive cut at arbitrary byte boundaries, pings when the
// connection is idle for the keepalive, gives up on a broker that does not answer the ping, and
// reports a closed connection.
TEST(MqttLink, PlainTcpSpeaksMqtt311ToAScriptedBroker) {
  using ridgewatch::daemon::MqttLink;
  const int lfd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(::bind(lfd, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
  ASSERT_EQ(::listen(lfd, 1), 0);
  socklen_t alen = sizeof a;
  ::getsockname(lfd, reinterpret_cast<sockaddr*>(&a), &alen);
  const int port = ntohs(a.sin_port);

  ridgewatch::app::MqttConfig cfg;  // no TLS: the plain-TCP link
  MqttLink::Options o;
  o.client_id = "rig-c";
  o.username = "user";
  o.password = "pw!";
  o.will_topic = "p/status";
  o.will_payload = "{\"state\":\"offline\"}";
  o.keepalive_s = 1;
  Recorder rec;
  std::string error;
  auto link = ridgewatch::daemon::make_mqtt_link(cfg, o, rec, error);
  ASSERT_TRUE(link) << error;
  ASSERT_EQ(link->connect("127.0.0.1", port), MOSQ_ERR_SUCCESS);
  const int fd = ::accept(lfd, nullptr, nullptr);
  ASSERT_GE(fd, 0);

  // CONNECT (3.1): "MQTT", level 4, flags user + password + will retain + will QoS 1 + will + clean
  // session = 0xEE, keepalive 1 s; payload client id, will topic, will message, user, password.
  Packet c = read_packet(fd);
  EXPECT_EQ(c.type, 0x10u);
  EXPECT_EQ(take_field(c.body), "MQTT");
  ASSERT_GE(c.body.size(), 4u);
  EXPECT_EQ(static_cast<unsigned char>(c.body[0]), 4u);
  EXPECT_EQ(static_cast<unsigned char>(c.body[1]), 0xEEu);
  EXPECT_EQ(static_cast<unsigned char>(c.body[2]) * 256 + static_cast<unsigned char>(c.body[3]), 1);
  c.body.erase(0, 4);
  for (const std::string want : {"rig-c", "p/status", "{\"state\":\"offline\"}", "user", "pw!"}) EXPECT_EQ(take_field(c.body), want);
  EXPECT_TRUE(c.body.empty());

  // CONNACK cut after its third byte: reported only once whole.
  send_bytes(fd, std::string("\x20\x02\x00", 3));
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(link->read(), MOSQ_ERR_SUCCESS);
  EXPECT_TRUE(rec.connacks.empty());
  send_bytes(fd, std::string("\x00", 1));
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(link->read(), MOSQ_ERR_SUCCESS);
  EXPECT_EQ(rec.connacks, std::vector<int>{0});

  // Three publishes queued, then written together: QoS 1, QoS 1 retained, QoS 0; a payload of 300
  // bytes needs a two-byte remaining length.
  const std::string big(300, 'z');
  int m1 = 0, m2 = 0, m3 = 0;
  ASSERT_EQ(link->publish(&m1, "p/events", "{\"seq\":1}", 1, false), MOSQ_ERR_SUCCESS);
  ASSERT_EQ(link->publish(&m2, "p/alarm", big, 1, true), MOSQ_ERR_SUCCESS);
  ASSERT_EQ(link->publish(&m3, "p/events", "q0", 0, false), MOSQ_ERR_SUCCESS);
  EXPECT_NE(m1, 0);
  EXPECT_NE(m2, 0);
  EXPECT_NE(m1, m2);
  EXPECT_TRUE(link->want_write());
  EXPECT_EQ(link->write(), MOSQ_ERR_SUCCESS);
  EXPECT_FALSE(link->want_write());
  auto check_publish = [&](unsigned type, const std::string& topic, int id, const std::string& payload) {
    Packet p = read_packet(fd);
    EXPECT_EQ(p.type, type);
    EXPECT_EQ(take_field(p.body), topic);
    if (id != 0) {
      ASSERT_GE(p.body.size(), 2u);
      EXPECT_EQ(static_cast<unsigned char>(p.body[0]) * 256 + static_cast<unsigned char>(p.body[1]), id);
      p.body.erase(0, 2);
    }
    EXPECT_EQ(p.body, payload);
  };
  check_publish(0x32, "p/events", m1, "{\"seq\":1}");  // PUBLISH, QoS 1
  check_publish(0x33, "p/alarm", m2, big);             // QoS 1, retain
  check_publish(0x30, "p/events", 0, "q0");            // QoS 0: no packet identifier

  // PUBACKs in another order, the second cut in the middle of its identifier.
  std::string acks;
  for (const int id : {m2, m1}) acks += std::string{'\x40', '\x02', static_cast<char>(id >> 8), static_cast<char>(id & 0xFF)};
  send_bytes(fd, acks.substr(0, 6));
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(link->read(), MOSQ_ERR_SUCCESS);
  EXPECT_EQ(rec.acks, std::vector<int>{m2});
  send_bytes(fd, acks.substr(6));
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(link->read(), MOSQ_ERR_SUCCESS);
  EXPECT_EQ(rec.acks, (std::vector<int>{m2, m1}));

  // Idle for the keepalive (1 s): a PINGREQ; answered, the link stays up; unanswered for another
  // keepalive, the link reports the broker gone. misc() is polled every 20 ms as the sender does.
  auto poll_misc_until = [&](const std::function<bool(int)>& done, std::chrono::milliseconds limit) {
    const auto end = std::chrono::steady_clock::now() + limit;
    int rc = MOSQ_ERR_SUCCESS;
    while (std::chrono::steady_clock::now() < end) {
      rc = link->misc();
      if (done(rc)) break;
      std::this_thread::sleep_for(20ms);
    }
    return rc;
  };
  const auto t0 = std::chrono::steady_clock::now();
  Packet ping;
  std::atomic<bool> pinged{false};
  std::thread pinger([&] {
    ping = read_packet(fd);
    pinged = true;
  });
  poll_misc_until([&](int) { return pinged.load(); }, 3s);
  pinger.join();
  EXPECT_EQ(ping.type, 0xC0u);
  EXPECT_TRUE(ping.body.empty());
  EXPECT_GE(std::chrono::steady_clock::now() - t0, 900ms);  // not before the keepalive (1 s, timer slack)
  send_bytes(fd, std::string("\xD0\x00", 2));                // PINGRESP
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(link->read(), MOSQ_ERR_SUCCESS);
  EXPECT_EQ(link->misc(), MOSQ_ERR_SUCCESS);
  // The next PINGREQ goes unanswered.
  const int rc = poll_misc_until([](int r) { return r != MOSQ_ERR_SUCCESS; }, 4s);
  EXPECT_EQ(rc, MOSQ_ERR_KEEPALIVE);

  // The broker closes the connection: reported as lost.
  ::close(fd);
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(link->read(), MOSQ_ERR_CONN_LOST);
  ::close(lfd);
}
