#include "batch.hpp"

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>

#include "slscan/session/batch.hpp"

namespace slscan::app {

namespace {

std::string this_executable() {
  std::error_code error;
  const auto path = std::filesystem::read_symlink("/proc/self/exe", error);
  if (error) throw std::runtime_error("cannot find this executable (/proc/self/exe): " + error.message());
  return path.string();
}

}  // namespace

int run_batch_plan(const BatchPlanCommand& command, const Console& console) {
  session::BatchPlanRequest request;
  request.captures = command.captures;
  request.calibration = command.calibration_path;
  request.config = command.config_path;
  request.root = command.root;
  request.partition = command.partition;
  request.slscan_executable = this_executable();
  request.software_version = SLSCAN_VERSION;
  (void)session::plan_batch(request, ConsoleLog(console));
  return exit_ok;
}

int run_batch_run(const BatchRunCommand& command, const Console& console) {
  const session::BatchPlan plan = session::load_batch(command.root);
  const session::LocalRunSummary summary =
      session::run_batch_locally(plan, command.jobs, ConsoleLog(console), &interrupted);
  console.info(std::to_string(summary.done) + " done, " + std::to_string(summary.skipped) + " skipped (done before), " +
               std::to_string(summary.failed) + " failed; slscan batch status " + plan.root);
  if (interrupted.load()) return exit_interrupted;
  return summary.failed == 0 ? exit_ok : exit_bad_input;
}

int run_batch_status(const BatchStatusCommand& command, const Console&) {
  const session::BatchPlan plan = session::load_batch(command.root);
  const auto statuses = session::batch_status(plan);
  std::size_t counts[4] = {0, 0, 0, 0};
  for (const auto& s : statuses) ++counts[static_cast<int>(s.state)];
  if (command.json) {
    nlohmann::json jobs = nlohmann::json::array();
    for (const auto& s : statuses)
      jobs.push_back({{"index", s.index},
                      {"capture", plan.jobs[s.index].capture},
                      {"state", session::job_state_name(s.state)},
                      {"message", s.message},
                      {"seconds", s.seconds},
                      {"exit_code", s.exit_code},
                      {"output", plan.output_dir(s.index)}});
    std::cout << nlohmann::json{{"root", plan.root},
                                {"jobs", statuses.size()},
                                {"done", counts[static_cast<int>(session::JobState::done)]},
                                {"failed", counts[static_cast<int>(session::JobState::failed)]},
                                {"running", counts[static_cast<int>(session::JobState::running)]},
                                {"pending", counts[static_cast<int>(session::JobState::pending)]},
                                {"tasks", jobs}}
                     .dump(2)
              << "\n";
  } else {
    std::cout << plan.root << ": " << statuses.size() << " jobs: " << counts[static_cast<int>(session::JobState::done)]
              << " done, " << counts[static_cast<int>(session::JobState::failed)] << " failed, "
              << counts[static_cast<int>(session::JobState::running)] << " running, "
              << counts[static_cast<int>(session::JobState::pending)] << " pending\n";
    for (const auto& s : statuses)
      if (s.state != session::JobState::done || s.exit_code != 0)
        std::cout << "  " << s.index << " " << session::job_state_name(s.state) << " " << plan.jobs[s.index].capture
                  << (s.exit_code != 0 ? " (exit " + std::to_string(s.exit_code) + ")" : "")
                  << (s.message.empty() ? "" : ": " + s.message) << "\n";
  }
  return exit_ok;
}

int run_batch_task(const BatchTaskCommand& command, const Console& console) {
  const session::BatchPlan plan = session::load_batch(command.root);
  const session::TaskResult result =
      session::run_batch_task(plan, command.index, [&](const session::BatchJob& job, const std::string& out) {
        return run_reprocess({job.capture, plan.calibration, out, plan.config}, console);
      });
  switch (result.outcome) {
    case session::TaskOutcome::skipped:
      console.info(result.message);
      return exit_ok;
    case session::TaskOutcome::done:
      console.info("job " + std::to_string(command.index) + " done: " + plan.output_dir(command.index));
      return exit_ok;
    case session::TaskOutcome::failed:
      std::cerr << "slscan: job " << command.index << " (" << plan.jobs[command.index].capture
                << ") failed: " << result.message << "\n";
      return result.exit_code != 0 ? result.exit_code : exit_bad_input;
  }
  return exit_internal;
}

}  // namespace slscan::app
