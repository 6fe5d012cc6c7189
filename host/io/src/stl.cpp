#include "slscan/io/stl.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cstdint>
#include <cstring>

#include "slscan/io/io_error.hpp"

namespace slscan::io {
namespace {

template <class T>
void put(std::string& out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  out.append(bytes, sizeof(T));
}

}  // namespace

void write_stl(const std::string& path, const std::vector<Eigen::Vector3f>& vertices,
               const std::vector<Eigen::Vector3i>& triangles, const std::string& header_text) {
  std::string out(80, '\0');
  std::memcpy(out.data(), header_text.data(), std::min<std::size_t>(79, header_text.size()));
  put(out, static_cast<std::uint32_t>(triangles.size()));
  for (const auto& t : triangles) {
    for (int k = 0; k < 3; ++k)
      if (t[k] < 0 || static_cast<std::size_t>(t[k]) >= vertices.size())
        throw IoError(path + ": triangle refers to vertex " + std::to_string(t[k]) + " of " +
                      std::to_string(vertices.size()));
    const Eigen::Vector3f& a = vertices[static_cast<std::size_t>(t[0])];
    const Eigen::Vector3f& b = vertices[static_cast<std::size_t>(t[1])];
    const Eigen::Vector3f& c = vertices[static_cast<std::size_t>(t[2])];
    Eigen::Vector3f n = (b - a).cross(c - a);
    const float len = n.norm();
    if (len > 0) n /= len;
    for (const Eigen::Vector3f* v : {static_cast<const Eigen::Vector3f*>(&n), &a, &b, &c})
      for (int k = 0; k < 3; ++k) put(out, (*v)[k]);
    put(out, std::uint16_t{0});
  }
  write_file_atomically(path, out);
}

}  // namespace slscan::io
