// libgpiod 2.x (Raspberry Pi OS, newer distributions): all lines of a request in one
// gpiod_line_request built from per-offset settings; edge events carry the kernel's
// CLOCK_MONOTONIC timestamp and per-line sequence numbers.
#include <gpiod.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>

#include "slproto/file_util.hpp"
#include "slscand/hal/gpiod/gpiod_chip.hpp"

namespace slscand::hal {

using slproto::Errc;
using slproto::errno_text;
using slproto::make_error;

void GpiodLineConfigDeleter::operator()(gpiod_line_config* config) const noexcept { gpiod_line_config_free(config); }

namespace {

struct SettingsDeleter {
  void operator()(gpiod_line_settings* s) const noexcept { gpiod_line_settings_free(s); }
};
struct RequestConfigDeleter {
  void operator()(gpiod_request_config* c) const noexcept { gpiod_request_config_free(c); }
};
struct ChipInfoDeleter {
  void operator()(gpiod_chip_info* i) const noexcept { gpiod_chip_info_free(i); }
};
struct EventBufferDeleter {
  void operator()(gpiod_edge_event_buffer* b) const noexcept { gpiod_edge_event_buffer_free(b); }
};

gpiod_line_edge edge_of(EdgeDetection edges) {
  switch (edges) {
    case EdgeDetection::none:
      return GPIOD_LINE_EDGE_NONE;
    case EdgeDetection::rising:
      return GPIOD_LINE_EDGE_RISING;
    case EdgeDetection::falling:
      return GPIOD_LINE_EDGE_FALLING;
    case EdgeDetection::both:
      return GPIOD_LINE_EDGE_BOTH;
  }
  return GPIOD_LINE_EDGE_NONE;
}

struct ChipHandle {
  gpiod_chip* chip = nullptr;
  std::string name;
  unsigned lines = 0;
  ~ChipHandle() {
    if (chip != nullptr) gpiod_chip_close(chip);
  }
};

class GpiodV2Request final : public LineRequest {
 public:
  GpiodV2Request(std::shared_ptr<ChipHandle> chip, LineRequestConfig config, gpiod_line_request* request)
      : chip_(std::move(chip)),
        config_(std::move(config)),
        request_(request),
        buffer_(gpiod_edge_event_buffer_new(64)) {}
  ~GpiodV2Request() override { gpiod_line_request_release(request_); }
  GpiodV2Request(const GpiodV2Request&) = delete;
  GpiodV2Request& operator=(const GpiodV2Request&) = delete;

  Status set_value(unsigned offset, bool value) override {
    const LineSettings* line = config_.find(offset);
    if (line == nullptr || line->direction != LineDirection::output) {
      return make_error(Errc::invalid_argument, chip_->name + ": line " + std::to_string(offset) +
                                                    " is not an output of request '" + config_.consumer + "'");
    }
    if (gpiod_line_request_set_value(request_, offset, value ? GPIOD_LINE_VALUE_ACTIVE : GPIOD_LINE_VALUE_INACTIVE) !=
        0) {
      return make_error(Errc::io_error,
                        chip_->name + ": setting line " + std::to_string(offset) + ": " + errno_text(errno));
    }
    return slproto::Ok{};
  }

  Result<bool> get_value(unsigned offset) override {
    if (config_.find(offset) == nullptr) {
      return make_error(Errc::invalid_argument, chip_->name + ": line " + std::to_string(offset) + " is not requested");
    }
    const gpiod_line_value value = gpiod_line_request_get_value(request_, offset);
    if (value == GPIOD_LINE_VALUE_ERROR) {
      return make_error(Errc::io_error,
                        chip_->name + ": reading line " + std::to_string(offset) + ": " + errno_text(errno));
    }
    return value == GPIOD_LINE_VALUE_ACTIVE;
  }

  Result<std::vector<EdgeEvent>> wait_edges(Nanos timeout_ns) override {
    std::vector<EdgeEvent> out;
    if (!buffer_) return make_error(Errc::io_error, chip_->name + ": cannot allocate an edge event buffer");
    const int rv = gpiod_line_request_wait_edge_events(request_, std::max<Nanos>(timeout_ns, 0));
    if (rv < 0) return make_error(Errc::io_error, chip_->name + ": waiting for GPIO edges: " + errno_text(errno));
    if (rv == 0) return out;
    const int n = gpiod_line_request_read_edge_events(request_, buffer_.get(), 64);
    if (n < 0) return make_error(Errc::io_error, chip_->name + ": reading GPIO edges: " + errno_text(errno));
    for (int i = 0; i < n; ++i) {
      gpiod_edge_event* e = gpiod_edge_event_buffer_get_event(buffer_.get(), static_cast<unsigned long>(i));
      EdgeEvent event;
      event.offset = gpiod_edge_event_get_line_offset(e);
      event.rising = gpiod_edge_event_get_event_type(e) == GPIOD_EDGE_EVENT_RISING_EDGE;
      event.timestamp_ns = static_cast<Nanos>(gpiod_edge_event_get_timestamp_ns(e));
      event.seqno = gpiod_edge_event_get_line_seqno(e);
      out.push_back(event);
    }
    return out;
  }

  const LineRequestConfig& config() const override { return config_; }

 private:
  std::shared_ptr<ChipHandle> chip_;
  LineRequestConfig config_;
  gpiod_line_request* request_;
  std::unique_ptr<gpiod_edge_event_buffer, EventBufferDeleter> buffer_;
};

class GpiodV2Chip final : public GpioChip {
 public:
  explicit GpiodV2Chip(std::shared_ptr<ChipHandle> chip) : chip_(std::move(chip)) {}
  std::string name() const override { return chip_->name; }
  unsigned line_count() const override { return chip_->lines; }

  Result<std::unique_ptr<LineRequest>> request_lines(const LineRequestConfig& config) override {
    for (const auto& line : config.lines) {
      if (line.offset >= chip_->lines) {
        return make_error(Errc::invalid_argument, chip_->name + ": " + line.name + " line " +
                                                      std::to_string(line.offset) + " does not exist (the chip has " +
                                                      std::to_string(chip_->lines) + " lines)");
      }
    }
    auto line_config = gpiod_v2_line_config(config);
    if (!line_config) return std::move(line_config).error();
    std::unique_ptr<gpiod_request_config, RequestConfigDeleter> request_config(gpiod_request_config_new());
    if (!request_config) return make_error(Errc::io_error, "libgpiod: out of memory");
    gpiod_request_config_set_consumer(request_config.get(), config.consumer.c_str());
    gpiod_request_config_set_event_buffer_size(request_config.get(), 64);
    gpiod_line_request* request = gpiod_chip_request_lines(chip_->chip, request_config.get(), line_config->get());
    if (request == nullptr) {
      return make_error(Errc::io_error,
                        chip_->name + ": cannot request the lines of '" + config.consumer + "': " + errno_text(errno));
    }
    return std::unique_ptr<LineRequest>(new GpiodV2Request(chip_, config, request));
  }

 private:
  std::shared_ptr<ChipHandle> chip_;
};

std::string chip_label(gpiod_chip* chip) {
  std::unique_ptr<gpiod_chip_info, ChipInfoDeleter> info(gpiod_chip_get_info(chip));
  return info ? gpiod_chip_info_get_label(info.get()) : "";
}

}  // namespace

Result<GpiodLineConfigPtr> gpiod_v2_line_config(const LineRequestConfig& config) {
  if (auto s = config.check(); !s) return s.error();
  GpiodLineConfigPtr line_config(gpiod_line_config_new());
  if (!line_config) return make_error(Errc::io_error, "libgpiod: out of memory");
  for (const auto& line : config.lines) {
    std::unique_ptr<gpiod_line_settings, SettingsDeleter> settings(gpiod_line_settings_new());
    if (!settings) return make_error(Errc::io_error, "libgpiod: out of memory");
    int rv = 0;
    if (line.direction == LineDirection::output) {
      rv |= gpiod_line_settings_set_direction(settings.get(), GPIOD_LINE_DIRECTION_OUTPUT);
      rv |= gpiod_line_settings_set_output_value(
          settings.get(), line.initial_value ? GPIOD_LINE_VALUE_ACTIVE : GPIOD_LINE_VALUE_INACTIVE);
    } else {
      rv |= gpiod_line_settings_set_direction(settings.get(), GPIOD_LINE_DIRECTION_INPUT);
      rv |= gpiod_line_settings_set_edge_detection(settings.get(), edge_of(line.edges));
      // The clock of V4L2 buffer timestamps, so GPIO and camera events compare directly.
      rv |= gpiod_line_settings_set_event_clock(settings.get(), GPIOD_LINE_CLOCK_MONOTONIC);
    }
    gpiod_line_settings_set_active_low(settings.get(), line.active_low);
    const unsigned offset = line.offset;
    if (rv != 0 || gpiod_line_config_add_line_settings(line_config.get(), &offset, 1, settings.get()) != 0) {
      return make_error(Errc::invalid_argument, "libgpiod rejected the settings of " + line.name + " (line " +
                                                    std::to_string(line.offset) + "): " + errno_text(errno));
    }
  }
  return line_config;
}

Result<std::unique_ptr<GpioChip>> open_gpiod_chip(const std::string& chip) {
  const GpiodChipSpec spec = parse_gpiod_chip_spec(chip);
  auto handle = std::make_shared<ChipHandle>();
  if (!spec.path.empty()) {
    handle->chip = gpiod_chip_open(spec.path.c_str());
    if (handle->chip == nullptr) {
      return make_error(Errc::io_error, "cannot open GPIO chip " + spec.path + ": " + errno_text(errno));
    }
  } else if (!spec.label.empty()) {
    // v2 has no open-by-label: look at every chip's label.
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator("/dev", ec)) {
      const std::string path = entry.path().string();
      if (path.rfind("/dev/gpiochip", 0) != 0 || !gpiod_is_gpiochip_device(path.c_str())) continue;
      gpiod_chip* candidate = gpiod_chip_open(path.c_str());
      if (candidate == nullptr) continue;
      if (chip_label(candidate) == spec.label) {
        handle->chip = candidate;
        break;
      }
      gpiod_chip_close(candidate);
    }
    if (handle->chip == nullptr) return make_error(Errc::io_error, "no GPIO chip labelled '" + spec.label + "'");
  } else {
    return make_error(Errc::invalid_argument, "empty GPIO chip name");
  }
  std::unique_ptr<gpiod_chip_info, ChipInfoDeleter> info(gpiod_chip_get_info(handle->chip));
  if (!info) return make_error(Errc::io_error, "cannot read GPIO chip info: " + errno_text(errno));
  handle->name = std::string(gpiod_chip_info_get_name(info.get())) + " [" + gpiod_chip_info_get_label(info.get()) + "]";
  handle->lines = static_cast<unsigned>(gpiod_chip_info_get_num_lines(info.get()));
  return std::unique_ptr<GpioChip>(new GpiodV2Chip(std::move(handle)));
}

}  // namespace slscand::hal
