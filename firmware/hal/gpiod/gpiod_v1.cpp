// libgpiod 1.6 (Debian 12). v1 requests lines one by one; edge events on several lines are
// waited for together with gpiod_line_event_wait_bulk.
#include <gpiod.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "slproto/file_util.hpp"
#include "slscand/hal/gpiod/gpiod_chip.hpp"

namespace slscand::hal {

using slproto::Errc;
using slproto::errno_text;
using slproto::make_error;

GpiodV1LineRequest gpiod_v1_request_for(const LineSettings& line) {
  GpiodV1LineRequest request;
  if (line.direction == LineDirection::output) {
    request.request_type = GPIOD_LINE_REQUEST_DIRECTION_OUTPUT;
  } else {
    switch (line.edges) {
      case EdgeDetection::none:
        request.request_type = GPIOD_LINE_REQUEST_DIRECTION_INPUT;
        break;
      case EdgeDetection::rising:
        request.request_type = GPIOD_LINE_REQUEST_EVENT_RISING_EDGE;
        break;
      case EdgeDetection::falling:
        request.request_type = GPIOD_LINE_REQUEST_EVENT_FALLING_EDGE;
        break;
      case EdgeDetection::both:
        request.request_type = GPIOD_LINE_REQUEST_EVENT_BOTH_EDGES;
        break;
    }
  }
  request.flags = line.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
  return request;
}

namespace {

struct ChipHandle {
  gpiod_chip* chip = nullptr;
  std::string name;
  ~ChipHandle() {
    if (chip != nullptr) gpiod_chip_close(chip);
  }
};

class GpiodV1Request final : public LineRequest {
 public:
  GpiodV1Request(std::shared_ptr<ChipHandle> chip, LineRequestConfig config)
      : chip_(std::move(chip)), config_(std::move(config)) {}
  ~GpiodV1Request() override {
    for (gpiod_line* line : lines_) gpiod_line_release(line);
  }
  GpiodV1Request(const GpiodV1Request&) = delete;
  GpiodV1Request& operator=(const GpiodV1Request&) = delete;

  Status add(const LineSettings& settings) {
    gpiod_line* line = gpiod_chip_get_line(chip_->chip, settings.offset);
    if (line == nullptr) {
      return make_error(Errc::invalid_argument, chip_->name + ": " + settings.name + " line " +
                                                    std::to_string(settings.offset) + " does not exist (the chip has " +
                                                    std::to_string(gpiod_chip_num_lines(chip_->chip)) + " lines)");
    }
    const GpiodV1LineRequest how = gpiod_v1_request_for(settings);
    gpiod_line_request_config request_config{config_.consumer.c_str(), how.request_type, how.flags};
    if (gpiod_line_request(line, &request_config, settings.initial_value ? 1 : 0) != 0) {
      return make_error(Errc::io_error, chip_->name + ": cannot request " + settings.name + " (line " +
                                            std::to_string(settings.offset) + "): " + errno_text(errno));
    }
    lines_.push_back(line);
    offsets_.push_back(settings.offset);
    if (settings.edges != EdgeDetection::none) event_lines_.push_back(line);
    return slproto::Ok{};
  }

  Status set_value(unsigned offset, bool value) override {
    gpiod_line* line = find(offset);
    if (line == nullptr || gpiod_line_direction(line) != GPIOD_LINE_DIRECTION_OUTPUT) {
      return make_error(Errc::invalid_argument, chip_->name + ": line " + std::to_string(offset) +
                                                    " is not an output of request '" + config_.consumer + "'");
    }
    if (gpiod_line_set_value(line, value ? 1 : 0) != 0) {
      return make_error(Errc::io_error,
                        chip_->name + ": setting line " + std::to_string(offset) + ": " + errno_text(errno));
    }
    return slproto::Ok{};
  }

  Result<bool> get_value(unsigned offset) override {
    gpiod_line* line = find(offset);
    if (line == nullptr) {
      return make_error(Errc::invalid_argument, chip_->name + ": line " + std::to_string(offset) + " is not requested");
    }
    const int value = gpiod_line_get_value(line);
    if (value < 0) {
      return make_error(Errc::io_error,
                        chip_->name + ": reading line " + std::to_string(offset) + ": " + errno_text(errno));
    }
    return value == 1;
  }

  Result<std::vector<EdgeEvent>> wait_edges(Nanos timeout_ns) override {
    std::vector<EdgeEvent> out;
    if (event_lines_.empty()) {
      sleep_until_ns(monotonic_now_ns() + std::max<Nanos>(timeout_ns, 0));
      return out;
    }
    gpiod_line_bulk bulk;
    gpiod_line_bulk_init(&bulk);
    for (gpiod_line* line : event_lines_) gpiod_line_bulk_add(&bulk, line);
    gpiod_line_bulk ready;
    gpiod_line_bulk_init(&ready);
    timespec timeout{};
    const Nanos t = std::max<Nanos>(timeout_ns, 0);
    timeout.tv_sec = static_cast<time_t>(t / kSecond);
    timeout.tv_nsec = static_cast<long>(t % kSecond);
    const int rv = gpiod_line_event_wait_bulk(&bulk, &timeout, &ready);
    if (rv < 0) return make_error(Errc::io_error, chip_->name + ": waiting for GPIO edges: " + errno_text(errno));
    if (rv == 0) return out;
    for (unsigned i = 0; i < gpiod_line_bulk_num_lines(&ready); ++i) {
      gpiod_line* line = gpiod_line_bulk_get_line(&ready, i);
      gpiod_line_event events[16];
      const int n = gpiod_line_event_read_multiple(line, events, 16);
      if (n < 0) return make_error(Errc::io_error, chip_->name + ": reading GPIO edges: " + errno_text(errno));
      for (int k = 0; k < n; ++k) {
        EdgeEvent event;
        event.offset = gpiod_line_offset(line);
        event.rising = events[k].event_type == GPIOD_LINE_EVENT_RISING_EDGE;
        event.timestamp_ns = static_cast<Nanos>(events[k].ts.tv_sec) * kSecond + events[k].ts.tv_nsec;
        event.seqno = ++seqno_;  // v1 has no kernel sequence numbers
        out.push_back(event);
      }
    }
    std::sort(out.begin(), out.end(),
              [](const EdgeEvent& a, const EdgeEvent& b) { return a.timestamp_ns < b.timestamp_ns; });
    return out;
  }

  const LineRequestConfig& config() const override { return config_; }

 private:
  gpiod_line* find(unsigned offset) const {
    for (std::size_t i = 0; i < offsets_.size(); ++i) {
      if (offsets_[i] == offset) return lines_[i];
    }
    return nullptr;
  }

  std::shared_ptr<ChipHandle> chip_;
  LineRequestConfig config_;
  std::vector<gpiod_line*> lines_;
  std::vector<unsigned> offsets_;
  std::vector<gpiod_line*> event_lines_;
  std::uint64_t seqno_ = 0;
};

class GpiodV1Chip final : public GpioChip {
 public:
  explicit GpiodV1Chip(std::shared_ptr<ChipHandle> chip) : chip_(std::move(chip)) {}
  std::string name() const override { return chip_->name; }
  unsigned line_count() const override { return gpiod_chip_num_lines(chip_->chip); }
  Result<std::unique_ptr<LineRequest>> request_lines(const LineRequestConfig& config) override {
    if (auto s = config.check(); !s) return s.error();
    auto request = std::make_unique<GpiodV1Request>(chip_, config);
    for (const auto& line : config.lines) {
      if (auto s = request->add(line); !s) return s.error();  // the destructor releases the rest
    }
    return std::unique_ptr<LineRequest>(std::move(request));
  }

 private:
  std::shared_ptr<ChipHandle> chip_;
};

}  // namespace

Result<std::unique_ptr<GpioChip>> open_gpiod_chip(const std::string& chip) {
  const GpiodChipSpec spec = parse_gpiod_chip_spec(chip);
  auto handle = std::make_shared<ChipHandle>();
  if (!spec.path.empty()) {
    handle->chip = gpiod_chip_open(spec.path.c_str());
    if (handle->chip == nullptr) {
      return make_error(Errc::io_error, "cannot open GPIO chip " + spec.path + ": " + errno_text(errno));
    }
  } else if (!spec.label.empty()) {
    handle->chip = gpiod_chip_open_by_label(spec.label.c_str());
    if (handle->chip == nullptr) {
      return make_error(Errc::io_error, "no GPIO chip labelled '" + spec.label + "' (" + errno_text(errno) + ")");
    }
  } else {
    return make_error(Errc::invalid_argument, "empty GPIO chip name");
  }
  handle->name = std::string(gpiod_chip_name(handle->chip)) + " [" + gpiod_chip_label(handle->chip) + "]";
  return std::unique_ptr<GpioChip>(new GpiodV1Chip(std::move(handle)));
}

}  // namespace slscand::hal
