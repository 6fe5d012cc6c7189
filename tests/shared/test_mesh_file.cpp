// slproto's mesh and PLY reader, shared by the virtual rig and the host: the same tetrahedron
// from every format, and bad files named by file and place.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "slproto/mesh_file.hpp"

namespace slproto {
namespace {

namespace fs = std::filesystem;

class MeshFileReader : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slproto-mesh-" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string write(const std::string& name, const std::string& bytes) const {
    const fs::path path = dir_ / name;
    std::ofstream(path, std::ios::binary) << bytes;
    return path.string();
  }
  fs::path dir_;
};

// A tetrahedron with one vertex per axis: four faces.
constexpr double kCorners[4][3] = {{0, 0, 0}, {10, 0, 0}, {0, 20, 0}, {0, 0, 30}};
constexpr int kFaces[4][3] = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};

std::string binary_stl() {
  std::string out(80, ' ');
  const std::uint32_t count = 4;
  out.append(reinterpret_cast<const char*>(&count), 4);
  for (const auto& face : kFaces) {
    const float normal[3] = {0, 0, 0};
    out.append(reinterpret_cast<const char*>(normal), 12);
    for (const int k : face) {
      const float v[3] = {static_cast<float>(kCorners[k][0]), static_cast<float>(kCorners[k][1]),
                          static_cast<float>(kCorners[k][2])};
      out.append(reinterpret_cast<const char*>(v), 12);
    }
    out.append(2, '\0');
  }
  return out;
}

std::string ascii_stl() {
  std::string out = "solid tetra\n";
  for (const auto& face : kFaces) {
    out += "facet normal 0 0 0\nouter loop\n";
    for (const int k : face)
      out += "vertex " + std::to_string(kCorners[k][0]) + " " + std::to_string(kCorners[k][1]) + " " +
             std::to_string(kCorners[k][2]) + "\n";
    out += "endloop\nendfacet\n";
  }
  return out + "endsolid tetra\n";
}

std::string obj() {
  return "# tetrahedron\nv 0 0 0\nv 10 0 0\nv 0 20 0\nv 0 0 30\nf 1 3 2\nf 1/1 2/2 4/4\nf -4 -1 -2\nf 2//2 3//3 4//4\n";
}

std::string ascii_ply() {
  return "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 4\nproperty float x\nproperty float y\n"
         "property float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
         "0 0 0\n10 0 0\n0 20 0\n0 0 30\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
}

std::string binary_ply() {
  std::string out =
      "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
      "property double z\nproperty uchar red\nelement face 4\nproperty list uchar uint vertex_indices\nend_header\n";
  for (const auto& corner : kCorners) {
    out.append(reinterpret_cast<const char*>(corner), 24);
    out.push_back('\x80');
  }
  for (const auto& face : kFaces) {
    out.push_back('\x03');
    for (const int k : face) {
      const std::uint32_t index = static_cast<std::uint32_t>(k);
      out.append(reinterpret_cast<const char*>(&index), 4);
    }
  }
  return out;
}

TEST_F(MeshFileReader, TheSameTetrahedronFromEveryFormat) {
  for (const auto& [name, bytes] : {std::pair<std::string, std::string>{"t.stl", binary_stl()},
                                    {"ascii.STL", ascii_stl()},
                                    {"t.obj", obj()},
                                    {"ascii.ply", ascii_ply()},
                                    {"binary.ply", binary_ply()}}) {
    auto mesh = read_mesh_file(write(name, bytes));
    ASSERT_TRUE(mesh.ok()) << name << ": " << mesh.error().message;
    ASSERT_EQ(mesh->triangles.size(), 4U) << name;
    for (std::size_t f = 0; f < 4; ++f)
      for (std::size_t c = 0; c < 3; ++c) {
        const auto& v = mesh->vertices[mesh->triangles[f][c]];
        const auto& expected = kCorners[kFaces[f][c]];
        EXPECT_EQ(v[0], expected[0]) << name << " face " << f;
        EXPECT_EQ(v[1], expected[1]) << name << " face " << f;
        EXPECT_EQ(v[2], expected[2]) << name << " face " << f;
      }
  }
}

TEST_F(MeshFileReader, PlyTableKeepsEveryVertexPropertyAndTheComments) {
  auto table = read_ply_table(write("b.ply", binary_ply()));
  ASSERT_TRUE(table.ok()) << table.error().message;
  EXPECT_EQ(table->vertex_count, 4U);
  ASSERT_EQ(table->property_names, (std::vector<std::string>{"x", "y", "z", "red"}));
  EXPECT_EQ(table->columns[3][2], 128.0);
  EXPECT_EQ(table->columns[static_cast<std::size_t>(table->find("z"))][3], 30.0);
  EXPECT_EQ(table->find("nx"), -1);
  ASSERT_EQ(table->faces.size(), 4U);
  EXPECT_EQ(table->faces[3], (std::vector<std::uint32_t>{1, 2, 3}));
  auto ascii = read_ply_table(write("a.ply", ascii_ply()));
  ASSERT_TRUE(ascii.ok()) << ascii.error().message;
  EXPECT_EQ(ascii->comments, (std::vector<std::string>{"made by hand"}));
}

TEST_F(MeshFileReader, BadFilesNameTheFileAndThePlace) {
  const std::string ply_header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  const std::string cut_binary = binary_ply().substr(0, binary_ply().size() - 30);
  struct Case {
    std::string name, bytes, expected;
    Errc code;
  };
  for (const Case& c : std::vector<Case>{
           {"index.obj", "v 0 0 0\nv 1 0 0\nf 1 2 3\n", "index.obj:3: face index 3 out of range (2 vertices so far)",
            Errc::malformed},
           {"word.obj", "v 0 0 0\nf 1 x 2\n", "word.obj:2: bad face index 'x'", Errc::malformed},
           {"nan.obj", "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "vertex 0 is not finite", Errc::malformed},
           {"points.obj", "v 0 0 0\nv 1 0 0\n", "no triangles", Errc::malformed},
           {"short.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n",
            "ASCII STL: 2 vertices, not a multiple of 3", Errc::malformed},
           {"junk.stl", std::string(100, 'x'), "neither a binary STL", Errc::malformed},
           {"big.ply", "ply\nformat binary_big_endian 1.0\nelement vertex 0\nend_header\n",
            "header line 2: format 'binary_big_endian' is not supported", Errc::unsupported},
           {"face.ply", ply_header + "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
            "face 0 names vertex 7 but the file has 3 vertices", Errc::malformed},
           {"cut.ply", cut_binary, "file ends in face 1 (truncated)", Errc::truncated},
           {"huge.ply",
            "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nend_header\n",
            "the header promises at least", Errc::truncated},
           {"noxyz.ply",
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float u\nelement face 0\n"
            "property list uchar int vertex_indices\nend_header\n0.5\n",
            "the vertices lack x, y or z", Errc::malformed},
           {"cube.xyz", "1 2 3\n", "unknown mesh extension '.xyz'", Errc::unsupported},
       }) {
    const std::string path = write(c.name, c.bytes);
    auto mesh = read_mesh_file(path);
    ASSERT_FALSE(mesh.ok()) << c.name;
    EXPECT_EQ(mesh.error().message.rfind(path + ":", 0), 0U) << mesh.error().message;
    EXPECT_NE(mesh.error().message.find(c.expected), std::string::npos) << mesh.error().message;
    EXPECT_EQ(mesh.error().code, c.code) << c.name << ": " << errc_name(mesh.error().code);
  }
  auto missing = read_mesh_file((dir_ / "missing.stl").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, Errc::io_error);
  EXPECT_NE(missing.error().message.find("cannot open"), std::string::npos) << missing.error().message;
}

}  // namespace
}  // namespace slproto
