#include "status.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>

#include "progress.hpp"
#include "slproto/handshake.hpp"
#include "slproto/status.hpp"
#include "slproto/transport.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::app {

namespace pb = slproto::pb;

std::pair<std::string, std::uint16_t> parse_scanner_address(const std::string& text) {
  std::string host = text;
  std::string port_text;
  if (!text.empty() && text.front() == '[') {
    const auto close = text.find(']');
    if (close == std::string::npos) throw std::invalid_argument("scanner address '" + text + "': no closing ']'");
    host = text.substr(1, close - 1);
    if (close + 1 < text.size()) {
      if (text[close + 1] != ':') throw std::invalid_argument("scanner address '" + text + "': ':' expected after ']'");
      port_text = text.substr(close + 2);
    }
  } else if (const auto colon = text.rfind(':'); colon != std::string::npos && text.find(':') == colon) {
    host = text.substr(0, colon);  // one colon: HOST:PORT (more than one: a bare IPv6 literal)
    port_text = text.substr(colon + 1);
  }
  if (host.empty()) throw std::invalid_argument("scanner address '" + text + "': no host");
  if (port_text.empty() && text.size() > host.size() && text.back() == ':')
    throw std::invalid_argument("scanner address '" + text + "': empty port");
  std::uint16_t port = default_scanner_port;
  if (!port_text.empty()) {
    std::size_t used = 0;
    long value = -1;
    try {
      value = std::stol(port_text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != port_text.size() || value < 1 || value > 65535)
      throw std::invalid_argument("scanner address '" + text + "': port '" + port_text + "' is not 1..65535");
    port = static_cast<std::uint16_t>(value);
  }
  return {host, port};
}

std::string read_token_file(const std::string& path) {
  const char* env_token_file = std::getenv("SLSCAN_TOKEN_FILE");
  const std::string file = !path.empty() ? path : (env_token_file != nullptr ? env_token_file : "");
  if (file.empty()) return {};
  std::ifstream in(file);
  if (!in) throw io::IoError(file + ": cannot read the token file");
  std::string token;
  std::getline(in, token);
  while (!token.empty() && (token.back() == '\r' || token.back() == ' ' || token.back() == '\t')) token.pop_back();
  token.erase(0, std::min(token.find_first_not_of(" \t"), token.size()));
  if (token.empty()) throw io::IoError(file + ": the token file is empty");
  return token;
}

namespace {

const char* state_text(pb::ScanState state) {
  switch (state) {
    case pb::SCAN_STATE_DONE:
      return "done";
    case pb::SCAN_STATE_ABORTED:
      return "aborted";
    case pb::SCAN_STATE_FAILED:
      return "failed";
    default:
      return "unfinished";
  }
}

std::string duration_text(double seconds) {
  char buffer[64];
  if (seconds < 120)
    std::snprintf(buffer, sizeof buffer, "%.1f s", seconds);
  else if (seconds < 7200)
    std::snprintf(buffer, sizeof buffer, "%.0f min", seconds / 60);
  else if (seconds < 172800)
    std::snprintf(buffer, sizeof buffer, "%.1f h", seconds / 3600);
  else
    std::snprintf(buffer, sizeof buffer, "%.1f days", seconds / 86400);
  return buffer;
}

std::string utc_text(std::uint64_t unix_ns) {
  const std::time_t t = static_cast<std::time_t>(unix_ns / 1'000'000'000u);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof buffer, "%Y-%m-%d %H:%M:%S UTC", &tm);
  return buffer;
}

nlohmann::json to_json(const pb::StatusReply& s, const std::string& address) {
  nlohmann::json j = {{"address", address},
                      {"board", s.board_name()},
                      {"software_version", s.software_version()},
                      {"protocol_version", s.protocol_version()},
                      {"protocol_range", {s.min_protocol_version(), s.max_protocol_version()}},
                      {"backends", s.backends()},
                      {"uptime_s", static_cast<double>(s.uptime_ns()) * 1e-9},
                      {"scanning", s.scanning()},
                      {"connections", s.connections()},
                      {"scans",
                       {{"done", s.scans_done()},
                        {"aborted", s.scans_aborted()},
                        {"failed", s.scans_failed()},
                        {"refused", s.scans_refused()}}},
                      {"last_error", s.last_error()},
                      {"last_scan", nullptr}};
  if (s.has_last_scan()) {
    const pb::LastScan& l = s.last_scan();
    j["last_scan"] = {{"scan_id", l.scan_id()},
                      {"result", state_text(l.final_state())},
                      {"finished_unix_s", static_cast<double>(l.finished_unix_ns()) * 1e-9},
                      {"views_completed", l.views_completed()},
                      {"views_requested", l.views_requested()},
                      {"frames_sent", l.frames_sent()},
                      {"frames_total", l.frames_total()},
                      {"duration_s", static_cast<double>(l.duration_ns()) * 1e-9},
                      {"text", l.text()},
                      {"host", l.host()}};
  }
  return j;
}

}  // namespace

std::string format_status(const pb::StatusReply& s, const std::string& address, std::int64_t now_unix_ns) {
  std::string out;
  auto line = [&](const std::string& key, const std::string& value) { out += key + ": " + value + "\n"; };
  line("scanner", address);
  line("board", s.board_name() + ((s.capabilities() & pb::CAPABILITY_SIMULATED) ? " (simulated)" : ""));
  line("firmware", s.software_version() + " (backends: " + s.backends() + ")");
  line("protocol", "slproto " + std::to_string(s.protocol_version()) + " in use; the board speaks " +
                       std::to_string(s.min_protocol_version()) + ".." + std::to_string(s.max_protocol_version()) +
                       ", this host " + std::to_string(slproto::min_protocol_version) + ".." +
                       std::to_string(slproto::protocol_version));
  line("uptime", duration_text(static_cast<double>(s.uptime_ns()) * 1e-9));
  line("state", s.scanning() ? "scanning" : "idle");
  line("scans", std::to_string(s.scans_done()) + " done, " + std::to_string(s.scans_aborted()) + " aborted, " +
                    std::to_string(s.scans_failed()) + " failed, " + std::to_string(s.scans_refused()) +
                    " refused since start (" + std::to_string(s.connections()) + " connections)");
  if (!s.has_last_scan()) {
    line("last scan", "none since slscand started");
  } else {
    const pb::LastScan& l = s.last_scan();
    const double ago = static_cast<double>(now_unix_ns - static_cast<std::int64_t>(l.finished_unix_ns())) * 1e-9;
    line("last scan", std::string(state_text(l.final_state())) + ", scan " + std::to_string(l.scan_id()) + " from " +
                          l.host() + ", finished " + utc_text(l.finished_unix_ns()) + " (" +
                          duration_text(std::max(0.0, ago)) + " ago)");
    line("  views", std::to_string(l.views_completed()) + " of " + std::to_string(l.views_requested()));
    line("  frames", std::to_string(l.frames_sent()) + " of " + std::to_string(l.frames_total()) + " sent");
    line("  duration", duration_text(static_cast<double>(l.duration_ns()) * 1e-9));
    line("  result", l.text());
  }
  if (!s.last_error().empty()) line("last error", s.last_error());
  return out;
}

std::string format_discovered(const std::vector<slproto::DiscoveredScanner>& scanners) {
  std::string out;
  for (const auto& s : scanners) {
    const std::string where =
        (s.address.find(':') != std::string::npos ? "[" + s.address + "]" : s.address) + ":" + std::to_string(s.port);
    out += s.instance + "  " + where + " (" + s.host_name + (s.interface.empty() ? "" : " on " + s.interface) + ")  ";
    auto advert = slproto::from_txt_records(s.txt);
    if (!advert) {
      out += "unreadable announcement: " + advert.error().message + "\n";
      continue;
    }
    out += "board " + advert->board + ", " + advert->software_version + ", slproto " +
           std::to_string(advert->min_protocol) + ".." + std::to_string(advert->max_protocol) +
           (advert->token_required ? ", token required" : "") + (advert->simulated ? ", simulated" : "") + "\n";
    const std::string skew = slproto::version_skew_message(
        {slproto::min_protocol_version, slproto::protocol_version}, "slscan " SLSCAN_VERSION,
        {advert->min_protocol, advert->max_protocol}, advert->board, advert->software_version);
    if (!skew.empty()) out += "  incompatible: " + skew + "\n";
  }
  return out;
}

int run_discover(const DiscoverCommand& command, const Console& console) {
  if (!(command.wait_s > 0 && command.wait_s <= 60))
    throw std::invalid_argument("--wait must be in (0, 60] seconds, not " + short_number(command.wait_s));
  auto found = slproto::browse_scanners(std::chrono::milliseconds(static_cast<long>(command.wait_s * 1000)));
  if (!found) throw DeviceError(found.error().message);
  if (command.json) {
    nlohmann::json list = nlohmann::json::array();
    for (const auto& s : *found) {
      nlohmann::json entry = {{"instance", s.instance}, {"host_name", s.host_name}, {"address", s.address},
                              {"port", s.port},         {"interface", s.interface}, {"txt", s.txt}};
      if (auto advert = slproto::from_txt_records(s.txt)) {
        entry["board"] = advert->board;
        entry["software_version"] = advert->software_version;
        entry["protocol_range"] = {advert->min_protocol, advert->max_protocol};
        entry["token_required"] = advert->token_required;
      }
      list.push_back(entry);
    }
    std::cout << list.dump(2) << "\n";
    return exit_ok;
  }
  if (found->empty()) {
    console.warn("no scanner answered within " + short_number(command.wait_s) +
                 " s (is slscand running with a non-loopback bind_address and avahi-daemon on the board, and "
                 "are both on this network segment? Otherwise give the scanner as HOST:PORT)");
    return exit_device;
  }
  std::cout << format_discovered(*found);
  return exit_ok;
}

int run_status(const StatusCommand& command, const Console&) {
  const auto [host, port] = parse_scanner_address(command.address);
  const std::string token = read_token_file(command.token_file);
  const std::string where = host + ":" + std::to_string(port);
  auto connection = slproto::connect(host, port, std::chrono::seconds(3));
  if (!connection) throw DeviceError("cannot connect to " + where + ": " + connection.error().message);
  auto reply =
      slproto::client_handshake(*connection, slproto::make_hello("slscan status", "slscan " SLSCAN_VERSION, 0, token));
  if (!reply) throw DeviceError("the scanner at " + where + " refused the connection: " + reply.error().message);
  auto status = slproto::request_status(*connection, *reply);
  if (!status) throw DeviceError(where + ": " + status.error().message);
  connection->close();
  if (command.json) {
    std::cout << to_json(*status, where).dump(2) << "\n";
  } else {
    const auto now =
        std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
            .count();
    std::cout << format_status(*status, where, now);
  }
  return exit_ok;
}

}  // namespace slscan::app
