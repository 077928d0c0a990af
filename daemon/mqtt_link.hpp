// The MQTT connection the sink's sender thread drives, behind one small interface with two
// implementations:
//
//   plain TCP  MQTT 3.1.1 written and parsed here (CONNECT/CONNACK, PUBLISH QoS 0/1, PUBACK,
//              PINGREQ/PINGRESP, DISCONNECT). publish() only appends the packet to an output buffer;
//              write() hands everything buffered to the kernel in one send(2), and read() takes
//              everything that arrived with one recv(2) and parses every PUBACK in it. A round of N
//              events therefore costs two system calls instead of libmosquitto's 4-5 per event (one
//              write(2) per PUBLISH, a wake-up byte on its internal socketpair, three read(2) per PUBACK).
//   TLS        libmosquitto (mosquitto_tls_set: CA, optional client certificate and key), unchanged.
//
// Both report in libmosquitto's terms (MOSQ_ERR_* return codes, CONNACK return codes, message ids)
// so the sink's logic and its log texts are the same for either.
#pragma once

#include <memory>
#include <string>
#include <string_view>

#include "app/config_yaml.hpp"

namespace ridgewatch::daemon {

class MqttLink {
 public:
  /// What the link reports while reading (called on the sender thread, from read()).
  struct Events {
    virtual ~Events() = default;
    virtual void on_connect(int connack_rc) = 0;  ///< CONNACK: 0 accepted, else the refusal code
    virtual void on_publish(int mid) = 0;         ///< PUBACK of a QoS 1 message (or QoS 0 handed over)
  };
  struct Options {
    std::string client_id, username, password;  // password empty: none
    std::string will_topic, will_payload;       // retained, QoS 1
    int keepalive_s = 30;
  };

  virtual ~MqttLink() = default;
  /// Connects (TCP, then CONNECT sent; the CONNACK arrives through read()). MOSQ_ERR_SUCCESS or an
  /// error (MOSQ_ERR_ERRNO with errno set).
  virtual int connect(const std::string& host, int port) = 0;
  virtual int socket() const = 0;
  virtual bool want_write() const = 0;
  /// Queues (plain TCP) or writes (libmosquitto) one PUBLISH; *mid is its message id.
  virtual int publish(int* mid, const std::string& topic, std::string_view payload, int qos, bool retain) = 0;
  virtual int read() = 0;   ///< reads what arrived, reporting through Events
  virtual int write() = 0;  ///< writes what is queued, as far as the socket takes it
  virtual int misc() = 0;   ///< keepalive: PINGREQ when due; MOSQ_ERR_KEEPALIVE when the broker is silent
  /// Several publishes follow (libmosquitto: TCP_CORK on, so they leave in few segments; off again
  /// at the end). Plain TCP needs nothing: its publishes leave in one send(2) anyway.
  virtual void burst(bool) {}
  virtual void disconnect() = 0;  ///< DISCONNECT (the broker then drops the Last Will), best effort
};

/// libmosquitto's client when cfg.tls.ca_file is set, the plain-TCP MQTT 3.1.1 link otherwise.
/// Null with `error` set when the client cannot be set up (TLS files).
std::unique_ptr<MqttLink> make_mqtt_link(const app::MqttConfig& cfg, const MqttLink::Options& options,
                                         MqttLink::Events& events, std::string& error);

}  // namespace ridgewatch::daemon
