#include "daemon/mqtt_link.hpp"

#include <mosquitto.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <vector>

namespace ridgewatch::daemon {

namespace {

using Clock = std::chrono::steady_clock;

// ---- plain TCP: MQTT 3.1.1 (OASIS standard, 2014) ------------------------------------------------

// Control packet types (first byte, high nibble; section 2.2.1).
constexpr unsigned char kConnect = 0x10, kConnack = 0x20, kPublish = 0x30, kPuback = 0x40, kPingreq = 0xC0,
                        kPingresp = 0xD0, kDisconnect = 0xE0;

void put_u16(std::string& out, std::size_t v) {
  out += static_cast<char>((v >> 8) & 0xFF);
  out += static_cast<char>(v & 0xFF);
}

// A length-prefixed string or binary field (1.5.3); callers keep fields below 64 KiB.
void put_field(std::string& out, std::string_view s) {
  put_u16(out, s.size());
  out.append(s);
}

// Fixed header: type byte and the remaining length as a base-128 varint (2.2.3, at most 4 bytes).
void put_header(std::string& out, unsigned char type, std::size_t remaining) {
  out += static_cast<char>(type);
  do {
    unsigned char b = remaining % 128;
    remaining /= 128;
    if (remaining > 0) b |= 0x80;
    out += static_cast<char>(b);
  } while (remaining > 0);
}

class TcpLink final : public MqttLink {
 public:
  TcpLink(const Options& o, Events& events) : opt_(o), events_(events) {}
  ~TcpLink() override { close_socket(); }

  int connect(const std::string& host, int port) override {
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* found = nullptr;
    if (::getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &found) != 0 || !found) return MOSQ_ERR_EAI;
    int err = ECONNREFUSED;
    for (addrinfo* a = found; a && fd_ < 0; a = a->ai_next) {
      const int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
      if (fd < 0) continue;
      // A broker that does not answer must not hold the sender (and a stop) for the kernel's ~2 min.
      timeval tv{5, 0};
      ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
      if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
        fd_ = fd;
      } else {
        err = errno;
        ::close(fd);
      }
    }
    ::freeaddrinfo(found);
    if (fd_ < 0) {
      errno = err;
      return MOSQ_ERR_ERRNO;
    }
    // Our rounds already gather many messages into one send(2); Nagle would only hold a live event
    // back until the previous segment's ACK.
    const int one = 1;
    ::setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    queue_connect();
    return write();
  }

  int socket() const override { return fd_; }
  bool want_write() const override { return out_off_ < out_.size(); }

  int publish(int* mid, const std::string& topic, std::string_view payload, int qos, bool retain) override {
    if (fd_ < 0) return MOSQ_ERR_NO_CONN;
    if (topic.size() > 0xFFFF) return MOSQ_ERR_INVAL;
    const std::size_t remaining = 2 + topic.size() + (qos > 0 ? 2 : 0) + payload.size();
    if (remaining > 268435455) return MOSQ_ERR_PAYLOAD_SIZE;  // the varint's limit (2.2.3)
    next_id_ = next_id_ == 0xFFFF ? 1 : next_id_ + 1;         // packet identifiers are non-zero (2.3.1)
    *mid = next_id_;
    put_header(out_, static_cast<unsigned char>(kPublish | (qos > 0 ? 0x02 : 0x00) | (retain ? 0x01 : 0x00)),
               remaining);
    put_field(out_, topic);
    if (qos > 0) put_u16(out_, next_id_);
    out_.append(payload);
    last_out_ = Clock::now();
    return MOSQ_ERR_SUCCESS;
  }

  int write() override {
    while (out_off_ < out_.size()) {
      const ssize_t n = ::send(fd_, out_.data() + out_off_, out_.size() - out_off_, MSG_NOSIGNAL | MSG_DONTWAIT);
      if (n > 0) {
        out_off_ += static_cast<std::size_t>(n);
      } else if (n < 0 && errno == EINTR) {
        continue;
      } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
        return MOSQ_ERR_SUCCESS;  // the rest when the socket has room (the sender polls for POLLOUT)
      } else {
        return n < 0 && errno != ECONNRESET && errno != EPIPE ? MOSQ_ERR_ERRNO : MOSQ_ERR_CONN_LOST;
      }
    }
    out_.clear();
    out_off_ = 0;
    return MOSQ_ERR_SUCCESS;
  }

  int read() override {
    if (fd_ < 0) return MOSQ_ERR_NO_CONN;
    for (;;) {
      const std::size_t have = in_.size();
      in_.resize(have + kReadChunk);
      const ssize_t n = ::recv(fd_, in_.data() + have, kReadChunk, MSG_DONTWAIT);
      in_.resize(have + static_cast<std::size_t>(std::max<ssize_t>(n, 0)));
      if (n == 0) return MOSQ_ERR_CONN_LOST;
      if (n < 0) {
        if (errno == EINTR) continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK) return MOSQ_ERR_SUCCESS;
        return errno == ECONNRESET ? MOSQ_ERR_CONN_LOST : MOSQ_ERR_ERRNO;
      }
      if (const int rc = parse(); rc != MOSQ_ERR_SUCCESS) return rc;
      if (static_cast<std::size_t>(n) < kReadChunk) return MOSQ_ERR_SUCCESS;  // drained
    }
  }

  int misc() override {
    // Keepalive (3.1.2.10): a PINGREQ when nothing went out for keepalive_s; a broker that has not
    // answered it within another keepalive_s is gone.
    if (fd_ < 0 || opt_.keepalive_s <= 0) return fd_ < 0 ? MOSQ_ERR_NO_CONN : MOSQ_ERR_SUCCESS;
    const auto now = Clock::now();
    const auto keepalive = std::chrono::seconds(opt_.keepalive_s);
    if (ping_sent_ != Clock::time_point{}) return now - ping_sent_ >= keepalive ? MOSQ_ERR_KEEPALIVE : MOSQ_ERR_SUCCESS;
    if (now - last_out_ >= keepalive || now - last_in_ >= keepalive) {
      put_header(out_, kPingreq, 0);
      ping_sent_ = last_out_ = now;
      return write();
    }
    return MOSQ_ERR_SUCCESS;
  }

  void disconnect() override {
    if (fd_ < 0) return;
    put_header(out_, kDisconnect, 0);
    write();
    close_socket();
  }

 private:
  static constexpr std::size_t kReadChunk = 16384;  // 4096 PUBACKs

  void close_socket() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

  void queue_connect() {
    // Variable header (3.1.2) and payload (3.1.3): protocol "MQTT" level 4, a clean session, the
    // retained QoS 1 Last Will, user name and password when given.
    std::string body;
    put_field(body, "MQTT");
    body += static_cast<char>(4);
    unsigned char flags = 0x02;                                     // clean session
    if (!opt_.will_topic.empty()) flags |= 0x04 | (1 << 3) | 0x20;  // will, will QoS 1, will retain
    if (!opt_.username.empty()) flags |= 0x80;
    if (!opt_.username.empty() && !opt_.password.empty()) flags |= 0x40;
    body += static_cast<char>(flags);
    put_u16(body, static_cast<std::size_t>(opt_.keepalive_s));
    put_field(body, opt_.client_id);
    if (!opt_.will_topic.empty()) {
      put_field(body, opt_.will_topic);
      put_field(body, opt_.will_payload);
    }
    if (!opt_.username.empty()) put_field(body, opt_.username);
    if (!opt_.username.empty() && !opt_.password.empty()) put_field(body, opt_.password);
    put_header(out_, kConnect, body.size());
    out_ += body;
    last_out_ = last_in_ = Clock::now();
  }

  // Every whole packet in in_: PUBACKs acknowledge, CONNACK accepts or refuses, PINGRESP answers the
  // keepalive. A broker sends nothing else to a client without subscriptions; anything else is skipped.
  int parse() {
    std::size_t pos = 0;
    bool any = false;
    while (pos < in_.size()) {
      std::size_t remaining = 0, used = 1;
      bool complete = false;
      for (unsigned shift = 0; pos + used < in_.size() && used <= 4; shift += 7) {
        const auto b = static_cast<unsigned char>(in_[pos + used++]);
        remaining |= static_cast<std::size_t>(b & 0x7F) << shift;
        if ((b & 0x80) == 0) {
          complete = true;
          break;
        }
      }
      if (!complete) {
        if (used > 4) return MOSQ_ERR_MALFORMED_PACKET;
        break;  // the length continues in the next read
      }
      if (pos + used + remaining > in_.size()) break;
      const auto type = static_cast<unsigned char>(in_[pos]) & 0xF0;
      const auto* body = reinterpret_cast<const unsigned char*>(in_.data() + pos + used);
      if (type == kPuback && remaining >= 2) {
        events_.on_publish(body[0] << 8 | body[1]);
      } else if (type == kConnack && remaining >= 2) {
        events_.on_connect(body[1]);
      } else if (type == kPingresp) {
        ping_sent_ = Clock::time_point{};
      }
      pos += used + remaining;
      any = true;
    }
    in_.erase(0, pos);
    if (any) last_in_ = Clock::now();
    return MOSQ_ERR_SUCCESS;
  }

  Options opt_;
  Events& events_;
  int fd_ = -1;
  std::string out_, in_;
  std::size_t out_off_ = 0;
  int next_id_ = 0;
  Clock::time_point last_out_{}, last_in_{}, ping_sent_{};
};

// ---- TLS: libmosquitto ---------------------------------------------------------------------------

class MosquittoLink final : public MqttLink {
 public:
  MosquittoLink(const app::MqttConfig& cfg, const Options& o, Events& events, std::string& error)
      : keepalive_s_(o.keepalive_s) {
    mosq_ = mosquitto_new(o.client_id.c_str(), true, &events);
    if (!mosq_) {
      error = "cannot create a client (out of memory)";
      return;
    }
    mosquitto_int_option(mosq_, MOSQ_OPT_PROTOCOL_VERSION, MQTT_PROTOCOL_V311);
    // No limit of its own (0): the sink bounds what is in flight (a limit here would queue inside the
    // library instead of leaving the events in the spool).
    mosquitto_max_inflight_messages_set(mosq_, 0);
    mosquitto_connect_callback_set(mosq_,
                                   [](struct mosquitto*, void* e, int rc) { static_cast<Events*>(e)->on_connect(rc); });
    mosquitto_publish_callback_set(
        mosq_, [](struct mosquitto*, void* e, int mid) { static_cast<Events*>(e)->on_publish(mid); });
    if (!o.username.empty())
      mosquitto_username_pw_set(mosq_, o.username.c_str(), o.password.empty() ? nullptr : o.password.c_str());
    const int rc = mosquitto_tls_set(mosq_, cfg.tls.ca_file.c_str(), nullptr,
                                     cfg.tls.cert_file.empty() ? nullptr : cfg.tls.cert_file.c_str(),
                                     cfg.tls.key_file.empty() ? nullptr : cfg.tls.key_file.c_str(), nullptr);
    if (rc != MOSQ_ERR_SUCCESS) {
      error = std::string("TLS setup failed: ") + mosquitto_strerror(rc);
      return;
    }
    if (!o.will_topic.empty())
      mosquitto_will_set(mosq_, o.will_topic.c_str(), static_cast<int>(o.will_payload.size()), o.will_payload.data(), 1,
                         true);
  }
  ~MosquittoLink() override {
    if (mosq_) mosquitto_destroy(mosq_);
  }
  bool ok() const { return mosq_ != nullptr; }

  int connect(const std::string& host, int port) override {
    return mosquitto_connect(mosq_, host.c_str(), port, keepalive_s_);
  }
  int socket() const override { return mosquitto_socket(mosq_); }
  bool want_write() const override { return mosquitto_want_write(mosq_); }
  int publish(int* mid, const std::string& topic, std::string_view payload, int qos, bool retain) override {
    return mosquitto_publish(mosq_, mid, topic.c_str(), static_cast<int>(payload.size()), payload.data(), qos, retain);
  }
  int read() override {
    // libmosquitto reads packets until a read fails with EAGAIN, but tests errno also after a read
    // that succeeded: a stale EAGAIN from an earlier call would end the loop after one packet.
    errno = 0;
    return mosquitto_loop_read(mosq_, 1);
  }
  int write() override { return mosquitto_want_write(mosq_) ? mosquitto_loop_write(mosq_, 1) : MOSQ_ERR_SUCCESS; }
  int misc() override { return mosquitto_loop_misc(mosq_); }
  void burst(bool on) override {
    // TCP_CORK: libmosquitto writes each PUBLISH with its own write(2); corked, the packets of one
    // round leave in as few full segments as possible when the cork is pulled.
    const int fd = mosquitto_socket(mosq_);
    if (fd < 0) return;
    const int v = on ? 1 : 0;
    ::setsockopt(fd, IPPROTO_TCP, TCP_CORK, &v, sizeof v);
  }
  void disconnect() override { mosquitto_disconnect(mosq_); }

 private:
  struct mosquitto* mosq_ = nullptr;
  int keepalive_s_;
};

}  // namespace

std::unique_ptr<MqttLink> make_mqtt_link(const app::MqttConfig& cfg, const MqttLink::Options& options,
                                         MqttLink::Events& events, std::string& error) {
  if (cfg.tls.ca_file.empty()) return std::make_unique<TcpLink>(options, events);
  auto link = std::make_unique<MosquittoLink>(cfg, options, events, error);
  if (!error.empty() || !link->ok()) return nullptr;
  return link;
}

}  // namespace ridgewatch::daemon
