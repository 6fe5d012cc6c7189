// slscan batch plan / run / status / task: reprocessing many captures, on Slurm or locally
// (host/session/batch.hpp; docs/scale.md).
#pragma once

#include <string>
#include <vector>

#include "run.hpp"

namespace slscan::app {

struct BatchPlanCommand {
  std::vector<std::string> captures;
  std::string calibration_path;
  std::string config_path;
  std::string root;
  std::string partition;
};
int run_batch_plan(const BatchPlanCommand& command, const Console& console);

struct BatchRunCommand {
  std::string root;
  int jobs = 1;
};
int run_batch_run(const BatchRunCommand& command, const Console& console);

struct BatchStatusCommand {
  std::string root;
  bool json = false;
};
int run_batch_status(const BatchStatusCommand& command, const Console& console);

struct BatchTaskCommand {
  std::string root;
  std::size_t index = 0;
};
int run_batch_task(const BatchTaskCommand& command, const Console& console);

}  // namespace slscan::app
