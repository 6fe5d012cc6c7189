// HDR end to end (docs/hdr.md), as a person runs it: `slscan demo` starts slscand on the sim
// board with the shiny blade (small rig, the rig's exact calibration) and scans it once at the
// default exposure and once with a bracket; the bracket must decode what the default exposure
// loses to clipping, report what each exposure gave, and reprocess to the same bytes. A bracket
// the board cannot run ends the scan with the value and the limit named, and writes no model.
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
  }
  static void TearDownTestSuite() {
    delete single_;
    delete hdr_;
    if (!keep_) fs::remove_all(dir_);
  }
  void TearDown() override {
    if (HasFailure() && !keep_) {
      keep_ = true;
      std::printf("keeping %s (logs, outputs) to look at\n", dir_.c_str());
    }
  }
  static Finished demo(const std::string& name, const std::vector<std::string>& extra) {
    std::vector<std::string> args{SLSCAN_BIN,  "demo",
                                  "--small",   "--true-calibration",
                                  "--scene",   "shiny_blade",
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

}  // namespace
