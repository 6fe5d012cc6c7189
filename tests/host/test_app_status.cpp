// slscan status: scanner addresses as a person types them, and the report it prints from a
// board's StatusReply (the daemon side is tested in test_slscand_sim).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "status.hpp"

namespace {

using namespace slscan::app;
using ::testing::HasSubstr;
namespace pb = slproto::pb;

TEST(ScannerAddress, HostPortForms) {
  EXPECT_EQ(parse_scanner_address("scanner.local"), std::make_pair(std::string("scanner.local"), std::uint16_t{7878}));
  EXPECT_EQ(parse_scanner_address("10.0.0.7:6000"), std::make_pair(std::string("10.0.0.7"), std::uint16_t{6000}));
  EXPECT_EQ(parse_scanner_address("[fe80::1]:7000"), std::make_pair(std::string("fe80::1"), std::uint16_t{7000}));
  EXPECT_EQ(parse_scanner_address("[::1]"), std::make_pair(std::string("::1"), std::uint16_t{7878}));
  EXPECT_EQ(parse_scanner_address("::1"), std::make_pair(std::string("::1"), std::uint16_t{7878}));
}

TEST(ScannerAddress, BadFormsNameTheTextAndTheProblem) {
  auto message_of = [](const std::string& text) {
    try {
      (void)parse_scanner_address(text);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_THAT(message_of("pi:0"), HasSubstr("'pi:0': port '0' is not 1..65535"));
  EXPECT_THAT(message_of("pi:70000"), HasSubstr("port '70000'"));
  EXPECT_THAT(message_of("pi:50x"), HasSubstr("port '50x'"));
  EXPECT_THAT(message_of("pi:"), HasSubstr("empty port"));
  EXPECT_THAT(message_of(":5025"), HasSubstr("no host"));
  EXPECT_THAT(message_of("[fe80::1"), HasSubstr("no closing ']'"));
}

pb::StatusReply sample_status() {
  pb::StatusReply s;
  s.set_board_name("rpi");
  s.set_software_version("slscand 0.2.0");
  s.set_protocol_version(2);
  s.set_min_protocol_version(1);
  s.set_max_protocol_version(2);
  s.set_backends("gpio-v1, v4l2, serial");
  s.set_uptime_ns(7'200'000'000'000);
  s.set_scans_done(3);
  s.set_scans_failed(1);
  s.set_connections(9);
  pb::LastScan* l = s.mutable_last_scan();
  l->set_scan_id(17);
  l->set_final_state(pb::SCAN_STATE_FAILED);
  l->set_finished_unix_ns(1'790'000'000'000'000'000);
  l->set_views_completed(4);
  l->set_views_requested(6);
  l->set_frames_sent(312);
  l->set_frames_total(468);
  l->set_duration_ns(14'500'000'000);
  l->set_text("turntable did not answer within 2000 ms");
  l->set_host("192.168.1.20:40112");
  s.set_last_error("turntable did not answer within 2000 ms");
  return s;
}

TEST(StatusReport, NamesBoardVersionsAndTheLastScan) {
  const std::string text = format_status(sample_status(), "pi.local:5025", 1'790'000'090'000'000'000);
  EXPECT_THAT(text, HasSubstr("scanner: pi.local:5025\n"));
  EXPECT_THAT(text, HasSubstr("board: rpi\n"));
  EXPECT_THAT(text, HasSubstr("firmware: slscand 0.2.0 (backends: gpio-v1, v4l2, serial)\n"));
  EXPECT_THAT(text, HasSubstr("protocol: slproto 2 in use; the board speaks 1..2"));
  EXPECT_THAT(text, HasSubstr("uptime: 2.0 h\n"));
  EXPECT_THAT(text, HasSubstr("state: idle\n"));
  EXPECT_THAT(text, HasSubstr("scans: 3 done, 0 aborted, 1 failed, 0 refused since start (9 connections)"));
  EXPECT_THAT(text, HasSubstr("last scan: failed, scan 17 from 192.168.1.20:40112, finished 2026-09-21 14:13:20 UTC"));
  EXPECT_THAT(text, HasSubstr("(90.0 s ago)"));
  EXPECT_THAT(text, HasSubstr("  views: 4 of 6\n"));
  EXPECT_THAT(text, HasSubstr("  frames: 312 of 468 sent\n"));
  EXPECT_THAT(text, HasSubstr("  duration: 14.5 s\n"));
  EXPECT_THAT(text, HasSubstr("  result: turntable did not answer within 2000 ms\n"));
}

TEST(StatusReport, ABoardThatHasNotScannedSaysSo) {
  pb::StatusReply s = sample_status();
  s.clear_last_scan();
  s.set_scanning(true);
  s.set_capabilities(pb::CAPABILITY_SIMULATED);
  const std::string text = format_status(s, "127.0.0.1:5025", 0);
  EXPECT_THAT(text, HasSubstr("board: rpi (simulated)\n"));
  EXPECT_THAT(text, HasSubstr("state: scanning\n"));
  EXPECT_THAT(text, HasSubstr("last scan: none since slscand started\n"));
  EXPECT_THAT(text, ::testing::Not(HasSubstr("  views:")));
}

}  // namespace
