// Reprocessing many captures: a batch is a job list (one capture per job) under a root folder,
// run as a Slurm array (one array task per job: `slscan batch task ROOT --index I`, an ordinary
// reprocess with atomic outputs) or on this machine (`slscan batch run ROOT --jobs N`, the same
// tasks as child processes). docs/scale.md.
//
//   ROOT/jobs.json            the plan: calibration, config, software version, the jobs
//   ROOT/batch.sbatch         the sbatch array script over the jobs not done yet
//   ROOT/logs/task-I.log      each task's output (Slurm's --output, or the local runner's)
//   ROOT/jobs/I/out/          job I's outputs (reprocess's files), complete or absent
//   ROOT/jobs/I/done.json     written last, after out/ is in place: job I is done for its key
//   ROOT/jobs/I/failed.json   why job I failed (for its key)
//   ROOT/jobs/I/running.json  a task is (or was, if killed) working on job I
//
// A job is done when done.json holds the job's key: SHA-256 over the capture's SHA-256, the
// calibration's, the config's and the software version. A changed input (or a new slscan)
// changes the key, so the job is redone; an unchanged one is skipped. A task killed half-way
// leaves out.partial/ and running.json, never done.json.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "slscan/session/file_hash.hpp"
#include "slscan/session/session_log.hpp"

namespace slscan::session {

struct BatchJob {
  std::size_t index = 0;
  std::string capture;  // absolute path
  std::uint64_t capture_bytes = 0;
  std::int64_t capture_mtime_ns = 0;  // with the size: the plan re-hashes only changed files
  std::string capture_sha256;
  std::string key;  // what done.json must hold
};

struct BatchPlan {
  std::string root;  // absolute
  std::string calibration, calibration_sha256;
  std::string config, config_sha256;  // "" and "" for the defaults
  std::string software_version;
  std::string slscan;  // the executable each task runs
  std::vector<BatchJob> jobs;

  std::string job_dir(std::size_t index) const;
  std::string output_dir(std::size_t index) const;  // job_dir/out
  std::string log_path(std::size_t index) const;    // ROOT/logs/task-I.log
};

// Resources asked of Slurm per task, from the largest capture of the batch (docs/scale.md).
struct TaskResources {
  int cpus = 2;
  std::uint64_t memory_mb = 0;
  int time_minutes = 0;
};
TaskResources task_resources(std::uint64_t capture_bytes);

struct BatchPlanRequest {
  std::vector<std::string> captures;
  std::string calibration;
  std::string config;  // "" = defaults
  std::string root;
  std::string slscan_executable;  // absolute path of the slscan the tasks run
  std::string software_version;
  std::string partition;  // "" = the cluster's default
};

// Hashes the inputs (a capture whose path, size and mtime are unchanged since an earlier plan of
// ROOT keeps its hash), writes ROOT/jobs.json and ROOT/batch.sbatch, creates ROOT/logs.
// Throws io::IoError for a missing or unreadable input, std::invalid_argument for an empty or
// duplicate capture list.
BatchPlan plan_batch(const BatchPlanRequest& request, const SessionLog& log);

// Reads ROOT/jobs.json; throws io::IoError naming the file and field.
BatchPlan load_batch(const std::string& root);

enum class JobState { pending, running, done, failed };
const char* job_state_name(JobState state) noexcept;

struct JobStatus {
  std::size_t index = 0;
  JobState state = JobState::pending;
  std::string message;  // failed: why; running: where and since when; pending: why (e.g. stale)
  double seconds = 0;   // done / failed: how long the task took
  int exit_code = 0;    // done / failed: the reprocess's exit code (6: outputs with self-check findings)
};
std::vector<JobStatus> batch_status(const BatchPlan& plan);

enum class TaskOutcome { skipped, done, failed };
struct TaskResult {
  TaskOutcome outcome = TaskOutcome::failed;
  std::string message;
  int exit_code = 0;
};

// What a task runs: reprocess `job` into `output_dir` (absent, to be created); returns the
// reprocess's exit code (0, or 6 for outputs written with self-check findings) or throws.
using ReprocessFunction = std::function<int(const BatchJob& job, const std::string& output_dir)>;

// One job, as one array task does it: skipped if done for its key; otherwise the capture is
// checked against the plan (size, mtime), reprocessed into out.partial/, moved to out/, and
// done.json written last. A failure (an exception, or an exit code other than 0 and 6) writes
// failed.json with its message and leaves no out/.
TaskResult run_batch_task(const BatchPlan& plan, std::size_t index, const ReprocessFunction& reprocess);

struct LocalRunSummary {
  std::size_t done = 0, skipped = 0, failed = 0;
};
// Runs the jobs not done yet on this machine, `parallel` at a time, each as a child process
// `slscan batch task ROOT --index I` (output to ROOT/logs/task-I.log). `stop` set: no new
// tasks start; running ones finish.
LocalRunSummary run_batch_locally(const BatchPlan& plan, int parallel, const SessionLog& log, StopFlag stop);

}  // namespace slscan::session
