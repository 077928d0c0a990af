#include "app/event_json.hpp"

#include <charconv>
#include <cmath>
#include <nlohmann/json.hpp>
#include <system_error>

namespace ridgewatch::app {

namespace {

// The event line is written directly rather than through a JSON document: building and dumping an
// nlohmann::ordered_json per event cost ~42 000 instructions (callgrind, ridgewatchd on a 60 s replay),
// a quarter of the per-impact analysis; this writer needs a few thousand. Numbers use std::to_chars'
// shortest round-trip form (a parser gets the same double back); strings that need escaping (quotes,
// backslashes, control characters, anything outside ASCII, possibly invalid UTF-8 in a file name) go
// through nlohmann's serializer, so their escaping and the replacement of invalid UTF-8 stay exactly
// the library's.

void put_number(std::string& out, double v) {
  if (!std::isfinite(v)) {
    out += "null";
    return;
  }
  char buf[32];
  const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, v);
  if (ec != std::errc()) {  // cannot happen for a finite double in 32 characters
    out += "null";
    return;
  }
  const std::string_view text(buf, static_cast<std::size_t>(end - buf));
  out += text;
  // Keep a floating-point look for integral values ("0.0", not "0"), as JSON readers that type
  // numbers by their spelling (and the earlier output) expect.
  if (text.find_first_of(".e") == std::string_view::npos) out += ".0";
}

void put_string(std::string& out, std::string_view s) {
  bool plain = true;
  for (const char c : s) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x20 || u >= 0x80 || c == '"' || c == '\\') {
      plain = false;
      break;
    }
  }
  if (plain) {
    out += '"';
    out += s;
    out += '"';
    return;
  }
  // A file name that is not valid UTF-8 is replaced (U+FFFD), never aborts the log line.
  out += nlohmann::json(std::string(s)).dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

void put_key(std::string& out, std::string_view key) {
  out += '"';
  out += key;
  out += "\":";
}

}  // namespace

std::string event_json(const pipeline::ImpactEvent& e, std::string_view source, std::string_view wall_time,
                       std::string_view stream) {
  std::string out;
  out.reserve(512 + source.size());
  append_event_json(out, e, source, wall_time, stream);
  return out;
}

void append_event_json(std::string& out, const pipeline::ImpactEvent& e, std::string_view source,
                       std::string_view wall_time, std::string_view stream) {
  out += '{';
  put_key(out, "t_s");
  put_number(out, e.t_s);
  out += ',';
  put_key(out, "sample_index");
  char buf[24];
  const auto idx = std::to_chars(buf, buf + sizeof buf, e.sample_index);
  out.append(buf, idx.ptr);
  out += ',';
  put_key(out, "source");
  put_string(out, source);
  if (!stream.empty()) {
    out += ',';
    put_key(out, "stream");
    put_string(out, stream);
  }
  if (!wall_time.empty()) {
    out += ',';
    put_key(out, "wall_time");
    put_string(out, wall_time);
  }
  const auto field = [&out](std::string_view key, double v) {
    out += ',';
    put_key(out, key);
    put_number(out, v);
  };
  field("f_hz", e.f_hz);
  field("f_sd_hz", e.f_sd_hz);
  field("zeta", e.zeta);
  out += ',';
  put_key(out, "zeta_ci95");
  out += '[';
  put_number(out, e.zeta_ci95_lo);
  out += ',';
  put_number(out, e.zeta_ci95_hi);
  out += ']';
  field("snr_db", e.snr_db);
  field("amplitude", e.amplitude);
  field("window_s", e.window_s);
  out += ',';
  put_key(out, "status");
  put_string(out, pipeline::to_string(e.status));
  out += ',';
  put_key(out, "alarm");
  put_string(out, trend::to_string(e.alarm.level));
  out += ',';
  put_key(out, "alarm_detail");
  out += '{';
  put_key(out, "ewma_ln_zeta");
  put_number(out, e.alarm.ewma_ln_zeta);
  field("cusum_up", e.alarm.cusum_up);
  field("cusum_down", e.alarm.cusum_down);
  field("baseline_zeta", std::exp(e.alarm.baseline_ln_zeta));
  out += ',';
  put_key(out, "transition");
  out += e.alarm.transition() ? "true" : "false";
  out += "}}";
}

}  // namespace ridgewatch::app
