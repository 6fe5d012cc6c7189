// Version skew between a host and a board built from different releases: the hello exchange
// picks the highest common protocol version, or refuses with a message naming both ranges and
// what to upgrade where. The "other release" is played by a ServerIdentity / Hello with another
// version range (the record framing is the same for every release, which is what makes the
// refusal readable at all).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <future>

#include "slproto/framing.hpp"
#include "slproto/handshake.hpp"
#include "slproto/status.hpp"
#include "slproto/transport.hpp"

namespace {

using namespace slproto;
using namespace std::chrono_literals;
using ::testing::HasSubstr;

struct Outcome {
  Result<pb::HelloReply> client = make_error(Errc::internal, "not run");
  Result<pb::Hello> server = make_error(Errc::internal, "not run");
  Connection host;
  Connection board;
  Server listener;
};

// A board speaking `board` and a host whose Hello claims `host` (software strings included).
Outcome handshake_between(VersionRange board, std::string board_software, VersionRange host,
                          std::string host_software) {
  Outcome out;
  auto server = Server::listen("127.0.0.1", 0);
  EXPECT_TRUE(server.ok());
  out.listener = std::move(*server);
  auto accepted = std::async(std::launch::async, [&] { return out.listener.accept(5s); });
  auto host_connection = connect("127.0.0.1", out.listener.port(), 5s);
  EXPECT_TRUE(host_connection.ok());
  auto board_connection = accepted.get();
  EXPECT_TRUE(board_connection.ok());
  out.host = std::move(*host_connection);
  out.board = std::move(*board_connection);
  ServerIdentity identity{"rig", std::move(board_software), 0, {}, 2, "", board};
  auto server_side = std::async(std::launch::async, [&] { return server_handshake(out.board, identity); });
  pb::Hello hello = make_hello("test-host", std::move(host_software));
  hello.set_min_protocol_version(host.min);
  hello.set_protocol_version(host.max);
  out.client = client_handshake(out.host, hello);
  out.server = server_side.get();
  return out;
}

TEST(VersionSkew, OverlappingRangesNegotiateTheHighestCommonVersion) {
  Outcome newer_board = handshake_between({1, 7}, "slscand 0.7.0", {1, 2}, "slscan 0.2.0");
  ASSERT_TRUE(newer_board.client.ok()) << newer_board.client.error().message;
  EXPECT_EQ(newer_board.client->protocol_version(), 2u);
  EXPECT_EQ(newer_board.client->min_protocol_version(), 1u);

  Outcome older_board = handshake_between({1, 1}, "slscand 0.1.0", {1, 2}, "slscan 0.2.0");
  ASSERT_TRUE(older_board.client.ok()) << older_board.client.error().message;
  EXPECT_EQ(older_board.client->protocol_version(), 1u);
  ASSERT_TRUE(older_board.server.ok());
}

TEST(VersionSkew, StatusIsNotAskedOfABoardThatNegotiatedAnOlderVersion) {
  Outcome o = handshake_between({1, 1}, "slscand 0.1.0", {1, 2}, "slscan 0.2.0");
  ASSERT_TRUE(o.client.ok()) << o.client.error().message;
  Result<pb::StatusReply> status = request_status(o.host, *o.client, 1s);
  ASSERT_FALSE(status.ok());
  EXPECT_EQ(status.error().code, Errc::wrong_version);
  EXPECT_THAT(status.error().message, HasSubstr("board 'rig' (slscand 0.1.0) speaks slproto 1..1"));
  EXPECT_THAT(status.error().message, HasSubstr("status needs slproto >= 2"));
  EXPECT_THAT(status.error().message, HasSubstr("upgrade slscand on the board to >= 0.2.0"));
  // Nothing was sent: an old board would have closed the connection on the unknown record.
  EXPECT_EQ(o.board.receive(100ms).error().code, Errc::timeout);
}

TEST(VersionSkew, BoardTooOldIsRefusedNamingBothRangesAndTheBoardUpgrade) {
  Outcome o = handshake_between({1, 1}, "slscand 0.1.0", {2, 3}, "slscan 0.3.0");
  ASSERT_FALSE(o.client.ok());
  EXPECT_EQ(o.client.error().code, Errc::wrong_version);
  EXPECT_THAT(o.client.error().message,
              HasSubstr("board 'rig' (slscand 0.1.0) speaks slproto 1..1, the host (slscan 0.3.0) speaks 2..3: "
                        "upgrade slscand on the board to >= 0.2.0"));
  ASSERT_FALSE(o.server.ok());
  EXPECT_EQ(o.server.error().code, Errc::wrong_version);
  EXPECT_THAT(o.server.error().message, HasSubstr("upgrade slscand on the board"));
}

TEST(VersionSkew, HostTooOldIsRefusedNamingBothRangesAndTheHostUpgrade) {
  Outcome o = handshake_between({2, 3}, "slscand 0.3.0", {1, 1}, "slscan 0.1.0");
  ASSERT_FALSE(o.client.ok());
  EXPECT_EQ(o.client.error().code, Errc::wrong_version);
  EXPECT_THAT(o.client.error().message,
              HasSubstr("board 'rig' (slscand 0.3.0) speaks slproto 2..3, the host (slscan 0.1.0) speaks 1..1: "
                        "upgrade slscan on the host to >= 0.2.0"));
  EXPECT_FALSE(o.server.ok());
}

TEST(VersionSkew, VersionsBeyondThisBuildAreNamedByNumber) {
  // The brief's example: a board of 2..3 and a host of 4..5, neither release known here.
  EXPECT_EQ(version_skew_message({4, 5}, "", {2, 3}, "", ""),
            "board speaks slproto 2..3, the host speaks 4..5: upgrade slscand on the board to a release that "
            "speaks slproto >= 4");
  EXPECT_EQ(version_skew_message({2, 3}, "slscan 9", {4, 5}, "pi", "slscand 11"),
            "board 'pi' (slscand 11) speaks slproto 4..5, the host (slscan 9) speaks 2..3: upgrade slscan on the "
            "host to a release that speaks slproto >= 4");
  EXPECT_EQ(version_skew_message({1, 3}, "", {3, 5}, "", ""), "");  // they share 3
}

TEST(VersionSkew, EveryVersionThisBuildSpeaksHasARelease) {
  for (std::uint32_t v = min_protocol_version; v <= protocol_version; ++v)
    EXPECT_FALSE(first_release_speaking(v).empty()) << "protocol " << v << " has no release in the table";
  EXPECT_TRUE(first_release_speaking(protocol_version + 1).empty());
}

TEST(VersionSkew, ARefusalFromABoardOlderThanTheMinVersionFieldIsStillExplained) {
  // slscand 0.1.0 refuses with only protocol_version (its single version) and its own text.
  auto server = Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(server.ok());
  auto accepted = std::async(std::launch::async, [&] { return server->accept(5s); });
  auto host = connect("127.0.0.1", server->port(), 5s);
  ASSERT_TRUE(host.ok());
  auto board = accepted.get();
  ASSERT_TRUE(board.ok());
  auto old_board = std::async(std::launch::async, [&] {
    auto hello = board->receive_as<pb::Hello>(5s);
    EXPECT_TRUE(hello.ok());
    pb::HelloReply reply;
    reply.set_accepted(false);
    reply.set_protocol_version(1);
    reply.set_software_version("slscand 0.1.0");
    reply.set_board_name("rpi");
    reply.set_error_code(static_cast<std::uint32_t>(Errc::wrong_version));
    reply.set_error_text("client speaks protocol 2..2, server 1..1");
    EXPECT_TRUE(board->send(reply).ok());
  });
  pb::Hello hello = make_hello("h", "slscan 0.3.0");
  hello.set_min_protocol_version(2);
  hello.set_protocol_version(2);
  auto reply = client_handshake(*host, hello);
  old_board.get();
  ASSERT_FALSE(reply.ok());
  EXPECT_THAT(reply.error().message,
              HasSubstr("board 'rpi' (slscand 0.1.0) speaks slproto 1..1, the host (slscan 0.3.0) speaks 2..2: "
                        "upgrade slscand on the board to >= 0.2.0"));
}

TEST(VersionSkew, RecordsAreFramedWithTheFramingVersionNotTheProtocolVersion) {
  // A board of any protocol range reads this build's Hello: its header says framing version 1.
  auto bytes = encode(make_hello("h", "slscan"));
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(std::to_integer<int>((*bytes)[4]) | (std::to_integer<int>((*bytes)[5]) << 8), framing_version);
  EXPECT_EQ(framing_version, 1);
}

}  // namespace
