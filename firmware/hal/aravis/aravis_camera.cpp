#include "slscand/hal/aravis/aravis_camera.hpp"

#include <arv.h>
#include <ifaddrs.h>
#include <net/if.h>
#include <netinet/in.h>
#include <time.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

// ---------------------------------------------------------------------------------------------
// Pure parts: wire formats, unpacking, frame ids, clock mapping.

const char* genicam_wire_format_name(GenicamWireFormat format) noexcept {
  switch (format) {
    case GenicamWireFormat::mono8:
      return "Mono8";
    case GenicamWireFormat::mono10:
      return "Mono10";
    case GenicamWireFormat::mono12:
      return "Mono12";
    case GenicamWireFormat::mono10p:
      return "Mono10p";
    case GenicamWireFormat::mono12p:
      return "Mono12p";
    case GenicamWireFormat::mono10_packed:
      return "Mono10Packed";
    case GenicamWireFormat::mono12_packed:
      return "Mono12Packed";
  }
  return "unknown";
}

int genicam_bits_per_pixel(GenicamWireFormat format) noexcept {
  switch (format) {
    case GenicamWireFormat::mono8:
      return 8;
    case GenicamWireFormat::mono10:
    case GenicamWireFormat::mono12:
      return 16;
    case GenicamWireFormat::mono10p:
      return 10;
    case GenicamWireFormat::mono12p:
    case GenicamWireFormat::mono10_packed:  // 2 pixels in 3 bytes, whatever the depth
    case GenicamWireFormat::mono12_packed:
      return 12;
  }
  return 0;
}

PixelFormat genicam_pixel_format(GenicamWireFormat format) noexcept {
  switch (format) {
    case GenicamWireFormat::mono8:
      return PixelFormat::mono8;
    case GenicamWireFormat::mono10:
    case GenicamWireFormat::mono10p:
    case GenicamWireFormat::mono10_packed:
      return PixelFormat::mono10;
    case GenicamWireFormat::mono12:
    case GenicamWireFormat::mono12p:
    case GenicamWireFormat::mono12_packed:
      return PixelFormat::mono12;
  }
  return PixelFormat::mono8;
}

Result<GenicamWireFormat> choose_genicam_wire_format(PixelFormat wanted, const std::vector<std::string>& available) {
  std::vector<GenicamWireFormat> preference;
  switch (wanted) {
    case PixelFormat::mono8:
      preference = {GenicamWireFormat::mono8};
      break;
    case PixelFormat::mono10:
      preference = {GenicamWireFormat::mono10, GenicamWireFormat::mono10p, GenicamWireFormat::mono10_packed};
      break;
    case PixelFormat::mono12:
      preference = {GenicamWireFormat::mono12, GenicamWireFormat::mono12p, GenicamWireFormat::mono12_packed};
      break;
  }
  for (const GenicamWireFormat f : preference) {
    if (std::find(available.begin(), available.end(), genicam_wire_format_name(f)) != available.end()) return f;
  }
  std::string wants, offers;
  for (const GenicamWireFormat f : preference)
    wants += (wants.empty() ? "" : ", ") + std::string(genicam_wire_format_name(f));
  for (const auto& a : available) offers += (offers.empty() ? "" : ", ") + a;
  return make_error(Errc::unsupported, std::string("pixel format ") + pixel_format_name(wanted) + " needs one of " +
                                           wants + "; the camera offers " + (offers.empty() ? "none" : offers));
}

std::size_t genicam_image_bytes(GenicamWireFormat format, int width, int height) noexcept {
  const auto pixels = static_cast<std::size_t>(std::max(0, width)) * static_cast<std::size_t>(std::max(0, height));
  return (pixels * static_cast<std::size_t>(genicam_bits_per_pixel(format)) + 7) / 8;
}

Status genicam_unpack(GenicamWireFormat format, const std::uint8_t* src, std::size_t src_bytes, int width, int height,
                      std::uint8_t* dst) {
  const std::size_t need = genicam_image_bytes(format, width, height);
  if (src_bytes < need) {
    return make_error(Errc::truncated, std::string(genicam_wire_format_name(format)) + " image of " +
                                           std::to_string(width) + " x " + std::to_string(height) + " needs " +
                                           std::to_string(need) + " bytes; the buffer has " +
                                           std::to_string(src_bytes));
  }
  const auto pixels = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  auto put = [dst](std::size_t i, unsigned value) {
    dst[2 * i] = static_cast<std::uint8_t>(value & 0xff);
    dst[2 * i + 1] = static_cast<std::uint8_t>(value >> 8);
  };
  switch (format) {
    case GenicamWireFormat::mono8:
      std::memcpy(dst, src, pixels);
      return slproto::Ok{};
    case GenicamWireFormat::mono10:
    case GenicamWireFormat::mono12: {
      // Already little-endian uint16; keep only the format's bits (a stray high bit would
      // decode as a saturated pixel).
      const unsigned mask = format == GenicamWireFormat::mono10 ? 0x3ff : 0xfff;
      for (std::size_t i = 0; i < pixels; ++i) put(i, (src[2 * i] | (src[2 * i + 1] << 8)) & mask);
      return slproto::Ok{};
    }
    case GenicamWireFormat::mono10p:
    case GenicamWireFormat::mono12p: {
      // PFNC "p" formats: one little-endian bit stream, pixel i in bits [i * n, i * n + n).
      const unsigned bits = format == GenicamWireFormat::mono10p ? 10 : 12;
      const unsigned mask = (1u << bits) - 1;
      std::size_t bit = 0;
      for (std::size_t i = 0; i < pixels; ++i, bit += bits) {
        const std::size_t byte = bit / 8;
        unsigned word = src[byte];
        if (byte + 1 < src_bytes) word |= static_cast<unsigned>(src[byte + 1]) << 8;
        if (byte + 2 < src_bytes) word |= static_cast<unsigned>(src[byte + 2]) << 16;
        put(i, (word >> (bit % 8)) & mask);
      }
      return slproto::Ok{};
    }
    case GenicamWireFormat::mono10_packed:
    case GenicamWireFormat::mono12_packed: {
      // GigE Vision 1.x packed: pixels a, b in 3 bytes: [a high bits] [low bits of a and b] [b high bits].
      const bool ten = format == GenicamWireFormat::mono10_packed;
      for (std::size_t i = 0; i < pixels; i += 2) {
        const std::uint8_t* p = src + (i / 2) * 3;
        const unsigned a = ten ? (static_cast<unsigned>(p[0]) << 2) | (p[1] & 0x3u)
                               : (static_cast<unsigned>(p[0]) << 4) | (p[1] & 0xfu);
        put(i, a);
        if (i + 1 < pixels) {
          const unsigned b = ten ? (static_cast<unsigned>(p[2]) << 2) | ((p[1] >> 4) & 0x3u)
                                 : (static_cast<unsigned>(p[2]) << 4) | (p[1] >> 4);
          put(i + 1, b);
        }
      }
      return slproto::Ok{};
    }
  }
  return make_error(Errc::internal, "unknown wire format");
}

std::uint64_t FrameIdUnwrapper::next(std::uint64_t raw_id) {
  if (!have_last_) {
    have_last_ = true;
    last_raw_ = raw_id;
    counter_ = raw_id;
    return counter_;
  }
  std::uint64_t delta = 0;
  if (raw_id < 0x10000 && last_raw_ < 0x10000 && raw_id < last_raw_ && last_raw_ - raw_id > 0x8000) {
    // A 16-bit block id wrapped. GigE Vision 1.x never sends block id 0, so 0xffff -> 1 is one step.
    delta = raw_id + 0x10000 - last_raw_;
    if (last_raw_ == 0xffff && raw_id == 1) delta = 1;
  } else if (raw_id > last_raw_) {
    delta = raw_id - last_raw_;
  } else {
    delta = 0;  // repeated or older id: not a new frame in the counter's sense
  }
  last_raw_ = raw_id;
  counter_ += delta;
  return counter_;
}

Result<ClockMapping> clock_mapping_from_latches(const std::vector<ClockLatchSample>& samples) {
  const ClockLatchSample* best = nullptr;
  for (const auto& s : samples) {
    if (s.monotonic_after_ns < s.monotonic_before_ns || s.device_ns == 0) continue;
    if (best == nullptr ||
        s.monotonic_after_ns - s.monotonic_before_ns < best->monotonic_after_ns - best->monotonic_before_ns) {
      best = &s;
    }
  }
  if (best == nullptr) {
    return make_error(Errc::hardware, "the camera's timestamp latch returned no usable sample (all zero)");
  }
  ClockMapping m;
  m.kind = ClockMapping::Kind::latched;
  const Nanos mid = best->monotonic_before_ns + (best->monotonic_after_ns - best->monotonic_before_ns) / 2;
  m.device_to_monotonic_ns = mid - best->device_ns;
  m.uncertainty_ns = (best->monotonic_after_ns - best->monotonic_before_ns) / 2;
  return m;
}

bool looks_like_wall_clock(std::int64_t device_ns, std::int64_t realtime_at_arrival_ns) noexcept {
  const std::int64_t d = realtime_at_arrival_ns - device_ns;
  return device_ns > 0 && d > -2 * kSecond && d < 2 * kSecond;
}

// ---------------------------------------------------------------------------------------------
// The camera.

namespace {

std::string take_error(GError*& error, const char* fallback = "unknown error") {
  std::string text = error != nullptr && error->message != nullptr ? error->message : fallback;
  g_clear_error(&error);
  return text;
}

Nanos realtime_minus_monotonic_ns() {
  timespec m1{}, r{}, m2{};
  clock_gettime(CLOCK_MONOTONIC, &m1);
  clock_gettime(CLOCK_REALTIME, &r);
  clock_gettime(CLOCK_MONOTONIC, &m2);
  const Nanos mono = (m1.tv_sec * kSecond + m1.tv_nsec + m2.tv_sec * kSecond + m2.tv_nsec) / 2;
  return r.tv_sec * kSecond + r.tv_nsec - mono;
}

Nanos realtime_now_ns() {
  timespec r{};
  clock_gettime(CLOCK_REALTIME, &r);
  return r.tv_sec * kSecond + r.tv_nsec;
}

std::string join(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& i : items) out += (out.empty() ? "" : ", ") + i;
  return out;
}

std::string inet_text(GSocketAddress* address) {
  if (address == nullptr || !G_IS_INET_SOCKET_ADDRESS(address)) return "";
  GInetAddress* inet = g_inet_socket_address_get_address(G_INET_SOCKET_ADDRESS(address));
  gchar* text = g_inet_address_to_string(inet);
  std::string s = text != nullptr ? text : "";
  g_free(text);
  return s;
}

// The host interface that has `address`, and its link speed from sysfs ("" / -1 if unknown).
std::pair<std::string, int> host_interface_for(const std::string& address) {
  ifaddrs* list = nullptr;
  if (address.empty() || getifaddrs(&list) != 0) return {"", -1};
  std::string name;
  for (ifaddrs* i = list; i != nullptr; i = i->ifa_next) {
    if (i->ifa_addr == nullptr || i->ifa_addr->sa_family != AF_INET) continue;
    GSocketAddress* sa = g_socket_address_new_from_native(i->ifa_addr, sizeof(sockaddr_in));
    if (sa != nullptr) {
      if (inet_text(sa) == address) name = i->ifa_name;
      g_object_unref(sa);
    }
    if (!name.empty()) break;
  }
  freeifaddrs(list);
  int speed = -1;
  if (!name.empty()) {
    std::ifstream in("/sys/class/net/" + name + "/speed");
    if (!(in >> speed)) speed = -1;
  }
  return {name, speed};
}

std::vector<std::string> enumeration(ArvCamera* camera, const char* feature) {
  std::vector<std::string> values;
  GError* error = nullptr;
  guint n = 0;
  const char** names = arv_camera_dup_available_enumerations_as_strings(camera, feature, &n, &error);
  g_clear_error(&error);
  if (names == nullptr) return values;
  for (guint i = 0; i < n; ++i) values.emplace_back(names[i]);
  g_free(names);
  return values;
}

bool has_feature(ArvCamera* camera, const char* feature) {
  GError* error = nullptr;
  const bool yes = arv_camera_is_feature_available(camera, feature, &error) != 0;
  g_clear_error(&error);
  return yes;
}

void control_lost_callback(ArvDevice* /*device*/, gpointer flag) { static_cast<std::atomic<bool>*>(flag)->store(true); }

std::string buffer_status_text(ArvBufferStatus status) {
  switch (status) {
    case ARV_BUFFER_STATUS_SUCCESS:
      return "success";
    case ARV_BUFFER_STATUS_CLEARED:
      return "cleared";
    case ARV_BUFFER_STATUS_TIMEOUT:
      return "timed out in the stream (packets stopped arriving)";
    case ARV_BUFFER_STATUS_MISSING_PACKETS:
      return "missing packets (resend did not recover them)";
    case ARV_BUFFER_STATUS_WRONG_PACKET_ID:
      return "wrong packet id";
    case ARV_BUFFER_STATUS_SIZE_MISMATCH:
      return "larger than the buffer (image size changed?)";
    case ARV_BUFFER_STATUS_FILLING:
      return "still filling";
    case ARV_BUFFER_STATUS_ABORTED:
      return "aborted";
    default:
      return "status " + std::to_string(static_cast<int>(status));
  }
}

class AravisCamera final : public Camera {
 public:
  AravisCamera(ArvCamera* camera, AravisOptions options, std::string id)
      : camera_(camera), options_(std::move(options)), id_(std::move(id)) {
    GError* error = nullptr;
    const char* vendor = arv_camera_get_vendor_name(camera_, &error);
    g_clear_error(&error);
    const char* model = arv_camera_get_model_name(camera_, &error);
    g_clear_error(&error);
    const char* serial = arv_camera_get_device_serial_number(camera_, &error);
    g_clear_error(&error);
    vendor_ = vendor != nullptr ? vendor : "?";
    model_ = model != nullptr ? model : "?";
    serial_ = serial != nullptr ? serial : "";
    gige_ = arv_camera_is_gv_device(camera_) != 0;
    if (gige_) {
      ArvGvDevice* gv = ARV_GV_DEVICE(arv_camera_get_device(camera_));
      GSocketAddress* device_address = arv_gv_device_get_device_address(gv);
      GSocketAddress* interface_address = arv_gv_device_get_interface_address(gv);
      address_ = inet_text(device_address);
      interface_address_ = inet_text(interface_address);
      // Aravis' packet socket (used when the process may open one) does not see loopback
      // traffic: the fake camera on 127.0.0.1 streams through an ordinary UDP socket.
      if (address_.rfind("127.", 0) == 0) {
        arv_camera_gv_set_stream_options(camera_, ARV_GV_STREAM_OPTION_PACKET_SOCKET_DISABLED);
      }
    }
    control_lost_handler_ = g_signal_connect(arv_camera_get_device(camera_), "control-lost",
                                             G_CALLBACK(control_lost_callback), &control_lost_);
  }
  ~AravisCamera() override {
    (void)stop();
    g_signal_handler_disconnect(arv_camera_get_device(camera_), control_lost_handler_);
    g_object_unref(camera_);
  }
  AravisCamera(const AravisCamera&) = delete;
  AravisCamera& operator=(const AravisCamera&) = delete;

  std::string describe() const override {
    std::string s = "GenICam " + vendor_ + " " + model_;
    if (!serial_.empty()) s += " serial " + serial_;
    s += " (" + id_ + ")";
    if (!address_.empty()) s += " at " + address_;
    return s;
  }

  Result<CameraFormat> set_format(const CameraFormat& wanted) override {
    if (auto gone = check_present(); !gone) return gone.error();
    std::vector<std::string> formats;
    {
      GError* error = nullptr;
      guint n = 0;
      const char** names = arv_camera_dup_available_pixel_formats_as_strings(camera_, &n, &error);
      if (names == nullptr) return fail(Errc::io_error, "reading PixelFormat: " + take_error(error));
      for (guint i = 0; i < n; ++i) formats.emplace_back(names[i]);
      g_free(names);
    }
    auto wire = choose_genicam_wire_format(wanted.pixel_format, formats);
    if (!wire) return fail(wire.error().code, wire.error().message);
    GError* error = nullptr;
    arv_camera_set_pixel_format_from_string(camera_, genicam_wire_format_name(*wire), &error);
    if (error != nullptr) return fail(Errc::io_error, std::string("setting PixelFormat: ") + take_error(error));
    // The region must fit the sensor: some cameras (the fake among them) take any value.
    {
      GError* e2 = nullptr;
      gint wmin = 0, wmax = 0, hmin = 0, hmax = 0;
      const gint sensor_w = static_cast<gint>(arv_camera_get_integer(camera_, "SensorWidth", &e2));
      g_clear_error(&e2);
      const gint sensor_h = static_cast<gint>(arv_camera_get_integer(camera_, "SensorHeight", &e2));
      g_clear_error(&e2);
      arv_camera_get_width_bounds(camera_, &wmin, &wmax, &e2);
      g_clear_error(&e2);
      arv_camera_get_height_bounds(camera_, &hmin, &hmax, &e2);
      g_clear_error(&e2);
      // Without SensorWidth/Height, WidthMax/HeightMax at the current offset bound the window.
      gint x0 = 0, y0 = 0, w0 = 0, h0 = 0;
      arv_camera_get_region(camera_, &x0, &y0, &w0, &h0, &e2);
      g_clear_error(&e2);
      const gint full_w = sensor_w > 0 ? sensor_w : x0 + wmax, full_h = sensor_h > 0 ? sensor_h : y0 + hmax;
      if (wanted.width < wmin || wanted.height < hmin || options_.offset_x + wanted.width > full_w ||
          options_.offset_y + wanted.height > full_h) {
        return fail(Errc::unsupported, "region " + std::to_string(wanted.width) + " x " +
                                           std::to_string(wanted.height) + " at (" + std::to_string(options_.offset_x) +
                                           ", " + std::to_string(options_.offset_y) + ") does not fit the sensor's " +
                                           std::to_string(full_w) + " x " + std::to_string(full_h));
      }
    }
    arv_camera_set_region(camera_, options_.offset_x, options_.offset_y, wanted.width, wanted.height, &error);
    if (error != nullptr) {
      gint wmin = 0, wmax = 0, hmin = 0, hmax = 0;
      GError* e2 = nullptr;
      arv_camera_get_width_bounds(camera_, &wmin, &wmax, &e2);
      g_clear_error(&e2);
      arv_camera_get_height_bounds(camera_, &hmin, &hmax, &e2);
      g_clear_error(&e2);
      return fail(Errc::unsupported, "region " + std::to_string(wanted.width) + " x " + std::to_string(wanted.height) +
                                         " at (" + std::to_string(options_.offset_x) + ", " +
                                         std::to_string(options_.offset_y) + "): " + take_error(error) + " (width " +
                                         std::to_string(wmin) + ".." + std::to_string(wmax) + ", height " +
                                         std::to_string(hmin) + ".." + std::to_string(hmax) + ")");
    }
    gint x = 0, y = 0, w = 0, h = 0;
    arv_camera_get_region(camera_, &x, &y, &w, &h, &error);
    if (error != nullptr) return fail(Errc::io_error, "reading the region back: " + take_error(error));
    const char* got_format = arv_camera_get_pixel_format_as_string(camera_, &error);
    g_clear_error(&error);
    if (w != wanted.width || h != wanted.height || x != options_.offset_x || y != options_.offset_y ||
        got_format == nullptr || std::string(got_format) != genicam_wire_format_name(*wire)) {
      return fail(Errc::unsupported,
                  "the camera took " + std::to_string(w) + " x " + std::to_string(h) + " at (" + std::to_string(x) +
                      ", " + std::to_string(y) + ") " + (got_format != nullptr ? got_format : "?") +
                      " when asked for " + std::to_string(wanted.width) + " x " + std::to_string(wanted.height) +
                      " at (" + std::to_string(options_.offset_x) + ", " + std::to_string(options_.offset_y) + ") " +
                      genicam_wire_format_name(*wire) + " (check the sensor's size and increments)");
    }
    wire_ = *wire;
    format_ = wanted;
    format_.stride_bytes =
        static_cast<std::size_t>(wanted.width) * static_cast<std::size_t>(bytes_per_pixel(wanted.pixel_format));
    return format_;
  }

  Status set_exposure_us(double exposure_us) override {
    if (!(exposure_us > 0)) return fail(Errc::invalid_argument, "exposure must be positive");
    if (auto gone = check_present(); !gone) return gone.error();
    GError* error = nullptr;
    if (arv_camera_is_exposure_auto_available(camera_, &error)) {
      arv_camera_set_exposure_time_auto(camera_, ARV_AUTO_OFF, &error);
    }
    if (error != nullptr) return fail(Errc::io_error, "ExposureAuto = Off: " + take_error(error));
    double lo = 0, hi = 0;
    arv_camera_get_exposure_time_bounds(camera_, &lo, &hi, &error);
    if (error != nullptr) return fail(Errc::unsupported, "the camera has no exposure time: " + take_error(error));
    if (exposure_us < lo || exposure_us > hi) {
      return fail(Errc::invalid_argument, "exposure " + std::to_string(exposure_us) + " us is outside the camera's " +
                                              std::to_string(lo) + ".." + std::to_string(hi) + " us");
    }
    arv_camera_set_exposure_time(camera_, exposure_us, &error);
    if (error != nullptr) return fail(Errc::io_error, "setting the exposure time: " + take_error(error));
    const double got = arv_camera_get_exposure_time(camera_, &error);
    if (error != nullptr) return fail(Errc::io_error, "reading the exposure time back: " + take_error(error));
    // Cameras round to their line time; more than 1 % (or 2 us) off is a different exposure.
    if (std::abs(got - exposure_us) > std::max(2.0, 0.01 * exposure_us)) {
      return fail(Errc::unsupported, "asked for an exposure of " + std::to_string(exposure_us) +
                                         " us, the camera set " + std::to_string(got) + " us");
    }
    exposure_ns_ = static_cast<Nanos>(std::llround(got * kMicro));
    return slproto::Ok{};
  }

  Status set_gain(double gain) override {
    if (!(gain > 0)) return fail(Errc::invalid_argument, "gain must be positive");
    if (auto gone = check_present(); !gone) return gone.error();
    GError* error = nullptr;
    if (arv_camera_is_gain_auto_available(camera_, &error)) arv_camera_set_gain_auto(camera_, ARV_AUTO_OFF, &error);
    if (error != nullptr) return fail(Errc::io_error, "GainAuto = Off: " + take_error(error));
    if (has_feature(camera_, "Gain")) {
      // SFNC Gain is in dB; ours is a factor (1 = the sensor's base gain).
      const double db = 20.0 * std::log10(gain);
      double lo = 0, hi = 0;
      arv_camera_get_float_bounds(camera_, "Gain", &lo, &hi, &error);
      if (error != nullptr) return fail(Errc::io_error, "reading Gain's range: " + take_error(error));
      if (db < lo - 1e-9 || db > hi + 1e-9) {
        return fail(Errc::invalid_argument, "gain x" + std::to_string(gain) + " (" + std::to_string(db) +
                                                " dB) is outside the camera's " + std::to_string(lo) + ".." +
                                                std::to_string(hi) + " dB");
      }
      arv_camera_set_float(camera_, "Gain", std::clamp(db, lo, hi), &error);
      if (error != nullptr) return fail(Errc::io_error, "setting Gain: " + take_error(error));
      return slproto::Ok{};
    }
    if (has_feature(camera_, "GainRaw")) {
      // Raw gain has no unit we could convert a factor to: only the base gain is meaningful.
      if (std::abs(gain - 1.0) > 1e-9) {
        return fail(Errc::unsupported, "the camera has only GainRaw (no unit): set camera.gain = 1");
      }
      gint64 lo = 0, hi = 0;
      arv_camera_get_integer_bounds(camera_, "GainRaw", &lo, &hi, &error);
      if (error == nullptr) arv_camera_set_integer(camera_, "GainRaw", lo, &error);
      if (error != nullptr) return fail(Errc::io_error, "setting GainRaw: " + take_error(error));
      return slproto::Ok{};
    }
    if (std::abs(gain - 1.0) > 1e-9) return fail(Errc::unsupported, "the camera has no gain control");
    return slproto::Ok{};
  }

  Status set_trigger_mode(TriggerMode mode) override {
    if (auto gone = check_present(); !gone) return gone.error();
    GError* error = nullptr;
    const std::vector<std::string> selectors = enumeration(camera_, "TriggerSelector");
    // Only FrameStart may trigger: a stale AcquisitionStart trigger would hold every frame back.
    for (const auto& selector : selectors) {
      if (selector == "FrameStart") continue;
      arv_camera_set_string(camera_, "TriggerSelector", selector.c_str(), &error);
      if (error == nullptr) arv_camera_set_string(camera_, "TriggerMode", "Off", &error);
      g_clear_error(&error);
    }
    if (std::find(selectors.begin(), selectors.end(), "FrameStart") == selectors.end()) {
      if (mode == TriggerMode::free_run) return slproto::Ok{};
      return fail(Errc::unsupported,
                  "the camera has no FrameStart trigger (TriggerSelector offers " + join(selectors) + ")");
    }
    arv_camera_set_string(camera_, "TriggerSelector", "FrameStart", &error);
    if (error != nullptr) return fail(Errc::io_error, "TriggerSelector = FrameStart: " + take_error(error));
    if (mode == TriggerMode::free_run) {
      arv_camera_set_string(camera_, "TriggerMode", "Off", &error);
      if (error != nullptr) return fail(Errc::io_error, "TriggerMode = Off: " + take_error(error));
      trigger_mode_ = mode;
      return slproto::Ok{};
    }
    const std::string source = mode == TriggerMode::software ? "Software" : options_.trigger_input;
    const std::vector<std::string> sources = enumeration(camera_, "TriggerSource");
    if (std::find(sources.begin(), sources.end(), source) == sources.end()) {
      return fail(Errc::unsupported, "TriggerSource " + source + " is not one the camera offers (" + join(sources) +
                                         ")" + (mode == TriggerMode::external ? ": fix [camera] trigger_input" : ""));
    }
    arv_camera_set_string(camera_, "TriggerMode", "On", &error);
    if (error == nullptr) arv_camera_set_string(camera_, "TriggerSource", source.c_str(), &error);
    if (error == nullptr && mode == TriggerMode::external && has_feature(camera_, "TriggerActivation")) {
      arv_camera_set_string(camera_, "TriggerActivation", options_.trigger_activation.c_str(), &error);
    }
    if (error != nullptr) return fail(Errc::io_error, "setting the " + source + " trigger: " + take_error(error));
    trigger_mode_ = mode;
    return slproto::Ok{};
  }

  Status software_trigger() override {
    if (trigger_mode_ != TriggerMode::software) {
      return fail(Errc::invalid_argument, "software_trigger() while the camera is not in software trigger mode");
    }
    GError* error = nullptr;
    arv_camera_software_trigger(camera_, &error);
    if (error != nullptr) return gone_or(Errc::io_error, "TriggerSoftware: " + take_error(error));
    return slproto::Ok{};
  }

  Status start() override {
    if (stream_ != nullptr) return slproto::Ok{};
    if (format_.width == 0) return fail(Errc::invalid_argument, "start() before set_format()");
    if (auto gone = check_present(); !gone) return gone.error();
    GError* error = nullptr;
    if (gige_) {
      if (options_.packet_size > 0) {
        arv_camera_gv_set_packet_size(camera_, options_.packet_size, &error);
        if (error != nullptr) {
          return fail(Errc::io_error, "packet size " + std::to_string(options_.packet_size) + ": " + take_error(error));
        }
      } else if (!packet_size_negotiated_) {
        // The largest packet the path carries without fragmentation (the camera tests with DF set).
        arv_camera_gv_auto_packet_size(camera_, &error);
        g_clear_error(&error);  // keep the camera's default when the test fails
        packet_size_negotiated_ = true;
      }
    }
    if (has_feature(camera_, "AcquisitionMode")) {
      arv_camera_set_acquisition_mode(camera_, ARV_ACQUISITION_MODE_CONTINUOUS, &error);
      g_clear_error(&error);
    }
    const gint payload = static_cast<gint>(arv_camera_get_payload(camera_, &error));
    if (error != nullptr) return fail(Errc::io_error, "reading PayloadSize: " + take_error(error));
    const std::size_t need = genicam_image_bytes(wire_, format_.width, format_.height);
    if (static_cast<std::size_t>(payload) < need) {
      return fail(Errc::hardware, "PayloadSize " + std::to_string(payload) + " is smaller than a " +
                                      genicam_wire_format_name(wire_) + " image (" + std::to_string(need) + " bytes)");
    }
    stream_ = arv_camera_create_stream(camera_, nullptr, nullptr, &error);
    if (stream_ == nullptr) return gone_or(Errc::io_error, "creating the stream: " + take_error(error));
    if (ARV_IS_GV_STREAM(stream_)) {
      // Resend lost packets. The socket buffer holds a frame, and never less than 1 MiB: Aravis'
      // "auto" sizes it to one payload, which for a small ROI (a few kB) is fewer bytes than the
      // kernel charges for its few packets, so they are dropped. The kernel caps it at
      // net.core.rmem_max (docs/hardware.md).
      g_object_set(stream_, "packet-resend", ARV_GV_STREAM_PACKET_RESEND_ALWAYS, "socket-buffer",
                   ARV_GV_STREAM_SOCKET_BUFFER_FIXED, "socket-buffer-size", std::max(payload, 1 << 20), nullptr);
    }
    for (int i = 0; i < options_.buffers; ++i) arv_stream_push_buffer(stream_, arv_buffer_new(payload, nullptr));
    ids_.reset();
    last_alive_ns_ = monotonic_now_ns();
    realtime_offset_ns_ = realtime_minus_monotonic_ns();
    calibrate_clock();
    arv_camera_start_acquisition(camera_, &error);
    if (error != nullptr) {
      const std::string text = take_error(error);
      release_stream();
      return gone_or(Errc::io_error, "AcquisitionStart: " + text);
    }
    return slproto::Ok{};
  }

  Status stop() override {
    if (stream_ == nullptr) return slproto::Ok{};
    GError* error = nullptr;
    if (!control_lost_.load()) arv_camera_stop_acquisition(camera_, &error);
    g_clear_error(&error);
    release_stream();
    return slproto::Ok{};
  }

  Result<Frame> wait_frame(Nanos timeout_ns) override {
    if (stream_ == nullptr) return fail(Errc::invalid_argument, "wait_frame() while not streaming");
    const auto timeout_us = static_cast<guint64>(std::max<Nanos>(timeout_ns, 0) / kMicro);
    ArvBuffer* buffer = arv_stream_timeout_pop_buffer(stream_, timeout_us);
    if (buffer == nullptr) {
      // Is the camera still there? A register read costs a round trip on the sequencer's
      // thread, so only once nothing was heard from the camera for a while (a healthy scan's
      // short polls between triggers never pay for it).
      if (control_lost_.load() || monotonic_now_ns() - last_alive_ns_ > 250 * kMilli) {
        if (auto gone = check_present(); !gone) return gone.error();
        last_alive_ns_ = monotonic_now_ns();
      }
      std::string why;
      if (trigger_mode_ == TriggerMode::external) {
        why = ": no trigger on " + options_.trigger_input + " (" + options_.trigger_activation +
              ")? check the wiring from the projector's TRIG_OUT_1 (docs/hardware.md)";
      } else if (trigger_mode_ == TriggerMode::software) {
        why = ": the software trigger brought no frame";
      }
      return fail(Errc::timeout, "no frame within " + std::to_string(timeout_ns / kMilli) + " ms" + why);
    }
    Frame frame;
    frame.dequeued_ns = monotonic_now_ns();
    last_alive_ns_ = frame.dequeued_ns;
    const ArvBufferStatus status = arv_buffer_get_status(buffer);
    const std::uint64_t sequence = ids_.next(arv_buffer_get_frame_id(buffer));
    if (status != ARV_BUFFER_STATUS_SUCCESS) {
      arv_stream_push_buffer(stream_, buffer);
      return fail(Errc::hardware, "frame " + std::to_string(sequence) + " was lost: " + buffer_status_text(status));
    }
    const int width = arv_buffer_get_image_width(buffer);
    const int height = arv_buffer_get_image_height(buffer);
    if (width != format_.width || height != format_.height) {
      arv_stream_push_buffer(stream_, buffer);
      return fail(Errc::hardware, "frame " + std::to_string(sequence) + " is " + std::to_string(width) + " x " +
                                      std::to_string(height) + ", not the " + std::to_string(format_.width) + " x " +
                                      std::to_string(format_.height) + " set");
    }
    size_t size = 0;
    const auto* data = static_cast<const std::uint8_t*>(arv_buffer_get_image_data(buffer, &size));
    frame.format = format_;
    frame.sequence = sequence;
    frame.pixels.resize(format_.frame_bytes());
    auto unpacked = genicam_unpack(wire_, data, size, width, height, frame.pixels.data());
    const std::int64_t device_ns = static_cast<std::int64_t>(arv_buffer_get_timestamp(buffer));
    arv_stream_push_buffer(stream_, buffer);
    if (!unpacked) return fail(Errc::hardware, "frame " + std::to_string(sequence) + ": " + unpacked.error().message);
    map_times(device_ns, frame);
    return frame;
  }

  CameraLinkStats link_stats() const override {
    CameraLinkStats s = closed_streams_;
    if (stream_ != nullptr) add_stream_stats(stream_, s);
    return s;
  }

  std::vector<CameraDetail> check_details() const override {
    std::vector<CameraDetail> out;
    std::vector<std::string> formats;
    {
      GError* error = nullptr;
      guint n = 0;
      const char** names = arv_camera_dup_available_pixel_formats_as_strings(camera_, &n, &error);
      g_clear_error(&error);
      if (names != nullptr) {
        for (guint i = 0; i < n; ++i) formats.emplace_back(names[i]);
        g_free(names);
      }
    }
    GError* error = nullptr;
    double elo = 0, ehi = 0;
    arv_camera_get_exposure_time_bounds(camera_, &elo, &ehi, &error);
    const std::string exposure = error == nullptr ? std::to_string(static_cast<long long>(elo)) + ".." +
                                                        std::to_string(static_cast<long long>(ehi)) + " us"
                                                  : "none";
    g_clear_error(&error);
    gint wmax = 0, hmax = 0, lo = 0;
    arv_camera_get_width_bounds(camera_, &lo, &wmax, &error);
    g_clear_error(&error);
    arv_camera_get_height_bounds(camera_, &lo, &hmax, &error);
    g_clear_error(&error);
    std::string gain = has_feature(camera_, "Gain")      ? "Gain (dB)"
                       : has_feature(camera_, "GainRaw") ? "GainRaw only"
                                                         : "none";
    const std::vector<std::string> sources = enumeration(camera_, "TriggerSource");
    out.push_back({"camera features", "pixel formats " + join(formats) + "; sensor up to " + std::to_string(wmax) +
                                          " x " + std::to_string(hmax) + "; exposure " + exposure + "; gain " + gain +
                                          "; trigger sources " + (sources.empty() ? "none" : join(sources)) +
                                          "; timestamp latch " + (latch_feature() != nullptr ? "yes" : "no")});
    if (gige_) {
      const guint packet = arv_camera_gv_get_packet_size(camera_, &error);
      g_clear_error(&error);
      const auto [iface, speed] = host_interface_for(interface_address_);
      std::string link = "GigE Vision at " + address_ + " via " + (iface.empty() ? interface_address_ : iface) +
                         "; packet size " + std::to_string(packet) + " B; link speed ";
      if (has_feature(camera_, "GevLinkSpeed")) {
        link += std::to_string(arv_camera_get_integer(camera_, "GevLinkSpeed", &error)) + " Mb/s (camera)";
        g_clear_error(&error);
      } else if (speed > 0) {
        link += std::to_string(speed) + " Mb/s (host port)";
      } else {
        link += "unknown (neither the camera nor the host port reports one)";
      }
      out.push_back({"camera link", link});
    } else {
      out.push_back({"camera link", "USB3 Vision (" + id_ + ")"});
    }
    return out;
  }

 private:
  slproto::Error fail(Errc code, const std::string& message) const {
    return make_error(code, describe() + ": " + message);
  }

  // A camera that stopped answering is reported as gone, whatever the operation was.
  slproto::Error gone_or(Errc code, const std::string& message) {
    if (auto gone = check_present(); !gone) return gone.error();
    return fail(code, message);
  }

  Status check_present() {
    if (!control_lost_.load()) {
      // One register read: a camera that is unplugged or powered off fails it within the
      // GVCP timeout and retries (about a second).
      if (!gige_) return slproto::Ok{};
      guint32 value = 0;
      GError* error = nullptr;
      if (arv_device_read_register(arv_camera_get_device(camera_), 0x0 /* GigE Vision version */, &value, &error)) {
        return slproto::Ok{};
      }
      g_clear_error(&error);
      control_lost_.store(true);
    }
    return fail(Errc::disconnected,
                "the camera stopped answering (control channel lost): check its power and network cable, and that "
                "its IP address did not change");
  }

  static void add_stream_stats(ArvStream* stream, CameraLinkStats& s) {
    guint64 completed = 0, failures = 0, underruns = 0;
    arv_stream_get_statistics(stream, &completed, &failures, &underruns);
    s.frames_completed += completed;
    s.frames_failed += failures;
    s.underruns += underruns;
    if (ARV_IS_GV_STREAM(stream)) {
      s.packets_missing += arv_stream_get_info_uint64_by_name(stream, "n_missing_packets");
      s.packets_resent += arv_stream_get_info_uint64_by_name(stream, "n_resent_packets");
      s.resend_requests += arv_stream_get_info_uint64_by_name(stream, "n_resend_requests");
    }
  }

  void release_stream() {
    if (stream_ == nullptr) return;
    add_stream_stats(stream_, closed_streams_);
    g_object_unref(stream_);
    stream_ = nullptr;
  }

  const char* latch_feature() const {
    if (has_feature(camera_, "TimestampLatch") && has_feature(camera_, "TimestampLatchValue")) return "TimestampLatch";
    if (has_feature(camera_, "GevTimestampControlLatch") && has_feature(camera_, "GevTimestampValue"))
      return "GevTimestampControlLatch";
    return nullptr;
  }

  // The camera's clock against ours, by latching its counter between two monotonic reads.
  void calibrate_clock() {
    mapping_ = {};
    const char* latch = latch_feature();
    if (latch == nullptr) return;
    const bool sfnc = std::string(latch) == "TimestampLatch";
    const char* value_feature = sfnc ? "TimestampLatchValue" : "GevTimestampValue";
    // Ticks to ns: SFNC timestamps are in ns; GigE Vision 1.x counts at GevTimestampTickFrequency.
    double ns_per_tick = 1.0;
    GError* error = nullptr;
    if (!sfnc && has_feature(camera_, "GevTimestampTickFrequency")) {
      const gint64 hz = arv_camera_get_integer(camera_, "GevTimestampTickFrequency", &error);
      if (error == nullptr && hz > 0) ns_per_tick = 1e9 / static_cast<double>(hz);
      g_clear_error(&error);
    }
    std::vector<ClockLatchSample> samples;
    for (int i = 0; i < 5; ++i) {
      ClockLatchSample s;
      s.monotonic_before_ns = monotonic_now_ns();
      arv_camera_execute_command(camera_, latch, &error);
      s.monotonic_after_ns = monotonic_now_ns();
      if (error != nullptr) {
        g_clear_error(&error);
        continue;
      }
      const gint64 ticks = arv_camera_get_integer(camera_, value_feature, &error);
      if (error != nullptr) {
        g_clear_error(&error);
        continue;
      }
      s.device_ns = static_cast<std::int64_t>(static_cast<double>(ticks) * ns_per_tick);
      samples.push_back(s);
    }
    if (auto m = clock_mapping_from_latches(samples)) mapping_ = *m;
  }

  // GenICam cameras stamp a frame at the start of its exposure (SFNC's convention; Aravis'
  // fake camera when it fills the image).
  void map_times(std::int64_t device_ns, Frame& frame) {
    Nanos start = 0;
    if (mapping_.kind == ClockMapping::Kind::latched) {
      start = device_ns + mapping_.device_to_monotonic_ns;
    } else if (device_ns != 0 && looks_like_wall_clock(device_ns, realtime_now_ns())) {
      mapping_.kind = ClockMapping::Kind::wall_clock;
      start = device_ns - realtime_offset_ns_;
    }
    // A mapping that puts the exposure after the frame arrived is wrong: report no time.
    if (start <= 0 || start > frame.dequeued_ns) return;
    frame.exposure_start_ns = start;
    frame.exposure_end_ns = start + exposure_ns_;
  }

  ArvCamera* camera_;
  AravisOptions options_;
  std::string id_, vendor_, model_, serial_, address_, interface_address_;
  bool gige_ = false;
  gulong control_lost_handler_ = 0;
  std::atomic<bool> control_lost_{false};
  ArvStream* stream_ = nullptr;
  CameraLinkStats closed_streams_;
  CameraFormat format_;
  GenicamWireFormat wire_ = GenicamWireFormat::mono8;
  TriggerMode trigger_mode_ = TriggerMode::free_run;
  Nanos exposure_ns_ = 0;
  bool packet_size_negotiated_ = false;
  FrameIdUnwrapper ids_;
  ClockMapping mapping_;
  Nanos realtime_offset_ns_ = 0;
  Nanos last_alive_ns_ = 0;  // the last frame or answered register read
};

}  // namespace

std::vector<std::string> list_aravis_cameras() {
  arv_update_device_list();
  std::vector<std::string> out;
  for (unsigned i = 0; i < arv_get_n_devices(); ++i) {
    auto text = [](const char* s) { return std::string(s != nullptr ? s : "?"); };
    out.push_back(text(arv_get_device_id(i)) + " (" + text(arv_get_device_vendor(i)) + " " +
                  text(arv_get_device_model(i)) + ", serial " + text(arv_get_device_serial_nbr(i)) + ") at " +
                  text(arv_get_device_address(i)) + " over " + text(arv_get_device_protocol(i)));
  }
  return out;
}

Result<std::unique_ptr<Camera>> open_aravis_camera(const AravisOptions& options) {
  arv_update_device_list();
  const unsigned n = arv_get_n_devices();
  std::string id;
  if (options.device == "auto") {
    if (n == 0) {
      return make_error(Errc::io_error,
                        "no GenICam camera found (Aravis searched GigE Vision and USB3 Vision): check the camera's "
                        "power, cable and IP address (docs/hardware.md)");
    }
    id = arv_get_device_id(0);
  } else {
    for (unsigned i = 0; i < n && id.empty(); ++i) {
      for (const char* candidate : {arv_get_device_id(i), arv_get_device_serial_nbr(i), arv_get_device_address(i),
                                    arv_get_device_physical_id(i)}) {
        if (candidate != nullptr && options.device == candidate) {
          id = arv_get_device_id(i);
          break;
        }
      }
    }
    if (id.empty()) id = options.device;  // an IP address on another subnet: Aravis asks it directly
  }
  GError* error = nullptr;
  ArvCamera* camera = arv_camera_new(id.c_str(), &error);
  if (camera == nullptr) {
    std::string found;
    for (const auto& line : list_aravis_cameras()) found += (found.empty() ? "" : "; ") + line;
    return make_error(Errc::io_error, "cannot open GenICam camera '" + options.device + "': " + take_error(error) +
                                          " (found: " + (found.empty() ? "none" : found) + ")");
  }
  return std::unique_ptr<Camera>(new AravisCamera(camera, options, id));
}

}  // namespace slscand::hal
