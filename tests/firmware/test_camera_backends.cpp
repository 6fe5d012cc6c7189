// V4L2 and libcamera backends: format negotiation, control mapping, timestamps and the errors
// for a device that is not there. No camera needed.
#include <gtest/gtest.h>

#include "slscand/hal/camera.hpp"
#if defined(SLSCAND_HAVE_V4L2)
#include <linux/videodev2.h>

#include "slscand/hal/v4l2/v4l2_camera.hpp"
#endif
#if defined(SLSCAND_HAVE_LIBCAMERA)
#include <libcamera/libcamera.h>

#include "slscand/hal/libcamera/libcamera_camera.hpp"
#endif

using namespace slscand;
using namespace slscand::hal;

TEST(PixelFormat, NamesRoundTrip) {
  for (PixelFormat f : {PixelFormat::mono8, PixelFormat::mono10, PixelFormat::mono12}) {
    auto parsed = parse_pixel_format(pixel_format_name(f));
    ASSERT_TRUE(parsed.ok());
    EXPECT_EQ(*parsed, f);
  }
  EXPECT_EQ(bytes_per_pixel(PixelFormat::mono8), 1);
  EXPECT_EQ(bytes_per_pixel(PixelFormat::mono12), 2);
  EXPECT_FALSE(parse_pixel_format("bayer").ok());
}

#if defined(SLSCAND_HAVE_V4L2)
TEST(V4l2, FormatAcceptedOnlyWhenExact) {
  CameraFormat wanted{1280, 1024, PixelFormat::mono10, 0};
  auto ok = v4l2_accept_format(wanted, {1280, 1024, V4L2_PIX_FMT_Y10, 2560 + 64});
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->stride_bytes, 2624u);
  EXPECT_EQ(ok->frame_bytes(), 2624u * 1024u);
  auto resized = v4l2_accept_format(wanted, {1280, 960, V4L2_PIX_FMT_Y10, 2560});
  ASSERT_FALSE(resized.ok());
  EXPECT_NE(resized.error().message.find("1280x960"), std::string::npos) << resized.error().message;
  EXPECT_NE(resized.error().message.find("Y10"), std::string::npos);
  auto converted = v4l2_accept_format(wanted, {1280, 1024, V4L2_PIX_FMT_GREY, 1280});
  ASSERT_FALSE(converted.ok());
  EXPECT_NE(converted.error().message.find("GREY"), std::string::npos);
  EXPECT_FALSE(v4l2_accept_format(wanted, {1280, 1024, V4L2_PIX_FMT_Y10, 1280}).ok());  // stride < row
  EXPECT_EQ(v4l2_fourcc_for(PixelFormat::mono8), V4L2_PIX_FMT_GREY);
  EXPECT_EQ(v4l2_fourcc_for(PixelFormat::mono12), V4L2_PIX_FMT_Y12);
}

TEST(V4l2, ExposureControlMapping) {
  const V4l2Control absolute{V4L2_CID_EXPOSURE_ABSOLUTE, 1, 5000, 1, 156, "Exposure (Absolute)"};
  const V4l2Control automatic{V4L2_CID_EXPOSURE_AUTO, 0, 3, 1, 3, "Auto Exposure"};
  auto uvc = v4l2_exposure_controls({automatic, absolute}, 8333);
  ASSERT_TRUE(uvc.ok()) << uvc.error().message;
  ASSERT_EQ(uvc->size(), 2u);
  EXPECT_EQ((*uvc)[0], std::make_pair(std::uint32_t{V4L2_CID_EXPOSURE_AUTO}, std::int32_t{V4L2_EXPOSURE_MANUAL}));
  EXPECT_EQ((*uvc)[1], std::make_pair(std::uint32_t{V4L2_CID_EXPOSURE_ABSOLUTE}, std::int32_t{83}));  // 100 us units
  auto too_long = v4l2_exposure_controls({absolute}, 1e6);
  ASSERT_FALSE(too_long.ok());
  EXPECT_NE(too_long.error().message.find("[1, 5000]"), std::string::npos) << too_long.error().message;

  const V4l2Control lines{V4L2_CID_EXPOSURE, 4, 1100, 1, 1000, "Exposure"};
  EXPECT_FALSE(v4l2_exposure_controls({lines}, 8333).ok());  // line time unknown
  auto sensor = v4l2_exposure_controls({lines}, 8333, 14.5);
  ASSERT_TRUE(sensor.ok()) << sensor.error().message;
  EXPECT_EQ((*sensor)[0].second, 575);  // 8333 / 14.5 = 574.7
  auto none = v4l2_exposure_controls({}, 8333);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().code, slproto::Errc::unsupported);
}

TEST(V4l2, GainAndTriggerControls) {
  const V4l2Control analogue{V4L2_CID_ANALOGUE_GAIN, 16, 256, 1, 16, "Analogue Gain"};
  auto doubled = v4l2_gain_controls({analogue}, 2.0);
  ASSERT_TRUE(doubled.ok());
  EXPECT_EQ((*doubled)[0].second, 32);
  EXPECT_FALSE(v4l2_gain_controls({analogue}, 100.0).ok());
  EXPECT_TRUE(v4l2_gain_controls({}, 1.0).ok());   // nothing to do
  EXPECT_FALSE(v4l2_gain_controls({}, 2.0).ok());  // asked for gain, none available
  const V4l2Control trigger{0x009a2001, 0, 1, 1, 0, "Trigger Mode"};
  const std::vector<V4l2Control> with_trigger{analogue, trigger};
  ASSERT_NE(v4l2_find_trigger_control(with_trigger), nullptr);
  EXPECT_EQ(v4l2_find_trigger_control(with_trigger)->id, 0x009a2001u);
  EXPECT_EQ(v4l2_find_trigger_control({analogue}), nullptr);
}

TEST(V4l2, FrameTimesFromBufferFlags) {
  const Nanos exposure = 8333 * kMicro;
  auto soe = v4l2_frame_times(V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_SOE, 12, 500, exposure);
  ASSERT_TRUE(soe.ok());
  EXPECT_EQ(soe->exposure_start_ns, 12 * kSecond + 500 * kMicro);
  EXPECT_EQ(soe->exposure_end_ns, soe->exposure_start_ns + exposure);
  auto eof = v4l2_frame_times(V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_EOF, 12, 500, exposure);
  ASSERT_TRUE(eof.ok());
  EXPECT_EQ(eof->exposure_end_ns, 12 * kSecond + 500 * kMicro);
  EXPECT_EQ(eof->exposure_start_ns, eof->exposure_end_ns - exposure);
  EXPECT_FALSE(v4l2_frame_times(V4L2_BUF_FLAG_TIMESTAMP_COPY, 12, 500, exposure).ok());
}

TEST(V4l2, MissingOrWrongDeviceIsAClearError) {
  auto missing = open_v4l2_camera("/dev/video99");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("/dev/video99"), std::string::npos);
  EXPECT_NE(missing.error().message.find("No such file"), std::string::npos) << missing.error().message;
  auto not_v4l2 = open_v4l2_camera("/dev/null");
  ASSERT_FALSE(not_v4l2.ok());
  EXPECT_NE(not_v4l2.error().message.find("not a V4L2 device"), std::string::npos) << not_v4l2.error().message;
}
#endif

#if defined(SLSCAND_HAVE_LIBCAMERA)
TEST(Libcamera, PixelFormats) {
  EXPECT_EQ(libcamera_pixel_format_for(PixelFormat::mono8), libcamera::formats::R8);
  EXPECT_EQ(libcamera_pixel_format_for(PixelFormat::mono10), libcamera::formats::R10);
  EXPECT_EQ(libcamera_pixel_format_for(PixelFormat::mono12), libcamera::formats::R12);
}

TEST(Libcamera, RequestControls) {
  auto controls = libcamera_request_controls({8333, 2.0, 16667});
  ASSERT_TRUE(controls.ok()) << controls.error().message;
  const libcamera::ControlList& list = **controls;
  EXPECT_EQ(list.get(libcamera::controls::AeEnable).value_or(true), false);
  EXPECT_EQ(list.get(libcamera::controls::ExposureTime).value_or(0), 8333);
  EXPECT_FLOAT_EQ(list.get(libcamera::controls::AnalogueGain).value_or(0.f), 2.0f);
  auto limits = list.get(libcamera::controls::FrameDurationLimits);
  ASSERT_TRUE(limits.has_value());
  EXPECT_EQ((*limits)[0], 16667);
  EXPECT_EQ((*limits)[1], 16667);
  auto free_period = libcamera_request_controls({8333, 1.0, 0});
  ASSERT_TRUE(free_period.ok());
  EXPECT_FALSE((*free_period)->get(libcamera::controls::FrameDurationLimits).has_value());
  EXPECT_FALSE(libcamera_request_controls({0, 1.0, 0}).ok());
  EXPECT_FALSE(libcamera_request_controls({8333, 0.5, 0}).ok());
  auto short_period = libcamera_request_controls({8333, 1.0, 5000});
  ASSERT_FALSE(short_period.ok());
  EXPECT_NE(short_period.error().message.find("shorter than the exposure"), std::string::npos);
  EXPECT_EQ(libcamera_version_string().substr(0, 2), "0.");
}

TEST(Libcamera, MissingCameraIsAClearError) {
  auto camera = open_libcamera_camera("/base/no/such/camera");
  ASSERT_FALSE(camera.ok());
  EXPECT_NE(camera.error().message.find("/base/no/such/camera"), std::string::npos) << camera.error().message;
}
#endif
