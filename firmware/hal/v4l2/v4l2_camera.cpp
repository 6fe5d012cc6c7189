#include "slscand/hal/v4l2/v4l2_camera.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

namespace {

std::string fourcc_text(std::uint32_t fourcc) {
  std::string s(4, ' ');
  for (int i = 0; i < 4; ++i) s[static_cast<std::size_t>(i)] = static_cast<char>((fourcc >> (8 * i)) & 0xff);
  return s;
}

const V4l2Control* find(const std::vector<V4l2Control>& available, std::uint32_t id) {
  for (const auto& c : available) {
    if (c.id == id) return &c;
  }
  return nullptr;
}

Result<std::int32_t> fit(const V4l2Control& control, double value, const std::string& what) {
  const double step = std::max(1, control.step);
  const double snapped = control.minimum + std::round((value - control.minimum) / step) * step;
  if (!std::isfinite(value) || snapped < control.minimum || snapped > control.maximum) {
    return make_error(Errc::invalid_argument, what + " " + std::to_string(value) + " is outside the control '" +
                                                  control.name + "' range [" + std::to_string(control.minimum) + ", " +
                                                  std::to_string(control.maximum) + "]");
  }
  return static_cast<std::int32_t>(snapped);
}

int xioctl(int fd, unsigned long request, void* arg) {
  int rv = 0;
  do {
    rv = ::ioctl(fd, request, arg);
  } while (rv < 0 && errno == EINTR);
  return rv;
}

}  // namespace

std::uint32_t v4l2_fourcc_for(PixelFormat format) noexcept {
  switch (format) {
    case PixelFormat::mono8:
      return V4L2_PIX_FMT_GREY;
    case PixelFormat::mono10:
      return V4L2_PIX_FMT_Y10;
    case PixelFormat::mono12:
      return V4L2_PIX_FMT_Y12;
  }
  return 0;
}

Result<CameraFormat> v4l2_accept_format(const CameraFormat& wanted, const V4l2NegotiatedFormat& got) {
  const std::uint32_t fourcc = v4l2_fourcc_for(wanted.pixel_format);
  if (got.width != static_cast<std::uint32_t>(wanted.width) ||
      got.height != static_cast<std::uint32_t>(wanted.height) || got.fourcc != fourcc) {
    return make_error(Errc::unsupported, "the camera offers " + std::to_string(got.width) + "x" +
                                             std::to_string(got.height) + " " + fourcc_text(got.fourcc) +
                                             " when asked for " + std::to_string(wanted.width) + "x" +
                                             std::to_string(wanted.height) + " " + fourcc_text(fourcc) + " (" +
                                             pixel_format_name(wanted.pixel_format) + ")");
  }
  const std::size_t packed =
      static_cast<std::size_t>(wanted.width) * static_cast<std::size_t>(bytes_per_pixel(wanted.pixel_format));
  if (got.bytes_per_line < packed) {
    return make_error(Errc::malformed, "the camera reports " + std::to_string(got.bytes_per_line) +
                                           " bytes per line, fewer than a row's " + std::to_string(packed));
  }
  CameraFormat format = wanted;
  format.stride_bytes = got.bytes_per_line;
  return format;
}

Result<V4l2ControlValues> v4l2_exposure_controls(const std::vector<V4l2Control>& available, double exposure_us,
                                                 double line_time_us) {
  if (!(exposure_us > 0)) return make_error(Errc::invalid_argument, "exposure must be positive");
  V4l2ControlValues values;
  if (const V4l2Control* absolute = find(available, V4L2_CID_EXPOSURE_ABSOLUTE)) {
    if (find(available, V4L2_CID_EXPOSURE_AUTO) != nullptr) {
      values.emplace_back(V4L2_CID_EXPOSURE_AUTO, V4L2_EXPOSURE_MANUAL);
    }
    auto v = fit(*absolute, exposure_us / 100.0, "exposure (100 us units)");
    if (!v) return std::move(v).error();
    values.emplace_back(V4L2_CID_EXPOSURE_ABSOLUTE, *v);
    return values;
  }
  if (const V4l2Control* lines = find(available, V4L2_CID_EXPOSURE)) {
    if (!(line_time_us > 0)) {
      return make_error(Errc::unsupported,
                        "the camera sets exposure in sensor lines (V4L2_CID_EXPOSURE) and its line "
                        "time is unknown");
    }
    auto v = fit(*lines, exposure_us / line_time_us, "exposure (lines)");
    if (!v) return std::move(v).error();
    values.emplace_back(V4L2_CID_EXPOSURE, *v);
    return values;
  }
  return make_error(Errc::unsupported, "the camera has no manual exposure control (EXPOSURE_ABSOLUTE or EXPOSURE)");
}

Result<V4l2ControlValues> v4l2_gain_controls(const std::vector<V4l2Control>& available, double gain) {
  if (!(gain > 0)) return make_error(Errc::invalid_argument, "gain must be positive");
  const V4l2Control* control = find(available, V4L2_CID_ANALOGUE_GAIN);
  if (control == nullptr) control = find(available, V4L2_CID_GAIN);
  if (control == nullptr) {
    if (gain == 1.0) return V4l2ControlValues{};  // nothing to change
    return make_error(Errc::unsupported, "the camera has no gain control (ANALOGUE_GAIN or GAIN)");
  }
  auto v = fit(*control, std::max(1, control->default_value) * gain, "gain");
  if (!v) return std::move(v).error();
  return V4l2ControlValues{{control->id, *v}};
}

const V4l2Control* v4l2_find_trigger_control(const std::vector<V4l2Control>& available) {
  for (const auto& c : available) {
    std::string lower = c.name;
    std::transform(lower.begin(), lower.end(), lower.begin(),
                   [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
    if (lower.find("trigger") != std::string::npos && lower.find("mode") != std::string::npos) return &c;
  }
  return nullptr;
}

Result<V4l2FrameTimes> v4l2_frame_times(std::uint32_t buffer_flags, std::int64_t tv_sec, std::int64_t tv_usec,
                                        Nanos exposure_ns) {
  if ((buffer_flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) != V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC) {
    return make_error(Errc::unsupported, "the camera's buffer timestamps are not CLOCK_MONOTONIC");
  }
  const Nanos stamp = tv_sec * kSecond + tv_usec * kMicro;
  V4l2FrameTimes times;
  if ((buffer_flags & V4L2_BUF_FLAG_TSTAMP_SRC_MASK) == V4L2_BUF_FLAG_TSTAMP_SRC_SOE) {
    times.exposure_start_ns = stamp;
    times.exposure_end_ns = stamp + exposure_ns;
  } else {  // end of frame: the last line's read-out; the exposure ended at most then
    times.exposure_end_ns = stamp;
    times.exposure_start_ns = stamp - exposure_ns;
  }
  return times;
}

namespace {

class V4l2Camera final : public Camera {
 public:
  V4l2Camera(int fd, std::string device, std::string card)
      : fd_(fd), device_(std::move(device)), card_(std::move(card)) {
    enumerate_controls();
  }
  ~V4l2Camera() override {
    (void)stop();
    ::close(fd_);
  }
  V4l2Camera(const V4l2Camera&) = delete;
  V4l2Camera& operator=(const V4l2Camera&) = delete;

  std::string describe() const override { return "V4L2 " + device_ + " (" + card_ + ")"; }

  Result<CameraFormat> set_format(const CameraFormat& wanted) override {
    v4l2_format fmt{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    fmt.fmt.pix.width = static_cast<std::uint32_t>(wanted.width);
    fmt.fmt.pix.height = static_cast<std::uint32_t>(wanted.height);
    fmt.fmt.pix.pixelformat = v4l2_fourcc_for(wanted.pixel_format);
    fmt.fmt.pix.field = V4L2_FIELD_NONE;
    if (xioctl(fd_, VIDIOC_S_FMT, &fmt) != 0) return io_error("VIDIOC_S_FMT");
    auto format = v4l2_accept_format(
        wanted, {fmt.fmt.pix.width, fmt.fmt.pix.height, fmt.fmt.pix.pixelformat, fmt.fmt.pix.bytesperline});
    if (!format) return make_error(format.error().code, device_ + ": " + format.error().message);
    format_ = *format;
    return format;
  }

  Status set_exposure_us(double exposure_us) override {
    auto values = v4l2_exposure_controls(controls_, exposure_us);
    if (!values) return make_error(values.error().code, device_ + ": " + values.error().message);
    exposure_ns_ = static_cast<Nanos>(exposure_us * kMicro);
    return apply(*values);
  }

  Status set_gain(double gain) override {
    auto values = v4l2_gain_controls(controls_, gain);
    if (!values) return make_error(values.error().code, device_ + ": " + values.error().message);
    return apply(*values);
  }

  Status set_trigger_mode(TriggerMode mode) override {
    if (mode == TriggerMode::software) return make_error(Errc::unsupported, device_ + ": V4L2 has no software trigger");
    if (const V4l2Control* control = v4l2_find_trigger_control(controls_)) {
      return apply({{control->id, mode == TriggerMode::external ? 1 : 0}});
    }
    // No standard control exists; drivers such as imx296 take it as a module parameter
    // (docs/hardware.md). The sequencer's timestamp check catches a free-running sensor.
    return slproto::Ok{};
  }

  Status start() override {
    if (streaming_) return slproto::Ok{};
    if (format_.width == 0) return make_error(Errc::invalid_argument, device_ + ": start() before set_format()");
    v4l2_requestbuffers req{};
    req.count = 4;
    req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    req.memory = V4L2_MEMORY_MMAP;
    if (xioctl(fd_, VIDIOC_REQBUFS, &req) != 0) return io_error("VIDIOC_REQBUFS");
    if (req.count < 2) return make_error(Errc::hardware, device_ + ": the driver granted fewer than 2 buffers");
    for (std::uint32_t i = 0; i < req.count; ++i) {
      v4l2_buffer buf{};
      buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      buf.memory = V4L2_MEMORY_MMAP;
      buf.index = i;
      if (xioctl(fd_, VIDIOC_QUERYBUF, &buf) != 0) return io_error("VIDIOC_QUERYBUF");
      void* mem = ::mmap(nullptr, buf.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, buf.m.offset);
      if (mem == MAP_FAILED) return io_error("mmap");
      buffers_.push_back({mem, buf.length});
      if (xioctl(fd_, VIDIOC_QBUF, &buf) != 0) return io_error("VIDIOC_QBUF");
    }
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (xioctl(fd_, VIDIOC_STREAMON, &type) != 0) return io_error("VIDIOC_STREAMON");
    streaming_ = true;
    last_sequence_ = -1;
    return slproto::Ok{};
  }

  Status stop() override {
    if (streaming_) {
      int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      xioctl(fd_, VIDIOC_STREAMOFF, &type);
      streaming_ = false;
    }
    for (const auto& b : buffers_) ::munmap(b.first, b.second);
    if (!buffers_.empty()) {
      buffers_.clear();
      v4l2_requestbuffers req{};
      req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      req.memory = V4L2_MEMORY_MMAP;
      xioctl(fd_, VIDIOC_REQBUFS, &req);
    }
    return slproto::Ok{};
  }

  Result<Frame> wait_frame(Nanos timeout_ns) override {
    if (!streaming_) return make_error(Errc::invalid_argument, device_ + ": wait_frame() while not streaming");
    pollfd pfd{fd_, POLLIN, 0};
    const int ready = ::poll(&pfd, 1, static_cast<int>((std::max<Nanos>(timeout_ns, 0) + kMilli - 1) / kMilli));
    if (ready < 0) return io_error("poll");
    if (ready == 0) {
      return make_error(Errc::timeout, device_ + ": no frame within " + std::to_string(timeout_ns / kMilli) + " ms");
    }
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    if (xioctl(fd_, VIDIOC_DQBUF, &buf) != 0) return io_error("VIDIOC_DQBUF");
    Frame frame;
    frame.dequeued_ns = monotonic_now_ns();
    frame.format = format_;
    frame.sequence = buf.sequence;
    auto times = v4l2_frame_times(buf.flags, buf.timestamp.tv_sec, buf.timestamp.tv_usec, exposure_ns_);
    if (times) {
      frame.exposure_start_ns = times->exposure_start_ns;
      frame.exposure_end_ns = times->exposure_end_ns;
    }
    const std::size_t bytes = std::min<std::size_t>(buf.bytesused, format_.frame_bytes());
    frame.pixels.assign(static_cast<const std::uint8_t*>(buffers_[buf.index].first),
                        static_cast<const std::uint8_t*>(buffers_[buf.index].first) + bytes);
    frame.pixels.resize(format_.frame_bytes(), 0);
    const bool short_frame = buf.bytesused < format_.frame_bytes() || (buf.flags & V4L2_BUF_FLAG_ERROR) != 0;
    if (xioctl(fd_, VIDIOC_QBUF, &buf) != 0) return io_error("VIDIOC_QBUF");
    if (short_frame) {
      return make_error(Errc::hardware, device_ + ": frame " + std::to_string(buf.sequence) + " is incomplete (" +
                                            std::to_string(buf.bytesused) + " of " +
                                            std::to_string(format_.frame_bytes()) + " bytes)");
    }
    last_sequence_ = buf.sequence;
    return frame;
  }

 private:
  slproto::Error io_error(const char* what) const {
    return make_error(Errc::io_error, device_ + ": " + what + " failed: " + std::strerror(errno));
  }

  void enumerate_controls() {
    v4l2_queryctrl query{};
    query.id = V4L2_CTRL_FLAG_NEXT_CTRL;
    while (xioctl(fd_, VIDIOC_QUERYCTRL, &query) == 0) {
      if ((query.flags & V4L2_CTRL_FLAG_DISABLED) == 0) {
        controls_.push_back({query.id, query.minimum, query.maximum, query.step, query.default_value,
                             reinterpret_cast<const char*>(query.name)});
      }
      query.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
    }
  }

  Status apply(const V4l2ControlValues& values) {
    for (const auto& [id, value] : values) {
      v4l2_control control{id, value};
      if (xioctl(fd_, VIDIOC_S_CTRL, &control) != 0) return io_error("VIDIOC_S_CTRL");
    }
    return slproto::Ok{};
  }

  int fd_;
  std::string device_;
  std::string card_;
  std::vector<V4l2Control> controls_;
  std::vector<std::pair<void*, std::size_t>> buffers_;
  CameraFormat format_;
  Nanos exposure_ns_ = 0;
  bool streaming_ = false;
  std::int64_t last_sequence_ = -1;
};

}  // namespace

Result<std::unique_ptr<Camera>> open_v4l2_camera(const std::string& device) {
  const int fd = ::open(device.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return make_error(Errc::io_error, "cannot open camera " + device + ": " + std::strerror(errno));
  v4l2_capability cap{};
  if (xioctl(fd, VIDIOC_QUERYCAP, &cap) != 0) {
    const int err = errno;
    ::close(fd);
    return make_error(Errc::io_error, device + " is not a V4L2 device (VIDIOC_QUERYCAP: " + std::strerror(err) + ")");
  }
  const std::uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) != 0 ? cap.device_caps : cap.capabilities;
  if ((caps & V4L2_CAP_VIDEO_CAPTURE) == 0 || (caps & V4L2_CAP_STREAMING) == 0) {
    ::close(fd);
    return make_error(Errc::unsupported, device + " is not a streaming single-planar capture device");
  }
  return std::unique_ptr<Camera>(new V4l2Camera(fd, device, reinterpret_cast<const char*>(cap.card)));
}

}  // namespace slscand::hal
