// The batch's bookkeeping (host/session/batch.hpp) without reprocessing: job keys, done /
// failed / interrupted markers, skipping what is done, redoing what changed, the sbatch
// script's array. The real reprocess under a real Slurm: tests/integration/test_slurm_batch.sh.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "slscan/io/io_error.hpp"
#include "slscan/session/batch.hpp"

namespace slscan::session {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

class Batch : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_batch_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    std::ofstream(dir_ / "a.slcap") << "capture a";
    std::ofstream(dir_ / "b.slcap") << "capture b";
    std::ofstream(dir_ / "calib.json") << "{}";
    std::ofstream(dir_ / "config.json") << R"({"mesh": {"enabled": false}})";
  }
  void TearDown() override { fs::remove_all(dir_); }
  BatchPlan plan(const std::string& version = "0.2.0") {
    BatchPlanRequest request;
    request.captures = {(dir_ / "a.slcap").string(), (dir_ / "b.slcap").string()};
    request.calibration = (dir_ / "calib.json").string();
    request.config = (dir_ / "config.json").string();
    request.root = (dir_ / "root").string();
    request.slscan_executable = "/bin/true";
    request.software_version = version;
    return plan_batch(request, QuietLog());
  }
  // A reprocess that writes one file from the capture's bytes, and counts its calls.
  ReprocessFunction writes(int& calls) {
    return [&calls](const BatchJob& job, const std::string& out) {
      ++calls;
      fs::create_directories(out);
      std::ofstream(fs::path(out) / "model.ply") << "model of " << read_text(job.capture);
      return 0;
    };
  }
  fs::path dir_;
  int calls_ = 0;
};

TEST_F(Batch, DoneJobsAreSkippedAndChangedInputsRedone) {
  BatchPlan p = plan();
  ASSERT_EQ(p.jobs.size(), 2u);
  EXPECT_EQ(p.jobs[0].capture_sha256, sha256_text("capture a"));
  EXPECT_EQ(sha256_text("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_THAT(read_text(dir_ / "root" / "batch.sbatch"), HasSubstr("#SBATCH --array=0-1\n"));
  EXPECT_THAT(read_text(dir_ / "root" / "batch.sbatch"), HasSubstr("batch task '" + p.root + "' --index"));
  int calls = 0;
  EXPECT_EQ(run_batch_task(p, 0, writes(calls)).outcome, TaskOutcome::done);
  EXPECT_EQ(read_text(fs::path(p.output_dir(0)) / "model.ply"), "model of capture a");
  EXPECT_FALSE(fs::exists(p.output_dir(0) + ".partial"));
  EXPECT_FALSE(fs::exists(fs::path(p.job_dir(0)) / "running.json"));
  auto status = batch_status(p);
  EXPECT_EQ(status[0].state, JobState::done);
  EXPECT_EQ(status[1].state, JobState::pending);
  // Planned again: only the pending job is in the array; done is not redone.
  p = plan();
  EXPECT_THAT(read_text(dir_ / "root" / "batch.sbatch"), HasSubstr("#SBATCH --array=1\n"));
  EXPECT_EQ(run_batch_task(p, 0, writes(calls)).outcome, TaskOutcome::skipped);
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(run_batch_task(p, 1, writes(calls)).outcome, TaskOutcome::done);
  EXPECT_EQ(calls, 2);
  // A changed capture (same size: the mtime and the hash tell) is redone; the other is not.
  std::ofstream(dir_ / "a.slcap") << "capture A";
  fs::last_write_time(dir_ / "a.slcap", fs::last_write_time(dir_ / "a.slcap") + std::chrono::seconds(2));
  p = plan();
  status = batch_status(p);
  EXPECT_EQ(status[0].state, JobState::pending);
  EXPECT_THAT(status[0].message, HasSubstr("done for another key"));
  EXPECT_EQ(status[1].state, JobState::done);
  EXPECT_EQ(run_batch_task(p, 0, writes(calls)).outcome, TaskOutcome::done);
  EXPECT_EQ(read_text(fs::path(p.output_dir(0)) / "model.ply"), "model of capture A");
  // A changed config, or another software version, changes every key.
  std::ofstream(dir_ / "config.json") << R"({"mesh": {"enabled": true}})";
  p = plan();
  for (const auto& s : batch_status(p)) EXPECT_EQ(s.state, JobState::pending);
  std::ofstream(dir_ / "config.json") << R"({"mesh": {"enabled": false}})";
  p = plan();
  for (const auto& s : batch_status(p)) EXPECT_EQ(s.state, JobState::done);
  p = plan("0.3.0");
  for (const auto& s : batch_status(p)) EXPECT_EQ(s.state, JobState::pending);
}

TEST_F(Batch, FailuresAreRecordedWithTheirMessageAndLeaveNoOutputs) {
  const BatchPlan p = plan();
  const TaskResult result = run_batch_task(p, 1, [](const BatchJob& job, const std::string& out) -> int {
    fs::create_directories(out);
    std::ofstream(fs::path(out) / "half.ply") << "half";
    throw io::IoError(job.capture + ": record: payload CRC mismatch in frame record at file offset 1234");
  });
  EXPECT_EQ(result.outcome, TaskOutcome::failed);
  EXPECT_FALSE(fs::exists(p.output_dir(1)));
  EXPECT_FALSE(fs::exists(p.output_dir(1) + ".partial"));
  const auto status = batch_status(p);
  EXPECT_EQ(status[1].state, JobState::failed);
  EXPECT_THAT(status[1].message,
              HasSubstr("b.slcap: record: payload CRC mismatch in frame record at file offset 1234"));
  EXPECT_EQ(status[0].state, JobState::pending);
  // An exit code other than 0 or 6 fails too; 6 (outputs with self-check findings) is done.
  EXPECT_EQ(run_batch_task(p, 0,
                           [](const BatchJob&, const std::string& out) {
                             fs::create_directories(out);
                             return 4;
                           })
                .outcome,
            TaskOutcome::failed);
  EXPECT_EQ(run_batch_task(p, 0,
                           [](const BatchJob&, const std::string& out) {
                             fs::create_directories(out);
                             return 6;
                           })
                .outcome,
            TaskOutcome::done);
  EXPECT_EQ(batch_status(p)[0].exit_code, 6);
}

TEST_F(Batch, AKilledTaskLeavesNothingThatLooksDone) {
  const BatchPlan p = plan();
  // What a task killed half-way leaves: running.json (its pid now gone), out.partial/.
  const pid_t child = ::fork();
  if (child == 0) ::_exit(0);
  ASSERT_GT(child, 0);
  ::waitpid(child, nullptr, 0);
  char host[256] = {};
  ::gethostname(host, sizeof host - 1);
  fs::create_directories(p.output_dir(0) + ".partial");
  io::write_file_atomically(
      (fs::path(p.job_dir(0)) / "running.json").string(),
      nlohmann::json{{"key", p.jobs[0].key}, {"host", host}, {"pid", child}, {"started", "x"}}.dump());
  auto status = batch_status(p);
  EXPECT_EQ(status[0].state, JobState::pending);
  EXPECT_THAT(status[0].message, HasSubstr("interrupted"));
  // One still running (this process) shows as running.
  fs::create_directories(p.job_dir(1));
  io::write_file_atomically(
      (fs::path(p.job_dir(1)) / "running.json").string(),
      nlohmann::json{{"key", p.jobs[1].key}, {"host", host}, {"pid", ::getpid()}, {"started", "x"}}.dump());
  EXPECT_EQ(batch_status(p)[1].state, JobState::running);
  int calls = 0;
  EXPECT_EQ(run_batch_task(p, 0, writes(calls)).outcome, TaskOutcome::done);
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(batch_status(p)[0].state, JobState::done);
}

TEST_F(Batch, BadPlansAreRefusedClearly) {
  BatchPlanRequest request;
  request.calibration = (dir_ / "calib.json").string();
  request.root = (dir_ / "root").string();
  request.slscan_executable = "/bin/true";
  EXPECT_THROW(plan_batch(request, QuietLog()), std::invalid_argument);
  request.captures = {(dir_ / "a.slcap").string(), (dir_ / "." / "a.slcap").string()};
  try {
    plan_batch(request, QuietLog());
    FAIL() << "a capture listed twice was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("listed twice"));
  }
  request.captures = {(dir_ / "missing.slcap").string()};
  EXPECT_THROW(plan_batch(request, QuietLog()), io::IoError);
  const BatchPlan p = plan();
  std::ofstream(dir_ / "root" / "jobs.json") << R"({"format": 1, "root": 3})";
  try {
    (void)load_batch(p.root);
    FAIL() << "a broken jobs.json was read";
  } catch (const io::IoError& e) {
    EXPECT_THAT(e.what(), HasSubstr("jobs.json: field \"root\""));
  }
  EXPECT_THROW(run_batch_task(p, 7, writes(calls_)), std::invalid_argument);
}

}  // namespace
}  // namespace slscan::session
