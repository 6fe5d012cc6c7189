#include "slscand/hal/libcamera/libcamera_camera.hpp"

#include <libcamera/libcamera.h>
#include <libcamera/version.h>
#include <sys/mman.h>

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <mutex>

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

libcamera::PixelFormat libcamera_pixel_format_for(PixelFormat format) {
  switch (format) {
    case PixelFormat::mono8:
      return libcamera::formats::R8;
    case PixelFormat::mono10:
      return libcamera::formats::R10;
    case PixelFormat::mono12:
      return libcamera::formats::R12;
  }
  return libcamera::formats::R8;
}

Result<std::unique_ptr<libcamera::ControlList>> libcamera_request_controls(const LibcameraControlSettings& settings) {
  if (!(settings.exposure_us > 0) || settings.exposure_us > 1e9) {
    return make_error(Errc::invalid_argument, "libcamera: exposure " + std::to_string(settings.exposure_us) +
                                                  " us is not a positive 32-bit microsecond count");
  }
  if (!(settings.gain >= 1.0)) {
    return make_error(Errc::invalid_argument,
                      "libcamera: analogue gain " + std::to_string(settings.gain) + " is below 1");
  }
  if (settings.frame_period_us != 0 && !(settings.frame_period_us >= settings.exposure_us)) {
    return make_error(Errc::invalid_argument, "libcamera: frame period " + std::to_string(settings.frame_period_us) +
                                                  " us is shorter than the exposure");
  }
  auto controls = std::make_unique<libcamera::ControlList>(libcamera::controls::controls);
  controls->set(libcamera::controls::AeEnable, false);
  controls->set(libcamera::controls::ExposureTime, static_cast<std::int32_t>(std::lround(settings.exposure_us)));
  controls->set(libcamera::controls::AnalogueGain, static_cast<float>(settings.gain));
  if (settings.frame_period_us > 0) {
    const std::int64_t period = std::llround(settings.frame_period_us);
    controls->set(libcamera::controls::FrameDurationLimits, libcamera::Span<const std::int64_t, 2>({period, period}));
  }
  return controls;
}

std::string libcamera_version_string() {
  return std::to_string(LIBCAMERA_VERSION_MAJOR) + "." + std::to_string(LIBCAMERA_VERSION_MINOR) + "." +
         std::to_string(LIBCAMERA_VERSION_PATCH);
}

namespace {

class LibcameraCamera final : public Camera {
 public:
  LibcameraCamera(std::unique_ptr<libcamera::CameraManager> manager, std::shared_ptr<libcamera::Camera> camera)
      : manager_(std::move(manager)), camera_(std::move(camera)) {}
  ~LibcameraCamera() override {
    (void)stop();
    camera_->release();
    camera_.reset();
    manager_->stop();
  }
  LibcameraCamera(const LibcameraCamera&) = delete;
  LibcameraCamera& operator=(const LibcameraCamera&) = delete;

  std::string describe() const override { return "libcamera " + libcamera_version_string() + " " + camera_->id(); }

  Result<CameraFormat> set_format(const CameraFormat& wanted) override {
    config_ = camera_->generateConfiguration({libcamera::StreamRole::Raw});
    if (!config_ || config_->empty()) return make_error(Errc::unsupported, describe() + ": no raw stream");
    libcamera::StreamConfiguration& stream = config_->at(0);
    stream.pixelFormat = libcamera_pixel_format_for(wanted.pixel_format);
    stream.size = libcamera::Size(static_cast<unsigned>(wanted.width), static_cast<unsigned>(wanted.height));
    stream.bufferCount = 4;
    const auto status = config_->validate();
    if (status == libcamera::CameraConfiguration::Invalid ||
        stream.pixelFormat != libcamera_pixel_format_for(wanted.pixel_format) ||
        stream.size != libcamera::Size(static_cast<unsigned>(wanted.width), static_cast<unsigned>(wanted.height))) {
      return make_error(Errc::unsupported, describe() + " offers " + stream.toString() + " when asked for " +
                                               std::to_string(wanted.width) + "x" + std::to_string(wanted.height) +
                                               "-" + libcamera_pixel_format_for(wanted.pixel_format).toString());
    }
    if (camera_->configure(config_.get()) != 0) {
      return make_error(Errc::hardware, describe() + ": configure() refused " + stream.toString());
    }
    format_ = wanted;
    format_.stride_bytes = stream.stride;
    return format_;
  }

  Status set_exposure_us(double exposure_us) override {
    settings_.exposure_us = exposure_us;
    return check_settings();
  }
  Status set_gain(double gain) override {
    settings_.gain = gain;
    return check_settings();
  }
  Status set_trigger_mode(TriggerMode mode) override {
    if (mode == TriggerMode::software) {
      return slproto::make_error(slproto::Errc::unsupported, "libcamera has no software trigger");
    }
    // libcamera 0.3 has no trigger control: an external trigger is a sensor driver setting
    // (e.g. imx296's trigger_mode module parameter, docs/hardware.md).
    return slproto::Ok{};
  }

  Status start() override {
    if (running_) return slproto::Ok{};
    if (!config_) return make_error(Errc::invalid_argument, describe() + ": start() before set_format()");
    libcamera::Stream* stream = config_->at(0).stream();
    allocator_ = std::make_unique<libcamera::FrameBufferAllocator>(camera_);
    if (allocator_->allocate(stream) < 0) return make_error(Errc::hardware, describe() + ": cannot allocate buffers");
    for (const auto& buffer : allocator_->buffers(stream)) {
      std::unique_ptr<libcamera::Request> request = camera_->createRequest();
      if (!request || request->addBuffer(stream, buffer.get()) != 0) {
        return make_error(Errc::hardware, describe() + ": cannot create a request");
      }
      requests_.push_back(std::move(request));
    }
    auto controls = libcamera_request_controls(settings_);
    if (!controls) return controls.error();
    camera_->requestCompleted.connect(this, &LibcameraCamera::on_complete);
    if (camera_->start(controls->get()) != 0) return make_error(Errc::hardware, describe() + ": start() failed");
    running_ = true;
    for (auto& request : requests_) {
      request->controls().merge(**controls);
      if (camera_->queueRequest(request.get()) != 0)
        return make_error(Errc::hardware, describe() + ": queueRequest failed");
    }
    return slproto::Ok{};
  }

  Status stop() override {
    if (running_) {
      camera_->stop();
      camera_->requestCompleted.disconnect(this);
      running_ = false;
    }
    {
      std::lock_guard lock(mutex_);
      completed_.clear();
    }
    requests_.clear();
    allocator_.reset();
    return slproto::Ok{};
  }

  Result<Frame> wait_frame(Nanos timeout_ns) override {
    libcamera::Request* request = nullptr;
    {
      std::unique_lock lock(mutex_);
      if (!cv_.wait_for(lock, std::chrono::nanoseconds(timeout_ns), [&] { return !completed_.empty(); })) {
        return make_error(Errc::timeout,
                          describe() + ": no frame within " + std::to_string(timeout_ns / kMilli) + " ms");
      }
      request = completed_.front();
      completed_.pop_front();
    }
    Frame frame;
    frame.dequeued_ns = monotonic_now_ns();
    frame.format = format_;
    if (request->status() != libcamera::Request::RequestComplete) {
      requeue(request);
      return make_error(Errc::hardware, describe() + ": request cancelled");
    }
    const libcamera::FrameBuffer* buffer = request->buffers().begin()->second;
    frame.sequence = buffer->metadata().sequence;
    const auto sensor_ts = request->metadata().get(libcamera::controls::SensorTimestamp);
    const auto exposure = request->metadata().get(libcamera::controls::ExposureTime);
    if (sensor_ts) {
      // SensorTimestamp is the start of exposure of the first line, on CLOCK_BOOTTIME.
      frame.exposure_start_ns = boottime_to_monotonic_ns(*sensor_ts);
      frame.exposure_end_ns = frame.exposure_start_ns + (exposure ? *exposure : 0) * kMicro;
    }
    frame.pixels.resize(format_.frame_bytes());
    std::size_t copied = 0;
    for (const auto& plane : buffer->planes()) {
      const std::size_t map_length = plane.offset + plane.length;
      void* mem = ::mmap(nullptr, map_length, PROT_READ, MAP_SHARED, plane.fd.get(), 0);
      if (mem == MAP_FAILED) {
        requeue(request);
        return make_error(Errc::io_error, describe() + ": cannot map a frame buffer");
      }
      const std::size_t n = std::min<std::size_t>(plane.length, frame.pixels.size() - copied);
      std::memcpy(frame.pixels.data() + copied, static_cast<const std::uint8_t*>(mem) + plane.offset, n);
      copied += n;
      ::munmap(mem, map_length);
    }
    requeue(request);
    return frame;
  }

 private:
  Status check_settings() {
    auto controls = libcamera_request_controls(settings_);
    if (!controls) return controls.error();
    return slproto::Ok{};
  }

  void requeue(libcamera::Request* request) {
    request->reuse(libcamera::Request::ReuseBuffers);
    if (auto controls = libcamera_request_controls(settings_)) request->controls().merge(**controls);
    if (running_) camera_->queueRequest(request);
  }

  void on_complete(libcamera::Request* request) {
    if (request->status() == libcamera::Request::RequestCancelled) return;
    {
      std::lock_guard lock(mutex_);
      completed_.push_back(request);
    }
    cv_.notify_all();
  }

  std::unique_ptr<libcamera::CameraManager> manager_;
  std::shared_ptr<libcamera::Camera> camera_;
  std::unique_ptr<libcamera::CameraConfiguration> config_;
  std::unique_ptr<libcamera::FrameBufferAllocator> allocator_;
  std::vector<std::unique_ptr<libcamera::Request>> requests_;
  LibcameraControlSettings settings_{8333, 1.0, 0};
  CameraFormat format_;
  bool running_ = false;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<libcamera::Request*> completed_;
};

}  // namespace

Result<std::unique_ptr<Camera>> open_libcamera_camera(const std::string& id) {
  auto manager = std::make_unique<libcamera::CameraManager>();
  if (const int rv = manager->start(); rv != 0) {
    return make_error(Errc::io_error, "libcamera: CameraManager::start failed (" + std::to_string(rv) + ")");
  }
  std::shared_ptr<libcamera::Camera> camera;
  if (id.empty() || id == "auto") {
    if (!manager->cameras().empty()) camera = manager->cameras().front();
  } else {
    camera = manager->get(id);
  }
  if (!camera) {
    std::string known;
    for (const auto& c : manager->cameras()) known += (known.empty() ? "" : ", ") + c->id();
    manager->stop();
    return make_error(Errc::io_error,
                      "libcamera: no camera '" + id + "' (found: " + (known.empty() ? "none" : known) + ")");
  }
  if (camera->acquire() != 0) {
    const std::string name = camera->id();
    camera.reset();
    manager->stop();
    return make_error(Errc::busy, "libcamera: camera " + name + " is in use by another process");
  }
  return std::unique_ptr<Camera>(new LibcameraCamera(std::move(manager), std::move(camera)));
}

}  // namespace slscand::hal
