// What one HIL scan produced, from three independent sources, and its files on disk:
//   the sequencer's timing log (slscand --timing-log: scan-N-timing.csv), copied as timing.csv;
//   the frames as a host received them (their headers' timestamps), frames.csv;
//   the observer's edges on the trigger lines (the sim bus's record, or libgpiod edge events on
//   inputs wired back from the trigger outputs on a real board), edges.csv;
//   and the scan's request and ScanDone, scan.txt.
// `slscan_hil check DIR` re-runs the checks on a saved directory; tests tamper with a copy.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "slproto/result.hpp"

namespace slscan::hil {

using Nanos = std::int64_t;

struct LogEvent {
  std::string kind;  // the TimingEventKind name without its prefix: "PROJECTOR_TRIGGER", ...
  Nanos ns = 0;
  std::uint32_t source = 0;
};

struct FrameRecord {
  std::uint64_t sequence = 0;
  std::uint32_t view = 0;
  std::uint32_t projector = 0;
  std::uint32_t pattern = 0;
  std::uint32_t exposure_index = 0;  // the bracket member (0 without a bracket)
  Nanos trigger_ns = 0;
  Nanos exposure_start_ns = 0;
  Nanos exposure_end_ns = 0;
  Nanos dequeued_ns = 0;
};

// Offsets are the board file's output/input lines (a real observer's wired-back inputs are
// mapped to the line they watch when recorded).
struct Edge {
  unsigned offset = 0;
  bool rising = false;
  Nanos ns = 0;
};

struct ScanInfo {
  std::uint32_t views = 0;
  std::uint32_t projectors = 0;
  std::uint32_t patterns = 0;
  double period_us = 0;
  double exposure_us = 0;
  std::string final_state;  // "DONE", "FAILED", ...
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_dropped = 0;
  Nanos duration_ns = 0;
  std::string text;
  // HDR (docs/hdr.md): the bracket's exposures in capture order (empty: exposure_us alone) and
  // the pattern periods the board waits after each change (its exposure_change_frames).
  std::vector<double> exposures_us;
  std::uint32_t exposure_change_frames = 0;
  std::uint64_t exposure_count() const { return exposures_us.empty() ? 1 : exposures_us.size(); }
  double exposure_of(std::uint32_t index) const { return exposures_us.empty() ? exposure_us : exposures_us.at(index); }
  std::uint64_t expected_frames() const {
    return static_cast<std::uint64_t>(views) * projectors * patterns * exposure_count();
  }
  // Frames plus the waits after exposure changes, in pattern periods: each view waits for the
  // change to every bracket member but the first (ScanPlan::capture_periods; the change back to
  // the first happens while the turntable moves).
  std::uint64_t capture_periods() const {
    return expected_frames() + static_cast<std::uint64_t>(views) * (exposure_count() - 1) * exposure_change_frames;
  }
};

struct HilRecord {
  ScanInfo scan;
  std::vector<LogEvent> log;
  std::vector<FrameRecord> frames;
  std::vector<Edge> edges;
  bool have_edges = false;  // false: no observer on this run (the cross-checks are skipped)
};

// slscand's timing log CSV ("kind,monotonic_ns,source" with TIMING_EVENT_ names).
slproto::Result<std::vector<LogEvent>> parse_timing_log(const std::string& text, const std::string& where);
// The sim bus's edge record or edges.csv ("offset,rising,monotonic_ns").
slproto::Result<std::vector<Edge>> parse_edges(const std::string& text, const std::string& where);

slproto::Status save_record(const HilRecord& record, const std::string& dir);
slproto::Result<HilRecord> load_record(const std::string& dir);

slproto::Result<std::string> read_text_file(const std::string& path);

}  // namespace slscan::hil
