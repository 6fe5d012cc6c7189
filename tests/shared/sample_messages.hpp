// One filled-in instance of every control message (every field set to something non-default,
// so a round trip that drops a field fails), shared by the protocol tests and the fuzz corpus
// generator.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "slproto/messages.hpp"

namespace slproto::samples {

inline pb::Hello sample_hello() {
  pb::Hello m;
  m.set_protocol_version(protocol_version);
  m.set_min_protocol_version(min_protocol_version);
  m.set_software_version("slscan 0.1.0");
  m.set_capabilities(pb::CAPABILITY_TURNTABLE | pb::CAPABILITY_TWO_PROJECTORS);
  m.set_board_name("bench-rig");
  m.set_auth_token("s3cret");
  m.set_client_name("host-test");
  return m;
}

inline pb::HelloReply sample_hello_reply() {
  pb::HelloReply m;
  m.set_accepted(true);
  m.set_protocol_version(protocol_version);
  m.set_software_version("slscand 0.1.0");
  m.set_capabilities(pb::CAPABILITY_HARDWARE_TRIGGER | pb::CAPABILITY_TIMING_LOG);
  m.set_board_name("bench-rig");
  m.set_error_code(0);
  m.set_error_text("");
  m.mutable_camera()->set_width(2464);
  m.mutable_camera()->set_height(2056);
  m.mutable_camera()->add_pixel_formats(pb::PIXEL_FORMAT_MONO8);
  m.mutable_camera()->add_pixel_formats(pb::PIXEL_FORMAT_MONO12);
  m.mutable_camera()->set_model("HS510GC");
  m.set_projector_count(2);
  return m;
}

inline pb::ScanRequest sample_scan_request() {
  pb::ScanRequest m;
  m.set_scan_id(42);
  for (int i = 0; i < 4; ++i) m.add_turntable_angles_deg(90.0 * i);
  m.add_projectors(0);
  m.add_projectors(1);
  *m.mutable_plan() = to_proto(PatternPlanConfig{});
  m.set_exposure_us(8000);
  m.set_pattern_period_us(16667);
  m.set_trigger_delay_us(100);
  m.set_settle_ms(300);
  m.set_pixel_format(pb::PIXEL_FORMAT_MONO8);
  m.set_timing_events(true);
  return m;
}

inline pb::Progress sample_progress() {
  pb::Progress m;
  m.set_scan_id(42);
  m.set_state(pb::SCAN_STATE_CAPTURING);
  m.set_view_index(2);
  m.set_view_count(4);
  m.set_frames_sent(77);
  m.set_frames_total(152);
  m.set_turntable_angle_deg(180.0);
  m.set_text("view 3 of 4");
  m.set_monotonic_ns(123456789012);
  return m;
}

// A small frame: width x height mono8, tightly packed; payload_crc32c left 0 (encoders set it).
inline pb::FrameHeader sample_frame_header(std::uint32_t width = 7, std::uint32_t height = 3) {
  pb::FrameHeader m;
  m.set_scan_id(42);
  m.set_view_index(1);
  m.set_commanded_angle_deg(90.0);
  m.set_reported_angle_deg(90.0125);
  m.set_projector_id(1);
  m.set_pattern_index(12);
  m.set_pattern_kind(pb::PATTERN_KIND_PHASE_STEP);
  m.set_pattern_kind_index(1);
  m.set_exposure_us(8000);
  m.set_trigger_ns(1000000000);
  m.set_exposure_start_ns(1000020000);
  m.set_exposure_end_ns(1008020000);
  m.set_readout_ns(1020000000);
  m.set_sequence(31);
  set_frame_geometry(m, width, height, pb::PIXEL_FORMAT_MONO8);
  auto* event = m.add_timing_events();
  event->set_kind(pb::TIMING_EVENT_PROJECTOR_TRIGGER);
  event->set_monotonic_ns(1000000000);
  event->set_source(1);
  event = m.add_timing_events();
  event->set_kind(pb::TIMING_EVENT_EXPOSURE_START);
  event->set_monotonic_ns(1000020000);
  return m;
}

inline std::vector<std::byte> sample_payload(std::size_t size, std::uint32_t seed = 1) {
  std::vector<std::byte> payload(size);
  std::uint32_t state = seed * 2654435761u + 12345u;
  for (auto& b : payload) {
    state = state * 1664525u + 1013904223u;
    b = static_cast<std::byte>(state >> 24);
  }
  return payload;
}

inline pb::ScanDone sample_scan_done() {
  pb::ScanDone m;
  m.set_scan_id(42);
  m.set_final_state(pb::SCAN_STATE_DONE);
  m.set_frames_sent(152);
  m.set_views_completed(4);
  m.set_duration_ns(9876543210);
  auto* stat = m.add_timing();
  stat->set_name("trigger_to_exposure_start");
  stat->set_count(152);
  stat->set_mean_us(20.5);
  stat->set_stddev_us(1.25);
  stat->set_min_us(18.0);
  stat->set_max_us(24.0);
  stat->set_p99_us(23.5);
  m.set_frames_dropped(0);
  m.set_text("ok");
  return m;
}

inline pb::Error sample_error() {
  pb::Error m;
  m.set_code(static_cast<std::uint32_t>(Errc::hardware));
  m.set_text("turntable did not reach 90 deg");
  m.set_scan_id(42);
  m.set_fatal(true);
  return m;
}

inline pb::Abort sample_abort() {
  pb::Abort m;
  m.set_scan_id(42);
  m.set_reason("user pressed stop");
  return m;
}

inline pb::Heartbeat sample_heartbeat() {
  pb::Heartbeat m;
  m.set_sequence(9);
  m.set_monotonic_ns(5550000000);
  return m;
}

inline pb::StatusRequest sample_status_request() { return {}; }

inline pb::StatusReply sample_status_reply() {
  pb::StatusReply m;
  m.set_board_name("bench-rig");
  m.set_software_version("slscand 0.2.0");
  m.set_protocol_version(2);
  m.set_min_protocol_version(1);
  m.set_max_protocol_version(2);
  m.set_capabilities(pb::CAPABILITY_TURNTABLE);
  m.set_backends("gpio-v1, v4l2, serial");
  m.set_uptime_ns(3600000000000);
  m.set_scanning(true);
  m.set_connections(7);
  m.set_scans_done(5);
  m.set_scans_aborted(1);
  m.set_scans_failed(2);
  m.set_scans_refused(3);
  pb::LastScan* last = m.mutable_last_scan();
  last->set_scan_id(42);
  last->set_final_state(pb::SCAN_STATE_DONE);
  last->set_finished_unix_ns(1790000000000000000);
  last->set_views_completed(6);
  last->set_views_requested(6);
  last->set_frames_sent(468);
  last->set_frames_total(468);
  last->set_duration_ns(21000000000);
  last->set_text("scan complete");
  last->set_host("192.168.1.20:40112");
  m.set_last_error("turntable did not answer");
  return m;
}

struct SampleRecord {
  Body body;
  std::vector<std::byte> payload;
};

// One record of every message type, in MessageType order.
inline std::vector<SampleRecord> sample_records() {
  std::vector<SampleRecord> records;
  records.push_back({sample_hello(), {}});
  records.push_back({sample_hello_reply(), {}});
  records.push_back({sample_scan_request(), {}});
  records.push_back({sample_progress(), {}});
  records.push_back({sample_frame_header(), sample_payload(7 * 3)});
  records.push_back({sample_scan_done(), {}});
  records.push_back({sample_error(), {}});
  records.push_back({sample_abort(), {}});
  records.push_back({sample_heartbeat(), {}});
  records.push_back({sample_status_request(), {}});
  records.push_back({sample_status_reply(), {}});
  return records;
}

}  // namespace slproto::samples
