#include "gpiod_observer.hpp"

#if defined(SLSCAND_HAVE_GPIOD)
#include "slscand/hal/gpiod/gpiod_chip.hpp"
#endif

namespace slscan::hil {

GpiodObserver::~GpiodObserver() { stop(); }

bool GpiodObserver::start(const slscand::hal::BoardConfig& board, std::string& error) {
#if defined(SLSCAND_HAVE_GPIOD)
  auto chip = slscand::hal::open_gpiod_chip(board.observer.chip);
  if (!chip) {
    error = "observer: " + chip.error().message;
    return false;
  }
  chip_ = std::move(*chip);
  slscand::hal::LineRequestConfig config;
  config.consumer = "slscan_hil observer";
  const auto& o = board.observer;
  const char* names[4] = {"observer.left_trig_in_1", "observer.left_trig_out_1", "observer.right_trig_in_1",
                          "observer.right_trig_out_1"};
  const std::optional<unsigned> inputs[4] = {o.left_trig_in_1, o.left_trig_out_1, o.right_trig_in_1,
                                             o.right_trig_out_1};
  const unsigned watched[4] = {board.projectors[0].trig_in_1, board.projectors[0].trig_out_1,
                               board.projectors[1].trig_in_1, board.projectors[1].trig_out_1};
  for (int i = 0; i < 4; ++i) {
    if (!inputs[i]) continue;
    config.lines.push_back(
        {*inputs[i], slscand::hal::LineDirection::input, false, slscand::hal::EdgeDetection::both, false, names[i]});
    map_.emplace_back(*inputs[i], watched[i]);
  }
  auto request = chip_->request_lines(config);
  if (!request) {
    error = "observer: " + request.error().message;
    return false;
  }
  request_ = std::move(*request);
  thread_ = std::thread([this] { run(); });
  return true;
#else
  (void)board;
  error = "observer: this slscan_hil was built without libgpiod";
  return false;
#endif
}

void GpiodObserver::stop() {
  quit_ = true;
  if (thread_.joinable()) thread_.join();
}

std::vector<Edge> GpiodObserver::edges() {
  std::lock_guard lock(mutex_);
  return edges_;
}

std::string GpiodObserver::error() {
  std::lock_guard lock(mutex_);
  return error_;
}

void GpiodObserver::run() {
  std::uint64_t last_seqno = 0;
  while (!quit_) {
    auto events = request_->wait_edges(50 * 1'000'000);
    std::lock_guard lock(mutex_);
    if (!events) {
      error_ = events.error().message;
      return;
    }
    for (const auto& e : *events) {
      // A seqno gap is the kernel's event buffer overflowing: edges were lost to the observer.
      if (last_seqno != 0 && e.seqno != last_seqno + 1 && error_.empty()) {
        error_ = "the kernel dropped " + std::to_string(e.seqno - last_seqno - 1) + " edge events";
      }
      last_seqno = e.seqno;
      for (const auto& [input, watched] : map_) {
        if (input == e.offset) edges_.push_back({watched, e.rising, e.timestamp_ns});
      }
    }
  }
}

}  // namespace slscan::hil
