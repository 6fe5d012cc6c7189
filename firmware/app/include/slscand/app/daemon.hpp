// slscand's server: one host at a time over slproto/TCP. A connection is a hello exchange, then
// any number of scans: ScanRequest -> Progress / frames (each with its timing events) ->
// ScanDone, with Error before ScanDone when a scan fails. Abort, a host that disconnects and
// every device fault end the scan through the sequencer's one clean-up path, and the daemon
// waits for the next scan (or the next host).
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "slproto/transport.hpp"
#include "slscand/hal/backends.hpp"
#include "slscand/sequencer/sequencer.hpp"

namespace slscand {

struct DaemonOptions {
  std::string bind_address;        // "" = the board's
  int port = -1;                   // -1 = the board's, 0 = any free port
  std::string timing_log_dir;      // "" = do not write timing logs on the board
  std::string auth_token;          // "" = none required (refused on a non-loopback address...
  bool insecure_no_token = false;  // ...unless this is set: security.hpp, check_listen_policy)
  std::size_t queue_capacity = 8;  // frames between the sequencer and the streamer
  bool realtime = true;            // SCHED_FIFO + mlockall if the board allows it
  slproto::ConnectionOptions connection;
  // A connection must complete its hello within this (a silent or trickling peer is dropped).
  std::chrono::milliseconds handshake_timeout{3000};
  // Connections served at once past their hello (the scanning host, status questions); one
  // more is told "busy" and closed at once.
  std::size_t max_connections = 4;
  // Connections still in their hello (each dropped at handshake_timeout), counted apart from
  // max_connections, so silent connections cannot turn a real host away; when this many are
  // waiting the oldest is dropped for the newcomer (docs/security.md, "Limits").
  std::size_t max_handshakes = 64;
};

// What slscand accepts from a host (docs/security.md): a host sends only control messages, so
// frames with pixel payloads are refused, and control messages are small.
inline constexpr slproto::DecoderLimits kHostMessageLimits{64u << 10, 0};

struct DaemonStats {
  std::uint64_t connections = 0;
  std::uint64_t scans_started = 0;
  std::uint64_t scans_done = 0;
  std::uint64_t scans_aborted = 0;
  std::uint64_t scans_failed = 0;
  std::uint64_t scans_refused = 0;
  std::uint64_t handshakes_failed = 0;        // silent, wrong token, wrong version, garbage
  std::uint64_t connections_turned_away = 0;  // a second host while one was served
  std::string last_error;
  // The last scan that ran (any ending): its timing report with every percentile (ScanDone
  // carries only mean/stddev/min/max/p99) and how often back-pressure paused the sequencer.
  TimingReport last_timing;
  std::uint64_t last_backpressure_pauses = 0;
  // What StatusReply.last_scan carries; has_last_scan() is false until a scan ran.
  slproto::pb::LastScan last_scan;
  bool has_last_scan = false;
};

// slscand's version ("slscand 0.2.0"), from the project version.
const char* software_version();

class Daemon {
 public:
  static slproto::Result<std::unique_ptr<Daemon>> create(hal::BoardConfig board, hal::BoardDevices devices,
                                                         DaemonOptions options);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  std::uint16_t port() const { return server_.port(); }
  // Serves hosts until stop() is called (from any thread). One host at a time uses the scanner;
  // a host that connects meanwhile gets a status-only connection (StatusRequest is answered,
  // ScanRequest gets Errc::busy naming the host that has the scanner).
  void serve();
  void stop();
  bool busy() const { return scanning_.load(); }
  DaemonStats stats() const;
  hal::BoardDevices& devices() { return devices_; }
  const hal::BoardConfig& board() const { return board_; }
  // Whether its devices are the virtual rig's (CAPABILITY_SIMULATED).
  bool simulated() const { return devices_.simulated(); }

 private:
  Daemon(hal::BoardConfig board, hal::BoardDevices devices, DaemonOptions options, slproto::Server server);
  // One connection, on its own thread: the hello, then the scanner if no other host holds it,
  // else a status-only connection.
  // `hello_done(passed)` is called once the hello is over.
  void serve_connection(slproto::Connection& connection, const std::function<void(bool passed)>& hello_done);
  // The host that holds the scanner: scans, aborts, status.
  void handle_connection(slproto::Connection& connection, std::uint32_t negotiated);
  // Any other host: StatusRequest is answered; a ScanRequest or Abort gets Errc::busy naming
  // the host that has the scanner, and the connection is closed. Returns the scan request if
  // the scanner became free for it (this connection now holds it).
  std::optional<slproto::pb::ScanRequest> handle_status_only(slproto::Connection& connection, std::uint32_t negotiated);
  // Takes the scanner for `peer`, waiting up to `grace` for the holder to let go.
  bool try_claim_scanner(std::chrono::milliseconds grace, const std::string& peer);
  void release_scanner();
  // The hello exchange; the negotiated protocol version, 0 if the hello was refused.
  std::uint32_t handshake(slproto::Connection& connection);
  void release_admission();  // a connection admitted by its hello has ended
  slproto::pb::StatusReply status_reply(std::uint32_t negotiated) const;
  std::uint64_t capabilities() const;
  std::string busy_reason() const;
  // False when the connection is gone.
  bool run_scan(slproto::Connection& connection, const slproto::pb::ScanRequest& request);
  void write_timing_log(const ScanPlan& plan, const ScanOutcome& outcome, const std::vector<TimingEvent>& sent);

  hal::BoardConfig board_;
  hal::BoardDevices devices_;
  DaemonOptions options_;
  slproto::Server server_;
  Sequencer sequencer_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> scanning_{false};
  mutable std::mutex stats_mutex_;
  DaemonStats stats_;
  std::mutex admission_mutex_;
  std::size_t admitted_connections_ = 0;  // past their hello, counted against max_connections
  std::string realtime_warning_;
  std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
  std::atomic<bool> primary_active_{false};
  std::atomic<std::uint32_t> negotiated_{0};  // the primary connection's protocol version
  mutable std::mutex primary_mutex_;
  std::string primary_peer_;
};

// Frame-delivery statistics for ScanDone.
void add_timing_stats(const TimingReport& report, slproto::pb::ScanDone& done);

}  // namespace slscand
