// What a reconstruction leaves in its output folder: the fused model (PLY), the mesh (PLY, STL,
// OBJ, 3MF: those chosen), per-view clouds, report.json, and pictures (per-view depth, quality and fusion-source
// maps, previews of the model) and report.html showing all of it. Every file is written to a temporary name and
// renamed.
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "slscan/core/measure.hpp"
#include "slscan/core/scan_reconstruction.hpp"

namespace slscan::app {

nlohmann::json scan_result_to_json(const core::ScanResult& result);
// Every self-check finding of the scan, one line each ("view 0, left projector: cause: fix").
std::vector<std::string> self_check_findings(const core::ScanResult& result);
nlohmann::json ball_bar_to_json(const core::BallBarResult& ball_bar);

struct OutputFiles {
  std::string model_ply, mesh_ply, mesh_stl, mesh_obj, mesh_3mf, report_json, report_html;  // "": not written
  std::vector<std::string> pictures;
};

// Writes everything into `dir` (created if needed): the mesh, when the result has one, in each
// of `mesh_formats`. `report` is completed with the scan's figures and written last, as
// report.json, just after report.html shows it.
OutputFiles write_scan_outputs(const std::string& dir, const core::ScanResult& result, nlohmann::json report,
                               const core::MeshFormats& mesh_formats = {});

// A view's depth (camera z, turbo) and decode-quality (modulation, viridis) pictures as PNG:
// colours span the view's 1st-99th percentile (beyond: the end colours), black = nothing
// measured, and a colour bar below the picture states the range.
std::vector<unsigned char> depth_picture_png(const core::SparseOrganizedCloud& cloud);
std::vector<unsigned char> quality_picture_png(const core::SparseOrganizedCloud& cloud);

// A shaded splat rendering of a cloud with normals, seen from `azimuth_deg` around +z and
// `elevation_deg` above the xy plane; 8-bit grey, `size` x `size`.
std::vector<unsigned char> render_preview_png(const core::PointCloud& cloud, double azimuth_deg, double elevation_deg,
                                              int size);

}  // namespace slscan::app
