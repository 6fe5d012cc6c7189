#include "slscan/session/batch.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "slproto/file_util.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::session {

namespace fs = std::filesystem;
using nlohmann::json;
using slproto::errno_text;

namespace {

constexpr int plan_format = 1;

std::int64_t mtime_ns(const struct stat& info) {
  return static_cast<std::int64_t>(info.st_mtim.tv_sec) * 1'000'000'000 + info.st_mtim.tv_nsec;
}

struct stat stat_or_throw(const std::string& path, const std::string& what) {
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0) throw io::IoError(what + " " + path + ": " + errno_text(errno));
  if (!S_ISREG(info.st_mode)) throw io::IoError(what + " " + path + " is not a regular file");
  return info;
}

std::string job_key(const std::string& capture_sha, const std::string& calibration_sha, const std::string& config_sha,
                    const std::string& version) {
  return sha256_text("slscan batch key 1\ncapture " + capture_sha + "\ncalibration " + calibration_sha + "\nconfig " +
                     config_sha + "\nsoftware " + version + "\n");
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw io::IoError("cannot read " + path + ": " + errno_text(errno));
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

std::optional<json> read_json_if_exists(const std::string& path) {
  std::error_code error;
  if (!fs::exists(path, error)) return std::nullopt;
  try {
    return json::parse(read_text(path));
  } catch (const json::exception&) {
    return std::nullopt;  // a marker cut short counts as absent; markers are written atomically
  }
}

template <typename T>
T field(const json& object, const char* name, const std::string& file) {
  if (!object.is_object() || !object.contains(name))
    throw io::IoError(file + ": missing field \"" + std::string(name) + "\"");
  try {
    return object.at(name).get<T>();
  } catch (const json::exception& e) {
    throw io::IoError(file + ": field \"" + std::string(name) + "\": " + e.what());
  }
}

std::string array_spec(const std::vector<std::size_t>& indices) {
  std::string out;
  for (std::size_t i = 0; i < indices.size();) {
    std::size_t j = i;
    while (j + 1 < indices.size() && indices[j + 1] == indices[j] + 1) ++j;
    if (!out.empty()) out += ",";
    out += std::to_string(indices[i]);
    if (j > i) out += "-" + std::to_string(indices[j]);
    i = j + 1;
  }
  return out;
}

std::string shell_quote(const std::string& text) {
  std::string out = "'";
  for (char c : text) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

std::string host_name() {
  char name[256] = {};
  if (::gethostname(name, sizeof name - 1) != 0) return "unknown";
  return name;
}

double cpu_seconds_self() {
  struct rusage usage {};
  ::getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
         static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec) / 1e6;
}

long peak_rss_kb() {
  struct rusage usage {};
  ::getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss;
}

std::string now_iso() {
  const auto now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  char text[32];
  std::tm utc{};
  ::gmtime_r(&now, &utc);
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}

json plan_to_json(const BatchPlan& plan) {
  json jobs = json::array();
  for (const auto& job : plan.jobs)
    jobs.push_back({{"index", job.index},
                    {"capture", job.capture},
                    {"capture_bytes", job.capture_bytes},
                    {"capture_mtime_ns", job.capture_mtime_ns},
                    {"capture_sha256", job.capture_sha256},
                    {"key", job.key}});
  return {{"format", plan_format},
          {"root", plan.root},
          {"calibration", {{"file", plan.calibration}, {"sha256", plan.calibration_sha256}}},
          {"config", {{"file", plan.config}, {"sha256", plan.config_sha256}}},
          {"software_version", plan.software_version},
          {"slscan", plan.slscan},
          {"jobs", jobs}};
}

}  // namespace

std::string BatchPlan::job_dir(std::size_t index) const {
  return (fs::path(root) / "jobs" / std::to_string(index)).string();
}
std::string BatchPlan::output_dir(std::size_t index) const { return (fs::path(job_dir(index)) / "out").string(); }
std::string BatchPlan::log_path(std::size_t index) const {
  return (fs::path(root) / "logs" / ("task-" + std::to_string(index) + ".log")).string();
}

const char* job_state_name(JobState state) noexcept {
  switch (state) {
    case JobState::pending:
      return "pending";
    case JobState::running:
      return "running";
    case JobState::done:
      return "done";
    case JobState::failed:
      return "failed";
  }
  return "unknown";
}

TaskResources task_resources(std::uint64_t capture_bytes) {
  // Measured (docs/scale.md): reprocess holds about one view's frames of both projectors plus
  // the clouds; peak RSS was 0.33 GB for a 38 MB small-rig capture and 2.3 GB for a 1.16 GB
  // full capture. Ask for 1 GB + 2 bytes per capture byte, rounded up to 256 MB; time: 4x the
  // measured 0.05 CPU-s per MB on 2 cores, at least 10 minutes.
  TaskResources resources;
  resources.cpus = 2;
  const double mb = static_cast<double>(capture_bytes) / (1 << 20);
  resources.memory_mb = static_cast<std::uint64_t>(std::ceil((1024 + 2 * mb) / 256) * 256);
  resources.time_minutes = std::max(10, static_cast<int>(std::ceil(4 * 0.05 * mb / 60)));
  return resources;
}

BatchPlan plan_batch(const BatchPlanRequest& request, const SessionLog& log) {
  if (request.captures.empty()) throw std::invalid_argument("batch plan: no captures given");
  if (request.slscan_executable.empty()) throw std::invalid_argument("batch plan: the slscan executable is unknown");
  BatchPlan plan;
  plan.root = fs::absolute(request.root).lexically_normal().string();
  if (!plan.root.empty() && plan.root.back() == '/' && plan.root.size() > 1) plan.root.pop_back();
  plan.software_version = request.software_version;
  plan.slscan = request.slscan_executable;
  stat_or_throw(request.calibration, "calibration");
  plan.calibration = fs::absolute(request.calibration).lexically_normal().string();
  plan.calibration_sha256 = sha256_file(plan.calibration);
  if (!request.config.empty()) {
    stat_or_throw(request.config, "config");
    plan.config = fs::absolute(request.config).lexically_normal().string();
    plan.config_sha256 = sha256_file(plan.config);
  }

  // An earlier plan of this root: its hashes of unchanged captures are reused.
  std::map<std::string, BatchJob> earlier;
  if (fs::exists(fs::path(plan.root) / "jobs.json")) {
    try {
      for (const auto& job : load_batch(plan.root).jobs) earlier[job.capture] = job;
    } catch (const io::IoError& e) {
      log.warn(std::string("ignoring the earlier plan: ") + e.what());
    }
  }
  std::set<std::string> seen;
  std::uint64_t total = 0, largest = 0;
  std::size_t hashed = 0;
  for (const auto& path : request.captures) {
    const struct stat info = stat_or_throw(path, "capture");
    BatchJob job;
    job.index = plan.jobs.size();
    job.capture = fs::canonical(path).string();
    if (!seen.insert(job.capture).second)
      throw std::invalid_argument("batch plan: capture " + job.capture + " is listed twice");
    job.capture_bytes = static_cast<std::uint64_t>(info.st_size);
    job.capture_mtime_ns = mtime_ns(info);
    if (auto it = earlier.find(job.capture); it != earlier.end() && it->second.capture_bytes == job.capture_bytes &&
                                             it->second.capture_mtime_ns == job.capture_mtime_ns) {
      job.capture_sha256 = it->second.capture_sha256;
    } else {
      log.progress({"hashing captures", hashed, request.captures.size(), "captures", {}});
      job.capture_sha256 = sha256_file(job.capture);
      ++hashed;
    }
    job.key = job_key(job.capture_sha256, plan.calibration_sha256, plan.config_sha256, plan.software_version);
    total += job.capture_bytes;
    largest = std::max(largest, job.capture_bytes);
    plan.jobs.push_back(std::move(job));
  }
  log.end_progress();

  fs::create_directories(fs::path(plan.root) / "logs");
  fs::create_directories(fs::path(plan.root) / "jobs");
  io::write_file_atomically((fs::path(plan.root) / "jobs.json").string(), plan_to_json(plan).dump(2) + "\n");

  std::vector<std::size_t> pending;
  for (const auto& status : batch_status(plan))
    if (status.state != JobState::done) pending.push_back(status.index);
  const bool all_done = pending.empty();
  if (all_done)
    for (const auto& job : plan.jobs) pending.push_back(job.index);  // every task then skips
  const TaskResources resources = task_resources(largest);
  std::ostringstream script;
  script << "#!/bin/sh\n"
         << "# Written by `slscan batch plan` (docs/scale.md): one array task per capture not done yet.\n"
         << "# Submit: sbatch " << shell_quote((fs::path(plan.root) / "batch.sbatch").string()) << "\n"
         << "# Resources per task from the largest capture (" << largest << " bytes).\n"
         << "#SBATCH --job-name=slscan-batch\n"
         << "#SBATCH --array=" << array_spec(pending) << "\n"
         << "#SBATCH --ntasks=1\n"
         << "#SBATCH --cpus-per-task=" << resources.cpus << "\n"
         << "#SBATCH --mem=" << resources.memory_mb << "M\n"
         << "#SBATCH --time=" << resources.time_minutes << "\n"
         << "#SBATCH --output=" << (fs::path(plan.root) / "logs" / "task-%a.log").string() << "\n";
  if (!request.partition.empty()) script << "#SBATCH --partition=" << request.partition << "\n";
  script << "exec " << shell_quote(plan.slscan) << " batch task " << shell_quote(plan.root)
         << " --index \"$SLURM_ARRAY_TASK_ID\"\n";
  io::write_file_atomically((fs::path(plan.root) / "batch.sbatch").string(), script.str());
  fs::permissions(fs::path(plan.root) / "batch.sbatch", fs::perms::owner_exec | fs::perms::group_exec,
                  fs::perm_options::add);
  log.info(std::to_string(plan.jobs.size()) + " captures (" + std::to_string(total / 1000000) + " MB, " +
           std::to_string(hashed) + " hashed), " +
           std::to_string(all_done ? plan.jobs.size() : plan.jobs.size() - pending.size()) + " already done; " +
           "sbatch " + (fs::path(plan.root) / "batch.sbatch").string() + " or slscan batch run " + plan.root);
  return plan;
}

BatchPlan load_batch(const std::string& root) {
  const std::string file = (fs::path(root) / "jobs.json").string();
  json document;
  try {
    document = json::parse(read_text(file));
  } catch (const json::exception& e) {
    throw io::IoError(file + ": not valid JSON: " + e.what());
  }
  if (field<int>(document, "format", file) != plan_format)
    throw io::IoError(file + ": field \"format\": " + document["format"].dump() + " is not " +
                      std::to_string(plan_format));
  BatchPlan plan;
  plan.root = field<std::string>(document, "root", file);
  const json calibration = field<json>(document, "calibration", file);
  plan.calibration = field<std::string>(calibration, "file", file);
  plan.calibration_sha256 = field<std::string>(calibration, "sha256", file);
  const json config = field<json>(document, "config", file);
  plan.config = field<std::string>(config, "file", file);
  plan.config_sha256 = field<std::string>(config, "sha256", file);
  plan.software_version = field<std::string>(document, "software_version", file);
  plan.slscan = field<std::string>(document, "slscan", file);
  for (const json& entry : field<json>(document, "jobs", file)) {
    BatchJob job;
    job.index = field<std::size_t>(entry, "index", file);
    job.capture = field<std::string>(entry, "capture", file);
    job.capture_bytes = field<std::uint64_t>(entry, "capture_bytes", file);
    job.capture_mtime_ns = field<std::int64_t>(entry, "capture_mtime_ns", file);
    job.capture_sha256 = field<std::string>(entry, "capture_sha256", file);
    job.key = field<std::string>(entry, "key", file);
    if (job.index != plan.jobs.size())
      throw io::IoError(file + ": jobs[" + std::to_string(plan.jobs.size()) + "].index is " +
                        std::to_string(job.index));
    plan.jobs.push_back(std::move(job));
  }
  return plan;
}

std::vector<JobStatus> batch_status(const BatchPlan& plan) {
  std::vector<JobStatus> out;
  const std::string here = host_name();
  for (const auto& job : plan.jobs) {
    JobStatus status;
    status.index = job.index;
    const fs::path dir = plan.job_dir(job.index);
    const auto done = read_json_if_exists((dir / "done.json").string());
    const auto failed = read_json_if_exists((dir / "failed.json").string());
    const auto running = read_json_if_exists((dir / "running.json").string());
    std::error_code error;
    if (done && done->value("key", "") == job.key && fs::is_directory(plan.output_dir(job.index), error)) {
      status.state = JobState::done;
      status.seconds = done->value("seconds", 0.0);
      status.exit_code = done->value("exit_code", 0);
    } else if (running && running->value("key", "") == job.key) {
      const std::string host = running->value("host", "");
      const int pid = running->value("pid", 0);
      const bool gone = host == here && pid > 0 && ::kill(pid, 0) != 0 && errno == ESRCH;
      status.state = gone ? JobState::pending : JobState::running;
      status.message =
          std::string(gone ? "interrupted: the task " : "task ") + "started " + running->value("started", "") + " on " +
          host + " (pid " + std::to_string(pid) +
          (running->value("slurm_job", "").empty() ? "" : ", Slurm job " + running->value("slurm_job", "")) +
          (gone ? ") is gone" : ")");
    } else if (failed && failed->value("key", "") == job.key) {
      status.state = JobState::failed;
      status.message = failed->value("message", "");
      status.seconds = failed->value("seconds", 0.0);
      status.exit_code = failed->value("exit_code", 0);
    } else if (done) {
      status.message = "done for another key: an input or the software changed since";
    }
    out.push_back(std::move(status));
  }
  return out;
}

TaskResult run_batch_task(const BatchPlan& plan, std::size_t index, const ReprocessFunction& reprocess) {
  if (index >= plan.jobs.size())
    throw std::invalid_argument("batch task: index " + std::to_string(index) + " not in 0.." +
                                std::to_string(plan.jobs.size() - 1) + " of " + plan.root);
  const BatchJob& job = plan.jobs[index];
  const fs::path dir = plan.job_dir(index);
  const std::string out = plan.output_dir(index);
  const std::string partial = out + ".partial";
  TaskResult result;
  {
    const auto done = read_json_if_exists((dir / "done.json").string());
    std::error_code error;
    if (done && done->value("key", "") == job.key && fs::is_directory(out, error)) {
      result.outcome = TaskOutcome::skipped;
      result.message = "job " + std::to_string(index) + " is done already (" + job.capture + ")";
      return result;
    }
  }
  // Whatever an earlier key left goes first (done.json first: nothing may look done meanwhile).
  fs::create_directories(dir);
  fs::remove(dir / "done.json");
  fs::remove(dir / "failed.json");
  fs::remove_all(out);
  const char* slurm_job = std::getenv("SLURM_JOB_ID");
  io::write_file_atomically((dir / "running.json").string(), json{{"key", job.key},
                                                                  {"host", host_name()},
                                                                  {"pid", ::getpid()},
                                                                  {"slurm_job", slurm_job != nullptr ? slurm_job : ""},
                                                                  {"started", now_iso()}}
                                                                 .dump(2));
  const auto start = std::chrono::steady_clock::now();
  const double cpu_start = cpu_seconds_self();
  std::string message;
  int code = 0;
  try {
    fs::remove_all(partial);
    struct stat info {};
    if (::stat(job.capture.c_str(), &info) != 0) throw io::IoError("capture " + job.capture + ": " + errno_text(errno));
    if (static_cast<std::uint64_t>(info.st_size) != job.capture_bytes || mtime_ns(info) != job.capture_mtime_ns)
      throw io::IoError("capture " + job.capture + " changed since the plan (size or modification time): run " +
                        "`slscan batch plan` again");
    code = reprocess(job, partial);
    if (code != 0 && code != 6) message = "reprocess exited with code " + std::to_string(code);
  } catch (const std::exception& e) {
    message = e.what();
    if (code == 0) code = 2;
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const double cpu = cpu_seconds_self() - cpu_start;
  result.exit_code = code;
  if (message.empty()) {
    fs::remove_all(out);
    fs::rename(partial, out);
    io::write_file_atomically((dir / "done.json").string(), json{{"key", job.key},
                                                                 {"capture", job.capture},
                                                                 {"exit_code", code},
                                                                 {"seconds", seconds},
                                                                 {"cpu_seconds", cpu},
                                                                 {"peak_rss_kb", peak_rss_kb()},
                                                                 {"host", host_name()},
                                                                 {"finished", now_iso()}}
                                                                .dump(2));
    result.outcome = TaskOutcome::done;
  } else {
    std::error_code ignored;
    fs::remove_all(partial, ignored);
    fs::remove_all(out, ignored);
    io::write_file_atomically((dir / "failed.json").string(), json{{"key", job.key},
                                                                   {"capture", job.capture},
                                                                   {"exit_code", code},
                                                                   {"message", message},
                                                                   {"seconds", seconds},
                                                                   {"host", host_name()},
                                                                   {"finished", now_iso()}}
                                                                  .dump(2));
    result.outcome = TaskOutcome::failed;
    result.message = message;
  }
  fs::remove(dir / "running.json");
  return result;
}

LocalRunSummary run_batch_locally(const BatchPlan& plan, int parallel, const SessionLog& log, StopFlag stop) {
  if (parallel < 1) throw std::invalid_argument("batch run: --jobs must be at least 1");
  if (::access(plan.slscan.c_str(), X_OK) != 0)
    throw io::IoError("batch run: the plan's slscan " + plan.slscan + " is not executable: " + errno_text(errno));
  LocalRunSummary summary;
  std::vector<std::size_t> queue;
  for (const auto& status : batch_status(plan)) {
    if (status.state == JobState::done)
      ++summary.skipped;
    else
      queue.push_back(status.index);
  }
  std::reverse(queue.begin(), queue.end());
  std::map<pid_t, std::size_t> running;
  const std::size_t total = queue.size();
  while (!queue.empty() || !running.empty()) {
    while (!queue.empty() && running.size() < static_cast<std::size_t>(parallel) && !(stop && stop->load())) {
      const std::size_t index = queue.back();
      queue.pop_back();
      const std::string log_path = plan.log_path(index);
      const std::string index_text = std::to_string(index);
      const pid_t pid = ::fork();
      if (pid < 0) throw std::runtime_error("batch run: fork: " + errno_text(errno));
      if (pid == 0) {
        const int fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        if (fd >= 0) {
          ::dup2(fd, STDOUT_FILENO);
          ::dup2(fd, STDERR_FILENO);
        }
        ::execl(plan.slscan.c_str(), "slscan", "batch", "task", plan.root.c_str(), "--index", index_text.c_str(),
                static_cast<char*>(nullptr));
        ::_exit(127);
      }
      running[pid] = index;
    }
    if (running.empty()) break;  // stopped with nothing running
    int wstatus = 0;
    const pid_t pid = ::waitpid(-1, &wstatus, 0);
    if (pid < 0) {
      if (errno == EINTR) continue;
      throw std::runtime_error("batch run: waitpid: " + errno_text(errno));
    }
    const auto it = running.find(pid);
    if (it == running.end()) continue;
    const std::size_t index = it->second;
    running.erase(it);
    const bool ok = WIFEXITED(wstatus) && WEXITSTATUS(wstatus) == 0;
    (ok ? summary.done : summary.failed) += 1;
    if (!ok)
      log.warn("job " + std::to_string(index) + " (" + plan.jobs[index].capture + ") failed: " +
               (WIFEXITED(wstatus) ? "exit " + std::to_string(WEXITSTATUS(wstatus))
                                   : "signal " + std::to_string(WTERMSIG(wstatus))) +
               "; see " + plan.log_path(index));
    log.progress({"batch", summary.done + summary.failed, total, "jobs", {}});
  }
  log.end_progress();
  return summary;
}

}  // namespace slscan::session
