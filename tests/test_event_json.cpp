// The event-line writer (app/event_json.cpp) against an independent reference: the same object built
// as an nlohmann::ordered_json document, as the contract in app/event_json.hpp describes it. Parsed
// values must be identical (doubles bit-for-bit: the writer promises round-trip numbers), keys in the
// contract's order, non-finite numbers null, strings escaped so that the parser gets them back.
#include "app/event_json.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>
#include <random>
#include <string>

namespace rp = ridgewatch::pipeline;
using Json = nlohmann::ordered_json;

namespace {

Json num(double v) { return std::isfinite(v) ? Json(v) : Json(nullptr); }

Json reference(const rp::ImpactEvent& e, const std::string& source, const std::string& wall) {
  Json j;
  j["t_s"] = num(e.t_s);
  j["sample_index"] = e.sample_index;
  j["source"] = source;
  if (!wall.empty()) j["wall_time"] = wall;
  j["f_hz"] = num(e.f_hz);
  j["f_sd_hz"] = num(e.f_sd_hz);
  j["zeta"] = num(e.zeta);
  j["zeta_ci95"] = Json::array({num(e.zeta_ci95_lo), num(e.zeta_ci95_hi)});
  j["snr_db"] = num(e.snr_db);
  j["amplitude"] = num(e.amplitude);
  j["window_s"] = num(e.window_s);
  j["status"] = std::string(rp::to_string(e.status));
  j["alarm"] = std::string(ridgewatch::trend::to_string(e.alarm.level));
  j["alarm_detail"] = {{"ewma_ln_zeta", num(e.alarm.ewma_ln_zeta)},
                       {"cusum_up", num(e.alarm.cusum_up)},
                       {"cusum_down", num(e.alarm.cusum_down)},
                       {"baseline_zeta", num(std::exp(e.alarm.baseline_ln_zeta))},
                       {"transition", e.alarm.transition()}};
  return j;
}

rp::ImpactEvent typical() {
  rp::ImpactEvent e;
  e.sample_index = 166;
  e.t_s = 0.006484375;
  e.f_hz = 859.8786652892743;
  e.f_sd_hz = 2.533097184657696e-08;
  e.zeta = 0.023999999727183724;
  e.zeta_ci95_lo = 0.0239;
  e.zeta_ci95_hi = 0.0241;
  e.snr_db = 61.3;
  e.amplitude = 0.34596758602255734;
  e.window_s = 0.0344921875;
  e.alarm.level = ridgewatch::trend::AlarmLevel::alert;
  e.alarm.previous = ridgewatch::trend::AlarmLevel::normal;
  e.alarm.baseline_ln_zeta = std::log(0.024);
  e.alarm.ewma_ln_zeta = -3.6;
  e.alarm.cusum_up = 5.25;
  return e;
}

void expect_same(const rp::ImpactEvent& e, const std::string& source, const std::string& wall = {}) {
  const std::string line = ridgewatch::app::event_json(e, source, wall);
  EXPECT_EQ(line.find('\n'), std::string::npos) << line;
  const Json got = Json::parse(line);  // throws (test error) on malformed JSON
  // ordered_json compares objects element by element, so this also checks the key order.
  EXPECT_EQ(got, reference(e, source, wall)) << line;
}

}  // namespace

TEST(EventJson, TypicalEventEqualsTheReferenceDocument) {
  expect_same(typical(), "replay-data/sim-noise.wav");
  expect_same(typical(), "alsa:hw:1,0", "2026-11-21T06:04:48.160Z");
}

TEST(EventJson, NonFiniteNumbersAreNullAndIntegralValuesKeepAFloatSpelling) {
  rp::ImpactEvent e;  // defaults: NaN estimates, zero CUSUMs, NaN baseline
  e.status = rp::ImpactStatus::too_short;
  e.f_hz = std::numeric_limits<double>::infinity();
  expect_same(e, "x.wav");
  const std::string line = ridgewatch::app::event_json(e, "x.wav");
  EXPECT_NE(line.find("\"zeta\":null"), std::string::npos) << line;
  EXPECT_NE(line.find("\"f_hz\":null"), std::string::npos) << line;
  EXPECT_NE(line.find("\"cusum_up\":0.0"), std::string::npos) << line;
  EXPECT_NE(line.find("\"t_s\":0.0,"), std::string::npos) << line;
}

TEST(EventJson, RandomDoublesRoundTripExactly) {
  std::mt19937_64 rng(7);
  std::uniform_int_distribution<int> exponent(-300, 300);
  std::uniform_real_distribution<double> mantissa(-10.0, 10.0);
  for (int i = 0; i < 2000; ++i) {
    rp::ImpactEvent e = typical();
    e.zeta = mantissa(rng) * std::pow(10.0, exponent(rng));
    e.f_hz = std::round(mantissa(rng) * 1e6);  // integral values too
    e.sample_index = rng();
    const Json got = Json::parse(ridgewatch::app::event_json(e, "s"));
    ASSERT_EQ(got["zeta"].get<double>(), e.zeta);
    ASSERT_EQ(got["f_hz"].get<double>(), e.f_hz);
    ASSERT_EQ(got["sample_index"].get<std::uint64_t>(), e.sample_index);
  }
}

TEST(EventJson, SourceNamesAreEscapedAndInvalidUtf8IsReplaced) {
  expect_same(typical(), "dir with \"quotes\"\\and\\backslashes.wav");
  expect_same(typical(), "tab\there\nnewline\x01.wav");
  expect_same(typical(), "m\xC3\xA9sure-\xE2\x82\xAC.wav");  // valid UTF-8 (é, €)
  // Invalid UTF-8 (a Latin-1 file name): the writer must not throw or emit invalid JSON.
  const std::string line = ridgewatch::app::event_json(typical(), "mesure-\xE9t\xE9.wav");
  const Json got = Json::parse(line);
  EXPECT_EQ(got["source"].get<std::string>(), "mesure-\xEF\xBF\xBDt\xEF\xBF\xBD.wav");  // U+FFFD
}
