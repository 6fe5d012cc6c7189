#include "slscand/app/daemon.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <thread>
#include <vector>

#include "slproto/calibration.hpp"
#include "slproto/handshake.hpp"
#include "slscand/app/security.hpp"
#include "slscand/sequencer/realtime.hpp"
#if defined(SLSCAND_HAVE_SIM)
#include "slscand/hal/sim/sim_rig.hpp"
#endif

namespace slscand {

using slproto::Errc;
using slproto::make_error;
namespace pb = slproto::pb;
using namespace std::chrono_literals;

#ifndef SLSCAN_VERSION
#error "SLSCAN_VERSION must be defined by the build (the project version)"
#endif

const char* software_version() { return "slscand " SLSCAN_VERSION; }

namespace {
// A host that connects just after the previous one left may arrive before the daemon saw the
// previous one go (its receive loop polls): wait this long before treating it as a second host.
constexpr auto kPrimaryGrace = 2s;
// A status-only connection is for a quick question; it is closed after this long.
constexpr auto kStatusOnlyLifetime = 10s;

const char* state_name(pb::ScanState state) {
  switch (state) {
    case pb::SCAN_STATE_DONE:
      return "done";
    case pb::SCAN_STATE_ABORTED:
      return "aborted";
    case pb::SCAN_STATE_FAILED:
      return "failed";
    default:
      return "running";
  }
}
}  // namespace

void add_timing_stats(const TimingReport& report, pb::ScanDone& done) {
  for (const auto& s : report.all()) {
    pb::TimingStat* stat = done.add_timing();
    stat->set_name(s.name);
    stat->set_count(s.count);
    stat->set_mean_us(s.mean_us);
    stat->set_stddev_us(s.stddev_us);
    stat->set_min_us(s.min_us);
    stat->set_max_us(s.max_us);
    stat->set_p99_us(s.p99_us);
  }
}

slproto::Result<std::unique_ptr<Daemon>> Daemon::create(hal::BoardConfig board, hal::BoardDevices devices,
                                                        DaemonOptions options) {
  const std::string address = options.bind_address.empty() ? board.bind_address : options.bind_address;
  const int port = options.port < 0 ? board.port : options.port;
  if (auto policy = check_listen_policy(address, !options.auth_token.empty(), options.insecure_no_token); !policy)
    return policy.error();
  options.connection.limits = kHostMessageLimits;
  if (port > 65535) return make_error(Errc::invalid_argument, "port " + std::to_string(port) + " is out of range");
  slproto::ServerOptions server_options;
  server_options.connection = options.connection;
  auto server = slproto::Server::listen(address, static_cast<std::uint16_t>(port), server_options);
  if (!server) return std::move(server).error();
  return std::unique_ptr<Daemon>(
      new Daemon(std::move(board), std::move(devices), std::move(options), std::move(*server)));
}

Daemon::Daemon(hal::BoardConfig board, hal::BoardDevices devices, DaemonOptions options, slproto::Server server)
    : board_(std::move(board)),
      devices_(std::move(devices)),
      options_(std::move(options)),
      server_(std::move(server)),
      sequencer_(devices_, board_) {}

Daemon::~Daemon() {
  stop();
  sequencer_.make_safe(false);
}

void Daemon::stop() { stop_ = true; }

DaemonStats Daemon::stats() const {
  std::lock_guard lock(stats_mutex_);
  return stats_;
}

void Daemon::serve() {
  // Every connection gets its own thread: a silent or slow peer (handshake timeout) must not
  // hold up the accept loop, the scanning host, or a status question. The scanner itself is
  // claimed only by a host that has passed the handshake, so a silent connection cannot make
  // the daemon refuse the real host (docs/security.md).
  // A connection's place: while it is in its hello it can be dropped for a newcomer.
  struct Slot {
    std::mutex mutex;
    slproto::Connection* connection = nullptr;  // set while in the hello
    bool in_hello = true;
    bool served = false;  // past its hello: counts against max_connections
  };
  struct Worker {
    std::thread thread;
    std::shared_ptr<std::atomic<bool>> finished;
    std::shared_ptr<Slot> slot;
    std::uint64_t order = 0;  // accept order: the oldest hello is dropped first
  };
  std::vector<Worker> workers;
  std::uint64_t accepted = 0;
  auto reap = [&workers](bool all) {
    for (auto it = workers.begin(); it != workers.end();) {
      if (all || it->finished->load()) {
        it->thread.join();
        it = workers.erase(it);
      } else {
        ++it;
      }
    }
  };
  while (!stop_) {
    auto connection = server_.accept(100ms);
    reap(false);
    if (!connection) continue;  // timeout, or a client that vanished during accept
    {
      std::lock_guard lock(stats_mutex_);
      stats_.connections++;
    }
    std::size_t served = 0;
    std::vector<Worker*> in_hello;
    for (auto& worker : workers) {
      std::lock_guard lock(worker.slot->mutex);
      if (worker.slot->in_hello)
        in_hello.push_back(&worker);
      else if (worker.slot->served)
        ++served;
    }
    if (in_hello.size() >= options_.max_handshakes) {
      // Make room: the hello that has waited longest goes (its handshake fails at once).
      Worker* oldest = *std::min_element(in_hello.begin(), in_hello.end(),
                                         [](const Worker* a, const Worker* b) { return a->order < b->order; });
      std::lock_guard lock(oldest->slot->mutex);
      if (oldest->slot->in_hello && oldest->slot->connection != nullptr) {
        std::fprintf(stderr, "slscand: dropped %s: still in its hello while %zu newer connections wait\n",
                     oldest->slot->connection->peer_address().c_str(), in_hello.size());
        oldest->slot->connection->interrupt();
        oldest->slot->in_hello = false;
        oldest->slot->connection = nullptr;
      }
    }
    if (served >= options_.max_connections) {
      const std::string why =
          "busy: slscand already serves " + std::to_string(served) + " connections (the limit); try again later";
      std::fprintf(stderr, "slscand: turned away %s: %s\n", connection->peer_address().c_str(), why.c_str());
      (void)connection->send(slproto::to_proto(make_error(Errc::busy, why), 0, /*fatal=*/true), 200ms);
      connection->close();
      std::lock_guard lock(stats_mutex_);
      stats_.connections_turned_away++;
      continue;
    }
    auto finished = std::make_shared<std::atomic<bool>>(false);
    auto slot = std::make_shared<Slot>();
    auto owned = std::make_shared<slproto::Connection>(std::move(*connection));
    slot->connection = owned.get();
    std::thread thread([this, finished, slot, owned]() mutable {
      serve_connection(*owned, [&slot](bool passed) {
        std::lock_guard lock(slot->mutex);
        slot->in_hello = false;
        slot->served = passed;
        slot->connection = nullptr;
      });
      {
        std::lock_guard lock(slot->mutex);  // not dropped while it closes
        slot->in_hello = false;
        slot->served = false;
        slot->connection = nullptr;
      }
      owned->close();
      *finished = true;
    });
    workers.push_back(Worker{std::move(thread), std::move(finished), std::move(slot), accepted++});
  }
  reap(true);
}

bool Daemon::try_claim_scanner(std::chrono::milliseconds grace, const std::string& peer) {
  for (auto waited = 0ms;; waited += 10ms) {
    bool expected = false;
    if (primary_active_.compare_exchange_strong(expected, true)) {
      std::lock_guard lock(primary_mutex_);
      primary_peer_ = peer;
      return true;
    }
    if (waited >= grace || stop_) return false;
    std::this_thread::sleep_for(10ms);
  }
}

void Daemon::release_scanner() {
  {
    std::lock_guard lock(primary_mutex_);
    primary_peer_.clear();
  }
  primary_active_ = false;
}

void Daemon::release_admission() {
  std::lock_guard lock(admission_mutex_);
  if (admitted_connections_ > 0) --admitted_connections_;
}

void Daemon::serve_connection(slproto::Connection& connection, const std::function<void(bool passed)>& hello_done) {
  const std::uint32_t negotiated = handshake(connection);
  hello_done(negotiated != 0);
  if (negotiated == 0) return;
  struct Admission {
    explicit Admission(Daemon* owner) : daemon(owner) {}
    ~Admission() { daemon->release_admission(); }
    Admission(const Admission&) = delete;
    Admission& operator=(const Admission&) = delete;
    Daemon* daemon;
  } const admission{this};
  const std::string peer = connection.peer_address();
  if (!try_claim_scanner(0ms, peer)) {
    // Another host has the scanner: status questions are answered at once. Only a scan request
    // tries again to claim it (the other host may just have left).
    auto request = handle_status_only(connection, negotiated);
    if (!request) return;
    negotiated_ = negotiated;
    const bool connected = run_scan(connection, *request);
    if (connected) handle_connection(connection, negotiated);
    release_scanner();
    return;
  }
  negotiated_ = negotiated;
  handle_connection(connection, negotiated);
  release_scanner();
}

std::uint64_t Daemon::capabilities() const {
  return pb::CAPABILITY_TURNTABLE | pb::CAPABILITY_TWO_PROJECTORS | pb::CAPABILITY_TIMING_LOG |
         pb::CAPABILITY_EXPOSURE_BRACKET |
         (board_.trigger_source == hal::CameraTriggerSource::projector ? pb::CAPABILITY_HARDWARE_TRIGGER : 0) |
         (devices_.simulated() ? pb::CAPABILITY_SIMULATED : 0) |
         (devices_.places_calibration_target() ? pb::CAPABILITY_CALIBRATION_TARGET : 0);
}

std::uint32_t Daemon::handshake(slproto::Connection& connection) {
  slproto::ServerIdentity identity;
  identity.board_name = board_.name;
  identity.software_version = software_version();
  identity.capabilities = capabilities();
  identity.camera.set_width(static_cast<std::uint32_t>(devices_.camera_format.width));
  identity.camera.set_height(static_cast<std::uint32_t>(devices_.camera_format.height));
  identity.camera.add_pixel_formats(to_proto(devices_.camera_format.pixel_format));
  identity.camera.set_model(devices_.camera->describe());
  identity.projector_count = 2;
  identity.pattern_exposure_us = static_cast<std::uint32_t>(std::lround(board_.pattern_exposure_us));
  identity.pattern_period_us = static_cast<std::uint32_t>(std::lround(board_.pattern_period_us));
  identity.auth_token = options_.auth_token;
  // The connection limit is checked as the hello is answered, not only at accept: a host
  // accepted just before may not have been counted yet when this one was accepted.
  bool admitted = false;
  auto hello = slproto::server_handshake(connection, identity, options_.handshake_timeout, [&]() -> slproto::Status {
    std::lock_guard lock(admission_mutex_);
    if (admitted_connections_ >= options_.max_connections)
      return make_error(Errc::busy, "busy: slscand already serves " + std::to_string(admitted_connections_) +
                                        " connections (the limit); try again later");
    ++admitted_connections_;
    admitted = true;
    return {};
  });
  if (!hello && admitted) release_admission();
  if (!hello) {
    std::fprintf(stderr, "slscand: %s\n", hello.error().message.c_str());
    std::lock_guard lock(stats_mutex_);
    stats_.handshakes_failed++;
    stats_.last_error = hello.error().message;
    return 0;
  }
  return std::min<std::uint32_t>(hello->protocol_version(), identity.versions.max);
}

pb::StatusReply Daemon::status_reply(std::uint32_t negotiated) const {
  pb::StatusReply reply;
  reply.set_board_name(board_.name);
  reply.set_software_version(software_version());
  reply.set_protocol_version(negotiated);
  reply.set_min_protocol_version(slproto::min_protocol_version);
  reply.set_max_protocol_version(slproto::protocol_version);
  reply.set_capabilities(capabilities());
  reply.set_backends(hal::available_backends());
  reply.set_uptime_ns(static_cast<std::uint64_t>(
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - started_).count()));
  reply.set_scanning(scanning_);
  std::lock_guard lock(stats_mutex_);
  reply.set_connections(stats_.connections);
  reply.set_scans_done(stats_.scans_done);
  reply.set_scans_aborted(stats_.scans_aborted);
  reply.set_scans_failed(stats_.scans_failed);
  reply.set_scans_refused(stats_.scans_refused);
  reply.set_last_error(stats_.last_error);
  if (stats_.has_last_scan) *reply.mutable_last_scan() = stats_.last_scan;
  return reply;
}

std::string Daemon::busy_reason() const {
  std::string holder;
  {
    std::lock_guard lock(primary_mutex_);
    holder = primary_peer_.empty() ? std::string("another host") : primary_peer_;
  }
  return scanning_ ? "busy: scan in progress for " + holder
                   : "busy: host " + holder + " is connected (one host at a time)";
}

std::optional<pb::ScanRequest> Daemon::handle_status_only(slproto::Connection& connection, std::uint32_t negotiated) {
  const auto deadline = std::chrono::steady_clock::now() + kStatusOnlyLifetime;
  while (!stop_ && std::chrono::steady_clock::now() < deadline) {
    auto message = connection.receive(100ms);
    if (!message) {
      if (message.error().code == Errc::timeout) continue;
      return std::nullopt;
    }
    if (message->get<pb::StatusRequest>() != nullptr) {
      if (!connection.send(status_reply(negotiated))) return std::nullopt;
      continue;
    }
    if (message->get<pb::Error>() != nullptr) continue;
    std::uint64_t scan_id = 0;
    if (const auto* request = message->get<pb::ScanRequest>()) {
      // A host that reconnects just after leaving may get here before its old connection's
      // receive loop has noticed the close: give the old one a moment to let go.
      const pb::ScanRequest copy = *request;
      if (try_claim_scanner(kPrimaryGrace, connection.peer_address())) return copy;
      scan_id = copy.scan_id();
    } else if (const auto* abort = message->get<pb::Abort>()) {
      scan_id = abort->scan_id();
    }
    // A scan request or an abort from a second host: it cannot touch the scanner.
    const std::string why = busy_reason();
    std::fprintf(stderr, "slscand: turned away %s (%s): %s\n", connection.peer_address().c_str(),
                 slproto::message_type_name(message->type()), why.c_str());
    {
      std::lock_guard lock(stats_mutex_);
      stats_.connections_turned_away++;
    }
    (void)connection.send(slproto::to_proto(make_error(Errc::busy, why + "; this connection may only ask for status"),
                                            scan_id, /*fatal=*/true));
    return std::nullopt;
  }
  return std::nullopt;
}

void Daemon::handle_connection(slproto::Connection& connection, std::uint32_t negotiated) {
  while (!stop_) {
    auto message = connection.receive(100ms);
    if (!message) {
      if (message.error().code == Errc::timeout) continue;
      return;  // disconnected or a broken stream
    }
    if (const auto* request = message->get<pb::ScanRequest>()) {
      const pb::ScanRequest copy = *request;  // the message buffer is reused by the next receive
      if (!run_scan(connection, copy)) return;
    } else if (message->get<pb::StatusRequest>() != nullptr) {
      if (!connection.send(status_reply(negotiated))) return;
    } else if (const auto* abort = message->get<pb::Abort>()) {
      (void)connection.send(
          slproto::to_proto(make_error(Errc::invalid_argument, "no scan is running"), abort->scan_id()));
    } else if (message->get<pb::Error>() == nullptr) {
      (void)connection.send(slproto::to_proto(
          make_error(Errc::unsupported, std::string("slscand does not accept ") +
                                            slproto::message_type_name(message->type()) + " messages"),
          0));
    }
  }
}

bool Daemon::run_scan(slproto::Connection& connection, const pb::ScanRequest& request) {
  auto plan = make_scan_plan(request, board_, devices_.camera_format);
  if (!plan) {
    {
      std::lock_guard lock(stats_mutex_);
      stats_.scans_refused++;
      stats_.last_error = plan.error().message;
    }
    std::fprintf(stderr, "slscand: %s\n", plan.error().message.c_str());
    (void)connection.send(slproto::to_proto(plan.error(), request.scan_id()));
    pb::ScanDone done;
    done.set_scan_id(request.scan_id());
    done.set_final_state(pb::SCAN_STATE_FAILED);
    done.set_text(plan.error().message);
    return connection.send(done).ok();
  }
  {
    std::lock_guard lock(stats_mutex_);
    stats_.scans_started++;
  }
  scanning_ = true;
#if defined(SLSCAND_HAVE_SIM)
  // The bus's edge record goes out with this scan's timing log: start it empty.
  if (devices_.sim_rig && !options_.timing_log_dir.empty()) devices_.sim_rig->clear_records();
#endif

  BoundedQueue<SequencedFrame> queue(options_.queue_capacity);
  std::atomic<bool> abort{false};
  std::atomic<bool> connection_lost{false};
  std::mutex cause_mutex;
  std::string abort_cause;
  auto set_abort = [&](const std::string& cause) {
    std::lock_guard lock(cause_mutex);
    if (abort_cause.empty()) abort_cause = cause;
    abort = true;
  };

  std::uint64_t frames_sent = 0;
  std::vector<TimingEvent> sent_events;
  std::thread streamer([&] {
    for (;;) {
      std::optional<SequencedFrame> item = queue.pop(50ms);
      if (!item) {
        if (queue.closed_and_empty()) return;
        continue;
      }
      if (connection_lost) continue;  // drain: the scan is ending
      pb::FrameHeader header = make_frame_header(*item, plan->timing_events);
      auto status = connection.send_frame(header, std::as_bytes(std::span(item->frame.pixels)));
      if (!status) {
        connection_lost = true;
        set_abort("host connection lost while streaming: " + status.error().message);
        continue;
      }
      frames_sent++;
      sent_events.push_back(TimingEvent{pb::TIMING_EVENT_FRAME_SENT, monotonic_now_ns(), 0});
    }
  });

  ScanOutcome outcome;
  std::thread runner([&] {
    if (options_.realtime && board_.realtime) {
      const RealtimeResult rt = enter_realtime(board_.realtime_priority, board_.cpu);
      if (!rt.warnings.empty() && realtime_warning_ != rt.warnings) {
        realtime_warning_ = rt.warnings;
        std::fprintf(stderr, "slscand: warning: %s\n", rt.warnings.c_str());
      }
    }
    outcome = sequencer_.run(*plan, queue, abort, [&](const pb::Progress& p) {
      if (!connection_lost) (void)connection.send(p);
    });
    queue.close();
  });

  // Meanwhile, listen to the host: Abort, a second ScanRequest (busy), or its disappearance.
  while (!queue.closed_and_empty()) {
    auto message = connection.receive(20ms);
    if (!message) {
      if (message.error().code == Errc::timeout) continue;
      connection_lost = true;
      set_abort("host disconnected: " + message.error().message);
      break;
    }
    if (const auto* a = message->get<pb::Abort>()) {
      if (a->scan_id() == 0 || a->scan_id() == plan->scan_id) {
        set_abort("aborted by the host" + (a->reason().empty() ? std::string() : ": " + a->reason()));
      }
    } else if (const auto* r = message->get<pb::ScanRequest>()) {
      (void)connection.send(slproto::to_proto(
          make_error(Errc::busy, "scan " + std::to_string(plan->scan_id) + " is running"), r->scan_id()));
    } else if (message->get<pb::StatusRequest>() != nullptr) {
      (void)connection.send(status_reply(negotiated_));
    }
  }
  runner.join();
  queue.close();
  streamer.join();
  scanning_ = false;

  if (outcome.state == pb::SCAN_STATE_ABORTED) {
    std::lock_guard lock(cause_mutex);
    // The host's cause first; the sequencer's detail (where a turntable move was cut short)
    // after it, unless it is only the generic "scan aborted".
    std::string text = abort_cause.empty() ? "aborted" : abort_cause;
    if (!outcome.error.message.empty() && outcome.error.message != "scan aborted") {
      text += " (" + outcome.error.message + ")";
    }
    outcome.error = make_error(Errc::aborted, text);
  }
  if (connection_lost && outcome.state == pb::SCAN_STATE_DONE && frames_sent < outcome.frames_captured) {
    outcome.state = pb::SCAN_STATE_FAILED;
    outcome.error = make_error(Errc::disconnected, abort_cause);
  }
  const TimingReport report = make_timing_report(outcome.frames, static_cast<double>(plan->period_ns) / kMicro);
  {
    std::lock_guard lock(stats_mutex_);
    if (outcome.state == pb::SCAN_STATE_DONE)
      stats_.scans_done++;
    else if (outcome.state == pb::SCAN_STATE_ABORTED)
      stats_.scans_aborted++;
    else
      stats_.scans_failed++;
    if (outcome.state != pb::SCAN_STATE_DONE) stats_.last_error = outcome.error.message;
    stats_.last_timing = report;
    stats_.last_backpressure_pauses = outcome.backpressure_pauses;
    pb::LastScan& last = stats_.last_scan;
    last.set_scan_id(plan->scan_id);
    last.set_final_state(outcome.state);
    last.set_finished_unix_ns(static_cast<std::uint64_t>(
        std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
            .count()));
    last.set_views_completed(outcome.views_completed);
    last.set_views_requested(static_cast<std::uint32_t>(request.turntable_angles_deg_size()));
    last.set_frames_sent(frames_sent);
    last.set_frames_total(plan->frames_total());
    last.set_duration_ns(static_cast<std::uint64_t>(outcome.duration_ns));
    last.set_text(outcome.state == pb::SCAN_STATE_DONE ? "scan complete" : outcome.error.message);
    last.set_host(connection.peer_address());
    stats_.has_last_scan = true;
  }
  std::fprintf(stderr, "slscand: scan %llu %s: %llu of %llu frames sent%s%s\n",
               static_cast<unsigned long long>(plan->scan_id), state_name(outcome.state),
               static_cast<unsigned long long>(frames_sent), static_cast<unsigned long long>(plan->frames_total()),
               outcome.state == pb::SCAN_STATE_DONE ? "" : ": ", outcome.error.message.c_str());
  const hal::CameraLinkStats& link = outcome.camera_link;
  if (link.frames_completed + link.frames_failed + link.packets_missing + link.packets_resent > 0) {
    std::fprintf(
        stderr,
        "slscand: camera link: %llu frames received, %llu lost, %llu underruns; packets %llu missing, %llu "
        "resent (%llu resend requests)\n",
        static_cast<unsigned long long>(link.frames_completed), static_cast<unsigned long long>(link.frames_failed),
        static_cast<unsigned long long>(link.underruns), static_cast<unsigned long long>(link.packets_missing),
        static_cast<unsigned long long>(link.packets_resent), static_cast<unsigned long long>(link.resend_requests));
  }
  write_timing_log(*plan, outcome, sent_events);
  if (connection_lost) return false;

  if (outcome.state == pb::SCAN_STATE_FAILED) {
    (void)connection.send(slproto::to_proto(outcome.error, plan->scan_id));
  }
  pb::ScanDone done;
  done.set_scan_id(plan->scan_id);
  done.set_final_state(outcome.state);
  done.set_frames_sent(frames_sent);
  done.set_views_completed(outcome.views_completed);
  done.set_duration_ns(static_cast<std::uint64_t>(outcome.duration_ns));
  done.set_frames_dropped(0);  // never: back-pressure pauses the sequencer instead
  done.set_text(outcome.state == pb::SCAN_STATE_DONE ? "scan complete" : outcome.error.message);
  done.set_camera_frames_lost(outcome.camera_link.frames_failed + outcome.camera_link.underruns);
  done.set_camera_packets_missing(outcome.camera_link.packets_missing);
  done.set_camera_packets_resent(outcome.camera_link.packets_resent);
  done.set_camera_resend_requests(outcome.camera_link.resend_requests);
  add_timing_stats(report, done);
  return connection.send(done).ok();
}

void Daemon::write_timing_log(const ScanPlan& plan, const ScanOutcome& outcome, const std::vector<TimingEvent>& sent) {
  if (options_.timing_log_dir.empty()) return;
  std::string text = "# slscand timing log: kind,monotonic_ns,source\n";
  auto add = [&](const TimingEvent& e) {
    text += std::string(pb::TimingEventKind_Name(e.kind)) + "," + std::to_string(e.monotonic_ns) + "," +
            std::to_string(e.source) + "\n";
  };
  for (const auto& e : outcome.events) add(e);
  for (const auto& e : sent) add(e);
  const std::string path = options_.timing_log_dir + "/scan-" + std::to_string(plan.scan_id) + "-timing.csv";
  if (auto s = slproto::write_file_atomically(path, text); !s) {
    std::fprintf(stderr, "slscand: warning: cannot write the timing log: %s\n", s.error().message.c_str());
  }
#if defined(SLSCAND_HAVE_SIM)
  // The virtual bus's own record of the edges it carried, as a logic analyser on the trigger
  // lines would capture them: the HIL harness (tests/hil) checks the log above against it.
  if (devices_.sim_rig) {
    std::string edges = "# slscand sim GPIO bus edges: offset,rising,monotonic_ns\n";
    for (const auto& e : devices_.sim_rig->recorded_edges()) {
      edges += std::to_string(e.offset) + "," + (e.rising ? "1" : "0") + "," + std::to_string(e.timestamp_ns) + "\n";
    }
    const std::string edges_path = options_.timing_log_dir + "/scan-" + std::to_string(plan.scan_id) + "-edges.csv";
    if (auto s = slproto::write_file_atomically(edges_path, edges); !s) {
      std::fprintf(stderr, "slscand: warning: cannot write the GPIO edge record: %s\n", s.error().message.c_str());
    }
  }
#endif
}

}  // namespace slscand
