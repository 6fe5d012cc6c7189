// The hard-timed scan loop. For each angle: rotate and wait for the table to report the
// position, then settle; for each exposure of the plan's bracket (one without a bracket: set
// the camera's exposure, wait the board's exposure_change_frames periods for it to apply),
// for each projector (left, then right): start its sequence and, at
// absolute deadlines t0 + i * period (clock_nanosleep TIMER_ABSTIME), advance it, wait for its
// TRIG_OUT_1 acknowledgement, collect the camera frame and hand it to the streamer through a
// bounded queue. A full queue pauses the sequencer between patterns (the pause is logged and
// the remaining deadlines move); nothing is ever dropped.
//
// Every way a scan ends (done, abort, a device fault) leaves the projectors dark, the camera
// stopped, the turntable stopped if it was involved, and the sequencer ready for the next scan.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <vector>

#include "slproto/messages.hpp"
#include "slscand/hal/backends.hpp"
#include "slscand/sequencer/bounded_queue.hpp"
#include "slscand/sequencer/scan_plan.hpp"
#include "slscand/sequencer/timing.hpp"

namespace slscand {

struct SequencedFrame {
  std::uint64_t scan_id = 0;
  std::uint64_t sequence = 0;  // frame counter over the scan, from 0
  std::uint32_t view_index = 0;
  double commanded_angle_deg = 0;
  double reported_angle_deg = 0;
  std::uint32_t projector_id = 0;
  std::uint32_t pattern_index = 0;
  slproto::Pattern pattern;
  Nanos exposure_ns = 0;
  std::uint32_t exposure_index = 0;  // position in ScanPlan::exposures_ns
  FrameTiming timing;
  std::vector<TimingEvent> events;  // this frame's events (and the view's turntable events on its first frame)
  hal::Frame frame;
};

// The frame header a streamed frame carries (geometry, timestamps, pattern, timing events).
slproto::pb::FrameHeader make_frame_header(const SequencedFrame& frame, bool with_events);

struct ScanOutcome {
  slproto::pb::ScanState state = slproto::pb::SCAN_STATE_DONE;
  slproto::Error error;  // the cause when state is FAILED or ABORTED
  std::uint64_t frames_captured = 0;
  std::uint32_t views_completed = 0;
  Nanos duration_ns = 0;
  std::vector<TimingEvent> events;  // the whole scan's log
  std::vector<FrameTiming> frames;  // per-frame times for the report
  std::uint64_t backpressure_pauses = 0;
  hal::CameraLinkStats camera_link;  // the camera transport's counters over this scan
};

using ProgressCallback = std::function<void(const slproto::pb::Progress&)>;

class Sequencer {
 public:
  Sequencer(hal::BoardDevices& devices, const hal::BoardConfig& board) : devices_(devices), board_(board) {}

  // Runs `plan` on the calling thread; frames go to `out`. `abort` is polled between every
  // step and while waiting; set it to stop the scan (the host aborted or went away).
  // `abort_reason` is read only after `abort` was seen set.
  ScanOutcome run(const ScanPlan& plan, BoundedQueue<SequencedFrame>& out, const std::atomic<bool>& abort,
                  const ProgressCallback& progress = {});

  // Everything dark and stopped; safe at any time.
  void make_safe(bool stop_turntable);

 private:
  hal::BoardDevices& devices_;
  const hal::BoardConfig& board_;
};

}  // namespace slscand
