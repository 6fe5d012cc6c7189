#include "slscand/hal/projector.hpp"

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

Result<std::unique_ptr<DlpProjector>> DlpProjector::open(GpioChip& chip, const DlpLines& lines,
                                                         const std::string& name) {
  LineRequestConfig config;
  config.consumer = "slscand " + name;
  config.lines = {
      {lines.trig_in_1, LineDirection::output, false, EdgeDetection::none, false, name + ".trig_in_1"},
      {lines.trig_in_2, LineDirection::output, false, EdgeDetection::none, false, name + ".trig_in_2"},
      {lines.trig_out_1, LineDirection::input, false, EdgeDetection::both, false, name + ".trig_out_1"},
  };
  auto request = chip.request_lines(config);
  if (!request) return std::move(request).error();
  return std::unique_ptr<DlpProjector>(new DlpProjector(std::move(*request), lines, name));
}

DlpProjector::DlpProjector(std::unique_ptr<LineRequest> request, const DlpLines& lines, std::string name)
    : request_(std::move(request)), lines_(lines), name_(std::move(name)) {}

Status DlpProjector::start() {
  // Edges left over from an aborted scan would be taken for this scan's acknowledgements.
  pending_.clear();
  for (;;) {
    auto stale = request_->wait_edges(0);
    if (!stale) return stale.error();
    if (stale->empty()) break;
  }
  if (auto s = request_->set_value(lines_.trig_in_1, false); !s) return s;
  if (auto s = request_->set_value(lines_.trig_in_2, true); !s) return s;
  pattern_index_ = -1;
  running_ = true;
  return slproto::Ok{};
}

Result<Nanos> DlpProjector::advance() {
  if (!running_) return make_error(Errc::internal, name_ + ": advance() before start()");
  // The edge happens inside set_value; the time just before it is the earliest it can be, so
  // latencies measured from it are never negative (a preemption after the call would be).
  const Nanos edge_ns = monotonic_now_ns();
  if (auto s = request_->set_value(lines_.trig_in_1, true); !s) return s.error();
  sleep_until_ns(edge_ns + kTriggerPulseNs);
  if (auto s = request_->set_value(lines_.trig_in_1, false); !s) return s.error();
  ++pattern_index_;
  return edge_ns;
}

Result<EdgeEvent> DlpProjector::wait_edge(bool rising, Nanos timeout_ns) {
  const Nanos deadline = monotonic_now_ns() + timeout_ns;
  for (;;) {
    while (!pending_.empty()) {
      EdgeEvent event = pending_.front();
      pending_.pop_front();
      if (event.offset == lines_.trig_out_1 && event.rising == rising) return event;
    }
    const Nanos left = deadline - monotonic_now_ns();
    if (left <= 0) {
      return make_error(Errc::hardware, name_ + " did not acknowledge pattern " + std::to_string(pattern_index_) +
                                            ": no " + (rising ? "rising" : "falling") + " edge on TRIG_OUT_1 (line " +
                                            std::to_string(lines_.trig_out_1) + ") within " +
                                            std::to_string(timeout_ns / kMicro) + " us");
    }
    auto events = request_->wait_edges(left);
    if (!events) return std::move(events).error();
    pending_.insert(pending_.end(), events->begin(), events->end());
  }
}

Result<EdgeEvent> DlpProjector::wait_exposure_start(Nanos timeout_ns) { return wait_edge(true, timeout_ns); }
Result<EdgeEvent> DlpProjector::wait_exposure_end(Nanos timeout_ns) { return wait_edge(false, timeout_ns); }

Status DlpProjector::stop() {
  running_ = false;
  pattern_index_ = -1;
  Status first_error;
  if (auto s = request_->set_value(lines_.trig_in_2, false); !s) first_error = s;
  if (auto s = request_->set_value(lines_.trig_in_1, false); !s && first_error.ok()) first_error = s;
  return first_error;
}

}  // namespace slscand::hal
