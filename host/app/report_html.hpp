// report.html: what report.json says, laid out for a person, with the output folder's pictures
// and an interactive three.js viewer of the fused cloud. The page is self-contained apart from
// the PNGs beside it (relative links): the viewer's code and a subsampled cloud are inlined, so
// it opens from disk with no network.
#pragma once

#include <cstddef>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "slscan/core/point_cloud.hpp"

namespace slscan::app {

struct ReportViewer {
  std::string_view js;              // the bundle to inline; empty = no viewer
  std::string_view missing_reason;  // said on the page when `js` is empty
};

struct ReportHtmlOptions {
  std::size_t max_points = 200000;  // the embedded cloud is subsampled to at most this many
};

// The embedded cloud: positions quantised to uint16 over the bounding box, normals to int8, both
// base64 (the format host/app/viewer/src/viewer.js reads). Deterministic: the same cloud gives
// the same text.
nlohmann::json embed_cloud(const core::PointCloud& cloud, std::size_t max_points);

// The whole page. `report` is report.json's content; `pictures` are paths relative to the
// report's folder (pictures/view_<i>_<kind>.png and pictures/model_*.png).
std::string render_report_html(const nlohmann::json& report, const core::PointCloud& model,
                               const std::vector<std::string>& pictures, const ReportViewer& viewer,
                               const ReportHtmlOptions& options = {});

}  // namespace slscan::app
