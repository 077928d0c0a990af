// fleet_check: subscribes to ridgewatch/+/events on a broker (QoS 1, persistent session), and once
// the rigs are done (the --done-file appears) checks that every event of every rig's own event log
// arrived exactly once after de-duplication by seq, in order, with the same content.
//
//   fleet_check --port P --done-file F [--host H] [--timeout-s 20] RIG=EVENTS.jsonl ...
//
// Prints one line per rig (events logged, received, duplicates removed) and exits 0 when all match,
// 1 otherwise, 2 on usage errors.
#include <mosquitto.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

namespace {

using json = nlohmann::json;

struct Received {
  std::mutex mutex;
  std::map<std::string, std::vector<std::string>> by_topic;  // payloads in arrival order
  bool subscribed = false;
};

std::vector<json> read_jsonl(const std::string& path) {
  std::vector<json> out;
  std::ifstream f(path);
  std::string line;
  while (std::getline(f, line))
    if (!line.empty()) out.push_back(json::parse(line));
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::string host = "127.0.0.1", done_file;
  int port = 1883;
  double timeout_s = 20.0;
  std::vector<std::pair<std::string, std::string>> rigs;  // name, event log
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << "fleet_check: " << a << " needs a value\n";
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--host") host = next();
    else if (a == "--port") port = std::stoi(next());
    else if (a == "--done-file") done_file = next();
    else if (a == "--timeout-s") timeout_s = std::stod(next());
    else if (const auto eq = a.find('='); eq != std::string::npos) rigs.emplace_back(a.substr(0, eq), a.substr(eq + 1));
    else {
      std::cerr << "fleet_check: unexpected argument '" << a << "'\n";
      return 2;
    }
  }
  if (rigs.empty() || done_file.empty()) {
    std::cerr << "usage: fleet_check --port P --done-file F [--host H] [--timeout-s S] RIG=EVENTS.jsonl ...\n";
    return 2;
  }
  Received rx;
  mosquitto_lib_init();
  struct mosquitto* m = mosquitto_new("ridgewatch-fleet-check", false, &rx);
  mosquitto_reconnect_delay_set(m, 1, 2, false);
  mosquitto_connect_callback_set(m, [](struct mosquitto* c, void*, int rc) {
    if (rc == 0) mosquitto_subscribe(c, nullptr, "ridgewatch/+/events", 1);
  });
  mosquitto_subscribe_callback_set(m, [](struct mosquitto*, void* p, int, int, const int*) {
    auto* r = static_cast<Received*>(p);
    std::lock_guard<std::mutex> lock(r->mutex);
    r->subscribed = true;
  });
  mosquitto_message_callback_set(m, [](struct mosquitto*, void* p, const struct mosquitto_message* msg) {
    auto* r = static_cast<Received*>(p);
    std::lock_guard<std::mutex> lock(r->mutex);
    r->by_topic[msg->topic].emplace_back(static_cast<const char*>(msg->payload), static_cast<std::size_t>(msg->payloadlen));
  });
  if (mosquitto_connect(m, host.c_str(), port, 30) != MOSQ_ERR_SUCCESS) {
    std::cerr << "fleet_check: cannot connect to " << host << ":" << port << "\n";
    return 1;
  }
  mosquitto_loop_start(m);
  std::cout << "fleet_check: subscribed to ridgewatch/+/events on " << host << ":" << port << std::endl;
  while (!std::filesystem::exists(done_file)) std::this_thread::sleep_for(std::chrono::milliseconds(100));

  // The rigs are done: their logs are final. Wait until everything arrived (or the time-out).
  std::map<std::string, std::vector<json>> logs;
  for (const auto& [rig, path] : rigs) logs[rig] = read_jsonl(path);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  auto unique_count = [&](const std::string& rig) {
    std::lock_guard<std::mutex> lock(rx.mutex);
    std::map<std::uint64_t, bool> seqs;
    for (const auto& p : rx.by_topic["ridgewatch/" + rig + "/events"]) seqs[json::parse(p).at("seq").get<std::uint64_t>()] = true;
    return seqs.size();
  };
  for (;;) {
    bool all = true;
    for (const auto& [rig, log] : logs) all = all && unique_count(rig) >= log.size();
    if (all || std::chrono::steady_clock::now() > deadline) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // late duplicates, if any
  mosquitto_disconnect(m);
  mosquitto_loop_stop(m, true);
  mosquitto_destroy(m);

  bool ok = true;
  for (const auto& [rig, log] : logs) {
    std::vector<std::string> payloads = rx.by_topic["ridgewatch/" + rig + "/events"];
    std::map<std::uint64_t, std::string> first;
    std::vector<json> unique;
    std::size_t dups = 0, out_of_order = 0, conflicting = 0;
    std::uint64_t last = 0;
    for (const auto& p : payloads) {
      json j = json::parse(p);
      const std::uint64_t seq = j.at("seq").get<std::uint64_t>();
      if (const auto it = first.find(seq); it != first.end()) {
        ++dups;
        conflicting += it->second != p;
        continue;
      }
      out_of_order += seq <= last;
      last = seq;
      first[seq] = p;
      j.erase("seq");
      unique.push_back(std::move(j));
    }
    std::size_t mismatched = 0;
    for (std::size_t i = 0; i < std::min(unique.size(), log.size()); ++i) mismatched += unique[i] != log[i];
    // The seqs of one run start at 1 when its spool directory is new.
    const bool rig_ok = unique.size() == log.size() && mismatched == 0 && out_of_order == 0 && conflicting == 0;
    ok = ok && rig_ok;
    std::printf("%s: %zu events logged, %zu received exactly once after removing %zu duplicates by seq%s%s\n", rig.c_str(),
                log.size(), unique.size(), dups, rig_ok ? "" : " -- MISMATCH", rig_ok ? ", in order, identical" : "");
    if (!rig_ok)
      std::printf("  %zu differ from the log, %zu out of order, %zu duplicates with other content\n", mismatched,
                  out_of_order, conflicting);
  }
  std::printf("fleet_check: %s\n", ok ? "every event of every rig arrived exactly once" : "FAILED");
  return ok ? 0 : 1;
}
