// report.html without a browser: the embedded cloud decodes to the model within its
// quantisation step, the page carries the report's figures (escaped), and a build without the
// viewer bundle says so on the page instead of leaving an empty box. The page rendering in a
// real browser is tested in tests/integration/test_live_scan.cpp.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

#include "report_html.hpp"
#include "viewer_bundle.hpp"

namespace slscan::app {
namespace {

using nlohmann::json;

std::vector<unsigned char> decode_base64(const std::string& text) {
  std::vector<unsigned char> out;
  std::uint32_t buffer = 0;
  int bits = 0;
  for (char c : text) {
    if (c == '=') break;
    const char* alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    const char* at = std::strchr(alphabet, c);
    EXPECT_NE(at, nullptr) << "not base64: " << c;
    buffer = (buffer << 6) | static_cast<std::uint32_t>(at - alphabet);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<unsigned char>((buffer >> bits) & 0xff));
    }
  }
  return out;
}

core::PointCloud random_cloud(std::size_t n) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-80.0f, 80.0f);
  core::PointCloud cloud;
  for (std::size_t i = 0; i < n; ++i) {
    cloud.points.emplace_back(u(rng), u(rng), 0.5f * u(rng) + 40.0f);
    cloud.normals.push_back(Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized());
  }
  return cloud;
}

json sample_report() {
  json view = {
      {"view_index", 0},
      {"commanded_angle_deg", 0.0},
      {"projectors",
       {{{"present", true},
         {"decode", {{"valid", 5000}}},
         {"triangulate", {{"valid", 4900}}},
         {"decode_ms", 12.5},
         {"triangulate_ms", 3.25}},
        {{"present", false}, {"decode_ms", 0.0}, {"triangulate_ms", 0.0}}}},
      {"fusion", {{"both", 4000}, {"left_only", 900}, {"right_only", 0}, {"rejected", 3}}},
      {"flying_pixels_removed", 17},
      {"turntable_denoise",
       {{"input", 4900}, {"kept", 4500}, {"below_min_height", 390}, {"above_max_height", 0}, {"outside_radius", 10}}},
      {"points", 4500},
      {"fuse_ms", 1.5}};
  return {
      {"software", {{"slscan", "0.1.0"}, {"protocol_version", 1}}},
      {"capture", {{"file", "<b>scan</b>.slcap"}, {"frames", 40}, {"complete", false}, {"missing", {"view 1: all"}}}},
      {"measurement",
       {{"ball_bar",
         {{"centre_distance_mm", 150.12346},
          {"reference_distance_mm", 150.1164},
          {"distance_error_um", 6.85},
          {"sd", {{"value_um", 6.85}, {"mpe_um", 10.0}, {"verdict", "PASS"}}},
          {"region_rule", {{"text", "points within 0.50 mm of the robust fit"}}},
          {"spheres",
           {{{"centre_mm", {0, 0, 0}},
             {"diameter_mm", 30.0012},
             {"calibrated_diameter_mm", 30.0008},
             {"pf", {{"value_um", 12.3}, {"mpe_um", 10.0}, {"verdict", "FAIL"}}},
             {"pf_all_points_um", 31.5},
             {"ps", {{"value_um", 0.4}, {"verdict", "not judged (no MPE given)"}}},
             {"rms_um", 1.0},
             {"points", 900},
             {"left_out", 2},
             {"cone_points", 40},
             {"joints", {{{"axis", {1, 0, 0}}, {"half_angle_deg", 22.5}, {"attachment_points", 30}}}}}}}}}}},
      {"scan",
       {{"views", {view}},
        {"registration",
         {{"applied", true},
          {"iterations", 4},
          {"mode", "turntable"},
          {"axis_tilt_deg", 0.0021},
          {"axis_shift_mm", 0.0034},
          {"views",
           {{{"view", 0},
             {"correction_deg", 0.0},
             {"correction_mm", 0.0},
             {"angle_correction_deg", 0.0},
             {"residual_rms_mm", 0.0123},
             {"correspondences", 812}}}},
          {"pairs", json::array()}}},
        {"model", {{"merged_points", 4500}, {"outliers_removed", 20}, {"points", 4480}}},
        {"stage_ms", {{"registration", 81.5}, {"outlier_removal", 9.0}}}}}};
}

TEST(ReportHtml, EmbeddedCloudDecodesToTheModelWithinOneStep) {
  const core::PointCloud cloud = random_cloud(1000);
  const json embedded = embed_cloud(cloud, 1000);
  ASSERT_EQ(embedded["count"], 1000);
  const auto positions = decode_base64(embedded["positions"]);
  const auto normals = decode_base64(embedded["normals"]);
  ASSERT_EQ(positions.size(), 1000u * 3 * 2);
  ASSERT_EQ(normals.size(), 1000u * 3);
  for (std::size_t i = 0; i < cloud.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      const std::size_t at = 2 * (3 * i + static_cast<std::size_t>(k));
      const std::uint16_t q = static_cast<std::uint16_t>(positions[at] | (positions[at + 1] << 8));
      const double scale = embedded["scale"][k], origin = embedded["origin"][k];
      ASSERT_NEAR(origin + q * scale, cloud.points[i][k], 0.51 * scale) << i << " " << k;
      const auto n = static_cast<std::int8_t>(normals[3 * i + static_cast<std::size_t>(k)]);
      ASSERT_NEAR(n / 127.0, cloud.normals[i][k], 0.5 / 127 + 1e-6);
    }
}

TEST(ReportHtml, LargeCloudsAreSubsampledEvenlyAndDeterministically) {
  const core::PointCloud cloud = random_cloud(10000);
  const json a = embed_cloud(cloud, 3000), b = embed_cloud(cloud, 3000);
  EXPECT_EQ(a["count"], 3000);
  EXPECT_EQ(a["total"], 10000);
  EXPECT_EQ(decode_base64(a["positions"]).size(), 3000u * 6);
  EXPECT_EQ(a, b);
  // An empty model embeds nothing, without dividing by zero.
  const json none = embed_cloud(core::PointCloud{}, 100);
  EXPECT_EQ(none["count"], 0);
  EXPECT_EQ(none["positions"], "");
}

TEST(ReportHtml, PageCarriesTheFiguresEscaped) {
  const std::string html = render_report_html(
      sample_report(), random_cloud(100),
      {"pictures/view_0_depth.png", "pictures/view_0_fusion_source.png", "pictures/model_az0_el20.png"},
      {"/*viewer*/", ""});
  for (const char* figure : {"150.1235", "6.8", "30.0012", "0.0123", "812", "4480", "81.5", "12.5",
                             "4000 / 900 / 0 / 3", "4500 / 390 / 0 / 10", "view 1: all", "incomplete"})
    EXPECT_NE(html.find(figure), std::string::npos) << figure;
  // The ball bar as VDI/VDE 2634-2 figures with their verdicts, never an unexplained "form error".
  for (const char* figure :
       {"SD, sphere-spacing error", "+6.8 &micro;m <span class=\"pass\">PASS", "PF, probing error form",
        "12.3 &micro;m <span class=\"fail\">FAIL</span> (MPE 10.0 &micro;m)", "31.5 &micro;m",
        "+0.4 &micro;m <span class=\"note\">(no MPE given)", "40 points in 22.5&deg;",
        "points within 0.50 mm of the robust fit", "900 (2)"})
    EXPECT_NE(html.find(figure), std::string::npos) << figure;
  // Registration says what the turntable mode found: how far the axis moved, each view's angle.
  for (const char* text : {"mode turntable", "moved 0.0021&deg; and 0.0034 mm from the calibrated one",
                           "<th>angle correction (&deg;)</th>"})
    EXPECT_NE(html.find(text), std::string::npos) << text;
  EXPECT_EQ(html.find("form error"), std::string::npos);
  EXPECT_EQ(html.find("<b>scan</b>"), std::string::npos) << "a file name went into the page unescaped";
  EXPECT_NE(html.find("&lt;b&gt;scan&lt;/b&gt;.slcap"), std::string::npos);
  EXPECT_NE(html.find("<img src=\"pictures/view_0_fusion_source.png\""), std::string::npos);
  EXPECT_NE(html.find("<img src=\"pictures/model_az0_el20.png\""), std::string::npos);
  EXPECT_NE(html.find("id=\"slscan-cloud\""), std::string::npos);
  EXPECT_NE(html.find("<script>/*viewer*/</script>"), std::string::npos);
  EXPECT_NE(html.find("data-points=\"100\""), std::string::npos);
}

TEST(ReportHtml, WithoutTheViewerBundleThePageSaysSo) {
  const std::string html =
      render_report_html(sample_report(), random_cloud(100), {}, {"", "slscan was built without Node.js"});
  EXPECT_NE(html.find("data-status=\"missing\""), std::string::npos);
  EXPECT_NE(html.find("viewer is missing from this report: slscan was built without Node.js"), std::string::npos);
  EXPECT_EQ(html.find("id=\"slscan-cloud\""), std::string::npos) << "no cloud without a viewer to draw it";
  EXPECT_NE(html.find("150.1235"), std::string::npos) << "the figures are there all the same";
}

TEST(ReportHtml, ThisBuildHasTheViewerOrSaysWhyNot) {
  // Either a real bundle (three.js is hundreds of kB and defines the viewer's entry point) or
  // a reason for the report to show.
  if (report_viewer_js().empty()) {
    EXPECT_FALSE(report_viewer_missing_reason().empty());
    GTEST_SKIP() << "built without the viewer: " << report_viewer_missing_reason();
  }
  EXPECT_GT(report_viewer_js().size(), 100000u);
  EXPECT_NE(report_viewer_js().find("slscan-cloud"), std::string_view::npos);
  EXPECT_EQ(report_viewer_js().find("</script"), std::string_view::npos);
  EXPECT_TRUE(report_viewer_missing_reason().empty());
}

}  // namespace
}  // namespace slscan::app
