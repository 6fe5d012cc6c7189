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
  std::uint64_t expected_frames() const { return static_cast<std::uint64_t>(views) * projectors * patterns; }
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
