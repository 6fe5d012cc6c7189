// The mesh files of a run (issue 19, docs/cli.md "Outputs"): PLY, STL, OBJ and 3MF, each read
// back (PLY by our table reader, OBJ and STL by read_mesh, 3MF by lib3mf) with its vertex and
// triangle counts and coordinates; the chosen formats written as part of the output set; the
// command line's mesh options applied over the config, and bad ones refused.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <sstream>
#include <string>

#include "config.hpp"
#include "outputs.hpp"
#include "run.hpp"
#include "slscan/io/mesh_file.hpp"
#include "slscan/io/ply.hpp"
#include "slscan/io/stl.hpp"

namespace slscan::app {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

class MeshFiles : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_mesh_files_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  fs::path dir_;
};

// A torus (R 20 mm, r 6 mm) off the origin, at coordinates with all their float digits: closed,
// consistently oriented (counter-clockwise seen from outside), one outward normal per vertex,
// and a band of faces flagged as filled.
core::TriangleMesh torus(int nu, int nv) {
  core::TriangleMesh mesh;
  const Eigen::Vector3f centre(123.456789f, -45.678912f, 7.891234f);
  const double R = 20, r = 6;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const double u = 2 * std::numbers::pi * i / nu, v = 2 * std::numbers::pi * j / nv;
      const Eigen::Vector3d n(std::cos(v) * std::cos(u), std::cos(v) * std::sin(u), std::sin(v));
      const Eigen::Vector3d p((R + r * std::cos(v)) * std::cos(u), (R + r * std::cos(v)) * std::sin(u),
                              r * std::sin(v));
      mesh.vertices.push_back(centre + p.cast<float>());
      mesh.normals.push_back(n.cast<float>());
    }
  const auto at = [&](int i, int j) { return static_cast<std::uint32_t>(((i + nu) % nu) * nv + (j + nv) % nv); };
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      mesh.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      mesh.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
      const std::uint8_t filled = i == 3 ? 1 : 0;
      mesh.filled.push_back(filled);
      mesh.filled.push_back(filled);
    }
  return mesh;
}

// Every triangle of `read` has the corners of the same triangle of `written` (read_mesh welds
// and renumbers the vertices, so they are compared through the triangles), within `tolerance`.
void expect_same_triangles(const core::TriangleMesh& read, const core::TriangleMesh& written, float tolerance) {
  ASSERT_EQ(read.triangles.size(), written.triangles.size());
  float worst = 0;
  for (std::size_t t = 0; t < written.triangles.size(); ++t)
    for (std::size_t k = 0; k < 3; ++k)
      worst = std::max(
          worst,
          (read.vertices[read.triangles[t][k]] - written.vertices[written.triangles[t][k]]).cwiseAbs().maxCoeff());
  EXPECT_LE(worst, tolerance);
}

std::vector<Eigen::Vector3i> as_int(const core::TriangleMesh& mesh) {
  std::vector<Eigen::Vector3i> out;
  for (const auto& t : mesh.triangles)
    out.emplace_back(static_cast<int>(t[0]), static_cast<int>(t[1]), static_cast<int>(t[2]));
  return out;
}

TEST_F(MeshFiles, PlyReadsBackExactly) {
  const core::TriangleMesh mesh = torus(48, 24);
  io::write_mesh_ply(path("m.ply"), mesh.vertices, mesh.normals, as_int(mesh), {}, mesh.filled);
  const io::PlyTable table = io::read_ply_table(path("m.ply"));
  ASSERT_EQ(table.vertex_count, mesh.vertices.size());
  ASSERT_EQ(table.faces.size(), mesh.triangles.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    ASSERT_EQ(static_cast<float>(table.column("x")[i]), mesh.vertices[i].x()) << i;
    ASSERT_EQ(static_cast<float>(table.column("y")[i]), mesh.vertices[i].y()) << i;
    ASSERT_EQ(static_cast<float>(table.column("z")[i]), mesh.vertices[i].z()) << i;
    ASSERT_EQ(static_cast<float>(table.column("nz")[i]), mesh.normals[i].z()) << i;
  }
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    ASSERT_EQ(table.faces[t], std::vector<std::uint32_t>(mesh.triangles[t].begin(), mesh.triangles[t].end())) << t;
}

TEST_F(MeshFiles, StlRoundTripKeepsEveryTriangle) {
  const core::TriangleMesh mesh = torus(48, 24);
  io::write_stl(path("m.stl"), mesh.vertices, as_int(mesh), "slscan test");
  const core::TriangleMesh read = io::read_mesh(path("m.stl"));
  // The soup of 3 corners per facet welds back to the torus' vertices.
  EXPECT_EQ(read.vertices.size(), mesh.vertices.size());
  expect_same_triangles(read, mesh, 0);  // binary floats: exact
  EXPECT_TRUE(core::mesh_topology(read).closed());
}

TEST_F(MeshFiles, ObjReadsBackExactlyWithNormalsAndTheFilledGroup) {
  const core::TriangleMesh mesh = torus(48, 24);
  io::write_obj(path("m.obj"), mesh, {"slscan test"});
  const core::TriangleMesh read = io::read_mesh(path("m.obj"));
  EXPECT_EQ(read.vertices.size(), mesh.vertices.size());
  expect_same_triangles(read, mesh, 0);  // shortest round-trip text: exact
  // The text itself: the unit, one vn per vertex, and the filled faces in their group.
  std::istringstream in(read_bytes(path("m.obj")));
  std::size_t v = 0, vn = 0, faces = 0, filled_faces = 0;
  bool in_filled = false, unit = false;
  for (std::string line; std::getline(in, line);) {
    unit = unit || line == "# units: mm";
    if (line.rfind("v ", 0) == 0) ++v;
    if (line.rfind("vn ", 0) == 0) ++vn;
    if (line == "g filled") in_filled = true;
    if (line == "g measured") in_filled = false;
    if (line.rfind("f ", 0) == 0) {
      ++faces;
      filled_faces += in_filled ? 1 : 0;
      EXPECT_NE(line.find("//"), std::string::npos) << line;
    }
  }
  EXPECT_TRUE(unit);
  EXPECT_EQ(v, mesh.vertices.size());
  EXPECT_EQ(vn, mesh.vertices.size());
  EXPECT_EQ(faces, mesh.triangles.size());
  EXPECT_EQ(filled_faces, 2u * 24u);
}

TEST_F(MeshFiles, ThreeMfReadsBackThroughLib3mfInMillimetres) {
  const core::TriangleMesh mesh = torus(48, 24);
  io::write_3mf(path("m.3mf"), mesh, "slscan test");
  const io::ThreeMfContents read = io::read_3mf(path("m.3mf"));
  EXPECT_EQ(read.unit, "millimeter");
  EXPECT_EQ(read.build_items, 1u);
  ASSERT_EQ(read.object_types, std::vector<std::string>{"model"});  // closed: a solid
  ASSERT_EQ(read.mesh.vertices.size(), mesh.vertices.size());
  ASSERT_EQ(read.mesh.triangles, mesh.triangles);
  // lib3mf prints 6 decimals: 0.5 nm, then the float's own step at ~150 mm (15 nm).
  float worst = 0;
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    worst = std::max(worst, (read.mesh.vertices[i] - mesh.vertices[i]).cwiseAbs().maxCoeff());
  EXPECT_LE(worst, 2e-5f);
  // The same mesh gives the same file (UUIDs from the mesh, not random).
  const std::string first = read_bytes(path("m.3mf"));
  io::write_3mf(path("m.3mf"), mesh, "slscan test");
  EXPECT_EQ(read_bytes(path("m.3mf")), first);
  // An open mesh (a raw scan) is a 3MF surface, not a solid.
  core::TriangleMesh open = mesh;
  open.triangles.resize(open.triangles.size() - 2);
  open.filled.resize(open.triangles.size());
  io::write_3mf(path("open.3mf"), open, "slscan test");
  EXPECT_EQ(io::read_3mf(path("open.3mf")).object_types, std::vector<std::string>{"surface"});
  // And read_mesh takes a 3MF nominal.
  EXPECT_EQ(io::read_mesh(path("m.3mf")).triangles.size(), mesh.triangles.size());
}

TEST_F(MeshFiles, BadMeshesAreRefusedAndNothingIsWritten) {
  core::TriangleMesh mesh = torus(12, 8);
  mesh.triangles.back()[2] = static_cast<std::uint32_t>(mesh.vertices.size());
  EXPECT_THROW(io::write_obj(path("bad.obj"), mesh), io::IoError);
  EXPECT_THROW(io::write_3mf(path("bad.3mf"), mesh, "bad"), io::IoError);
  core::TriangleMesh flags = torus(12, 8);
  flags.filled.pop_back();
  EXPECT_THROW(io::write_obj(path("flags.obj"), flags), io::IoError);
  EXPECT_FALSE(fs::exists(path("bad.obj")));
  EXPECT_FALSE(fs::exists(path("bad.3mf")));
  EXPECT_FALSE(fs::exists(path("flags.obj")));
  // Not a 3MF: lib3mf's reason, naming the file.
  std::ofstream(path("not.3mf")) << "not a zip";
  try {
    (void)io::read_3mf(path("not.3mf"));
    ADD_FAILURE() << "a text file read as 3MF";
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find(path("not.3mf") + ": 3MF: reading failed"), std::string::npos) << e.what();
  }
}

// A reconstruction result whose mesh is the torus, and a small model.
core::ScanResult meshed_result() {
  core::ScanResult result;
  for (int k = 0; k < 200; ++k) {
    result.model.points.emplace_back(static_cast<float>(k % 20), static_cast<float>(k / 20), 1.0f);
    result.model.normals.emplace_back(0.0f, 0.0f, 1.0f);
  }
  result.meshed = true;
  result.mesh.mesh = torus(32, 16);
  return result;
}

TEST_F(MeshFiles, TheChosenFormatsAreWrittenWithTheSetAndReplacedByTheNext) {
  const fs::path out = dir_ / "out";
  const core::ScanResult result = meshed_result();
  core::MeshFormats all;
  ASSERT_EQ(core::parse_mesh_formats("3mf,obj,stl,ply", all), "");
  const OutputFiles files = write_scan_outputs(out.string(), result, json::object(), all);
  EXPECT_EQ(files.mesh_obj, (out / "mesh.obj").string());
  EXPECT_EQ(files.mesh_3mf, (out / "mesh.3mf").string());
  EXPECT_EQ(io::read_mesh(files.mesh_obj).triangles.size(), result.mesh.mesh.triangles.size());
  EXPECT_EQ(io::read_3mf(files.mesh_3mf).mesh.vertices.size(), result.mesh.mesh.vertices.size());
  EXPECT_EQ(io::read_ply_table(files.mesh_ply).faces.size(), result.mesh.mesh.triangles.size());
  EXPECT_EQ(io::read_mesh(files.mesh_stl).triangles.size(), result.mesh.mesh.triangles.size());
  const json report = json::parse(read_bytes(out / "report.json"));
  EXPECT_EQ(report["outputs"]["mesh_obj"], "mesh.obj");
  EXPECT_EQ(report["outputs"]["mesh_3mf"], "mesh.3mf");
  // report.json is the newest file of the set (its completion marker).
  for (const char* name : {"mesh.ply", "mesh.stl", "mesh.obj", "mesh.3mf"})
    EXPECT_LE(fs::last_write_time(out / name), fs::last_write_time(out / "report.json")) << name;

  // The default run writes PLY and STL only, and the earlier OBJ and 3MF go with the old set.
  const OutputFiles again = write_scan_outputs(out.string(), result, json::object());
  EXPECT_TRUE(again.mesh_obj.empty());
  EXPECT_TRUE(fs::exists(out / "mesh.ply"));
  EXPECT_TRUE(fs::exists(out / "mesh.stl"));
  EXPECT_FALSE(fs::exists(out / "mesh.obj"));
  EXPECT_FALSE(fs::exists(out / "mesh.3mf"));
  const json second = json::parse(read_bytes(out / "report.json"));
  EXPECT_FALSE(second["outputs"].contains("mesh_obj"));
  EXPECT_EQ(second["outputs"]["mesh_ply"], "mesh.ply");
}

TEST(MeshFormats, ParseAndPrint) {
  core::MeshFormats formats;
  EXPECT_EQ(core::mesh_formats_text(formats), "ply,stl");
  ASSERT_EQ(core::parse_mesh_formats("obj", formats), "");
  EXPECT_EQ(formats, (core::MeshFormats{false, false, true, false}));
  ASSERT_EQ(core::parse_mesh_formats("3mf,ply", formats), "");
  EXPECT_EQ(core::mesh_formats_text(formats), "ply,3mf");
  for (const char* bad : {"", "ply,", ",ply", "PLY", "ply stl", "step", "obj,obj"}) {
    core::MeshFormats kept;
    EXPECT_NE(core::parse_mesh_formats(bad, kept), "") << bad;
    EXPECT_EQ(kept, core::MeshFormats{}) << bad << ": changed on failure";
  }
  EXPECT_EQ(core::parse_mesh_formats("ply,step", formats), "unknown mesh format \"step\" (ply, stl, obj or 3mf)");
  EXPECT_EQ(core::parse_mesh_formats("stl,stl", formats), "\"stl\" is listed twice");
}

TEST(MeshOverrides, CommandLineOverTheConfig) {
  core::ReconstructionOptions options;
  apply_mesh_overrides({}, options);  // nothing given: the config's (here the defaults)
  EXPECT_TRUE(options.build_mesh);
  EXPECT_EQ(options.mesh.mode, core::MeshMode::watertight);
  EXPECT_EQ(options.mesh.fill_holes_mm, 10);
  EXPECT_EQ(options.mesh_formats, core::MeshFormats{});

  apply_mesh_overrides({.mode = "watertight", .fill_holes_mm = 4.5, .formats = "stl,3mf"}, options);
  EXPECT_EQ(options.mesh.fill_holes_mm, 4.5);
  EXPECT_EQ(options.mesh_formats, (core::MeshFormats{false, true, false, true}));
  apply_mesh_overrides({.mode = "raw"}, options);
  EXPECT_EQ(options.mesh.mode, core::MeshMode::raw);
  apply_mesh_overrides({.max_triangles = 200000, .simplify_tolerance_mm = 0.002}, options);
  EXPECT_EQ(options.mesh.max_triangles, 200000u);
  EXPECT_EQ(options.mesh.simplify_tolerance_mm, 0.002);
  apply_mesh_overrides({.mode = "none"}, options);
  EXPECT_FALSE(options.build_mesh);
  apply_mesh_overrides({.mode = "watertight"}, options);
  EXPECT_TRUE(options.build_mesh);

  const auto refused = [](const MeshOverrides& overrides, core::ReconstructionOptions o, const std::string& why) {
    try {
      apply_mesh_overrides(overrides, o);
      ADD_FAILURE() << "accepted: " << why;
    } catch (const UsageError& e) {
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  };
  const core::ReconstructionOptions defaults;
  refused({.mode = "smooth"}, defaults, "--mesh must be watertight, raw or none, not \"smooth\"");
  refused({.mode = "raw", .fill_holes_mm = 5}, defaults, "--fill-holes applies to the watertight mesh");
  refused({.mode = "none", .fill_holes_mm = 5}, defaults, "--fill-holes: this run makes no mesh (--mesh none)");
  refused({.fill_holes_mm = -1}, defaults, "--fill-holes must be a diameter >= 0 mm");
  refused({.fill_holes_mm = std::nan("")}, defaults, "--fill-holes must be a diameter >= 0 mm");
  refused({.formats = "ply,gltf"}, defaults, "--mesh-formats: unknown mesh format \"gltf\"");
  refused({.max_triangles = 3}, defaults, "--max-triangles must be 0 (no limit) or >= 4, not 3");
  refused({.mode = "none", .max_triangles = 5000}, defaults, "--max-triangles: this run makes no mesh (--mesh none)");
  refused({.simplify_tolerance_mm = 2}, defaults, "--simplify-tolerance must be in [0, 1] mm");
  refused({.simplify_tolerance_mm = std::nan("")}, defaults, "--simplify-tolerance must be in [0, 1] mm");
  refused({.mode = "none", .simplify_tolerance_mm = 0.01}, defaults, "--simplify-tolerance: this run makes no mesh");
  refused({.mode = "none", .formats = "obj"}, defaults, "--mesh-formats: this run makes no mesh (--mesh none)");
  // The config's mode counts too.
  core::ReconstructionOptions raw_config;
  apply_config(json::parse(R"({"mesh": {"mode": "raw"}})"), raw_config);
  refused({.fill_holes_mm = 5}, raw_config, "this run's is raw (the config's mesh.mode)");
  core::ReconstructionOptions no_mesh_config;
  apply_config(json::parse(R"({"mesh": {"enabled": false}})"), no_mesh_config);
  refused({.formats = "obj"}, no_mesh_config, "(the config's mesh.enabled is false)");
}

// The simplification's two keys: read, written back into report.json's config, refused out of range.
TEST(MeshSimplification, ConfigKeysRoundTripAndAbsurdValuesAreRefused) {
  core::ReconstructionOptions options;
  apply_config(json::parse(R"({"mesh": {"max_triangles": 150000, "simplify_tolerance_mm": 0.003}})"), options);
  EXPECT_EQ(options.mesh.max_triangles, 150000u);
  EXPECT_EQ(options.mesh.simplify_tolerance_mm, 0.003);
  core::ReconstructionOptions again;
  apply_config(config_to_json(options), again);
  EXPECT_EQ(again.mesh.max_triangles, 150000u);
  EXPECT_EQ(again.mesh.simplify_tolerance_mm, 0.003);
  for (const char* text : {R"({"mesh": {"simplify_tolerance_mm": 5}})", R"({"mesh": {"max_triangles": 2}})",
                           R"({"mesh": {"max_triangles": -1}})"}) {
    core::ReconstructionOptions o;
    EXPECT_THROW(
        {
          apply_config(json::parse(text), o);
          o.check();
        },
        std::exception)
        << text;
  }
}

TEST(MeshFormats, ConfigFileSectionAndReport) {
  core::ReconstructionOptions options;
  apply_config(json::parse(R"({"mesh": {"formats": "obj,3mf"}})"), options);
  EXPECT_EQ(options.mesh_formats, (core::MeshFormats{false, false, true, true}));
  EXPECT_EQ(config_to_json(options)["mesh"]["formats"], "obj,3mf");
  core::ReconstructionOptions again;
  apply_config(config_to_json(options), again);
  EXPECT_EQ(again.mesh_formats, options.mesh_formats);
  try {
    apply_config(json::parse(R"({"mesh": {"formats": "ply,dxf"}})"), again);
    ADD_FAILURE() << "dxf accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "config: mesh.formats: unknown mesh format \"dxf\" (ply, stl, obj or 3mf)");
  }
  EXPECT_THROW(apply_config(json::parse(R"({"mesh": {"formats": ["ply"]}})"), again), std::invalid_argument);
}

}  // namespace
}  // namespace slscan::app
