#include "slscand/hal/sim/sim_rig.hpp"

#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

#include "slscand/hal/priority_inheritance_mutex.hpp"

namespace slscand::hal::sim {

using slproto::Errc;
using slproto::make_error;

namespace {

constexpr unsigned kLineCount = 64;
constexpr std::size_t kMaxRecordedEdges = 1 << 20;

std::chrono::steady_clock::time_point to_steady(Nanos ns) {
  // steady_clock is CLOCK_MONOTONIC on Linux.
  return std::chrono::steady_clock::time_point(std::chrono::nanoseconds(ns));
}

Result<PixelFormat> format_for_bit_depth(int bits) {
  switch (bits) {
    case 8:
      return PixelFormat::mono8;
    case 10:
      return PixelFormat::mono10;
    case 12:
      return PixelFormat::mono12;
    default:
      break;
  }
  return make_error(Errc::unsupported, "sim camera: scene bit depth " + std::to_string(bits) + " has no pixel format");
}

struct CameraJob {
  Nanos start_ns = 0;
  Nanos end_ns = 0;
  int side = -1;
  int pattern_index = -1;
  std::uint64_t sequence = 0;
  Nanos camera_exposure_ns = 0, projector_exposure_ns = 0;  // as set when the camera was triggered
};

}  // namespace

class SimLineRequest;

struct SimRig::Core {
  BoardConfig board;
  slrig::Scene scene;
  slrig::Scene board_scene;            // the board file's scene, restored after a calibration target
  std::uint64_t scene_generation = 0;  // bumped whenever `scene` changes: the renderer is rebuilt
  std::uint64_t placements = 0;        // calibration targets placed so far (noise seeds)
  bool target_placed = false;          // `scene` holds a calibration target instead of board_scene's objects
  std::unique_ptr<TurntableEmulator> table;

  // Guards all state below. Taken by the real-time sequencer (line writes, frame waits) and by
  // the normal-priority renderer, hence priority inheritance.
  PriorityInheritanceMutex mutex;
  std::condition_variable_any scheduler_cv;
  std::condition_variable_any edges_cv;
  std::condition_variable_any camera_cv;
  bool quit = false;

  // Scheduler: device reactions due at a monotonic time, in order.
  std::multimap<Nanos, std::function<void(Nanos)>> events;

  // Bus.
  std::array<bool, kLineCount> values{};
  std::array<const void*, kLineCount> owner{};
  std::vector<SimLineRequest*> requests;
  std::vector<RecordedEdge> edges;

  // Projectors.
  struct Dlp {
    DlpLines lines;
    bool running = false;
    int index = -1;
    int lit_pattern = -1;
    std::uint64_t generation = 0;
  };
  std::array<Dlp, 2> dlp;
  std::optional<slproto::PatternPlan> plan;
  Nanos projector_exposure_ns = 0;
  SimFaults faults;

  // Camera.
  bool camera_started = false;
  TriggerMode trigger_mode = TriggerMode::external;
  Nanos camera_exposure_ns = 0;
  std::uint64_t camera_generation = 0;
  std::uint64_t camera_sequence = 0;
  std::uint64_t fault_base_sequence = 0;  // camera_sequence when the faults were set
  std::deque<CameraJob> jobs;
  std::deque<Frame> frames;
  // Why the last frame could not be rendered (the renderer threw: a scene it cannot draw). The
  // frame is not delivered; wait_frame reports this instead, and the camera thread goes on
  // serving. Cleared by the camera's start() and stop().
  std::string render_error;
  std::vector<ExposureRecord> exposures;
  CameraFormat format;

  std::thread scheduler_thread;
  std::thread camera_thread;

  ~Core() {
    {
      std::lock_guard lock(mutex);
      quit = true;
    }
    scheduler_cv.notify_all();
    camera_cv.notify_all();
    edges_cv.notify_all();
    if (scheduler_thread.joinable()) scheduler_thread.join();
    if (camera_thread.joinable()) camera_thread.join();
  }

  void schedule(Nanos due, std::function<void(Nanos)> fn) {  // lock held
    const bool earliest = events.empty() || due < events.begin()->first;
    events.emplace(due, std::move(fn));
    if (earliest) scheduler_cv.notify_all();
  }

  void drive(unsigned offset, bool value, Nanos now);  // lock held
  void on_trigger_in_2(int side, bool value, Nanos now);
  void on_trigger_in_1(int side, Nanos now);
  void on_camera_trigger(Nanos now);
  void run_scheduler();
  void run_camera();
};

class SimLineRequest final : public LineRequest {
 public:
  SimLineRequest(std::shared_ptr<SimRig::Core> core, LineRequestConfig config)
      : core_(std::move(core)), config_(std::move(config)) {}
  ~SimLineRequest() override {
    std::lock_guard lock(core_->mutex);
    for (const auto& line : config_.lines) core_->owner[line.offset] = nullptr;
    std::erase(core_->requests, this);
  }
  SimLineRequest(const SimLineRequest&) = delete;
  SimLineRequest& operator=(const SimLineRequest&) = delete;

  Status set_value(unsigned offset, bool value) override {
    const LineSettings* line = config_.find(offset);
    if (line == nullptr || line->direction != LineDirection::output) {
      return make_error(Errc::invalid_argument, "sim GPIO: line " + std::to_string(offset) +
                                                    " is not an output of request '" + config_.consumer + "'");
    }
    std::lock_guard lock(core_->mutex);
    core_->drive(offset, value != line->active_low, monotonic_now_ns());
    return slproto::Ok{};
  }

  Result<bool> get_value(unsigned offset) override {
    const LineSettings* line = config_.find(offset);
    if (line == nullptr) {
      return make_error(Errc::invalid_argument,
                        "sim GPIO: line " + std::to_string(offset) + " is not in request '" + config_.consumer + "'");
    }
    std::lock_guard lock(core_->mutex);
    return core_->values[offset] != line->active_low;
  }

  Result<std::vector<EdgeEvent>> wait_edges(Nanos timeout_ns) override {
    std::unique_lock lock(core_->mutex);
    core_->edges_cv.wait_until(lock, to_steady(monotonic_now_ns() + std::max<Nanos>(timeout_ns, 0)),
                               [&] { return !pending_.empty() || core_->quit; });
    std::vector<EdgeEvent> out(pending_.begin(), pending_.end());
    pending_.clear();
    return out;
  }

  const LineRequestConfig& config() const override { return config_; }

  // Called by the bus with the lock held.
  void deliver(unsigned offset, bool value, Nanos now) {
    const LineSettings* line = config_.find(offset);
    if (line == nullptr || line->direction != LineDirection::input) return;
    const bool logical = value != line->active_low;
    const bool wanted = line->edges == EdgeDetection::both || (line->edges == EdgeDetection::rising && logical) ||
                        (line->edges == EdgeDetection::falling && !logical);
    if (!wanted) return;
    pending_.push_back(EdgeEvent{offset, logical, now, ++seqno_});
  }

 private:
  std::shared_ptr<SimRig::Core> core_;
  LineRequestConfig config_;
  std::deque<EdgeEvent> pending_;
  std::uint64_t seqno_ = 0;
};

void SimRig::Core::drive(unsigned offset, bool value, Nanos now) {
  if (offset >= kLineCount || values[offset] == value) return;
  values[offset] = value;
  if (edges.size() < kMaxRecordedEdges) edges.push_back(RecordedEdge{offset, value, now});
  for (SimLineRequest* request : requests) request->deliver(offset, value, now);
  edges_cv.notify_all();
  for (int side = 0; side < 2; ++side) {
    if (offset == dlp[side].lines.trig_in_2) on_trigger_in_2(side, value, now);
    if (offset == dlp[side].lines.trig_in_1 && value) on_trigger_in_1(side, now);
  }
  if (value) {
    const bool from_projector = board.trigger_source == CameraTriggerSource::projector &&
                                (offset == dlp[0].lines.trig_out_1 || offset == dlp[1].lines.trig_out_1);
    const bool from_gpio = board.trigger_source == CameraTriggerSource::gpio && board.camera_trigger_line &&
                           offset == *board.camera_trigger_line;
    if (from_projector || from_gpio) on_camera_trigger(now);
  }
}

void SimRig::Core::on_trigger_in_2(int side, bool value, Nanos now) {
  Dlp& d = dlp[side];
  d.generation++;  // cancels the exposure in flight
  d.index = -1;
  d.lit_pattern = -1;
  d.running = value;
  if (!value && values[d.lines.trig_out_1]) drive(d.lines.trig_out_1, false, now);
}

void SimRig::Core::on_trigger_in_1(int side, Nanos now) {
  Dlp& d = dlp[side];
  if (!d.running || faults.projector_silent[side]) return;
  d.index++;
  const std::size_t count = plan ? plan->size() : slproto::PatternPlan(scene.pattern_plan).size();
  const int pattern = static_cast<int>(static_cast<std::size_t>(d.index) % count);  // the sequence loops
  const std::uint64_t generation = d.generation;
  const Nanos show = now + static_cast<Nanos>(board.projector_latency_us * kMicro);
  schedule(show, [this, side, generation, pattern](Nanos t) {
    Dlp& p = dlp[side];
    if (p.generation != generation) return;
    p.lit_pattern = pattern;
    drive(p.lines.trig_out_1, true, t);
  });
  schedule(show + projector_exposure_ns, [this, side, generation, pattern](Nanos t) {
    Dlp& p = dlp[side];
    if (p.generation != generation || p.lit_pattern != pattern) return;
    p.lit_pattern = -1;
    drive(p.lines.trig_out_1, false, t);
  });
}

void SimRig::Core::on_camera_trigger(Nanos now) {
  if (!camera_started || trigger_mode != TriggerMode::external) return;
  const std::uint64_t generation = camera_generation;
  schedule(now + static_cast<Nanos>(board.sim_camera_latency_us * kMicro), [this, generation](Nanos start) {
    if (generation != camera_generation) return;
    CameraJob job;
    job.start_ns = start;
    job.end_ns = start + camera_exposure_ns;
    job.sequence = camera_sequence++;
    job.camera_exposure_ns = camera_exposure_ns;
    job.projector_exposure_ns = projector_exposure_ns;
    ExposureRecord record;
    record.start_ns = start;
    record.exposure_ns = camera_exposure_ns;
    for (int side = 0; side < 2; ++side) {
      if (dlp[side].lit_pattern >= 0) {
        record.lit_count++;
        if (job.side < 0) {
          job.side = side;
          job.pattern_index = dlp[side].lit_pattern;
        }
      }
    }
    record.side = job.side;
    record.pattern_index = job.pattern_index;
    exposures.push_back(record);
    const Nanos readout_done = job.end_ns + static_cast<Nanos>(board.readout_us * kMicro);
    schedule(readout_done, [this, generation, job](Nanos) {
      if (generation != camera_generation || faults.camera_silent) return;
      if (faults.drop_frame_after >= 0 &&
          job.sequence == fault_base_sequence + static_cast<std::uint64_t>(faults.drop_frame_after))
        return;
      jobs.push_back(job);
      camera_cv.notify_all();
    });
  });
}

void SimRig::Core::run_scheduler() {
  // The virtual devices' reactions are the hardware's timing model: run them at real-time
  // priority when the process may (just below the sequencer's), so a loaded machine delays
  // them less. The thread sleeps between events, so it cannot starve anything.
  sched_param param{};
  param.sched_priority = 70;
  (void)pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
  std::unique_lock lock(mutex);
  while (!quit) {
    if (events.empty()) {
      scheduler_cv.wait(lock);
      continue;
    }
    const Nanos due = events.begin()->first;
    Nanos now = monotonic_now_ns();
    if (now < due - 200 * kMicro) {
      // Coarse wait (woken early if an earlier event is scheduled), then a precise sleep.
      scheduler_cv.wait_until(lock, to_steady(due - 200 * kMicro));
      continue;
    }
    if (now < due) {
      lock.unlock();
      sleep_until_ns(due);
      lock.lock();
      continue;
    }
    // Device reactions happen at their model time, not when this thread got to run them: on
    // a loaded machine the scheduler may run late, and a late "exposure start" must still see
    // the pattern that the model says was lit then.
    auto node = events.extract(events.begin());
    node.mapped()(due);
  }
}

namespace {

slrig::Exposure rendered_exposure(const CameraJob& job, double board_exposure_us, double reference_exposure_us) {
  // The sim board's pattern_exposure_us stands for the scene's reference exposure (the board
  // keeps it short so tests run fast): a frame exposed for k times the board's exposure is
  // rendered at k times the reference. At the board's own exposure: the reference itself.
  const auto board_ns = static_cast<Nanos>(board_exposure_us * kMicro);
  slrig::Exposure exposure;
  if (job.camera_exposure_ns == board_ns && job.projector_exposure_ns >= job.camera_exposure_ns) return exposure;
  const double scale = reference_exposure_us / static_cast<double>(board_ns);
  exposure.exposure_us = scale * static_cast<double>(job.camera_exposure_ns);
  // Projector and camera start together (its TRIG_OUT_1 triggers the camera): a shorter DLP
  // exposure lights only part of the camera's.
  if (job.projector_exposure_ns < job.camera_exposure_ns)
    exposure.projector_us = scale * static_cast<double>(job.projector_exposure_ns);
  return exposure;
}

}  // namespace

void SimRig::Core::run_camera() {
  std::optional<slrig::ViewRenderer> renderer;
  double renderer_angle = NAN;
  std::uint64_t renderer_generation = 0;
  auto view_index_of = [](const slrig::Scene& s, double angle) {
    for (std::size_t i = 0; i < s.view_angles_deg.size(); ++i) {
      const double d = std::remainder(angle - s.view_angles_deg[i], 360.0);
      if (std::abs(d) < 0.5) return static_cast<int>(i);
    }
    return 0;
  };
  // Called without the lock. `scene` changes between scans (place_calibration_target), so a
  // renderer of another generation is rebuilt from a copy taken under the lock. A scene the
  // renderer refuses (it throws) leaves no renderer and returns why; the same scene and angle
  // are not tried again (the idle warm-up would otherwise retry it every few milliseconds).
  std::optional<slrig::Scene> rendered_scene;
  std::string renderer_error;
  auto ensure_renderer = [&](double angle) -> bool {
    std::uint64_t generation = 0;
    {
      std::lock_guard guard(mutex);
      generation = scene_generation;
      if (!rendered_scene || generation != renderer_generation) rendered_scene = scene;
    }
    const bool same = std::abs(angle - renderer_angle) < 1e-6 && renderer_generation == generation;
    if (same && (renderer || !renderer_error.empty())) return renderer.has_value();
    renderer.reset();
    renderer_error.clear();
    renderer_angle = angle;
    renderer_generation = generation;
    try {
      renderer.emplace(*rendered_scene, angle, view_index_of(*rendered_scene, angle));
    } catch (const std::exception& e) {
      renderer_error = e.what();
    }
    return renderer.has_value();
  };
  std::unique_lock lock(mutex);
  while (!quit) {
    if (jobs.empty()) {
      camera_cv.wait_for(lock, std::chrono::milliseconds(5), [&] { return !jobs.empty() || quit; });
      if (jobs.empty() && !quit && !table->moving()) {
        // Warm the renderer for the table's new position while the sequencer waits to settle.
        const double angle = table->angle_deg();
        lock.unlock();
        (void)ensure_renderer(angle);
        lock.lock();
      }
      continue;
    }
    const CameraJob job = jobs.front();
    jobs.pop_front();
    const std::uint64_t generation = camera_generation;
    const CameraFormat frame_format = format;
    std::optional<slproto::PatternPlan> frame_plan = plan;
    const bool short_frame = faults.short_frame_after >= 0 &&
                             job.sequence == fault_base_sequence + static_cast<std::uint64_t>(faults.short_frame_after);
    lock.unlock();

    // The renderer throws on what it cannot draw (a scene it refuses, a plan it was not cast
    // for): that is this frame's error, reported by wait_frame, never an exception leaving the
    // thread (which would end slscand).
    Frame frame;
    std::string error;
    const double angle = table->angle_deg();
    if (!ensure_renderer(angle)) {
      error = "cannot render the scene at " + std::to_string(angle) + " deg: " + renderer_error;
    } else {
      try {
        frame.format = frame_format;
        frame.pixels.resize(renderer->frame_bytes());
        const slrig::Exposure exposure =
            rendered_exposure(job, board.pattern_exposure_us, rendered_scene->sensor.exposure_us);
        if (job.side < 0) {
          renderer->render_ambient(frame.pixels, exposure);
        } else if (frame_plan) {
          renderer->render(static_cast<slproto::ProjectorSide>(job.side), *frame_plan,
                           static_cast<std::size_t>(job.pattern_index), frame.pixels, exposure);
        } else {  // no plan loaded yet: the scene's own, at the board's exposure
          renderer->render(static_cast<slproto::ProjectorSide>(job.side), static_cast<std::size_t>(job.pattern_index),
                           frame.pixels);
        }
      } catch (const std::exception& e) {
        error = std::string("cannot render frame ") + std::to_string(job.sequence) + ": " + e.what();
      }
    }
    if (short_frame) frame.pixels.resize(frame.pixels.size() / 2);
    frame.sequence = job.sequence;
    frame.exposure_start_ns = job.start_ns;
    frame.exposure_end_ns = job.end_ns;

    lock.lock();
    if (generation == camera_generation) {
      if (error.empty()) {
        frames.push_back(std::move(frame));
      } else {
        render_error = std::move(error);
      }
      camera_cv.notify_all();
    }
  }
}

namespace {

class SimGpioChip final : public GpioChip {
 public:
  explicit SimGpioChip(std::shared_ptr<SimRig::Core> core) : core_(std::move(core)) {}
  std::string name() const override { return "sim-gpio [virtual rig]"; }
  unsigned line_count() const override { return kLineCount; }

  Result<std::unique_ptr<LineRequest>> request_lines(const LineRequestConfig& config) override {
    if (auto s = config.check(); !s) return s.error();
    std::lock_guard lock(core_->mutex);
    for (const auto& line : config.lines) {
      if (line.offset >= kLineCount) {
        return make_error(Errc::invalid_argument, "sim GPIO: " + line.name + " line " + std::to_string(line.offset) +
                                                      " is out of range (the chip has " + std::to_string(kLineCount) +
                                                      " lines)");
      }
      if (core_->owner[line.offset] != nullptr) {
        return make_error(
            Errc::busy, "sim GPIO: line " + std::to_string(line.offset) + " (" + line.name + ") is already requested");
      }
    }
    auto request = std::make_unique<SimLineRequest>(core_, config);
    for (const auto& line : config.lines) {
      core_->owner[line.offset] = request.get();
      if (line.direction == LineDirection::output) {
        core_->drive(line.offset, line.initial_value != line.active_low, monotonic_now_ns());
      }
    }
    core_->requests.push_back(request.get());
    return std::unique_ptr<LineRequest>(std::move(request));
  }

 private:
  std::shared_ptr<SimRig::Core> core_;
};

class SimCamera final : public Camera {
 public:
  explicit SimCamera(std::shared_ptr<SimRig::Core> core) : core_(std::move(core)) {}
  ~SimCamera() override { (void)stop(); }
  SimCamera(const SimCamera&) = delete;
  SimCamera& operator=(const SimCamera&) = delete;

  std::string describe() const override {
    return "sim camera " + std::to_string(core_->scene.camera.width) + "x" +
           std::to_string(core_->scene.camera.height) + " (scene '" + core_->scene.name + "')";
  }

  Result<CameraFormat> set_format(const CameraFormat& wanted) override {
    auto native = format_for_bit_depth(core_->scene.sensor.bit_depth);
    if (!native) return std::move(native).error();
    if (wanted.width != core_->scene.camera.width || wanted.height != core_->scene.camera.height ||
        wanted.pixel_format != *native) {
      return make_error(Errc::unsupported, "sim camera renders " + std::to_string(core_->scene.camera.width) + "x" +
                                               std::to_string(core_->scene.camera.height) + " " +
                                               pixel_format_name(*native) + ", not " + std::to_string(wanted.width) +
                                               "x" + std::to_string(wanted.height) + " " +
                                               pixel_format_name(wanted.pixel_format));
    }
    CameraFormat format = wanted;
    format.stride_bytes = static_cast<std::size_t>(wanted.width) * static_cast<std::size_t>(bytes_per_pixel(*native));
    std::lock_guard lock(core_->mutex);
    core_->format = format;
    return format;
  }

  Status set_exposure_us(double exposure_us) override {
    if (!(exposure_us > 0)) return make_error(Errc::invalid_argument, "sim camera: exposure must be positive");
    std::lock_guard lock(core_->mutex);
    if (core_->faults.camera_ignores_exposure) return slproto::Ok{};
    core_->camera_exposure_ns = static_cast<Nanos>(exposure_us * kMicro);
    return slproto::Ok{};
  }
  Status set_gain(double gain) override {
    if (!(gain > 0)) return make_error(Errc::invalid_argument, "sim camera: gain must be positive");
    return slproto::Ok{};  // the scene's sensor model fixes the response; gain 1 is what it renders
  }
  Status set_trigger_mode(TriggerMode mode) override {
    if (mode != TriggerMode::external) {
      return make_error(Errc::unsupported, "sim camera: only external trigger is modelled");
    }
    std::lock_guard lock(core_->mutex);
    core_->trigger_mode = mode;
    return slproto::Ok{};
  }
  Status start() override {
    std::lock_guard lock(core_->mutex);
    if (core_->format.width == 0) return make_error(Errc::invalid_argument, "sim camera: start() before set_format()");
    core_->camera_generation++;
    core_->jobs.clear();
    core_->frames.clear();
    core_->render_error.clear();
    core_->camera_started = true;
    return slproto::Ok{};
  }
  Status stop() override {
    std::lock_guard lock(core_->mutex);
    core_->camera_started = false;
    core_->camera_generation++;
    core_->jobs.clear();
    core_->frames.clear();
    core_->render_error.clear();
    return slproto::Ok{};
  }
  Result<Frame> wait_frame(Nanos timeout_ns) override {
    std::unique_lock lock(core_->mutex);
    const bool got = core_->camera_cv.wait_until(lock, to_steady(monotonic_now_ns() + timeout_ns), [&] {
      return !core_->frames.empty() || !core_->render_error.empty() || core_->quit;
    });
    if (core_->frames.empty() && !core_->render_error.empty()) {
      // The frames before the failed one were delivered; this one never will be.
      return make_error(Errc::hardware, "sim camera: " + core_->render_error);
    }
    if (!got || core_->frames.empty()) {
      return make_error(Errc::timeout,
                        "sim camera: no frame within " + std::to_string(timeout_ns / kMilli) + " ms of waiting");
    }
    Frame frame = std::move(core_->frames.front());
    core_->frames.pop_front();
    frame.dequeued_ns = monotonic_now_ns();
    return frame;
  }

 private:
  std::shared_ptr<SimRig::Core> core_;
};

}  // namespace

slproto::Result<std::shared_ptr<SimRig>> SimRig::create(const BoardConfig& board, const slrig::Scene* scene) {
  auto core = std::make_shared<Core>();
  core->board = board;
  if (scene != nullptr) {
    core->scene = *scene;
  } else {
    auto preset = slrig::scene_preset(board.sim_scene,
                                      board.sim_rig_size == "full" ? slrig::RigSize::full : slrig::RigSize::small);
    if (!preset) {
      return make_error(preset.error().code, board.source_path + ": sim.scene: " + preset.error().message);
    }
    core->scene = std::move(*preset);
  }
  core->board_scene = core->scene;
  core->projector_exposure_ns = static_cast<Nanos>(board.pattern_exposure_us * kMicro);
  core->camera_exposure_ns = core->projector_exposure_ns;
  for (int side = 0; side < 2; ++side) core->dlp[side].lines = board.projectors[side];
  const double max_speed = board.feed_deg_per_min / 60.0;
  auto table = TurntableEmulator::start(max_speed);
  if (!table) return std::move(table).error();
  core->table = std::move(*table);
  Core* raw = core.get();
  core->scheduler_thread = std::thread([raw] { raw->run_scheduler(); });
  core->camera_thread = std::thread([raw] { raw->run_camera(); });
  return std::shared_ptr<SimRig>(new SimRig(std::move(core)));
}

SimRig::~SimRig() = default;

std::unique_ptr<GpioChip> SimRig::make_gpio_chip() { return std::make_unique<SimGpioChip>(core_); }
std::unique_ptr<Camera> SimRig::make_camera() { return std::make_unique<SimCamera>(core_); }
TurntableEmulator& SimRig::turntable() { return *core_->table; }
const slrig::Scene& SimRig::scene() const { return core_->scene; }

void SimRig::load_patterns(const slproto::PatternPlan& plan, Nanos exposure_ns) {
  std::lock_guard lock(core_->mutex);
  // A renderer is cast for one coding axis and extent (its scene's plan): a plan along the other
  // axis (calibration scans both) needs a renderer of its own.
  if (!(core_->scene.pattern_plan == plan.config())) {
    core_->scene.pattern_plan = plan.config();
    core_->scene_generation++;
  }
  core_->plan = plan;
  core_->projector_exposure_ns = exposure_ns;
}

slproto::RigCalibration SimRig::true_calibration() const {
  std::lock_guard lock(core_->mutex);
  return slrig::ground_truth_calibration(core_->board_scene);
}

slproto::Status SimRig::place_calibration_target(const std::optional<slproto::CalibrationTargetPlacement>& target) {
  std::lock_guard lock(core_->mutex);
  if (!target) {
    if (!core_->target_placed) return slproto::Ok{};
    core_->scene = core_->board_scene;
    core_->target_placed = false;
    core_->scene_generation++;
    return slproto::Ok{};
  }
  // The calibration preset's checkerboard (material, plate margins), resized and placed.
  auto preset = slrig::scene_preset("calibration",
                                    core_->board.sim_rig_size == "full" ? slrig::RigSize::full : slrig::RigSize::small);
  if (!preset) return preset.error();
  slrig::SceneObject board = preset->objects.at(0);
  // The plate keeps the preset's margin around the squares (the rig needs it to cover them).
  const double margin_x = board.width - board.squares_x * board.square_mm;
  const double margin_y = board.height - board.squares_y * board.square_mm;
  board.squares_x = target->board.squares_x;
  board.squares_y = target->board.squares_y;
  board.square_mm = target->board.square_mm;
  board.thickness = target->board.thickness_mm;
  board.width = board.squares_x * board.square_mm + margin_x;
  board.height = board.squares_y * board.square_mm + margin_y;
  board.on_turntable = target->on_turntable;
  board.table_from_object = target->pose;
  slrig::Scene scene = core_->board_scene;
  scene.name = core_->board_scene.name + " + calibration target (" + target->pose_name + ")";
  scene.objects = {board};
  // A target the rig cannot draw (a board of no thickness, ...) is this scan's error, named
  // here: the board's scene stays as it was.
  if (auto status = slrig::check_scene(scene); !status)
    return make_error(Errc::invalid_argument, "sim board: cannot place the calibration target '" + target->pose_name +
                                                  "': " + status.error().message);
  // A new exposure set per placement: the noise differs between placements (and between the
  // two coding axes of one pose, which are two scans), but not between the views of one scan.
  scene.sensor.seed = core_->board_scene.sensor.seed + 7919 * ++core_->placements;
  core_->scene = std::move(scene);
  core_->target_placed = true;
  core_->scene_generation++;
  return slproto::Ok{};
}

void SimRig::set_faults(const SimFaults& faults) {
  std::lock_guard lock(core_->mutex);
  core_->faults = faults;
  core_->fault_base_sequence = core_->camera_sequence;
}

std::vector<RecordedEdge> SimRig::recorded_edges() const {
  std::vector<RecordedEdge> edges;
  {
    std::lock_guard lock(core_->mutex);
    edges = core_->edges;
  }
  // Device edges carry model times and may be executed after a later host edge was recorded.
  std::stable_sort(edges.begin(), edges.end(),
                   [](const RecordedEdge& a, const RecordedEdge& b) { return a.timestamp_ns < b.timestamp_ns; });
  return edges;
}

std::vector<ExposureRecord> SimRig::exposures() const {
  std::lock_guard lock(core_->mutex);
  return core_->exposures;
}

void SimRig::clear_records() {
  std::lock_guard lock(core_->mutex);
  core_->edges.clear();
  core_->exposures.clear();
}

std::array<bool, 2> SimRig::projectors_lit() const {
  std::lock_guard lock(core_->mutex);
  return {core_->dlp[0].lit_pattern >= 0, core_->dlp[1].lit_pattern >= 0};
}

bool SimRig::line_value(unsigned offset) const {
  std::lock_guard lock(core_->mutex);
  return offset < kLineCount && core_->values[offset];
}

}  // namespace slscand::hal::sim
