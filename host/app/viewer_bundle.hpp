// The report's 3D viewer: three.js and host/app/viewer/src/viewer.js, bundled by esbuild at
// build time and compiled into slscan (see docs/cli.md, "report.html").
#pragma once

#include <string_view>

namespace slscan::app {

// The minified bundle, ready to inline in a <script> element; empty when the build had no
// Node.js or no node_modules (scripts/bootstrap.sh runs `npm ci`).
std::string_view report_viewer_js();
// Why the bundle is empty (for the report to say), or empty when it is there.
std::string_view report_viewer_missing_reason();

}  // namespace slscan::app
