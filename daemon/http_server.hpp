// The daemon's HTTP listener (cpp-httplib): Prometheus /metrics, the live page / and its data
// /api/state, and /healthz. Off unless http.listen is set; the configuration's example binds to
// loopback. Two worker threads; every handler only reads a Telemetry snapshot.
#pragma once

#include <memory>
#include <string>

#include "daemon/metrics.hpp"

namespace ridgewatch::daemon {

class HttpServer {
 public:
  /// listen: "ADDRESS:PORT" (port 0: any free port, see port()). Throws app::UsageError naming
  /// http.listen when the address cannot be bound.
  HttpServer(const std::string& listen, const Telemetry& telemetry);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;
  int port() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The live page (daemon/web/index.html, compiled in: no external scripts, fonts or CDNs).
const std::string& live_page_html();

}  // namespace ridgewatch::daemon
