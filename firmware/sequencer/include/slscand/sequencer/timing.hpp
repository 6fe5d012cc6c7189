// The timing log: every event of a scan with its CLOCK_MONOTONIC time, and the statistics the
// timing report and ScanDone carry (pattern period and jitter, trigger-to-exposure latency,
// frame delivery).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "slproto/messages.hpp"
#include "slscand/hal/clock.hpp"

namespace slscand {

struct TimingEvent {
  slproto::pb::TimingEventKind kind = slproto::pb::TIMING_EVENT_UNSPECIFIED;
  Nanos monotonic_ns = 0;
  std::uint32_t source = 0;  // projector id, or 0 for the camera and turntable
};

// Per captured frame, the times the statistics are computed from.
struct FrameTiming {
  std::uint32_t view_index = 0;
  std::uint32_t projector_id = 0;
  std::uint32_t pattern_index = 0;
  Nanos deadline_ns = 0;        // when the trigger was due
  Nanos trigger_ns = 0;         // projector TRIG_IN_1 driven
  Nanos shown_ns = 0;           // projector TRIG_OUT_1 rising (kernel edge timestamp)
  Nanos exposure_start_ns = 0;  // camera
  Nanos exposure_end_ns = 0;
  Nanos dequeued_ns = 0;
  bool paused_before = false;  // back-pressure held this frame's trigger back
};

struct TimingSummary {
  std::string name;
  std::uint64_t count = 0;
  double mean_us = 0, stddev_us = 0, min_us = 0, max_us = 0, p50_us = 0, p99_us = 0;
};

TimingSummary summarize(std::string name, std::vector<double> values_us);

struct TimingReport {
  double nominal_period_us = 0;
  TimingSummary pattern_period;       // trigger to trigger within a projector pass
  TimingSummary period_jitter;        // |period - nominal|
  TimingSummary trigger_lateness;     // trigger driven - deadline
  TimingSummary trigger_to_shown;     // TRIG_IN_1 -> TRIG_OUT_1 (projector latency)
  TimingSummary trigger_to_exposure;  // TRIG_IN_1 -> camera exposure start
  TimingSummary frame_delivery;       // exposure end -> frame dequeued
  std::uint64_t paused_frames = 0;    // frames held back by back-pressure (excluded from periods)
  std::vector<TimingSummary> all() const;
  std::string to_text() const;
};

TimingReport make_timing_report(const std::vector<FrameTiming>& frames, double nominal_period_us);

}  // namespace slscand
