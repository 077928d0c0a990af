#include "daemon/http_server.hpp"

#include <httplib.h>

#include <nlohmann/json.hpp>
#include <thread>

#include "app/args.hpp"
#include "daemon/web_index_html.hpp"

namespace ridgewatch::daemon {

const std::string& live_page_html() {
  static const std::string page(kLivePageHtml);
  return page;
}

struct HttpServer::Impl {
  httplib::Server server;
  std::thread thread;
  int port = 0;
  std::vector<const Telemetry*> telemetries;
  std::string stream_names;  // /api/streams: a JSON array

  // The stream a request asks for (?stream=NAME), the first without the parameter; null if unknown.
  const Telemetry* find(const httplib::Request& req) const {
    if (!req.has_param("stream")) return telemetries.front();
    const std::string name = req.get_param_value("stream");
    for (const Telemetry* t : telemetries)
      if (t->stream() == name) return t;
    return nullptr;
  }
};

HttpServer::HttpServer(const std::string& listen, const Telemetry& telemetry)
    : HttpServer(listen, std::vector<const Telemetry*>{&telemetry}) {}

HttpServer::HttpServer(const std::string& listen, std::vector<const Telemetry*> telemetries)
    : impl_(std::make_unique<Impl>()) {
  impl_->telemetries = std::move(telemetries);
  nlohmann::json names = nlohmann::json::array();
  for (const Telemetry* t : impl_->telemetries)
    if (!t->stream().empty()) names.push_back(t->stream());
  impl_->stream_names = names.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  const auto colon = listen.rfind(':');
  if (colon == std::string::npos) throw app::UsageError("http.listen: must be ADDRESS:PORT (got '" + listen + "')");
  std::string host = listen.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
  const int port = std::stoi(listen.substr(colon + 1));
  auto& s = impl_->server;
  // Two workers are plenty for a scrape every few seconds and a page or two polling once a second
  // (the library's default is 8 threads or more).
  s.new_task_queue = [] { return new httplib::ThreadPool(2); };
  // The library's default also sets SO_REUSEPORT, which would let a second process share (and take
  // requests from) a port already in use; only SO_REUSEADDR (fast restarts) is wanted.
  s.set_socket_options([](socket_t sock) {
    int yes = 1;
    ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
  });
  const Impl* impl = impl_.get();
  s.Get("/metrics", [impl](const httplib::Request&, httplib::Response& res) {
    res.set_content(prometheus_exposition(impl->telemetries), "text/plain; version=0.0.4; charset=utf-8");
  });
  s.Get("/api/state", [impl](const httplib::Request& req, httplib::Response& res) {
    res.set_header("Cache-Control", "no-store");
    const Telemetry* t = impl->find(req);
    if (t == nullptr) {
      res.status = 404;
      res.set_content(nlohmann::json{{"error", "no stream '" + req.get_param_value("stream") + "'"}}.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace),
                      "application/json");
      return;
    }
    res.set_content(t->state_json(), "application/json");
  });
  s.Get("/api/streams", [impl](const httplib::Request&, httplib::Response& res) {
    res.set_content(impl->stream_names, "application/json");
  });
  s.Get("/healthz", [](const httplib::Request&, httplib::Response& res) { res.set_content("ok\n", "text/plain"); });
  s.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_header("Content-Security-Policy", "default-src 'self'; script-src 'unsafe-inline'; style-src 'unsafe-inline'");
    res.set_content(live_page_html(), "text/html; charset=utf-8");
  });
  if (port == 0) {
    impl_->port = s.bind_to_any_port(host);
    if (impl_->port < 0) throw app::UsageError("http.listen: cannot listen on '" + listen + "'");
  } else {
    if (!s.bind_to_port(host, port))
      throw app::UsageError("http.listen: cannot listen on '" + listen + "' (address in use or not local?)");
    impl_->port = port;
  }
  impl_->thread = std::thread([this] { impl_->server.listen_after_bind(); });
}

HttpServer::~HttpServer() {
  impl_->server.stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

int HttpServer::port() const { return impl_->port; }

}  // namespace ridgewatch::daemon
