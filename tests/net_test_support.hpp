// Test helpers for the network outputs: a free loopback port, a real mosquitto broker started by the
// test (bound to 127.0.0.1 only, stopped by the test), a libmosquitto subscriber that collects
// messages, and a small blocking HTTP GET. Nothing here contacts any address but 127.0.0.1.
#pragma once

#include <arpa/inet.h>
#include <mosquitto.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "process_runner.hpp"

namespace ridgewatch::test {

/// A fresh, empty scratch directory <temp>/ridgewatch-<name>-<pid>: one per test and per process
/// (ctest runs tests in parallel, and the sanitizer pass runs the same binaries again).
inline std::filesystem::path temp_dir(const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() / ("ridgewatch-" + name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

/// The objects of a JSON Lines file (an event log), in order.
inline std::vector<nlohmann::json> read_jsonl(const std::filesystem::path& p) {
  std::vector<nlohmann::json> out;
  std::ifstream f(p);
  std::string line;
  while (std::getline(f, line)) out.push_back(nlohmann::json::parse(line));
  return out;
}

/// A TCP port on 127.0.0.1 that was free a moment ago (the kernel picks it).
inline int free_loopback_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  ::close(fd);
  return ntohs(a.sin_port);
}

inline bool port_accepts(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<uint16_t>(port));
  const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

inline bool wait_for(const std::function<bool()>& cond, std::chrono::milliseconds timeout) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (!cond()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return true;
}

/// mosquitto on 127.0.0.1:port with persistence in `dir` (so a restarted broker still holds the
/// queued messages of a persistent subscriber session).
class Broker {
 public:
  Broker(const std::filesystem::path& dir, int port) : dir_(dir), port_(port) { start(); }
  /// `save_every_change` false: the database is saved once a minute instead, for a broker that is
  /// not killed again. Saving after every change writes the whole database (every message queued
  /// for a subscriber) per incoming message, so a subscriber that falls behind on a loaded host
  /// makes each save longer and the broker slower: it then never catches up.
  void start(bool save_every_change = true) {
    std::filesystem::create_directories(dir_);
    const auto conf = dir_ / "mosquitto.conf";
    std::ofstream(conf) << "listener " << port_ << " 127.0.0.1\nallow_anonymous true\npersistence true\n"
                        // Saved after every change (queued message, subscription), not once a second:
                        // a killed broker loses nothing it had acknowledged to the daemon. With the
                        // 1 s timer the messages acknowledged since the last save and not yet
                        // delivered to a slow subscriber (a loaded ThreadSanitizer run: 35 of 755)
                        // were lost by the broker, not by the daemon.
                        << "persistence_location " << dir_.string() << "/\n"
                        << (save_every_change ? "autosave_interval 1\nautosave_on_changes true\n" : "autosave_interval 60\n")
                        << "max_queued_messages 0\nlog_dest stderr\n"
                        // Started as root, mosquitto drops to user "mosquitto", which cannot write here.
                        << (::geteuid() == 0 ? "user root\n" : "");
    proc_ = std::make_unique<ChildProcess>(std::vector<std::string>{"/usr/sbin/mosquitto", "-c", conf.string()},
                                           std::vector<std::string>{}, (dir_ / "broker.out").string(),
                                           (dir_ / "broker.err").string());
    if (!wait_for([&] { return port_accepts(port_); }, std::chrono::seconds(10)))
      throw std::runtime_error("mosquitto did not start on port " + std::to_string(port_));
  }
  /// SIGTERM: mosquitto saves its persistence database and exits.
  void stop() {
    if (!proc_) return;
    proc_->signal(SIGTERM);
    proc_->wait(std::chrono::seconds(10));
    proc_.reset();
  }
  /// SIGSTOP then SIGKILL: the broker dies with messages it received but never acknowledged.
  void freeze_and_kill(std::chrono::milliseconds frozen) {
    if (!proc_) return;
    proc_->signal(SIGSTOP);
    std::this_thread::sleep_for(frozen);
    proc_->signal(SIGKILL);
    proc_->wait(std::chrono::seconds(10));
    proc_.reset();
  }
  ~Broker() { stop(); }
  int port() const { return port_; }

 private:
  std::filesystem::path dir_;
  int port_;
  std::unique_ptr<ChildProcess> proc_;
};

/// Files of a TLS client: the CA that signed the broker's certificate, and the client's own pair.
struct TlsFiles {
  std::string ca_file, cert_file, key_file;
};

/// A persistent-session QoS 1 subscriber. Its own thread runs the client (libmosquitto's threaded
/// loop trips ThreadSanitizer inside the library when the broker is killed) and reconnects every
/// 100 ms while the broker is away, subscribing again on every connection. With `tls` it connects
/// over TLS with those files.
class Subscriber {
 public:
  Subscriber(int port, const std::string& topic, const std::string& client_id = "ridgewatch-test-sub",
             const TlsFiles* tls = nullptr)
      : topic_(topic) {
    mosquitto_lib_init();
    m_ = mosquitto_new(client_id.c_str(), false, this);
    if (tls)
      mosquitto_tls_set(m_, tls->ca_file.c_str(), nullptr, tls->cert_file.c_str(), tls->key_file.c_str(), nullptr);
    mosquitto_connect_callback_set(m_, [](struct mosquitto* m, void* self, int rc) {
      if (rc == 0) mosquitto_subscribe(m, nullptr, static_cast<Subscriber*>(self)->topic_.c_str(), 1);
    });
    mosquitto_subscribe_callback_set(m_, [](struct mosquitto*, void* self, int, int, const int*) {
      static_cast<Subscriber*>(self)->subscribed_ = true;
    });
    mosquitto_message_callback_set(m_, [](struct mosquitto*, void* self, const struct mosquitto_message* msg) {
      auto* s = static_cast<Subscriber*>(self);
      std::lock_guard<std::mutex> lock(s->mutex_);
      s->messages_.push_back({msg->topic, std::string(static_cast<const char*>(msg->payload), static_cast<std::size_t>(msg->payloadlen)),
                              msg->retain});
    });
    thread_ = std::thread([this, port] {
      bool connected = false, ever = false;
      while (!stop_.load()) {
        if (!connected) {
          const int rc = ever ? mosquitto_reconnect(m_) : mosquitto_connect(m_, "127.0.0.1", port, 30);
          if (rc != MOSQ_ERR_SUCCESS) {
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
            continue;
          }
          connected = ever = true;
        }
        if (mosquitto_loop(m_, 20, 1) != MOSQ_ERR_SUCCESS) connected = false;
      }
      if (connected) {
        mosquitto_disconnect(m_);
        mosquitto_loop(m_, 20, 1);
      }
    });
    wait_for([&] { return subscribed_.load(); }, std::chrono::seconds(10));
  }
  ~Subscriber() {
    stop_ = true;
    thread_.join();
    mosquitto_destroy(m_);
  }
  struct Msg {
    std::string topic, payload;
    bool retained;
  };
  std::vector<Msg> messages() {
    std::lock_guard<std::mutex> lock(mutex_);
    return messages_;
  }
  /// The messages received after the first `first` (for readers that keep their place).
  std::vector<Msg> messages_from(std::size_t first) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (first >= messages_.size()) return {};
    return std::vector<Msg>(messages_.begin() + static_cast<std::ptrdiff_t>(first), messages_.end());
  }
  std::size_t count() {
    std::lock_guard<std::mutex> lock(mutex_);
    return messages_.size();
  }

 private:
  std::string topic_;
  struct mosquitto* m_ = nullptr;
  std::atomic<bool> subscribed_{false}, stop_{false};
  std::thread thread_;
  std::mutex mutex_;
  std::vector<Msg> messages_;
};

/// GET http://127.0.0.1:port/path over a plain socket (HTTP/1.0, whole body). Empty on failure.
inline std::string http_get(int port, const std::string& path, int* status = nullptr) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<uint16_t>(port));
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return {};
  }
  const std::string req = "GET " + path + " HTTP/1.0\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
  if (::write(fd, req.data(), req.size()) != static_cast<ssize_t>(req.size())) {
    ::close(fd);
    return {};
  }
  std::string resp;
  char buf[8192];
  for (ssize_t n; (n = ::read(fd, buf, sizeof buf)) > 0;) resp.append(buf, static_cast<std::size_t>(n));
  ::close(fd);
  const auto body = resp.find("\r\n\r\n");
  if (status) *status = resp.size() > 12 ? std::stoi(resp.substr(9, 3)) : 0;
  return body == std::string::npos ? std::string() : resp.substr(body + 4);
}

}  // namespace ridgewatch::test
