#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include "slscan/io/ply.hpp"
#include "slscan/io/stl.hpp"

namespace slscan::io {
namespace {

class PlyIo : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() / ("slscan_ply_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string path(const char* name) const { return (dir_ / name).string(); }
  std::filesystem::path dir_;
};

core::PointCloud example_cloud() {
  core::PointCloud cloud;
  for (int i = 0; i < 100; ++i) {
    cloud.points.emplace_back(0.25f * i, -1.5f * i, 600.125f + i);
    cloud.normals.emplace_back(0.f, 0.6f, -0.8f);
    cloud.confidence.push_back(0.01f * i);
    cloud.intensity.push_back(0.011f * static_cast<float>(i) - 0.05f);  // below 0 and above 1 at the ends
    cloud.view_id.push_back(static_cast<std::uint16_t>(i % 6));
  }
  return cloud;
}

TEST_F(PlyIo, BinaryRoundTripKeepsEveryChannel) {
  const core::PointCloud cloud = example_cloud();
  write_ply(path("a.ply"), cloud, {.binary = true, .comments = {"made by a test"}});
  const core::PointCloud back = read_ply(path("a.ply"));
  ASSERT_EQ(back.size(), cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    EXPECT_EQ(back.points[i], cloud.points[i]);
    EXPECT_EQ(back.normals[i], cloud.normals[i]);
    EXPECT_EQ(back.confidence[i], cloud.confidence[i]);
    EXPECT_EQ(back.intensity[i], cloud.intensity[i]);
    EXPECT_EQ(back.view_id[i], cloud.view_id[i]);
  }
  const PlyTable table = read_ply_table(path("a.ply"));
  ASSERT_EQ(table.comments.size(), 1u);
  EXPECT_EQ(table.comments[0], "made by a test");
  // The grey viewers show: red = green = blue = round(255 x intensity), clamped to 0..255.
  EXPECT_EQ(table.property_names, (std::vector<std::string>{"x", "y", "z", "nx", "ny", "nz", "confidence", "intensity",
                                                            "view_id", "red", "green", "blue"}));
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const double expected = std::clamp(std::round(255.0 * cloud.intensity[i]), 0.0, 255.0);
    EXPECT_EQ(table.column("red")[i], expected) << "vertex " << i;
    EXPECT_EQ(table.column("green")[i], expected) << "vertex " << i;
    EXPECT_EQ(table.column("blue")[i], expected) << "vertex " << i;
  }
  EXPECT_EQ(table.column("red").front(), 0.0);
  EXPECT_EQ(table.column("red").back(), 255.0);
}

TEST_F(PlyIo, AsciiRoundTripKeepsIntensityAndGrey) {
  const core::PointCloud cloud = example_cloud();
  write_ply(path("a.ply"), cloud, {.binary = false, .comments = {}});
  const PlyTable table = read_ply_table(path("a.ply"));
  const core::PointCloud back = read_ply(path("a.ply"));
  ASSERT_EQ(back.intensity.size(), cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    EXPECT_EQ(back.intensity[i], cloud.intensity[i]);
    EXPECT_EQ(back.view_id[i], cloud.view_id[i]);
    EXPECT_EQ(table.column("green")[i], std::clamp(std::round(255.0 * cloud.intensity[i]), 0.0, 255.0));
  }
}

TEST_F(PlyIo, CloudWithoutIntensityHasNoColourProperties) {
  core::PointCloud cloud = example_cloud();
  cloud.intensity.clear();
  write_ply(path("a.ply"), cloud);
  const PlyTable table = read_ply_table(path("a.ply"));
  EXPECT_LT(table.find("intensity"), 0);
  EXPECT_LT(table.find("red"), 0);
  EXPECT_TRUE(read_ply(path("a.ply")).intensity.empty());
}

TEST_F(PlyIo, MeshPlyCarriesVertexIntensity) {
  const std::vector<Eigen::Vector3f> vertices{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const std::vector<Eigen::Vector3f> normals(4, Eigen::Vector3f(0, 0, 1));
  const std::vector<Eigen::Vector3i> triangles{{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  const std::vector<float> intensity{0.0f, 0.25f, 0.5f, 1.0f};
  write_mesh_ply(path("m.ply"), vertices, normals, triangles, {}, {0, 0, 1, 0}, intensity);
  const PlyTable table = read_ply_table(path("m.ply"));
  ASSERT_EQ(table.vertex_count, 4u);
  ASSERT_EQ(table.faces.size(), 4u);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(table.column("intensity")[i], intensity[i]);
    EXPECT_EQ(table.column("red")[i], std::round(255.0 * intensity[i]));
    EXPECT_EQ(table.column("x")[i], vertices[i].x());
  }
  EXPECT_THROW(write_mesh_ply(path("bad.ply"), vertices, normals, triangles, {}, {}, {0.5f}), IoError);
  EXPECT_FALSE(std::filesystem::exists(path("bad.ply")));
}

TEST_F(PlyIo, AsciiRoundTripIsExactForFloats) {
  const core::PointCloud cloud = example_cloud();
  write_ply(path("a.ply"), cloud, {.binary = false, .comments = {}});
  const core::PointCloud back = read_ply(path("a.ply"));
  ASSERT_EQ(back.size(), cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) EXPECT_EQ(back.points[i], cloud.points[i]);
}

TEST_F(PlyIo, TruncatedAndMalformedFilesNameTheProblem) {
  write_ply(path("a.ply"), example_cloud());
  const auto size = std::filesystem::file_size(path("a.ply"));
  std::filesystem::resize_file(path("a.ply"), size - 10);
  try {
    (void)read_ply(path("a.ply"));
    FAIL() << "truncated file was accepted";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 99"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
  }
  std::ofstream(path("b.ply")) << "ply\nformat binary_big_endian 1.0\nend_header\n";
  EXPECT_THROW((void)read_ply(path("b.ply")), IoError);
  std::ofstream(path("c.ply")) << "not a ply\n";
  EXPECT_THROW((void)read_ply(path("c.ply")), IoError);
  EXPECT_THROW((void)read_ply(path("missing.ply")), IoError);
}

TEST_F(PlyIo, MeshPlyAndStlAreWellFormed) {
  const std::vector<Eigen::Vector3f> vertices{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const std::vector<Eigen::Vector3i> triangles{{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  write_mesh_ply(path("m.ply"), vertices, {}, triangles);
  const PlyTable table = read_ply_table(path("m.ply"));
  EXPECT_EQ(table.vertex_count, 4u);
  ASSERT_EQ(table.faces.size(), 4u);
  EXPECT_EQ(table.faces[3], (std::vector<std::uint32_t>{1, 2, 3}));
  write_stl(path("m.stl"), vertices, triangles);
  EXPECT_EQ(std::filesystem::file_size(path("m.stl")), 84u + 4u * 50u);
  EXPECT_THROW(write_stl(path("bad.stl"), vertices, {{0, 1, 7}}), IoError);
  EXPECT_FALSE(std::filesystem::exists(path("bad.stl")));
}

TEST(PlyReference, ReadsTheSlstudioSkullCloud) {
  const std::string reference =
      std::string(SLSCAN_SOURCE_DIR) + "/../shared/data/slstudio-skull-gray/reference_cloud.ply";
  if (!std::filesystem::exists(reference)) GTEST_SKIP() << "reference data not present at " << reference;
  const PlyTable table = read_ply_table(reference);
  EXPECT_EQ(table.vertex_count, 93876u);
  EXPECT_GE(table.find("u"), 0);
  const auto& z = table.column("z");
  EXPECT_GT(z[0], 100.0);  // millimetres in front of the camera
}

}  // namespace
}  // namespace slscan::io
