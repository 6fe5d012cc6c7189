#include "slscand/sequencer/sequencer.hpp"

#include <cmath>
#include <deque>
#include <optional>

#include "slproto/calibration.hpp"
#include "slproto/number_text.hpp"

namespace slscand {

using slproto::Errc;
using slproto::make_error;
namespace pb = slproto::pb;

namespace {

// A failure inside the loop: carries the cause out to the single clean-up path.
struct Failure {
  pb::ScanState state;
  slproto::Error error;
};

// Sleeps until `deadline` in slices, so an abort is seen within a few milliseconds.
bool sleep_until_or_abort(Nanos deadline, const std::atomic<bool>& abort) {
  for (;;) {
    if (abort.load()) return false;
    const Nanos now = monotonic_now_ns();
    if (now >= deadline) return true;
    sleep_until_ns(std::min(deadline, now + 5 * kMilli));
  }
}

}  // namespace

pb::FrameHeader make_frame_header(const SequencedFrame& f, bool with_events) {
  pb::FrameHeader h;
  h.set_scan_id(f.scan_id);
  h.set_view_index(f.view_index);
  h.set_commanded_angle_deg(f.commanded_angle_deg);
  h.set_reported_angle_deg(f.reported_angle_deg);
  h.set_projector_id(f.projector_id);
  h.set_pattern_index(f.pattern_index);
  h.set_pattern_kind(static_cast<pb::PatternKind>(f.pattern.kind));
  h.set_pattern_kind_index(f.pattern.index);
  h.set_exposure_us(static_cast<std::uint32_t>(f.exposure_ns / kMicro));
  h.set_exposure_index(f.exposure_index);
  h.set_trigger_ns(static_cast<std::uint64_t>(f.timing.trigger_ns));
  h.set_exposure_start_ns(static_cast<std::uint64_t>(f.timing.exposure_start_ns));
  h.set_exposure_end_ns(static_cast<std::uint64_t>(f.timing.exposure_end_ns));
  h.set_readout_ns(static_cast<std::uint64_t>(f.timing.dequeued_ns));
  h.set_sequence(f.sequence);
  h.set_width(static_cast<std::uint32_t>(f.frame.format.width));
  h.set_height(static_cast<std::uint32_t>(f.frame.format.height));
  h.set_pixel_format(to_proto(f.frame.format.pixel_format));
  h.set_stride_bytes(static_cast<std::uint32_t>(f.frame.format.stride_bytes));
  if (with_events) {
    for (const auto& e : f.events) {
      pb::TimingEvent* out = h.add_timing_events();
      out->set_kind(e.kind);
      out->set_monotonic_ns(static_cast<std::uint64_t>(e.monotonic_ns));
      out->set_source(e.source);
    }
  }
  return h;
}

void Sequencer::make_safe(bool stop_turntable) {
  for (auto& projector : devices_.projectors) {
    if (projector) (void)projector->stop();
  }
  if (devices_.camera_trigger && board_.camera_trigger_line) {
    (void)devices_.camera_trigger->set_value(*board_.camera_trigger_line, false);
  }
  if (devices_.camera) (void)devices_.camera->stop();
  if (stop_turntable && devices_.turntable) (void)devices_.turntable->stop();
}

namespace {

// One run of a plan: the state the scan's steps share (the event log, the frame counter, the
// camera's last sequence number) and the steps themselves, outermost first: the views
// (rotate, settle), each projector's pass over the patterns, and the frame collection that
// checks each frame and hands it on.
class ScanRun {
 public:
  ScanRun(hal::BoardDevices& devices, const hal::BoardConfig& board, const ScanPlan& plan,
          BoundedQueue<SequencedFrame>& out, const std::atomic<bool>& abort, const ProgressCallback& progress,
          ScanOutcome& outcome)
      : devices_(devices),
        board_(board),
        plan_(plan),
        out_(out),
        abort_(abort),
        progress_(progress),
        outcome_(outcome),
        ack_timeout_(static_cast<Nanos>(board.ack_timeout_ms * kMilli)),
        frame_timeout_(static_cast<Nanos>(board.frame_timeout_ms * kMilli)),
        move_timeout_(static_cast<Nanos>(board.move_timeout_s * kSecond)) {}

  // Every view of the plan; the failure that ended the scan, if any.
  std::optional<Failure> views();

  std::uint64_t frames_handed() const { return frames_handed_; }
  // Whether the failure (if any) came while the turntable was moving.
  bool turntable_involved() const { return turntable_involved_; }
  // The camera transport's counters when its stream started (none if it never did).
  const std::optional<hal::CameraLinkStats>& link_before() const { return link_before_; }

 private:
  // The view being captured, as every frame of it records.
  struct View {
    std::uint32_t index = 0;
    double commanded_deg = 0, reached_deg = 0;
  };

  void log(pb::TimingEventKind kind, Nanos ns, std::uint32_t source = 0) {
    const TimingEvent e{kind, ns, source};
    outcome_.events.push_back(e);
    pending_.push_back(e);
  }
  void report(pb::ScanState state, std::uint32_t view, double angle, const std::string& text) const;
  std::optional<Failure> fail_if_aborted() const {
    if (abort_.load()) return Failure{pb::SCAN_STATE_ABORTED, make_error(Errc::aborted, "scan aborted")};
    return std::nullopt;
  }

  // Rotates to view `v`'s angle and settles; the angle the table reached.
  std::optional<Failure> move_to(std::size_t v, View& view);
  // One projector's pass over the plan's patterns at `view`: triggers on absolute deadlines,
  // frames collected while waiting for the next one.
  std::optional<Failure> pass(const View& view, std::uint32_t projector_id, std::uint32_t exposure_index);
  // Sets the camera's (and the projectors') exposure to bracket member `exposure_index`.
  std::optional<Failure> set_exposure(std::uint32_t exposure_index);
  // Hands on the awaited frames that arrive by `wait_until` (all of them, each by its own due
  // time, if `all`), oldest first.
  std::optional<Failure> collect(std::deque<SequencedFrame>& awaiting, const View& view, std::uint32_t projector_id,
                                 Nanos wait_until, bool all);
  // The reason `frame` cannot be the awaited one (exposed before its trigger, a gap in the
  // camera's sequence, another size), if any.
  std::optional<Failure> check_frame(const hal::Frame& frame, const SequencedFrame& item) const;

  hal::BoardDevices& devices_;
  const hal::BoardConfig& board_;
  const ScanPlan& plan_;
  BoundedQueue<SequencedFrame>& out_;
  const std::atomic<bool>& abort_;
  const ProgressCallback& progress_;
  ScanOutcome& outcome_;
  const Nanos ack_timeout_, frame_timeout_, move_timeout_;

  std::vector<TimingEvent> pending_;  // events not yet attached to a frame
  std::uint64_t frames_handed_ = 0;
  bool turntable_involved_ = false;
  std::optional<std::uint64_t> last_camera_sequence_;
  std::optional<hal::CameraLinkStats> link_before_;
};

void ScanRun::report(pb::ScanState state, std::uint32_t view, double angle, const std::string& text) const {
  if (!progress_) return;
  pb::Progress p;
  p.set_scan_id(plan_.scan_id);
  p.set_state(state);
  p.set_view_index(view);
  p.set_view_count(static_cast<std::uint32_t>(plan_.angles_deg.size()));
  p.set_frames_sent(frames_handed_);
  p.set_frames_total(plan_.frames_total());
  p.set_turntable_angle_deg(angle);
  p.set_text(text);
  p.set_monotonic_ns(static_cast<std::uint64_t>(monotonic_now_ns()));
  progress_(p);
}

std::optional<Failure> ScanRun::views() {
  if (auto s = devices_.place_calibration_target(plan_.calibration_target); !s) {
    return Failure{pb::SCAN_STATE_FAILED, s.error()};
  }
  if (auto f = set_exposure(0)) return f;
  hal::Camera& camera = *devices_.camera;
  if (auto s = camera.start(); !s) return Failure{pb::SCAN_STATE_FAILED, s.error()};
  link_before_ = camera.link_stats();

  const auto exposures = static_cast<std::uint32_t>(plan_.exposures_ns.size());
  for (std::size_t v = 0; v < plan_.angles_deg.size(); ++v) {
    // Back to the bracket's first exposure before the table moves: the move and the settling
    // give the camera far longer than its change latency.
    if (v > 0 && exposures > 1)
      if (auto f = set_exposure(0)) return f;
    View view;
    if (auto f = move_to(v, view)) return f;
    for (std::uint32_t e = 0; e < exposures; ++e) {
      if (e > 0) {
        if (auto f = set_exposure(e)) return f;
        const Nanos latency = static_cast<Nanos>(board_.exposure_change_frames) * plan_.period_ns;
        log(pb::TIMING_EVENT_EXPOSURE_CHANGED, monotonic_now_ns(), e);
        if (!sleep_until_or_abort(monotonic_now_ns() + latency, abort_)) return fail_if_aborted();
      }
      for (const std::uint32_t projector_id : plan_.projectors) {
        if (auto f = pass(view, projector_id, e)) return f;
      }
    }
    outcome_.views_completed++;
  }
  return std::nullopt;
}

std::optional<Failure> ScanRun::set_exposure(std::uint32_t exposure_index) {
  const Nanos exposure_ns = plan_.exposures_ns.at(exposure_index);
  if (auto s = devices_.load_patterns(plan_.patterns, exposure_ns); !s) {
    return Failure{pb::SCAN_STATE_FAILED, s.error()};
  }
  if (auto s = devices_.camera->set_exposure_us(static_cast<double>(exposure_ns) / kMicro); !s) {
    auto error = s.error();
    if (plan_.exposures_ns.size() > 1)
      error.message = "exposure " + std::to_string(exposure_ns / kMicro) + " us (bracket member " +
                      std::to_string(exposure_index) + "): " + error.message;
    return Failure{pb::SCAN_STATE_FAILED, error};
  }
  return std::nullopt;
}

std::optional<Failure> ScanRun::move_to(std::size_t v, View& view) {
  view.index = static_cast<std::uint32_t>(v);
  view.commanded_deg = plan_.angles_deg[v];
  report(pb::SCAN_STATE_MOVING, view.index, view.commanded_deg,
         "rotating to " + slproto::short_number(view.commanded_deg) + " deg");
  log(pb::TIMING_EVENT_TURNTABLE_MOVE_START, monotonic_now_ns());
  turntable_involved_ = true;
  auto reached = devices_.turntable->rotate_to(view.commanded_deg, move_timeout_, &abort_);
  if (!reached) {
    const bool aborted = reached.error().code == Errc::aborted;
    return Failure{aborted ? pb::SCAN_STATE_ABORTED : pb::SCAN_STATE_FAILED, reached.error()};
  }
  view.reached_deg = *reached;
  const Nanos stopped = monotonic_now_ns();
  log(pb::TIMING_EVENT_TURNTABLE_MOVE_DONE, stopped);
  turntable_involved_ = false;
  if (auto f = fail_if_aborted()) return f;
  report(pb::SCAN_STATE_SETTLING, view.index, view.reached_deg, "settling");
  if (!sleep_until_or_abort(stopped + plan_.settle_ns, abort_)) return fail_if_aborted();
  log(pb::TIMING_EVENT_SETTLE_DONE, monotonic_now_ns());
  report(pb::SCAN_STATE_CAPTURING, view.index, view.reached_deg, "capturing");
  return std::nullopt;
}

std::optional<Failure> ScanRun::pass(const View& view, std::uint32_t projector_id, std::uint32_t exposure_index) {
  const Nanos exposure_ns = plan_.exposures_ns[exposure_index];
  hal::DlpProjector& projector = *devices_.projectors[projector_id];
  if (auto s = projector.start(); !s) return Failure{pb::SCAN_STATE_FAILED, s.error()};
  // Triggers and frames are pipelined: pattern i + 1 is triggered on time while frame i
  // is still being read out (or rendered, on the sim board). Frames come back in order.
  std::deque<SequencedFrame> awaiting;

  // The first trigger leaves a millisecond for the projector to arm its sequence.
  Nanos t0 = monotonic_now_ns() + kMilli;
  bool paused = false;
  Nanos previous_shown = 0;
  for (std::size_t i = 0; i < plan_.patterns.size(); ++i) {
    if (auto f = fail_if_aborted()) return f;
    Nanos deadline = t0 + static_cast<Nanos>(i) * plan_.period_ns;
    // Use the wait for this deadline to pass finished frames on.
    if (auto f = collect(awaiting, view, projector_id, deadline - 200 * kMicro, false)) return f;
    if (const Nanos late = monotonic_now_ns() - deadline; late > 0 && i > 0) {
      paused = true;  // held back by a full queue (or a slow camera): shift what follows
      t0 += late;
      deadline += late;
    }
    // After a late trigger (a late wake-up) never catch up by advancing the projector before
    // its last exposure (known from its TRIG_OUT_1 edge) has ended. Only then: ordinary
    // wake-up latency must not accumulate into the deadlines, so they stay absolute.
    const Nanos earliest = previous_shown + exposure_ns + 100 * kMicro;
    if (i > 0 && deadline < earliest) {
      const Nanos slip = earliest - deadline;
      t0 += slip;
      deadline += slip;
    }
    sleep_until_ns(deadline);
    SequencedFrame item;
    item.scan_id = plan_.scan_id;
    item.sequence = frames_handed_ + awaiting.size();
    item.view_index = view.index;
    item.commanded_angle_deg = view.commanded_deg;
    item.reported_angle_deg = view.reached_deg;
    item.projector_id = projector_id;
    item.pattern_index = static_cast<std::uint32_t>(i);
    item.pattern = plan_.patterns[i];
    item.exposure_ns = exposure_ns;
    item.exposure_index = exposure_index;
    FrameTiming& timing = item.timing;
    timing.view_index = view.index;
    timing.projector_id = projector_id;
    timing.pattern_index = static_cast<std::uint32_t>(i);
    timing.deadline_ns = deadline;
    timing.paused_before = paused;
    paused = false;
    auto trigger = projector.advance();
    if (!trigger) return Failure{pb::SCAN_STATE_FAILED, trigger.error()};
    timing.trigger_ns = *trigger;
    log(pb::TIMING_EVENT_PROJECTOR_TRIGGER, *trigger, projector_id);
    if (devices_.camera_trigger) {
      sleep_until_ns(*trigger + plan_.trigger_delay_ns);
      if (auto s = devices_.camera_trigger->set_value(*board_.camera_trigger_line, true); !s) {
        return Failure{pb::SCAN_STATE_FAILED, s.error()};
      }
      log(pb::TIMING_EVENT_CAMERA_TRIGGER, monotonic_now_ns());
    }
    auto shown = projector.wait_exposure_start(ack_timeout_);
    if (devices_.camera_trigger) (void)devices_.camera_trigger->set_value(*board_.camera_trigger_line, false);
    if (!shown) return Failure{pb::SCAN_STATE_FAILED, shown.error()};
    timing.shown_ns = shown->timestamp_ns;
    previous_shown = shown->timestamp_ns;
    log(pb::TIMING_EVENT_PATTERN_SHOWN, shown->timestamp_ns, projector_id);
    if (board_.trigger_source == hal::CameraTriggerSource::software) {
      // Bench cameras without a trigger line: expose once the pattern is up.
      if (auto s = devices_.camera->software_trigger(); !s) return Failure{pb::SCAN_STATE_FAILED, s.error()};
      log(pb::TIMING_EVENT_CAMERA_TRIGGER, monotonic_now_ns());
    }
    item.events = std::move(pending_);
    pending_.clear();
    awaiting.push_back(std::move(item));
  }
  if (auto f = collect(awaiting, view, projector_id, 0, true)) return f;
  if (auto s = projector.stop(); !s) return Failure{pb::SCAN_STATE_FAILED, s.error()};
  return std::nullopt;
}

std::optional<Failure> ScanRun::collect(std::deque<SequencedFrame>& awaiting, const View& view,
                                        std::uint32_t projector_id, Nanos wait_until, bool all) {
  hal::Camera& camera = *devices_.camera;
  while (!awaiting.empty()) {
    SequencedFrame& item = awaiting.front();
    const Nanos due = item.timing.shown_ns + item.exposure_ns + frame_timeout_;
    const Nanos now = monotonic_now_ns();
    const Nanos limit = all ? due : std::min(due, wait_until);
    auto frame = camera.wait_frame(std::max<Nanos>(0, limit - now));
    if (!frame) {
      if (frame.error().code == Errc::timeout && monotonic_now_ns() < due) return std::nullopt;  // not yet
      auto error = frame.error();
      error.message = std::string(error.code == Errc::timeout ? "camera timeout" : "camera error") + " at view " +
                      std::to_string(view.index) + ", " +
                      slproto::projector_side_name(static_cast<slproto::ProjectorSide>(projector_id)) +
                      " projector, pattern " + std::to_string(item.pattern_index) + ": " + error.message;
      return Failure{pb::SCAN_STATE_FAILED, error};
    }
    if (auto f = check_frame(*frame, item)) return f;
    last_camera_sequence_ = frame->sequence;
    item.timing.exposure_start_ns = frame->exposure_start_ns;
    item.timing.exposure_end_ns = frame->exposure_end_ns;
    item.timing.dequeued_ns = frame->dequeued_ns;
    for (const auto& [kind, ns] : {std::pair{pb::TIMING_EVENT_EXPOSURE_START, frame->exposure_start_ns},
                                   std::pair{pb::TIMING_EVENT_EXPOSURE_END, frame->exposure_end_ns},
                                   std::pair{pb::TIMING_EVENT_FRAME_DEQUEUED, frame->dequeued_ns}}) {
      const TimingEvent e{kind, ns, 0};
      outcome_.events.push_back(e);
      item.events.push_back(e);
    }
    item.frame = std::move(*frame);
    outcome_.frames.push_back(item.timing);
    // Back-pressure: a full queue blocks here, between patterns; the caller moves the
    // remaining deadlines by the pause, so the pattern period stays what was asked.
    if (out_.full()) outcome_.backpressure_pauses++;
    if (!out_.push(item, abort_)) {
      return fail_if_aborted().value_or(
          Failure{pb::SCAN_STATE_FAILED, make_error(Errc::internal, "frame queue closed")});
    }
    awaiting.pop_front();
    frames_handed_++;
  }
  return std::nullopt;
}

std::optional<Failure> ScanRun::check_frame(const hal::Frame& frame, const SequencedFrame& item) const {
  // A frame exposed before its trigger is a free-running camera or a stale buffer.
  if (frame.exposure_start_ns != 0 && frame.exposure_start_ns < item.timing.trigger_ns) {
    return Failure{pb::SCAN_STATE_FAILED,
                   make_error(Errc::hardware, "camera frame " + std::to_string(frame.sequence) +
                                                  " was exposed before its trigger: is the camera in "
                                                  "external trigger mode?")};
  }
  if (last_camera_sequence_ && frame.sequence != *last_camera_sequence_ + 1) {
    return Failure{
        pb::SCAN_STATE_FAILED,
        make_error(Errc::hardware, "camera dropped " + std::to_string(frame.sequence - *last_camera_sequence_ - 1) +
                                       " frame(s) before frame " + std::to_string(frame.sequence))};
  }
  // In a bracket a camera that ignored the exposure control would make every exposure the same
  // and the host's merge meaningless: a frame that says how long it was exposed must say the
  // exposure asked, within the board's stated error.
  if (plan_.exposures_ns.size() > 1 && frame.exposure_start_ns != 0 &&
      frame.exposure_end_ns > frame.exposure_start_ns) {
    const Nanos length = frame.exposure_end_ns - frame.exposure_start_ns;
    const auto tolerance = static_cast<Nanos>(board_.budget.exposure_error_max_us * kMicro);
    if (std::abs(length - item.exposure_ns) > tolerance) {
      return Failure{
          pb::SCAN_STATE_FAILED,
          make_error(Errc::hardware, "camera frame " + std::to_string(frame.sequence) + " was exposed for " +
                                         slproto::short_number(static_cast<double>(length) / kMicro) + " us, not the " +
                                         slproto::short_number(static_cast<double>(item.exposure_ns) / kMicro) +
                                         " us asked (bracket member " + std::to_string(item.exposure_index) +
                                         "; tolerance " + slproto::short_number(board_.budget.exposure_error_max_us) +
                                         " us, timing_budget.exposure_error_max_us): the camera ignores or clamps "
                                         "its exposure control")};
    }
  }
  // A frame of another size would stream as garbage or desynchronise the host's decode.
  const hal::CameraFormat& expected = devices_.camera_format;
  if (frame.format.width != expected.width || frame.format.height != expected.height ||
      frame.format.pixel_format != expected.pixel_format || frame.pixels.size() != frame.format.frame_bytes()) {
    return Failure{
        pb::SCAN_STATE_FAILED,
        make_error(Errc::hardware,
                   "camera frame " + std::to_string(frame.sequence) + " is " + std::to_string(frame.format.width) +
                       " x " + std::to_string(frame.format.height) + " " +
                       hal::pixel_format_name(frame.format.pixel_format) + " with " +
                       std::to_string(frame.pixels.size()) + " bytes; expected " + std::to_string(expected.width) +
                       " x " + std::to_string(expected.height) + " " + hal::pixel_format_name(expected.pixel_format) +
                       " with " + std::to_string(expected.frame_bytes()) + " bytes")};
  }
  return std::nullopt;
}

}  // namespace

ScanOutcome Sequencer::run(const ScanPlan& plan, BoundedQueue<SequencedFrame>& out, const std::atomic<bool>& abort,
                           const ProgressCallback& progress) {
  ScanOutcome outcome;
  const Nanos scan_start = monotonic_now_ns();
  ScanRun scan(devices_, board_, plan, out, abort, progress, outcome);
  std::optional<Failure> failure = scan.views();
  // One clean-up path for every ending.
  make_safe(failure.has_value() && (scan.turntable_involved() || failure->state == pb::SCAN_STATE_ABORTED));
  if (scan.link_before()) outcome.camera_link = devices_.camera->link_stats() - *scan.link_before();
  outcome.frames_captured = scan.frames_handed();
  outcome.duration_ns = monotonic_now_ns() - scan_start;
  if (failure) {
    outcome.state = failure->state;
    outcome.error = failure->error;
  } else {
    outcome.state = pb::SCAN_STATE_DONE;
  }
  return outcome;
}

}  // namespace slscand
