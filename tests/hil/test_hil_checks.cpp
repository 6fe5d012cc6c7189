// The HIL checks must catch what they are for. Each test starts from the record of a real sim
// scan (the hil_sim test's, a CTest fixture), tampers with one source -- the sequencer's log,
// the observer's edges, the frames or the budget -- and expects the check that guards against
// that fault to fail, naming it.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>

#include "hil_check.hpp"
#include "hil_record.hpp"

using namespace slscan::hil;

namespace {

class HilChecks : public ::testing::Test {
 protected:
  void SetUp() override {
    auto board = slscand::hal::load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml");
    ASSERT_TRUE(board.ok()) << board.error().message;
    board_ = *board;
    auto record = load_record(HIL_RECORD_DIR);
    ASSERT_TRUE(record.ok()) << record.error().message << " (the hil_sim test writes it)";
    record_ = *record;
    ASSERT_TRUE(record_.have_edges);
    ASSERT_EQ(record_.frames.size(), record_.scan.expected_frames());
  }

  // The failed checks' names, for assertions and messages.
  static std::vector<std::string> failed(const HilReport& report) {
    std::vector<std::string> names;
    for (const auto* c : report.failures()) names.push_back(c->name);
    return names;
  }
  static const Check* find(const HilReport& report, const std::string& name) {
    for (const auto& c : report.checks) {
      if (c.name == name) return &c;
    }
    return nullptr;
  }
  static bool has_failure(const HilReport& report, const std::string& name) {
    const Check* c = find(report, name);
    return c != nullptr && !c->pass;
  }

  // Index in record_.edges of the n-th rising edge on `offset`, by time.
  std::size_t rising_edge(unsigned offset, std::size_t n) const {
    std::vector<std::size_t> idx;
    for (std::size_t i = 0; i < record_.edges.size(); ++i) {
      if (record_.edges[i].offset == offset && record_.edges[i].rising) idx.push_back(i);
    }
    std::sort(idx.begin(), idx.end(), [&](auto a, auto b) { return record_.edges[a].ns < record_.edges[b].ns; });
    EXPECT_LT(n, idx.size());
    return idx.at(n);
  }
  std::size_t log_event(const std::string& kind, std::uint32_t source, std::size_t n) const {
    std::size_t seen = 0;
    for (std::size_t i = 0; i < record_.log.size(); ++i) {
      if (record_.log[i].kind == kind && record_.log[i].source == source && seen++ == n) return i;
    }
    ADD_FAILURE() << "no " << kind << " event " << n;
    return 0;
  }

  slscand::hal::BoardConfig board_;
  HilRecord record_;
};

TEST_F(HilChecks, TheUntamperedSimRecordPasses) {
  // Behaviour and observer checks only: the record may come from a sanitizer build, whose
  // timing the budgets do not judge (hil_sim judges the dev build's).
  CheckOptions behaviour;
  behaviour.timing = false;
  const HilReport report = evaluate(record_, board_, behaviour);
  EXPECT_TRUE(report.passed()) << report.table();
  // Every projector line was actually compared, not skipped.
  EXPECT_NE(find(report, "projector.left.trig_in_1 rising edges (line 17)"), nullptr);
  EXPECT_NE(find(report, "projector.right.trig_out_1 rising edges (line 25)"), nullptr);
  EXPECT_NE(report.json().find("\"passed\": true"), std::string::npos);
}

TEST_F(HilChecks, ObserverMissingATriggerEdgeIsACountMismatch) {
  record_.edges.erase(record_.edges.begin() + static_cast<std::ptrdiff_t>(rising_edge(17, 5)));
  const HilReport report = evaluate(record_, board_);
  const Check* c = find(report, "projector.left.trig_in_1 rising edges (line 17)");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->pass);
  EXPECT_EQ(c->measured, "37");
  EXPECT_NE(c->detail.find("the log records 38 PROJECTOR_TRIGGER"), std::string::npos) << c->detail;
  EXPECT_NE(report.table().find("FAILED"), std::string::npos);
}

TEST_F(HilChecks, ObserverSeeingAnExtraExposurePulseIsACountMismatch) {
  const Nanos t = record_.edges[rising_edge(25, 3)].ns + 100'000;
  record_.edges.push_back({25, true, t});
  record_.edges.push_back({25, false, t + 50'000});
  const HilReport report = evaluate(record_, board_);
  EXPECT_TRUE(has_failure(report, "projector.right.trig_out_1 rising edges (line 25)")) << report.table();
}

TEST_F(HilChecks, ALogTriggerShiftedBy1msDisagreesWithTheObserverAndTheFrames) {
  record_.log[log_event("PROJECTOR_TRIGGER", 0, 7)].ns += 1'000'000;
  const HilReport report = evaluate(record_, board_);
  const Check* c = find(report, "log vs observer timestamps");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->pass);
  EXPECT_NE(c->detail.find("projector.left trig_in_1 trigger 7"), std::string::npos) << c->detail;
  EXPECT_TRUE(has_failure(report, "frames agree with the timing log"));
}

TEST_F(HilChecks, ALogMissingAPatternShownEventIsCaught) {
  record_.log.erase(record_.log.begin() + static_cast<std::ptrdiff_t>(log_event("PATTERN_SHOWN", 1, 0)));
  const HilReport report = evaluate(record_, board_);
  EXPECT_TRUE(has_failure(report, "projector.right.trig_out_1 rising edges (line 25)")) << report.table();
}

TEST_F(HilChecks, AnExposurePulseBeforeItsTriggerBreaksTheOrder) {
  // The projector "answered" before it was triggered: its pulse moved 100 us ahead of TRIG_IN_1.
  const std::size_t trigger = rising_edge(17, 4);
  record_.edges[rising_edge(22, 4)].ns = record_.edges[trigger].ns - 100'000;
  const HilReport report = evaluate(record_, board_);
  const Check* c = find(report, "projector.left trigger -> exposure pulse order");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->pass);
  EXPECT_NE(c->detail.find("exposure pulse 4"), std::string::npos) << c->detail;
}

TEST_F(HilChecks, AFrameExposedAfterItsTriggerPulseIsCaught) {
  // Exposure start after TRIG_OUT_1 fell: the camera was not triggered by that pulse.
  FrameRecord& f = record_.frames[20];
  ASSERT_EQ(f.projector, 1u);
  f.exposure_start_ns += 3'000'000;
  const HilReport report = evaluate(record_, board_);
  const Check* c = find(report, "projector.right frames exposed inside their trigger pulse");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->pass);
  EXPECT_NE(c->detail.find("frame 20"), std::string::npos) << c->detail;
}

TEST_F(HilChecks, ALostFrameIsNamedBySequence) {
  record_.frames.erase(record_.frames.begin() + 11);
  record_.scan.frames_sent--;
  const HilReport report = evaluate(record_, board_);
  const Check* c = find(report, "frames lost");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->pass);
  EXPECT_EQ(c->measured, "1");
  EXPECT_NE(c->detail.find("first missing: sequence 11"), std::string::npos) << c->detail;
}

TEST_F(HilChecks, ATriggerLeftHighAfterTheScanIsCaught) {
  record_.edges.push_back({27, true, record_.edges.back().ns + 1'000'000});
  const HilReport report = evaluate(record_, board_);
  const Check* c = find(report, "projector.left lines low after the scan");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->pass);
  EXPECT_NE(c->detail.find("projector.left.trig_in_2"), std::string::npos) << c->detail;
}

TEST_F(HilChecks, AnImpossibleBudgetFailsNamingTheBudgetAndBothNumbers) {
  board_.budget.period_jitter_max_us = 0.001;
  board_.budget.move_settle_max_ms = 1;
  const HilReport report = evaluate(record_, board_);
  const auto names = failed(report);
  EXPECT_NE(std::find(names.begin(), names.end(), "timing_budget.period_jitter_max_us"), names.end());
  EXPECT_NE(std::find(names.begin(), names.end(), "timing_budget.move_settle_max_ms"), names.end());
  const Check* c = find(report, "timing_budget.period_jitter_max_us");
  EXPECT_EQ(c->limit, "<= 0.0 us");
  EXPECT_NE(c->detail.find("worst at frame"), std::string::npos) << c->detail;
}

TEST_F(HilChecks, WithoutTimingOnlyBehaviourAndOrderAreJudged) {
  // The VM's mode: an impossible latency budget does not matter, a lost edge still does.
  board_.budget.period_jitter_max_us = 0.001;
  CheckOptions behaviour;
  behaviour.timing = false;
  EXPECT_TRUE(evaluate(record_, board_, behaviour).passed());
  record_.edges.erase(record_.edges.begin() + static_cast<std::ptrdiff_t>(rising_edge(23, 0)));
  EXPECT_TRUE(has_failure(evaluate(record_, board_, behaviour), "projector.right.trig_in_1 rising edges (line 23)"));
}

TEST(HilRecordFiles, ASavedRecordLoadsBackIdentically) {
  auto record = load_record(HIL_RECORD_DIR);
  ASSERT_TRUE(record.ok()) << record.error().message;
  const std::string dir = ::testing::TempDir() + "hil-roundtrip";
  std::filesystem::create_directories(dir);
  ASSERT_TRUE(save_record(*record, dir).ok());
  auto again = load_record(dir);
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_EQ(again->frames.size(), record->frames.size());
  EXPECT_EQ(again->edges.size(), record->edges.size());
  ASSERT_EQ(again->log.size(), record->log.size());
  EXPECT_EQ(again->log.back().ns, record->log.back().ns);
  EXPECT_EQ(again->scan.duration_ns, record->scan.duration_ns);
}

TEST(HilRecordFiles, BadLinesAreNamedByFileAndLine) {
  auto log = parse_timing_log("# header\nTIMING_EVENT_PROJECTOR_TRIGGER,12x,0\n", "t.csv");
  ASSERT_FALSE(log.ok());
  EXPECT_NE(log.error().message.find("t.csv:2: timestamp '12x'"), std::string::npos) << log.error().message;
  auto kind = parse_timing_log("PROJECTOR_TRIGGER,12,0\n", "t.csv");
  ASSERT_FALSE(kind.ok());
  EXPECT_NE(kind.error().message.find("t.csv:1: event kind"), std::string::npos) << kind.error().message;
  auto edges = parse_edges("17,1,5\n17,2,6\n", "e.csv");
  ASSERT_FALSE(edges.ok());
  EXPECT_NE(edges.error().message.find("e.csv:2: edge (0 or 1) '2'"), std::string::npos) << edges.error().message;
  auto short_row = parse_edges("17,1\n", "e.csv");
  ASSERT_FALSE(short_row.ok());
  EXPECT_NE(short_row.error().message.find("expected 3 comma-separated fields, got 2"), std::string::npos);
}

TEST(HilBoardBudget, BudgetAndObserverSectionsAreCheckedByName) {
  auto text = slscan::hil::read_text_file(std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml");
  ASSERT_TRUE(text.ok());
  auto board = slscand::hal::parse_board(*text, "sim.toml");
  ASSERT_TRUE(board.ok()) << board.error().message;
  EXPECT_DOUBLE_EQ(board->budget.scan_time_ratio_max, 15.0);

  const auto at = text->find("[timing_budget]\n") + std::string("[timing_budget]\n").size();
  const std::string key = "frame_delivery_max_us = ";
  const auto key_at = text->find(key);
  ASSERT_NE(key_at, std::string::npos);
  // Concatenated rather than insert()ed: GCC 12 at -O3 (the cross build) warns a false -Wrestrict on insert.
  const std::string negative_text = text->substr(0, key_at + key.size()) + "-" + text->substr(key_at + key.size());
  auto negative = slscand::hal::parse_board(negative_text, "neg.toml");
  ASSERT_FALSE(negative.ok());
  EXPECT_NE(negative.error().message.find("timing_budget.frame_delivery_max_us' must not be negative"),
            std::string::npos)
      << negative.error().message;
  auto typo =
      slscand::hal::parse_board(text->substr(0, at) + "period_jitter_p95_us = 1\n" + text->substr(at), "typo.toml");
  ASSERT_FALSE(typo.ok());
  EXPECT_NE(typo.error().message.find("unknown field 'timing_budget.period_jitter_p95_us'"), std::string::npos);
  auto orphan = slscand::hal::parse_board(*text + "\n[observer]\nleft_trig_in_1 = 5\n", "orphan.toml");
  ASSERT_FALSE(orphan.ok());
  EXPECT_NE(orphan.error().message.find("observer.chip is not"), std::string::npos) << orphan.error().message;
  auto wired =
      slscand::hal::parse_board(*text + "\n[observer]\nchip = \"gpiochip1\"\nright_trig_out_1 = 6\n", "w.toml");
  ASSERT_TRUE(wired.ok()) << wired.error().message;
  EXPECT_EQ(wired->observer.right_trig_out_1, 6u);
  EXPECT_FALSE(wired->observer.left_trig_in_1.has_value());
}

}  // namespace

namespace {

TEST(HilBoardBudget, ShippedBoardsCarryTheirBudgetsAndObserverWiring) {
  auto rpi = slscand::hal::load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/rpi.toml");
  ASSERT_TRUE(rpi.ok()) << rpi.error().message;
  EXPECT_EQ(rpi->observer.chip, "pinctrl-bcm2711");
  ASSERT_TRUE(rpi->observer.left_trig_in_1 && rpi->observer.right_trig_out_1);
  // An observer input must not be one of the lines it watches (or any other board line).
  for (const auto& line : {rpi->observer.left_trig_in_1, rpi->observer.left_trig_out_1, rpi->observer.right_trig_in_1,
                           rpi->observer.right_trig_out_1}) {
    for (const auto& p : rpi->projectors) {
      EXPECT_NE(*line, p.trig_in_1);
      EXPECT_NE(*line, p.trig_in_2);
      EXPECT_NE(*line, p.trig_out_1);
    }
  }
  EXPECT_LT(rpi->budget.period_jitter_p99_us, 100);
  auto vm = slscand::hal::load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/qemu-vm.toml");
  ASSERT_TRUE(vm.ok()) << vm.error().message;
  EXPECT_EQ(vm->gpio_backend, "gpiod");
  EXPECT_EQ(vm->serial_port, "/dev/ttyS1");
  auto bbb = slscand::hal::load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/beaglebone-black.toml");
  ASSERT_TRUE(bbb.ok()) << bbb.error().message;
  EXPECT_TRUE(bbb->observer.chip.empty());
}

}  // namespace

namespace {

// The bracketed sim scan (hil_sim_bracket: 2000 and 500 us, 2 periods after each change).
class HilBracketChecks : public ::testing::Test {
 protected:
  void SetUp() override {
    auto board = slscand::hal::load_board(HIL_BRACKET_BOARD);
    ASSERT_TRUE(board.ok()) << board.error().message;
    board_ = *board;
    auto record = load_record(HIL_BRACKET_RECORD_DIR);
    ASSERT_TRUE(record.ok()) << record.error().message << " (the hil_sim_bracket test writes it)";
    record_ = *record;
  }
  static const Check* find(const HilReport& report, const std::string& name) {
    for (const auto& c : report.checks)
      if (c.name == name) return &c;
    return nullptr;
  }
  slscand::hal::BoardConfig board_;
  HilRecord record_;
};

TEST_F(HilBracketChecks, TheRecordHoldsEveryExposureInScanOrderAndPasses) {
  ASSERT_EQ(record_.scan.exposures_us, (std::vector<double>{2000, 500}));
  EXPECT_EQ(record_.scan.exposure_change_frames, 2u);
  ASSERT_EQ(record_.frames.size(), record_.scan.expected_frames());
  EXPECT_EQ(record_.scan.expected_frames(), 2u * 2u * 2u * record_.scan.patterns);
  // 2 views, each waiting 2 periods for its change to 500 us.
  EXPECT_EQ(record_.scan.capture_periods(), record_.scan.expected_frames() + 4u);
  std::size_t short_frames = 0;
  for (const FrameRecord& f : record_.frames) short_frames += f.exposure_index == 1 ? 1 : 0;
  EXPECT_EQ(short_frames, record_.frames.size() / 2);
  CheckOptions behaviour;
  behaviour.timing = false;
  const HilReport report = evaluate(record_, board_, behaviour);
  EXPECT_TRUE(report.passed()) << report.table();
}

TEST_F(HilBracketChecks, AFrameOfTheWrongExposureOrOutOfOrderIsNamed) {
  // The first frame of the second exposure's pass claims the first exposure.
  auto it = std::find_if(record_.frames.begin(), record_.frames.end(),
                         [](const FrameRecord& f) { return f.exposure_index == 1; });
  ASSERT_NE(it, record_.frames.end());
  it->exposure_index = 0;
  CheckOptions behaviour;
  behaviour.timing = false;
  HilReport report = evaluate(record_, board_, behaviour);
  const Check* order = find(report, "frames in scan order");
  ASSERT_NE(order, nullptr);
  EXPECT_FALSE(order->pass);
  EXPECT_NE(order->detail.find("exposure 0"), std::string::npos) << order->detail;
  // An exposure index beyond the bracket.
  it->exposure_index = 7;
  report = evaluate(record_, board_, behaviour);
  order = find(report, "frames in scan order");
  ASSERT_NE(order, nullptr);
  EXPECT_NE(order->detail.find("has exposure index 7; the scan's bracket has 2"), std::string::npos) << order->detail;
}

TEST_F(HilBracketChecks, AFrameExposedForTheOtherMemberFailsTheExposureBudget) {
  // A camera that kept 2000 us for a 500 us frame (the timestamps say so).
  auto it = std::find_if(record_.frames.begin(), record_.frames.end(),
                         [](const FrameRecord& f) { return f.exposure_index == 1 && f.exposure_end_ns != 0; });
  ASSERT_NE(it, record_.frames.end());
  it->exposure_end_ns = it->exposure_start_ns + 2'000'000;
  const HilReport report = evaluate(record_, board_, CheckOptions{});
  const Check* exposure = find(report, "timing_budget.exposure_error_max_us");
  ASSERT_NE(exposure, nullptr);
  EXPECT_FALSE(exposure->pass);
  EXPECT_NE(exposure->detail.find("exposure 500 us"), std::string::npos) << exposure->detail;
}

}  // namespace
