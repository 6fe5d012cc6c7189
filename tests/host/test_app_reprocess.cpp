// End to end on the host side, without the firmware: the virtual rig renders a small ball-bar
// scan, the frames are written as a capture file exactly as the host records them, and
// `reprocess` reconstructs it. Checks the ball bar against its true length, that two runs are
// bit-identical, and that a truncated capture reconstructs what it holds and says what is lost.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

#include "run.hpp"
#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/framing.hpp"
#include "slproto/zstd_codec.hpp"
#include "slrig/rig.hpp"
#include "slscan/core/measure.hpp"
#include "slscan/io/ply.hpp"
#include "slscan/session/batch.hpp"
#include "slscan/session/reprocess.hpp"

namespace slscan::app {
namespace {

namespace fs = std::filesystem;

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Writes a capture of `scene` as slscan scan would record it: the request, then each frame.
void write_capture(const slrig::Scene& scene, const std::string& path) {
  const slproto::PatternPlan plan(scene.pattern_plan);
  slproto::pb::ScanRequest request;
  request.set_scan_id(42);
  for (double angle : scene.view_angles_deg) request.add_turntable_angles_deg(angle);
  request.add_projectors(0);
  request.add_projectors(1);
  *request.mutable_plan() = slproto::to_proto(scene.pattern_plan);
  request.set_exposure_us(8333);
  request.set_pattern_period_us(10000);
  request.set_pixel_format(slproto::pb::PIXEL_FORMAT_MONO8);
  auto capture = slproto::CaptureWriter::create(path);
  ASSERT_TRUE(capture.ok()) << capture.error().message;
  auto bytes = slproto::encode(request);
  ASSERT_TRUE(bytes.ok());
  ASSERT_TRUE(capture->append(*bytes).ok());
  std::uint64_t sequence = 0;
  for (std::size_t view = 0; view < scene.view_angles_deg.size(); ++view) {
    const slrig::ViewRenderer renderer(scene, scene.view_angles_deg[view], static_cast<int>(view));
    std::vector<std::uint8_t> pixels(renderer.frame_bytes());
    for (std::uint32_t side = 0; side < 2; ++side)
      for (std::size_t pattern = 0; pattern < plan.size(); ++pattern) {
        renderer.render(static_cast<slproto::ProjectorSide>(side), pattern, pixels);
        slproto::pb::FrameHeader header;
        header.set_scan_id(42);
        header.set_view_index(static_cast<std::uint32_t>(view));
        header.set_commanded_angle_deg(scene.view_angles_deg[view]);
        header.set_reported_angle_deg(scene.view_angles_deg[view]);
        header.set_projector_id(side);
        header.set_pattern_index(static_cast<std::uint32_t>(pattern));
        header.set_sequence(sequence++);
        slproto::set_frame_geometry(header, static_cast<std::uint32_t>(renderer.width()),
                                    static_cast<std::uint32_t>(renderer.height()));
        const std::span<const std::byte> payload(reinterpret_cast<const std::byte*>(pixels.data()), pixels.size());
        header.set_payload_crc32c(slproto::crc32c(payload));
        std::vector<std::byte> record;
        ASSERT_TRUE(slproto::encode(header, payload, record).ok());
        ASSERT_TRUE(capture->append(record).ok());
      }
  }
  slproto::pb::ScanDone done;
  done.set_scan_id(42);
  done.set_frames_sent(sequence);
  auto done_bytes = slproto::encode(done);
  ASSERT_TRUE(capture->append(*done_bytes).ok());
  ASSERT_TRUE(capture->finish().ok());
}

class Reprocess : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("slscan_reprocess_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    auto scene = slrig::scene_preset("ballbar", slrig::RigSize::small);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    scene_ = new slrig::Scene(*scene);
    write_capture(*scene_, (dir_ / "scan.slcap").string());
    ASSERT_TRUE(
        slproto::save_calibration((dir_ / "calib.json").string(), slrig::ground_truth_calibration(*scene_)).ok());
    // The mesh has its own tests; here it would only cost time.
    std::ofstream(dir_ / "config.json") << R"({"mesh": {"enabled": false}})";
  }
  static void TearDownTestSuite() {
    delete scene_;
    fs::remove_all(dir_);
  }
  static ReprocessRequest request(const std::string& capture, const std::string& out) {
    return {capture, (dir_ / "calib.json").string(), (dir_ / out).string(), (dir_ / "config.json").string()};
  }
  static inline fs::path dir_;
  static inline slrig::Scene* scene_ = nullptr;
  Console console_{.quiet = true, .json_log = false};
};

TEST_F(Reprocess, BallBarMeasuresTrueAndRunsAreBitIdentical) {
  ASSERT_EQ(run_reprocess(request((dir_ / "scan.slcap").string(), "a"), console_), exit_ok);
  const auto report = nlohmann::json::parse(read_bytes(dir_ / "a" / "report.json"));
  ASSERT_EQ(report["scan"]["views"].size(), 6u);
  EXPECT_TRUE(report["scan"]["registration"]["applied"].get<bool>()) << report["scan"]["registration"].dump();
  for (const auto& view : report["scan"]["views"]) {
    EXPECT_GT(view["fusion"]["both"].get<std::size_t>(), 1000u);
    EXPECT_GT(view["turntable_denoise"]["below_min_height"].get<std::size_t>(), 1000u) << "the platform is removed";
    // The noise estimate of each projector-view and the limits it set (noise-adaptive by
    // default; the rig is quiet, so the fixed limits are the ones in force).
    for (const auto& projector : view["projectors"]) {
      EXPECT_GT(projector["noise"]["depth_mm"].get<double>(), 0.0) << projector.dump();
      EXPECT_LT(projector["noise"]["depth_mm"].get<double>(), 0.05) << projector.dump();
      EXPECT_GT(projector["noise"]["coordinate_px"].get<double>(), 0.0) << projector.dump();
      EXPECT_FLOAT_EQ(projector["noise"]["smoothing_max_deviation_px"].get<float>(), 0.25f);
    }
    EXPECT_EQ(view["limits"]["noise_factor"].get<double>(), 3.0);
    EXPECT_FLOAT_EQ(view["limits"]["flying_pixels_max_abs_mm"].get<float>(), 0.1f);
    EXPECT_FLOAT_EQ(view["limits"]["fusion_agreement_mm"].get<float>(), 0.2f);
  }
  const core::PointCloud model = io::read_ply((dir_ / "a" / "model.ply").string());
  ASSERT_GT(model.size(), 5000u);
  // Small rig (640 x 512, ~4x coarser pixels than the full rig): the ball bar's length within
  // 30 um and each diameter within 30 um of truth. The full-size figures are in docs/accuracy.md.
  core::BallBarOptions options;
  options.nominal_radii_mm = {scene_->objects[0].radius_a, scene_->objects[0].radius_b};
  const core::BallBarResult bar = core::measure_ball_bar(model, options);
  EXPECT_NEAR(bar.centre_distance_mm, 150.1164, 0.030);
  EXPECT_NEAR(bar.spheres[0].radius_mm, 15.0004, 0.015);
  EXPECT_NEAR(bar.spheres[1].radius_mm, 15.00075, 0.015);

  ASSERT_EQ(run_reprocess(request((dir_ / "scan.slcap").string(), "b"), console_), exit_ok);
  EXPECT_TRUE(read_bytes(dir_ / "a" / "model.ply") == read_bytes(dir_ / "b" / "model.ply"))
      << "two reprocessings of one capture differ";
}

// report.json and report.html say who ran what when, with which calibration (its hash, date and
// age) and capture (its hash), and report.html links every file of the run in the folder.
TEST_F(Reprocess, ReportsCarryProvenanceAndLinkEveryFileOfTheRun) {
  // The hash function itself against FIPS 180-2's "abc" vector.
  std::ofstream(dir_ / "abc.txt", std::ios::binary) << "abc";
  EXPECT_EQ(session::sha256_file((dir_ / "abc.txt").string()),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");

  const fs::path calibration = dir_ / "aged_calibration.json";
  fs::copy_file(dir_ / "calib.json", calibration, fs::copy_options::overwrite_existing);
  fs::last_write_time(calibration, fs::file_time_type::clock::now() - std::chrono::hours(3 * 24 + 12));
  // The capture in the output folder itself: linked with the rest.
  fs::create_directories(dir_ / "own");
  fs::copy_file(dir_ / "scan.slcap", dir_ / "own" / "capture.slcap", fs::copy_options::overwrite_existing);
  ReprocessRequest r = request((dir_ / "own" / "capture.slcap").string(), "own");
  r.calibration_path = calibration.string();
  r.part_id = "blade <17> & co";
  r.operator_name = "J. Doe";
  const std::time_t before = std::time(nullptr);
  ASSERT_EQ(run_reprocess(r, console_), exit_ok);
  const std::time_t after = std::time(nullptr);
  const fs::path out = dir_ / "own";
  const auto report = nlohmann::json::parse(read_bytes(out / "report.json"));

  EXPECT_EQ(report["run"]["command"], "reprocess");
  EXPECT_EQ(report["run"]["part_id"], "blade <17> & co");
  EXPECT_EQ(report["run"]["operator"], "J. Doe");
  const std::string started = report["run"]["started_utc"].get<std::string>();
  // ISO 8601 in UTC to the second (checked by hand: std::regex trips GCC 12's
  // -Wmaybe-uninitialized in the sanitizer build).
  const std::string form = "dddd-dd-ddTdd:dd:ddZ";
  ASSERT_EQ(started.size(), form.size()) << started;
  for (std::size_t i = 0; i < form.size(); ++i)
    ASSERT_TRUE(form[i] == 'd' ? std::isdigit(static_cast<unsigned char>(started[i])) != 0 : started[i] == form[i])
        << started;
  std::tm tm{};
  ASSERT_NE(::strptime(started.c_str(), "%Y-%m-%dT%H:%M:%SZ", &tm), nullptr);
  const std::time_t started_at = ::timegm(&tm);
  EXPECT_GE(started_at, before - 1);
  EXPECT_LE(started_at, after);
  EXPECT_EQ(report["software"]["slscan"].get<std::string>().empty(), false);

  const auto& cal = report["calibration"];
  EXPECT_EQ(cal["sha256"], session::sha256_file(calibration.string()));
  EXPECT_NEAR(cal["age_days"].get<double>(), 3.5, 0.1) << cal.dump();
  ASSERT_TRUE(cal.contains("file_utc"));
  std::tm written{};
  ASSERT_NE(::strptime(cal["file_utc"].get<std::string>().c_str(), "%Y-%m-%dT%H:%M:%SZ", &written), nullptr);
  EXPECT_NEAR(static_cast<double>(started_at - ::timegm(&written)), 3.5 * 86400, 60);
  EXPECT_EQ(report["capture"]["sha256"], session::sha256_file((out / "capture.slcap").string()));
  EXPECT_EQ(report["capture"]["in_folder"], "capture.slcap");

  // Every file in the folder is listed and linked, and every listed file is there.
  const auto& files = report["files"];
  std::set<std::string> listed;
  for (const auto& f : files) listed.insert(f.get<std::string>());
  const std::string html = read_bytes(out / "report.html");
  std::size_t on_disk = 0;
  for (const auto& entry : fs::recursive_directory_iterator(out)) {
    if (!entry.is_regular_file()) continue;
    ++on_disk;
    const std::string relative = fs::relative(entry.path(), out).generic_string();
    EXPECT_TRUE(listed.count(relative)) << relative << " is in the folder but not in report.json's files";
    EXPECT_NE(html.find("<a href=\"" + relative + "\">"), std::string::npos) << relative << " is not linked";
  }
  EXPECT_EQ(listed.size(), on_disk) << files.dump();
  for (const char* expected : {"capture.slcap", "model.ply", "views/view_0.ply", "report.json", "report.html"})
    EXPECT_TRUE(listed.count(expected)) << expected;
  EXPECT_NE(html.find("blade &lt;17&gt; &amp; co"), std::string::npos) << "the part id, escaped";
  EXPECT_NE(html.find("J. Doe"), std::string::npos);
  EXPECT_NE(html.find(cal["sha256"].get<std::string>()), std::string::npos);
  EXPECT_NE(html.find(report["capture"]["sha256"].get<std::string>()), std::string::npos);
  EXPECT_NE(html.find("3.5 days before the run"), std::string::npos);

  // A capture elsewhere is named, hashed, but not linked as a file of the folder.
  ASSERT_EQ(run_reprocess(request((dir_ / "scan.slcap").string(), "elsewhere"), console_), exit_ok);
  const auto other = nlohmann::json::parse(read_bytes(dir_ / "elsewhere" / "report.json"));
  EXPECT_EQ(other["capture"]["sha256"], report["capture"]["sha256"]);
  EXPECT_FALSE(other["capture"].contains("in_folder"));
  for (const auto& f : other["files"]) EXPECT_NE(f, "capture.slcap");
  EXPECT_EQ(other["run"]["part_id"], "");
}

// The albedo channel in the files a user opens: model.ply's points carry `intensity` (0..1 of
// full scale) and the grey red = green = blue = round(255 x intensity) that MeshLab and
// CloudCompare show; mesh.ply's vertices carry the intensity of the points around them; the
// readers (read_ply, as compare / inspect / measure use it) still read the model.
TEST_F(Reprocess, ModelAndMeshCarryTheAlbedo) {
  std::ofstream(dir_ / "mesh_config.json") << R"({"mesh": {"enabled": true}})";
  ReprocessRequest with_mesh = request((dir_ / "scan.slcap").string(), "albedo");
  with_mesh.config_path = (dir_ / "mesh_config.json").string();
  ASSERT_EQ(run_reprocess(with_mesh, console_), exit_ok);
  const io::PlyTable model = io::read_ply_table((dir_ / "albedo" / "model.ply").string());
  const auto& intensity = model.column("intensity");
  ASSERT_GT(intensity.size(), 5000u);
  std::vector<double> sorted = intensity;
  std::sort(sorted.begin(), sorted.end());
  for (std::size_t i = 0; i < intensity.size(); ++i) {
    ASSERT_GE(intensity[i], 0.0) << "point " << i;
    ASSERT_LE(intensity[i], 1.0) << "point " << i;
    const double grey = std::round(255 * intensity[i]);
    ASSERT_EQ(model.column("red")[i], grey) << "point " << i;
    ASSERT_EQ(model.column("green")[i], grey) << "point " << i;
    ASSERT_EQ(model.column("blue")[i], grey) << "point " << i;
  }
  // The ball bar is matte white-ish (albedo 0.8 on the rig): a lit point reads well above black.
  const double median = sorted[sorted.size() / 2];
  std::printf("model intensity: median %.3f, 1-99 %% %.3f..%.3f over %zu points\n", median, sorted[sorted.size() / 100],
              sorted[sorted.size() * 99 / 100], sorted.size());
  EXPECT_GT(median, 0.2);
  EXPECT_EQ(io::read_ply((dir_ / "albedo" / "model.ply").string()).intensity.size(), intensity.size());

  const io::PlyTable mesh = io::read_ply_table((dir_ / "albedo" / "mesh.ply").string());
  ASSERT_GT(mesh.faces.size(), 1000u);
  const auto& vertex_intensity = mesh.column("intensity");
  ASSERT_EQ(vertex_intensity.size(), mesh.vertex_count);
  std::vector<double> vertex_sorted = vertex_intensity;
  std::sort(vertex_sorted.begin(), vertex_sorted.end());
  EXPECT_GE(vertex_sorted.front(), sorted.front());
  EXPECT_LE(vertex_sorted.back(), sorted.back());
  const double vertex_median = vertex_sorted[vertex_sorted.size() / 2];
  std::printf("mesh vertex intensity: median %.3f over %zu vertices\n", vertex_median, vertex_sorted.size());
  EXPECT_NEAR(vertex_median, median, 0.1 * median);
  for (std::size_t i = 0; i < mesh.vertex_count; ++i)
    ASSERT_EQ(mesh.column("red")[i], std::round(255 * vertex_intensity[i])) << "vertex " << i;
}

TEST_F(Reprocess, CompressedCaptureReprocessesToTheSameOutputs) {
  if (slproto::zstd_codec() == nullptr) GTEST_SKIP() << slproto::zstd_codec_description();
  const fs::path packed = dir_ / "packed.slcap", back = dir_ / "back.slcap";
  ASSERT_EQ(run_convert({(dir_ / "scan.slcap").string(), packed.string(), true}, console_), exit_ok);
  EXPECT_LT(fs::file_size(packed), fs::file_size(dir_ / "scan.slcap"));
  // Lossless: converting back gives the recorded file byte for byte.
  ASSERT_EQ(run_convert({packed.string(), back.string(), false}, console_), exit_ok);
  EXPECT_TRUE(read_bytes(back) == read_bytes(dir_ / "scan.slcap"));
  ASSERT_EQ(run_reprocess(request((dir_ / "scan.slcap").string(), "raw"), console_), exit_ok);
  ASSERT_EQ(run_reprocess(request(packed.string(), "packed"), console_), exit_ok);
  for (const char* file : {"model.ply", "views/view_0.ply", "views/view_5.ply"})
    EXPECT_TRUE(read_bytes(dir_ / "raw" / file) == read_bytes(dir_ / "packed" / file)) << file;
  // Converting onto itself is refused instead of destroying the input.
  EXPECT_THROW((void)run_convert({packed.string(), packed.string(), false}, console_), io::IoError);
}

TEST_F(Reprocess, TruncatedCaptureReconstructsWhatItHolds) {
  const fs::path cut = dir_ / "cut.slcap";
  fs::copy_file(dir_ / "scan.slcap", cut, fs::copy_options::overwrite_existing);
  // Cut in the middle of view 5's frames: views 0-4 are complete.
  const auto size = fs::file_size(cut);
  fs::resize_file(cut, size - size / 12 - 1000);
  ASSERT_EQ(run_reprocess(request(cut.string(), "cut"), console_), exit_ok);
  const auto report = nlohmann::json::parse(read_bytes(dir_ / "cut" / "report.json"));
  EXPECT_TRUE(report["capture"].contains("truncated_at_byte"));
  EXPECT_FALSE(report["capture"]["complete"].get<bool>());
  EXPECT_FALSE(report["capture"]["missing"].empty());
  EXPECT_GE(report["scan"]["views"].size(), 5u);
}

// A capture that holds no complete projector-view (cut inside view 0's first projector) is an
// error naming the capture, not an empty model reported as success; nothing is written.
TEST_F(Reprocess, CaptureWithoutACompleteViewIsAnErrorNotAnEmptyModel) {
  const fs::path cut = dir_ / "stub.slcap";
  fs::copy_file(dir_ / "scan.slcap", cut, fs::copy_options::overwrite_existing);
  fs::resize_file(cut, fs::file_size(cut) / 30);  // a few frames of view 0, left projector
  try {
    (void)run_reprocess(request(cut.string(), "stub"), console_);
    FAIL() << "a capture without a complete view was reported as a success";
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find(cut.string()), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("no view has the complete frames"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(dir_ / "stub" / "model.ply"));
  EXPECT_FALSE(fs::exists(dir_ / "stub" / "report.json"));
}

TEST_F(Reprocess, CorruptCaptureAndWrongCalibrationAreRefusedClearly) {
  const fs::path bad = dir_ / "bad.slcap";
  fs::copy_file(dir_ / "scan.slcap", bad, fs::copy_options::overwrite_existing);
  {
    std::fstream f(bad, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(static_cast<std::streamoff>(fs::file_size(bad) / 2));
    f.put('\x5a');
    f.put('\xa5');
  }
  try {
    (void)run_reprocess(request(bad.string(), "bad"), console_);
    FAIL() << "a corrupt capture was reconstructed";
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("offset"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(dir_ / "bad" / "model.ply"));

  // A calibration made for another pattern plan (not only another fringe period, which the
  // calibration holds for: slscan scan --fringe-period-px).
  slproto::RigCalibration other = slrig::ground_truth_calibration(*scene_);
  other.pattern_plan.phase_steps = 4;
  ASSERT_TRUE(slproto::save_calibration((dir_ / "other.json").string(), other).ok());
  ReprocessRequest r = request((dir_ / "scan.slcap").string(), "other");
  r.calibration_path = (dir_ / "other.json").string();
  try {
    (void)run_reprocess(r, console_);
    FAIL() << "a capture was reconstructed with a calibration for another plan";
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("pattern plan"), std::string::npos) << e.what();
    // Names what differs, with both values, not only both plans.
    EXPECT_NE(std::string(e.what()).find("phase_steps 8 in the capture, 4 in the calibration"), std::string::npos)
        << e.what();
    EXPECT_EQ(std::string(e.what()).find("period_px"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(dir_ / "other" / "model.ply"));
}

TEST_F(Reprocess, CorruptCalibrationFileIsRefusedNamingFileAndField) {
  const std::string good = slproto::format_calibration(slrig::ground_truth_calibration(*scene_));
  struct Case {
    std::string name, text, expected;
  };
  std::string no_camera = good;
  no_camera.replace(no_camera.find("\"camera\""), 8, "\"kamera\"");
  const std::vector<Case> cases = {
      {"cut.json", good.substr(0, good.size() / 2), "not valid JSON"},
      {"empty.json", "", "not valid JSON"},
      {"no_camera.json", no_camera, "camera"},
      {"huge_number.json", "{\"camera\": 1e999999}", "not valid JSON"},
  };
  for (const Case& c : cases) {
    const fs::path path = dir_ / c.name;
    std::ofstream(path) << c.text;
    ReprocessRequest r = request((dir_ / "scan.slcap").string(), "corrupt_" + c.name);
    r.calibration_path = path.string();
    try {
      (void)run_reprocess(r, console_);
      ADD_FAILURE() << c.name << " was accepted as a calibration";
    } catch (const io::IoError& e) {
      EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(c.expected), std::string::npos) << c.name << ": " << e.what();
    }
    EXPECT_FALSE(fs::exists(dir_ / ("corrupt_" + c.name)));
  }
}

// Issue 17 case 2: camera.fx 1e20 (1e100, 1e308) parsed, passed check() and reprocessing died of
// SIGSEGV. The calibration file is refused naming the field; and the pipeline given such a
// calibration in memory (no file check between) ends in a clean error or a result, never a crash.
TEST_F(Reprocess, AbsurdCalibrationIsRefusedAndNeverCrashesThePipeline) {
  const slproto::RigCalibration truth = slrig::ground_truth_calibration(*scene_);
  for (const double fx : {1e20, 1e100, 1e308}) {
    slproto::RigCalibration absurd = truth;
    absurd.camera.fx = fx;
    const fs::path path = dir_ / "absurd.json";
    {
      std::ofstream out(path);
      out << slproto::format_calibration(absurd);
    }
    ReprocessRequest r = request((dir_ / "scan.slcap").string(), "absurd");
    r.calibration_path = path.string();
    try {
      (void)run_reprocess(r, console_);
      ADD_FAILURE() << "fx " << fx << " was accepted";
    } catch (const io::IoError& e) {
      EXPECT_NE(std::string(e.what()).find(path.string() + ": camera.fx: "), std::string::npos) << e.what();
    }
  }
  // The reconstruction checks the calibration it is given too (the same bounds).
  slproto::RigCalibration absurd = truth;
  absurd.camera.fx = 1e20;
  core::ReconstructionOptions options;
  options.build_mesh = false;
  try {
    (void)session::reprocess_capture((dir_ / "scan.slcap").string(), absurd, options, session::QuietLog());
    ADD_FAILURE() << "fx 1e20 was reconstructed with";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("camera.fx: 1e+20 px is not a focal length"), std::string::npos) << e.what();
  }
}

// Issue 17 case 6: --out naming an existing file was an internal error (exit 5).
TEST_F(Reprocess, OutputPathThatIsAFileIsRefusedNamingIt) {
  const fs::path file = dir_ / "a_file";
  std::ofstream(file) << "not a folder";
  try {
    (void)run_reprocess(request((dir_ / "scan.slcap").string(), "a_file"), console_);
    FAIL() << "--out naming a file was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "reprocess --out " + file.string() + ": exists and is not a folder");
  }
  EXPECT_EQ(read_bytes(file), "not a folder");

  // scan: refused before the scanner is asked for anything (port 1: nothing listens there).
  ScanCommand scan;
  scan.port = 1;
  scan.calibration_path = (dir_ / "calib.json").string();
  scan.output_dir = file.string();
  try {
    (void)run_scan(scan, console_);
    FAIL() << "scan --out naming a file was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "scan --out " + file.string() + ": exists and is not a folder");
  }
  scan.output_dir = (file / "sub").string();  // a folder that cannot be made: its parent is a file
  try {
    (void)run_scan(scan, console_);
    FAIL() << "scan --out that cannot be created was accepted";
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("scan --out " + scan.output_dir + ": cannot create the folder ("),
              std::string::npos)
        << e.what();
  }
  EXPECT_EQ(read_bytes(file), "not a folder");
}

}  // namespace
}  // namespace slscan::app
