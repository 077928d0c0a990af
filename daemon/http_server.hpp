// The daemon's HTTP listener (cpp-httplib): Prometheus /metrics, the live page / and its data
// /api/state, the stream names /api/streams, and /healthz. Off unless http.listen is set; the
// configuration's example binds to loopback. Two worker threads; every handler only reads Telemetry
// snapshots.
//
// Several streams (`streams:`): one listener for all. /metrics carries every stream's samples with a
// `stream` label; /api/state?stream=NAME is one stream's page data (the first stream's without the
// parameter); /api/streams lists the names (an empty list for the one-stream daemon).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "daemon/metrics.hpp"

namespace ridgewatch::daemon {

class HttpServer {
 public:
  /// listen: "ADDRESS:PORT" (port 0: any free port, see port()). Throws app::UsageError naming
  /// http.listen when the address cannot be bound.
  HttpServer(const std::string& listen, const Telemetry& telemetry);
  /// Several streams: `telemetries` non-empty, each named (Telemetry::stream()), alive while this is.
  HttpServer(const std::string& listen, std::vector<const Telemetry*> telemetries);
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
