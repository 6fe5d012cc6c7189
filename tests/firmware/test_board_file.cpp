// Board files: the shipped ones load; a missing, mistyped, unknown or contradictory field is
// refused with a message naming it.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>
#include <string>

#include "slscand/hal/board.hpp"

using slscand::hal::BoardConfig;
using slscand::hal::CameraTriggerSource;
using slscand::hal::load_board;
using slscand::hal::parse_board;

namespace {

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

const std::string kSimPath = std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml";

// A shipped board file with one line replaced (or removed when `replacement` is empty).
std::string board_with(const std::string& path, const std::string& line_start, const std::string& replacement) {
  std::istringstream in(read_text(path));
  std::string out, line;
  bool found = false;
  while (std::getline(in, line)) {
    if (!found && line.rfind(line_start, 0) == 0) {
      found = true;
      if (!replacement.empty()) out += replacement + "\n";
      continue;
    }
    out += line + "\n";
  }
  EXPECT_TRUE(found) << "no line starting with '" << line_start << "' in " << path;
  return out;
}

std::string sim_with(const std::string& line_start, const std::string& replacement) {
  return board_with(kSimPath, line_start, replacement);
}

std::string error_of(const std::string& text) {
  auto board = parse_board(text, "test.toml");
  EXPECT_FALSE(board.ok());
  return board ? std::string() : board.error().message;
}

}  // namespace

TEST(BoardFile, ShippedBoardsLoad) {
  for (const char* name : {"sim", "rpi", "beaglebone-black", "rpi-gige", "sim-gige"}) {
    auto board = load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/" + name + ".toml");
    ASSERT_TRUE(board.ok()) << name << ": " << board.error().message;
    EXPECT_EQ(board->name, name);
    EXPECT_TRUE(board->check().ok());
  }
}

TEST(BoardFile, SimBoardValues) {
  auto board = load_board(kSimPath);
  ASSERT_TRUE(board.ok()) << board.error().message;
  EXPECT_TRUE(board->is_sim());
  EXPECT_EQ(board->bind_address, "127.0.0.1");  // loopback by default
  EXPECT_EQ(board->projectors[0].trig_in_1, 17u);
  EXPECT_EQ(board->projectors[1].trig_out_1, 25u);
  EXPECT_EQ(board->camera_format.width, 640);
  EXPECT_EQ(board->trigger_source, CameraTriggerSource::projector);
  EXPECT_FALSE(board->camera_trigger_line.has_value());
  EXPECT_DOUBLE_EQ(board->pattern_period_us, 5000);
}

TEST(BoardFile, GpioTriggerBoardHasItsLine) {
  auto board = load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/beaglebone-black.toml");
  ASSERT_TRUE(board.ok()) << board.error().message;
  EXPECT_EQ(board->trigger_source, CameraTriggerSource::gpio);
  ASSERT_TRUE(board->camera_trigger_line.has_value());
  EXPECT_EQ(*board->camera_trigger_line, 28u);
}

TEST(BoardFile, GigeBoardNamesTheCameraInputAndWindow) {
  auto board = load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/rpi-gige.toml");
  ASSERT_TRUE(board.ok()) << board.error().message;
  EXPECT_EQ(board->camera_backend, "aravis");
  EXPECT_EQ(board->trigger_source, CameraTriggerSource::gpio);
  EXPECT_EQ(*board->camera_trigger_line, 16u);
  EXPECT_EQ(board->camera_trigger_input, "Line0");
  EXPECT_EQ(board->camera_trigger_activation, "RisingEdge");
  EXPECT_EQ(board->camera_format.width, 2464);
  EXPECT_EQ(board->camera_format.height, 2056);
  EXPECT_EQ(board->camera_packet_size, 8192);
  auto bench = load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/sim-gige.toml");
  ASSERT_TRUE(bench.ok()) << bench.error().message;
  EXPECT_TRUE(bench->is_sim());
  EXPECT_EQ(bench->trigger_source, CameraTriggerSource::software);
}

TEST(BoardFile, GenicamFieldsAndSoftwareTriggerAreCheckedAgainstTheBackend) {
  // The software trigger exists only in the Aravis backend.
  EXPECT_NE(
      error_of(sim_with("trigger = \"projector\"", "trigger = \"software\"")).find("needs camera.backend = \"aravis\""),
      std::string::npos);
  // GenICam-only fields on another backend are a mistake, not a silent no-op.
  EXPECT_NE(error_of(sim_with("readout_us = 1500", "readout_us = 1500\ntrigger_input = \"Line1\""))
                .find("'camera.trigger_input' applies to camera.backend = \"aravis\" only"),
            std::string::npos);
  // A real camera among the virtual devices only when triggered in software.
  const std::string bench = std::string(SLSCAN_SOURCE_DIR) + "/boards/sim-gige.toml";
  const std::string projector_triggered = error_of(board_with(bench, "trigger = ", "trigger = \"projector\""));
  EXPECT_NE(projector_triggered.find("go together"), std::string::npos) << projector_triggered;
  auto edit = [&](const std::string& line_start, const std::string& to) {
    return error_of(board_with(bench, line_start, to));
  };
  EXPECT_NE(edit("buffers = 8", "buffers = 1").find("camera.buffers must be in 2..64"), std::string::npos);
  EXPECT_NE(edit("buffers = 8", "buffers = 8\ntrigger_activation = \"Rising\"").find("camera.trigger_activation"),
            std::string::npos);
  EXPECT_NE(edit("buffers = 8", "buffers = 8\npacket_size = 100").find("camera.packet_size"), std::string::npos);
  EXPECT_NE(edit("buffers = 8", "buffers = 8\noffset_x = -2").find("must not be negative"), std::string::npos);
}

TEST(BoardFile, MissingFieldIsNamed) {
  EXPECT_NE(error_of(sim_with("trig_out_1 = 25", "")).find("missing field 'projector.right.trig_out_1'"),
            std::string::npos);
  EXPECT_NE(error_of(sim_with("device =", "")).find("'camera.device'"), std::string::npos);
  EXPECT_NE(error_of(sim_with("pattern_period_us", "")).find("'timing.pattern_period_us'"), std::string::npos);
}

TEST(BoardFile, LineUsedTwiceIsNamedWithBothFunctions) {
  const std::string message = error_of(sim_with("trig_in_1 = 23", "trig_in_1 = 17"));
  EXPECT_NE(message.find("GPIO line 17 is assigned twice"), std::string::npos) << message;
  EXPECT_NE(message.find("projector.left.trig_in_1"), std::string::npos) << message;
  EXPECT_NE(message.find("projector.right.trig_in_1"), std::string::npos) << message;
}

TEST(BoardFile, ContradictionsAreRefused) {
  // A trigger line while the projectors trigger the camera.
  EXPECT_NE(
      error_of(sim_with("trigger = ", "trigger = \"projector\"\ntrigger_line = 5")).find("camera.trigger_line is set"),
      std::string::npos);
  // gpio trigger without its line.
  EXPECT_NE(error_of(sim_with("trigger = ", "trigger = \"gpio\"")).find("needs camera.trigger_line"),
            std::string::npos);
  // gpio trigger on a projector's line.
  EXPECT_NE(error_of(sim_with("trigger = ", "trigger = \"gpio\"\ntrigger_line = 22")).find("assigned twice"),
            std::string::npos);
  // A period that cannot hold exposure + read-out.
  EXPECT_NE(error_of(sim_with("pattern_period_us", "pattern_period_us = 3000")).find("must exceed"), std::string::npos);
  // Mixing the sim camera with real GPIO.
  EXPECT_NE(error_of(sim_with("backend = \"sim\"", "backend = \"gpiod\"")).find("go together"), std::string::npos);
  // Below the DLP's minimum exposure.
  EXPECT_NE(error_of(sim_with("pattern_exposure_us", "pattern_exposure_us = 100")).find("235 us"), std::string::npos);
  // An exposure change that never applies (or applies "before" it is made).
  EXPECT_NE(error_of(sim_with("readout_us = 1500", "readout_us = 1500\nexposure_change_frames = 40"))
                .find("camera.exposure_change_frames must be within 0 to 16 frames (40)"),
            std::string::npos);
  EXPECT_NE(error_of(sim_with("readout_us = 1500", "readout_us = 1500\nexposure_change_frames = -1"))
                .find("camera.exposure_change_frames"),
            std::string::npos);
  auto board = slscand::hal::parse_board(sim_with("readout_us = 1500", "readout_us = 1500\nexposure_change_frames = 2"),
                                         "sim.toml");
  ASSERT_TRUE(board.ok()) << board.error().message;
  EXPECT_EQ(board->exposure_change_frames, 2);
}

TEST(BoardFile, WrongTypesAndUnknownKeysAreNamed) {
  EXPECT_NE(error_of(sim_with("width = 640", "width = \"640\"")).find("'camera.width' must be an integer"),
            std::string::npos);
  EXPECT_NE(error_of(sim_with("port = 7878", "port = 70000")).find("network.port"), std::string::npos);
  EXPECT_NE(error_of(sim_with("gain = 1.0", "gian = 1.0")).find("unknown field 'camera.gian'"), std::string::npos);
  EXPECT_NE(error_of(sim_with("pixel_format", "pixel_format = \"rgb24\"")).find("unknown pixel format 'rgb24'"),
            std::string::npos);
  EXPECT_NE(error_of(sim_with("trig_in_1 = 17", "trig_in_1 = -3")).find("must not be negative"), std::string::npos);
  EXPECT_NE(error_of(sim_with("projector_latency_us", "projector_latency_us = -1")).find("timing.projector_latency_us"),
            std::string::npos);
  // The projectors' latency is a [timing] figure of every board, no longer a [sim] one.
  EXPECT_NE(error_of(sim_with("camera_latency_us", "camera_latency_us = 5\nprojector_latency_us = 15"))
                .find("unknown field 'sim.projector_latency_us'"),
            std::string::npos);
}

TEST(BoardFile, SyntaxErrorHasLineNumber) {
  const std::string message = error_of("[board]\nname = \"x\"\n[network\n");
  EXPECT_NE(message.find("test.toml:3"), std::string::npos) << message;
}

TEST(BoardFile, MissingFileIsNamed) {
  auto board = load_board("/nonexistent/board.toml");
  ASSERT_FALSE(board.ok());
  EXPECT_NE(board.error().message.find("/nonexistent/board.toml"), std::string::npos);
}

TEST(BoardFile, HardwareBoardsNameTheirMissingAndContradictoryFields) {
  const std::string rpi = std::string(SLSCAN_SOURCE_DIR) + "/boards/rpi.toml";
  const std::string bbb = std::string(SLSCAN_SOURCE_DIR) + "/boards/beaglebone-black.toml";
  EXPECT_NE(error_of(board_with(rpi, "chip =", "")).find("missing field 'gpio.chip'"), std::string::npos);
  EXPECT_NE(error_of(board_with(rpi, "chip =", "chip = \"\"")).find("gpio.chip must name a GPIO chip"),
            std::string::npos);
  EXPECT_NE(error_of(board_with(rpi, "port = \"usb", "port = \"\"")).find("turntable.port must name"),
            std::string::npos);
  EXPECT_NE(error_of(board_with(rpi, "baud =", "")).find("missing field 'turntable.baud'"), std::string::npos);
  // The Pi's camera is triggered by the projectors: a board trigger line contradicts that.
  EXPECT_NE(error_of(board_with(rpi, "trigger =", "trigger = \"projector\"\ntrigger_line = 5"))
                .find("camera.trigger_line is set"),
            std::string::npos);
  // Real GPIO with the emulated turntable (or the virtual camera) cannot work.
  EXPECT_NE(error_of(board_with(rpi, "serial =", "serial = \"emulator\"")).find("go together"), std::string::npos);
  EXPECT_NE(error_of(board_with(rpi, "backend = \"gpiod\"", "backend = \"gpoid\""))
                .find("gpio.backend must be \"gpiod\" or \"sim\", not \"gpoid\""),
            std::string::npos);
  // The BeagleBone drives the camera trigger itself: without its line, or on a projector's line.
  EXPECT_NE(error_of(board_with(bbb, "trigger_line =", "")).find("needs camera.trigger_line"), std::string::npos);
  EXPECT_NE(error_of(board_with(bbb, "trigger_line =", "trigger_line = 12")).find("GPIO line 12 is assigned twice"),
            std::string::npos);
  // A lost table header moves its keys into the table above: named, not silently ignored.
  const std::string lost = error_of(board_with(bbb, "[timing]", ""));
  EXPECT_NE(lost.find("unknown field 'camera."), std::string::npos) << lost;  // e.g. camera.ack_timeout_ms
}
