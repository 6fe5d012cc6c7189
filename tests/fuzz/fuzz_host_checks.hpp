// Properties of the host's file readers: PLY clouds and meshes (host/io/ply) here, calibration
// capture manifests in fuzz_manifest_checks.hpp. Bad input must end in an IoError with a
// message, never another exception, a crash or an allocation the file's size cannot justify.
// Shared with the corpus replay test in tests/host.
#pragma once

#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <string>

#include "fuzz_checks.hpp"
#include "slscan/io/ply.hpp"

namespace slproto::fuzz {

inline void check_ply_bytes(const std::uint8_t* bytes, std::size_t size) {
  const int fd = ::memfd_create("ply", MFD_CLOEXEC);
  if (fd < 0) return;
  if (size != 0 && ::write(fd, bytes, size) != static_cast<ssize_t>(size)) fuzz_fail("memfd write");
  const std::string path = "/proc/self/fd/" + std::to_string(fd);
  try {
    const slscan::io::PlyTable table = slscan::io::read_ply_table(path);
    for (const auto& column : table.columns) {
      if (column.size() != table.vertex_count) fuzz_fail("PLY column length differs from the vertex count");
    }
    if (table.columns.size() != table.property_names.size()) fuzz_fail("PLY columns and names disagree");
    for (const auto& face : table.faces) {
      for (const std::uint32_t index : face) {
        if (index >= table.vertex_count) fuzz_fail("PLY face index past the vertex count accepted");
      }
    }
  } catch (const slscan::io::IoError& e) {
    if (std::string(e.what()).empty()) fuzz_fail("PLY error without a message");
  }
  try {
    const auto cloud = slscan::io::read_ply(path);
    if (!cloud.normals.empty() && cloud.normals.size() != cloud.points.size())
      fuzz_fail("PLY normals and points differ in count");
  } catch (const slscan::io::IoError& e) {
    if (std::string(e.what()).empty()) fuzz_fail("PLY error without a message");
  }
  ::close(fd);
}

}  // namespace slproto::fuzz
