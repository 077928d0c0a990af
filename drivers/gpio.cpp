#include "drivers/gpio.hpp"

#include <gpiod.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <sstream>
#include <vector>

namespace ridgewatch::drivers {

namespace {

std::string line_name(const GpioLineConfig& config) {
  return "gpio " + config.chip + " line " + std::to_string(config.offset);
}

/// Opens the chip and gets the line; on failure closes what was opened and throws GpioError.
void open_line(const GpioLineConfig& config, gpiod_chip*& chip, gpiod_line*& line) {
  if (config.chip.empty()) throw GpioError("gpio: chip name is empty");
  chip = gpiod_chip_open_lookup(config.chip.c_str());
  if (chip == nullptr)
    throw GpioError("gpio " + config.chip + ": cannot open chip: " +
                    std::strerror(errno != 0 ? errno : ENODEV));
  const unsigned lines = gpiod_chip_num_lines(chip);
  if (config.offset >= lines) {
    gpiod_chip_close(chip);
    chip = nullptr;
    throw GpioError(line_name(config) + ": no such line (the chip has " + std::to_string(lines) + " lines)");
  }
  line = gpiod_chip_get_line(chip, config.offset);
  if (line == nullptr) {
    const int err = errno;
    gpiod_chip_close(chip);
    chip = nullptr;
    throw GpioError(line_name(config) + ": cannot get line: " + std::strerror(err));
  }
}

}  // namespace

GpiodTachoInput::GpiodTachoInput(const GpioLineConfig& config, TachoEdges edges) : name_(line_name(config)) {
  open_line(config, chip_, line_);
  gpiod_line_request_config request{};
  request.consumer = kGpioConsumer;
  request.request_type = edges == TachoEdges::rising    ? GPIOD_LINE_REQUEST_EVENT_RISING_EDGE
                         : edges == TachoEdges::falling ? GPIOD_LINE_REQUEST_EVENT_FALLING_EDGE
                                                        : GPIOD_LINE_REQUEST_EVENT_BOTH_EDGES;
  request.flags = config.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
  if (gpiod_line_request(line_, &request, 0) < 0) {
    const int err = errno;
    gpiod_chip_close(chip_);
    throw GpioError(name_ + ": cannot request edge events: " + std::strerror(err));
  }
}

GpiodTachoInput::~GpiodTachoInput() { gpiod_chip_close(chip_); }  // also releases the line

std::size_t GpiodTachoInput::wait_edges(std::chrono::nanoseconds timeout, std::vector<TachoEdge>& out) {
  const auto ns = timeout.count() < 0 ? 0 : timeout.count();
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(ns / 1000000000);
  ts.tv_nsec = static_cast<long>(ns % 1000000000);
  const int ready = gpiod_line_event_wait(line_, &ts);
  if (ready <= 0) {
    if (ready < 0) {
      ++errors_;
      last_error_ = name_ + ": waiting for edges failed: " + std::strerror(errno);
    }
    return 0;
  }
  // The kernel queues events; read all that are pending (up to 16 per call to the uAPI).
  gpiod_line_event events[16];
  const int n = gpiod_line_event_read_multiple(line_, events, 16);
  if (n < 0) {
    ++errors_;
    last_error_ = name_ + ": reading edges failed: " + std::strerror(errno);
    return 0;
  }
  for (int i = 0; i < n; ++i) {
    out.push_back(TachoEdge{static_cast<std::int64_t>(events[i].ts.tv_sec) * 1000000000 + events[i].ts.tv_nsec,
                            events[i].event_type == GPIOD_LINE_EVENT_RISING_EDGE});
  }
  return static_cast<std::size_t>(n);
}

GpiodRelayOutput::GpiodRelayOutput(const GpioLineConfig& config) : name_(line_name(config)) {
  open_line(config, chip_, line_);
  gpiod_line_request_config request{};
  request.consumer = kGpioConsumer;
  request.request_type = GPIOD_LINE_REQUEST_DIRECTION_OUTPUT;
  request.flags = config.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
  if (gpiod_line_request(line_, &request, 0) < 0) {  // 0: inactive = de-energised = alarm
    const int err = errno;
    gpiod_chip_close(chip_);
    throw GpioError(name_ + ": cannot request as output: " + std::strerror(err));
  }
}

GpiodRelayOutput::~GpiodRelayOutput() {
  gpiod_line_set_value(line_, 0);
  gpiod_chip_close(chip_);
}

void GpiodRelayOutput::set_healthy(bool healthy) {
  if (gpiod_line_set_value(line_, healthy ? 1 : 0) < 0) {
    ++errors_;
    last_error_ = name_ + ": setting the line failed: " + std::strerror(errno);
    return;
  }
  healthy_ = healthy;
}

}  // namespace ridgewatch::drivers

namespace ridgewatch::drivers {

std::string describe_gpio_chips() {
  std::vector<std::string> chips;
  std::error_code ec;
  for (auto it = std::filesystem::directory_iterator("/dev", ec); !ec && it != std::filesystem::directory_iterator();
       it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.rfind("gpiochip", 0) == 0) chips.push_back(name);
  }
  std::sort(chips.begin(), chips.end(), [](const std::string& a, const std::string& b) {
    return a.size() != b.size() ? a.size() < b.size() : a < b;  // gpiochip2 before gpiochip10
  });
  std::ostringstream o;
  if (chips.empty()) o << "no GPIO chips (/dev/gpiochip*); gpio.enabled must stay false on this machine\n";
  for (const auto& name : chips) {
    gpiod_chip* chip = gpiod_chip_open_lookup(name.c_str());
    if (chip == nullptr) {
      o << name << ": cannot open: " << std::strerror(errno != 0 ? errno : ENODEV)
        << " (the service user needs the gpio group)\n";
      continue;
    }
    const unsigned n = gpiod_chip_num_lines(chip);
    o << name << " [" << gpiod_chip_label(chip) << "] " << n << " lines (gpio.chip: \"" << name << "\")\n";
    for (unsigned i = 0; i < n; ++i) {
      gpiod_line* line = gpiod_chip_get_line(chip, i);
      if (line == nullptr) continue;
      const char* lname = gpiod_line_name(line);
      const char* consumer = gpiod_line_consumer(line);
      o << "  line " << i << ": " << (lname ? std::string("\"") + lname + "\"" : "unnamed") << " "
        << (gpiod_line_direction(line) == GPIOD_LINE_DIRECTION_OUTPUT ? "output" : "input")
        << (gpiod_line_is_used(line) ? std::string(" used by \"") + (consumer ? consumer : "kernel") + "\"" : " unused")
        << "\n";
    }
    gpiod_chip_close(chip);
  }
  return o.str();
}

}  // namespace ridgewatch::drivers
