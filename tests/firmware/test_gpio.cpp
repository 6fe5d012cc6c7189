// GPIO: request validation, the libgpiod request building (v1 or v2, whichever this build
// has) and the errors for a chip that is not there.
#include <gtest/gtest.h>

#include "slscand/hal/gpio.hpp"
#if defined(SLSCAND_HAVE_GPIOD)
#include <gpiod.h>

#include "slscand/hal/gpiod/gpiod_chip.hpp"
#endif

using namespace slscand::hal;

namespace {
LineRequestConfig projector_request() {
  LineRequestConfig config;
  config.consumer = "test";
  config.lines = {{17, LineDirection::output, false, EdgeDetection::none, false, "left.trig_in_1"},
                  {27, LineDirection::output, true, EdgeDetection::none, false, "left.trig_in_2"},
                  {22, LineDirection::input, false, EdgeDetection::both, false, "left.trig_out_1"},
                  {5, LineDirection::input, false, EdgeDetection::rising, true, "strobe"}};
  return config;
}
}  // namespace

TEST(LineRequestConfig, ChecksDuplicatesAndEdgesOnOutputs) {
  EXPECT_TRUE(projector_request().check().ok());
  LineRequestConfig duplicate = projector_request();
  duplicate.lines[1].offset = 17;
  auto s = duplicate.check();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("left.trig_in_2 (line 17) is requested twice"), std::string::npos)
      << s.error().message;
  LineRequestConfig edge_on_output = projector_request();
  edge_on_output.lines[0].edges = EdgeDetection::rising;
  ASSERT_FALSE(edge_on_output.check().ok());
  EXPECT_FALSE(LineRequestConfig{}.check().ok());
  EXPECT_EQ(projector_request().find(22)->name, "left.trig_out_1");
  EXPECT_EQ(projector_request().find(99), nullptr);
}

TEST(GpioChipPath, Names) {
  EXPECT_EQ(gpio_chip_path("gpiochip0"), "/dev/gpiochip0");
  EXPECT_EQ(gpio_chip_path("/dev/gpiochip3"), "/dev/gpiochip3");
}

#if defined(SLSCAND_HAVE_GPIOD)
TEST(Gpiod, ChipSpec) {
  EXPECT_EQ(parse_gpiod_chip_spec("gpiochip2").path, "/dev/gpiochip2");
  EXPECT_EQ(parse_gpiod_chip_spec("4").path, "/dev/gpiochip4");
  EXPECT_EQ(parse_gpiod_chip_spec("/dev/gpiochip1").path, "/dev/gpiochip1");
  EXPECT_EQ(parse_gpiod_chip_spec("pinctrl-rp1").label, "pinctrl-rp1");
  EXPECT_TRUE(parse_gpiod_chip_spec("pinctrl-rp1").path.empty());
}

TEST(Gpiod, MissingChipIsAClearError) {
  auto chip = open_gpiod_chip("gpiochip99");
  ASSERT_FALSE(chip.ok());
  EXPECT_EQ(chip.error().code, slproto::Errc::io_error);
  EXPECT_NE(chip.error().message.find("/dev/gpiochip99"), std::string::npos) << chip.error().message;
  EXPECT_NE(chip.error().message.find("No such file"), std::string::npos) << chip.error().message;
  auto by_label = open_gpiod_chip("no-such-label");
  ASSERT_FALSE(by_label.ok());
  EXPECT_NE(by_label.error().message.find("no-such-label"), std::string::npos);
  EXPECT_FALSE(open_gpiod_chip("").ok());
}

#if SLSCAND_GPIOD_API == 1
TEST(GpiodV1, RequestTypesAndFlags) {
  const LineRequestConfig config = projector_request();
  EXPECT_EQ(gpiod_v1_request_for(config.lines[0]).request_type, GPIOD_LINE_REQUEST_DIRECTION_OUTPUT);
  EXPECT_EQ(gpiod_v1_request_for(config.lines[0]).flags, 0);
  EXPECT_EQ(gpiod_v1_request_for(config.lines[2]).request_type, GPIOD_LINE_REQUEST_EVENT_BOTH_EDGES);
  EXPECT_EQ(gpiod_v1_request_for(config.lines[3]).request_type, GPIOD_LINE_REQUEST_EVENT_RISING_EDGE);
  EXPECT_EQ(gpiod_v1_request_for(config.lines[3]).flags, GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW);
  LineSettings plain_input{9, LineDirection::input, false, EdgeDetection::none, false, "in"};
  EXPECT_EQ(gpiod_v1_request_for(plain_input).request_type, GPIOD_LINE_REQUEST_DIRECTION_INPUT);
  plain_input.edges = EdgeDetection::falling;
  EXPECT_EQ(gpiod_v1_request_for(plain_input).request_type, GPIOD_LINE_REQUEST_EVENT_FALLING_EDGE);
}
#else
TEST(GpiodV2, LineConfigCarriesEverySetting) {
  auto config = gpiod_v2_line_config(projector_request());
  ASSERT_TRUE(config.ok()) << config.error().message;
  EXPECT_EQ(gpiod_line_config_get_num_configured_offsets(config->get()), 4u);
  auto settings_of = [&](unsigned offset) { return gpiod_line_config_get_line_settings(config->get(), offset); };
  gpiod_line_settings* out = settings_of(27);
  ASSERT_NE(out, nullptr);
  EXPECT_EQ(gpiod_line_settings_get_direction(out), GPIOD_LINE_DIRECTION_OUTPUT);
  EXPECT_EQ(gpiod_line_settings_get_output_value(out), GPIOD_LINE_VALUE_ACTIVE);
  gpiod_line_settings_free(out);
  gpiod_line_settings* in = settings_of(22);
  ASSERT_NE(in, nullptr);
  EXPECT_EQ(gpiod_line_settings_get_direction(in), GPIOD_LINE_DIRECTION_INPUT);
  EXPECT_EQ(gpiod_line_settings_get_edge_detection(in), GPIOD_LINE_EDGE_BOTH);
  EXPECT_EQ(gpiod_line_settings_get_event_clock(in), GPIOD_LINE_CLOCK_MONOTONIC);
  gpiod_line_settings_free(in);
  gpiod_line_settings* strobe = settings_of(5);
  ASSERT_NE(strobe, nullptr);
  EXPECT_TRUE(gpiod_line_settings_get_active_low(strobe));
  EXPECT_EQ(gpiod_line_settings_get_edge_detection(strobe), GPIOD_LINE_EDGE_RISING);
  gpiod_line_settings_free(strobe);
  LineRequestConfig bad = projector_request();
  bad.lines[1].offset = 17;
  EXPECT_FALSE(gpiod_v2_line_config(bad).ok());
}
#endif
#endif
