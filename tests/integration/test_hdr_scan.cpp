// HDR end to end (docs/hdr.md), as a person runs it: `slscan demo` starts slscand on the sim
// board with the shiny blade (small rig, the rig's exact calibration) and scans it once at the
// default exposure and once with a bracket; the bracket must decode what the default exposure
// loses to clipping, report what each exposure gave, and reprocess to the same bytes. A bracket
// the board cannot run ends the scan with the value and the limit named, and writes no model.
// Auto-exposure (`--exposure auto`) meters first: on the shiny blade it picks a bracket that
// decodes what the default loses, on a matte sphere the board's own exposure alone; a time
// budget no scan fits is refused before anything is captured. A shorter fringe period
// (`--fringe-period-px 4`, docs/hdr.md "Interreflection") goes through slscand the same way: it
// decodes what the default period decodes, and its capture reprocesses to the same bytes with
// the calibration made with the default period; an odd period is refused naming the rule.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "processes.hpp"

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using nlohmann::json;
using slscan::testing::Finished;
using slscan::testing::read_text;
using slscan::testing::run;

struct Totals {
  std::size_t valid = 0, saturated = 0;
  std::size_t chosen_short = 0;  // HDR: decoded pixels taken from the short exposure
  bool has_exposures = false;
};

Totals decode_totals(const json& report) {
  Totals t;
  for (const json& view : report["scan"]["views"])
    for (const json& p : view["projectors"]) {
      t.valid += p["decode"]["valid"].get<std::size_t>();
      t.saturated += p["decode"]["saturated"].get<std::size_t>();
      if (!p.contains("exposures")) continue;
      t.has_exposures = true;
      std::size_t chosen = 0;
      for (const json& e : p["exposures"]) chosen += e["chosen"].get<std::size_t>();
      EXPECT_EQ(chosen, p["decode"]["valid"].get<std::size_t>()) << "the exposures' shares add up to the decode";
      t.chosen_short += p["exposures"][1]["chosen"].get<std::size_t>();
    }
  return t;
}

class HdrScan : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("slscan_hdr_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    // The mesh is not what this suite checks: leave it out to keep the runs short.
    std::ofstream(dir_ / "config.json") << R"({"mesh": {"enabled": false}})";
    single_ = new Finished(demo("single", {}));
    hdr_ = new Finished(demo("hdr", {"--exposure-bracket", "2000,250"}));
    auto_ = new Finished(demo("auto", {"--exposure", "auto"}));
  }
  static void TearDownTestSuite() {
    delete single_;
    delete hdr_;
    delete auto_;
    if (!keep_) fs::remove_all(dir_);
  }
  void TearDown() override {
    if (HasFailure() && !keep_) {
      keep_ = true;
      std::printf("keeping %s (logs, outputs) to look at\n", dir_.c_str());
    }
  }
  static Finished demo(const std::string& name, const std::vector<std::string>& extra,
                       const std::string& scene = "shiny_blade") {
    std::vector<std::string> args{SLSCAN_BIN,  "demo",
                                  "--small",   "--true-calibration",
                                  "--scene",   scene,
                                  "--slscand", SLSCAND_BIN,
                                  "--board",   std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml",
                                  "--config",  (dir_ / "config.json").string(),
                                  "--out",     (dir_ / name).string()};
    args.insert(args.end(), extra.begin(), extra.end());
    return run(args, dir_ / name, {}, 600s);
  }
  static json report(const std::string& name) { return json::parse(read_text(dir_ / name / "report.json")); }

  static inline fs::path dir_;
  static inline Finished* single_ = nullptr;
  static inline Finished* hdr_ = nullptr;
  static inline Finished* auto_ = nullptr;
  static inline bool keep_ = false;
};

TEST_F(HdrScan, TheBracketDecodesWhatTheDefaultExposureLosesToClipping) {
  ASSERT_EQ(single_->exit_code, 0) << single_->err;
  ASSERT_EQ(hdr_->exit_code, 0) << hdr_->err;
  const Totals single = decode_totals(report("single")), hdr = decode_totals(report("hdr"));
  EXPECT_FALSE(single.has_exposures);
  ASSERT_TRUE(hdr.has_exposures);
  // The shiny blade clips at the reference exposure (docs/virtual-rig.md: ~42 % of what each
  // projector lights on it); at 1/8 of it nearly nothing does.
  EXPECT_GT(single.saturated, 20000u);
  EXPECT_LT(hdr.saturated, single.saturated / 20);
  EXPECT_GT(hdr.valid, single.valid + single.saturated * 9 / 10);
  EXPECT_GT(hdr.chosen_short, single.saturated * 9 / 10);
  // More of the blade in the model (the clipped lobe is on the blade, not the platform).
  const json single_model = report("single")["scan"]["model"], hdr_model = report("hdr")["scan"]["model"];
  EXPECT_GT(hdr_model["points"].get<double>(), 1.3 * single_model["points"].get<double>());
}

TEST_F(HdrScan, ReprocessOfTheBracketedCaptureIsBitIdentical) {
  ASSERT_EQ(hdr_->exit_code, 0) << hdr_->err;
  const Finished re = run({SLSCAN_BIN, "--quiet", "reprocess", (dir_ / "hdr" / "capture.slcap").string(), "--calib",
                           (dir_ / "hdr" / "calibration.json").string(), "--config", (dir_ / "config.json").string(),
                           "--out", (dir_ / "re").string()},
                          dir_ / "reprocess", {}, 600s);
  ASSERT_EQ(re.exit_code, 0) << re.err;
  std::size_t compared = 0;
  for (const auto& entry : fs::recursive_directory_iterator(dir_ / "hdr")) {
    if (entry.path().extension() != ".ply") continue;
    const fs::path relative = fs::relative(entry.path(), dir_ / "hdr");
    ASSERT_TRUE(fs::exists(dir_ / "re" / relative)) << relative;
    EXPECT_TRUE(read_text(entry.path()) == read_text(dir_ / "re" / relative))
        << relative << " differs between the live scan and its reprocessing";
    ++compared;
  }
  EXPECT_GE(compared, 2u);
  // The same shares per exposure in both reports.
  const json live = report("hdr")["scan"]["views"],
             again = json::parse(read_text(dir_ / "re" / "report.json"))["scan"]["views"];
  ASSERT_EQ(live.size(), again.size());
  for (std::size_t v = 0; v < live.size(); ++v)
    for (std::size_t p = 0; p < 2; ++p)
      EXPECT_EQ(live[v]["projectors"][p]["exposures"], again[v]["projectors"][p]["exposures"]) << v << " " << p;
}

TEST_F(HdrScan, AShorterFringePeriodScansThroughTheBoardAndReprocessesToTheSameBytes) {
  // A matte sphere: nothing clips, so both periods see the same surface.
  const Finished default_period = demo("period8", {}, "sphere");
  ASSERT_EQ(default_period.exit_code, 0) << default_period.err;
  const Finished short_period = demo("period4", {"--fringe-period-px", "4"}, "sphere");
  ASSERT_EQ(short_period.exit_code, 0) << short_period.err;
  // Finer fringes lose some pixels to blur (on the small rig a 4-pixel period is 2.2 camera
  // pixels: 6 % fewer decode, on the wall and the far platform), but the model is the same.
  const Totals p8 = decode_totals(report("period8")), p4 = decode_totals(report("period4"));
  EXPECT_GT(static_cast<double>(p4.valid), 0.9 * static_cast<double>(p8.valid));
  const double points = report("period8")["scan"]["model"]["points"].get<double>();
  EXPECT_NEAR(report("period4")["scan"]["model"]["points"].get<double>(), points, 0.03 * points);
  // The calibration was made with the default period; the capture says 4, and is decoded so.
  const Finished re = run({SLSCAN_BIN, "--quiet", "reprocess", (dir_ / "period4" / "capture.slcap").string(), "--calib",
                           (dir_ / "period4" / "calibration.json").string(), "--config",
                           (dir_ / "config.json").string(), "--out", (dir_ / "period4_re").string()},
                          dir_ / "period4_reprocess", {}, 600s);
  ASSERT_EQ(re.exit_code, 0) << re.err;
  EXPECT_TRUE(read_text(dir_ / "period4" / "model.ply") == read_text(dir_ / "period4_re" / "model.ply"))
      << "model.ply differs between the live scan and its reprocessing";
  // An odd period cannot carry the complementary bit: refused before the scan, naming it.
  const Finished odd = demo("period5", {"--fringe-period-px", "5"}, "sphere");
  EXPECT_EQ(odd.exit_code, 1) << odd.err;  // a bad command line
  EXPECT_NE(odd.err.find("--fringe-period-px 5: pattern plan: the complementary bit needs an even period_px"),
            std::string::npos)
      << odd.err;
  EXPECT_FALSE(fs::exists(dir_ / "period5" / "capture.slcap"));
}

TEST_F(HdrScan, ABracketTheBoardCannotRunIsRefusedNamingTheValueAndTheLimit) {
  const Finished refused = demo("refused", {"--exposure-bracket", "2000,100"});
  EXPECT_NE(refused.exit_code, 0);
  EXPECT_NE(refused.err.find("exposure_bracket_us[1] = 100 is below the projector's 235 us minimum"), std::string::npos)
      << refused.err;
  EXPECT_NE(refused.err.find("refused by board 'sim'"), std::string::npos) << refused.err;
  // No outputs as if it had scanned (the capture records the request and the refusal).
  EXPECT_FALSE(fs::exists(dir_ / "refused" / "model.ply"));
  EXPECT_FALSE(fs::exists(dir_ / "refused" / "report.json"));
}

TEST_F(HdrScan, AutoExposureBracketsTheShinyBlade) {
  ASSERT_EQ(single_->exit_code, 0) << single_->err;
  ASSERT_EQ(auto_->exit_code, 0) << auto_->err;
  EXPECT_NE((auto_->out + auto_->err).find("metering the exposure: white and black at 8 exposures, 250 to 32000 us"),
            std::string::npos)
      << auto_->out << auto_->err;
  const json metered = report("auto")["auto_exposure"];
  ASSERT_TRUE(metered.is_object()) << report("auto").dump(1).substr(0, 2000);
  const auto exposures = metered["exposures_us"].get<std::vector<double>>();
  ASSERT_GE(exposures.size(), 2u) << metered.dump(1);
  EXPECT_LT(exposures.front(), 2000) << "the highlights need an exposure shorter than the board's";
  EXPECT_TRUE(metered["met"].get<bool>()) << metered.dump(1);
  EXPECT_LE(metered["saturated_share"].get<double>(), 0.01);
  EXPECT_EQ(metered["metered"].size(), 8u);
  // What the scan did: the bracket chosen, in the frames and in the decode.
  const Totals single = decode_totals(report("single")), automatic = decode_totals(report("auto"));
  ASSERT_TRUE(automatic.has_exposures);
  EXPECT_LT(automatic.saturated, single.saturated / 20);
  EXPECT_GT(automatic.valid, single.valid + single.saturated * 9 / 10);
  EXPECT_GT(report("auto")["scan"]["model"]["points"].get<double>(),
            1.3 * report("single")["scan"]["model"]["points"].get<double>());
}

TEST_F(HdrScan, AutoExposureKeepsAMattePartAtTheBoardsExposure) {
  const Finished matte = demo("auto_matte", {"--exposure", "auto"}, "sphere");
  ASSERT_EQ(matte.exit_code, 0) << matte.err;
  const json metered = report("auto_matte")["auto_exposure"];
  EXPECT_EQ(metered["exposures_us"], json::array({2000.0})) << metered.dump(1);
  EXPECT_TRUE(metered["met"].get<bool>()) << metered.dump(1);
  // One exposure: no bracket in the scan.
  for (const json& view : report("auto_matte")["scan"]["views"])
    for (const json& p : view["projectors"]) EXPECT_FALSE(p.contains("exposures"));
}

TEST_F(HdrScan, ATimeBudgetNoScanFitsIsRefusedBeforeCapturing) {
  const Finished refused = demo("budget", {"--exposure", "auto", "--time-budget-s", "0.5"});
  EXPECT_NE(refused.exit_code, 0);
  // 6 views x 2 projectors x 19 frames at >= 3235 us each: 0.74 s at least.
  EXPECT_NE(refused.err.find("--time-budget-s 0.5: too short for the scan at any exposure (228 frames"),
            std::string::npos)
      << refused.err;
  EXPECT_FALSE(fs::exists(dir_ / "budget" / "capture.slcap"));
  EXPECT_FALSE(fs::exists(dir_ / "budget" / "report.json"));
}

}  // namespace
