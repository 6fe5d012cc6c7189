#include "slproto/handshake.hpp"

#include <algorithm>

namespace slproto {
namespace {

// Compares without an early exit so the time taken does not reveal how much of a guess matched.
bool same_secret(const std::string& expected, const std::string& given) noexcept {
  unsigned char difference = expected.size() == given.size() ? 0 : 1;
  const std::size_t n = std::max(expected.size(), given.size());
  for (std::size_t i = 0; i < n; ++i) {
    const auto a = static_cast<unsigned char>(i < expected.size() ? expected[i] : 0);
    const auto b = static_cast<unsigned char>(i < given.size() ? given[i] : 0);
    difference = static_cast<unsigned char>(difference | (a ^ b));
  }
  return difference == 0;
}

std::string range_text(VersionRange range) { return std::to_string(range.min) + ".." + std::to_string(range.max); }

std::string software_suffix(std::string_view software) {
  return software.empty() ? std::string() : " (" + std::string(software) + ")";
}

std::string upgrade_to(std::string_view program, std::string_view where, std::uint32_t version) {
  const std::string release = first_release_speaking(version);
  return "upgrade " + std::string(program) + " on " + std::string(where) +
         (release.empty()
              ? " to a release that speaks slproto >= " + std::to_string(version)
              : " to >= " + release + " (the first release speaking slproto " + std::to_string(version) + ")");
}

}  // namespace

std::string first_release_speaking(std::uint32_t version) {
  // One entry per protocol version, added with the release that introduces it.
  switch (version) {
    case 1:
      return "0.1.0";
    case 2:
      return "0.2.0";
    default:
      return {};
  }
}

std::string version_skew_message(VersionRange host, std::string_view host_software, VersionRange board,
                                 std::string_view board_name, std::string_view board_software) {
  if (std::max(host.min, board.min) <= std::min(host.max, board.max)) return {};
  const std::string ranges = "board" + (board_name.empty() ? std::string() : " '" + std::string(board_name) + "'") +
                             software_suffix(board_software) + " speaks slproto " + range_text(board) + ", the host" +
                             software_suffix(host_software) + " speaks " + range_text(host) + ": ";
  if (board.max < host.min) return ranges + upgrade_to("slscand", "the board", host.min);
  return ranges + upgrade_to("slscan", "the host", board.min);
}

pb::Hello make_hello(std::string client_name, std::string software_version, std::uint64_t capabilities,
                     std::string auth_token, std::string expected_board) {
  pb::Hello hello;
  hello.set_protocol_version(protocol_version);
  hello.set_min_protocol_version(min_protocol_version);
  hello.set_client_name(std::move(client_name));
  hello.set_software_version(std::move(software_version));
  hello.set_capabilities(capabilities);
  hello.set_auth_token(std::move(auth_token));
  hello.set_board_name(std::move(expected_board));
  return hello;
}

Result<pb::HelloReply> client_handshake(Connection& connection, const pb::Hello& hello,
                                        std::chrono::milliseconds timeout) {
  if (Status status = connection.send(hello, timeout); !status) return status.error();
  Result<pb::HelloReply> reply = connection.receive_as<pb::HelloReply>(timeout);
  if (!reply) return make_error(reply.error().code, "handshake: " + reply.error().message);
  const VersionRange host{hello.min_protocol_version(), hello.protocol_version()};
  if (!reply->accepted()) {
    Errc code = errc_from_wire(reply->error_code());
    if (code == Errc::wrong_version) {
      // Servers before HelloReply.min_protocol_version spoke exactly one version.
      const VersionRange board{
          reply->min_protocol_version() != 0 ? reply->min_protocol_version() : reply->protocol_version(),
          reply->protocol_version()};
      std::string skew =
          version_skew_message(host, hello.software_version(), board, reply->board_name(), reply->software_version());
      // A newer board knows which host release it needs; this host may not, so its words win.
      if (skew.empty() || (board.min > host.max && first_release_speaking(board.min).empty()))
        skew = reply->error_text();
      return make_error(code, "handshake with " + connection.peer_address() + ": " + skew);
    }
    return make_error(code, "handshake: " + connection.peer_address() + " rejected the hello: " + reply->error_text());
  }
  if (reply->protocol_version() < host.min || reply->protocol_version() > host.max)
    return make_error(Errc::wrong_version, "handshake: server chose protocol version " +
                                               std::to_string(reply->protocol_version()) + ", outside " +
                                               range_text(host));
  if (!hello.board_name().empty() && reply->board_name() != hello.board_name())
    return make_error(Errc::unsupported, "handshake: expected board \"" + hello.board_name() + "\" but " +
                                             connection.peer_address() + " is \"" + reply->board_name() + "\"");
  return reply;
}

Result<pb::Hello> server_handshake(Connection& connection, const ServerIdentity& identity,
                                   std::chrono::milliseconds timeout, const std::function<Status()>& admit) {
  Result<pb::Hello> hello = connection.receive_as<pb::Hello>(timeout);
  if (!hello) return make_error(hello.error().code, "handshake: " + hello.error().message);

  pb::HelloReply reply;
  reply.set_software_version(identity.software_version);
  reply.set_capabilities(identity.capabilities);
  reply.set_board_name(identity.board_name);
  *reply.mutable_camera() = identity.camera;
  reply.set_projector_count(identity.projector_count);
  reply.set_pattern_exposure_us(identity.pattern_exposure_us);
  reply.set_pattern_period_us(identity.pattern_period_us);
  reply.set_min_protocol_version(identity.versions.min);

  std::optional<Error> rejection;
  const VersionRange host{hello->min_protocol_version(), hello->protocol_version()};
  const std::uint32_t highest = std::min<std::uint32_t>(host.max, identity.versions.max);
  const std::uint32_t lowest = std::max<std::uint32_t>(host.min, identity.versions.min);
  if (host.max == 0 || host.min > host.max) {
    rejection =
        make_error(Errc::wrong_version, "the hello's protocol range " + range_text(host) +
                                            " is empty; this board speaks slproto " + range_text(identity.versions));
  } else if (highest < lowest) {
    rejection = make_error(Errc::wrong_version, version_skew_message(host, hello->software_version(), identity.versions,
                                                                     identity.board_name, identity.software_version));
  } else if (!identity.auth_token.empty() && !same_secret(identity.auth_token, hello->auth_token())) {
    rejection = make_error(Errc::unauthorized,
                           hello->auth_token().empty() ? "an auth token is required" : "the auth token is wrong");
  } else if (!hello->board_name().empty() && hello->board_name() != identity.board_name) {
    rejection = make_error(Errc::unsupported,
                           "this is board \"" + identity.board_name + "\", not \"" + hello->board_name() + "\"");
  } else if (admit) {
    if (Status admitted = admit(); !admitted) rejection = admitted.error();
  }
  if (rejection) {
    reply.set_accepted(false);
    reply.set_error_code(static_cast<std::uint32_t>(rejection->code));
    reply.set_error_text(rejection->message);
    reply.set_protocol_version(identity.versions.max);
    (void)connection.send(reply, timeout);  // best effort: we close either way
    connection.close();
    return make_error(rejection->code,
                      "handshake with " + connection.peer_address() + " rejected: " + rejection->message);
  }
  reply.set_accepted(true);
  reply.set_protocol_version(highest);
  if (Status status = connection.send(reply, timeout); !status) return status.error();
  return hello;
}

}  // namespace slproto
