// slrig-render: renders a virtual-rig scene (a preset or a JSON scene file) to PNG frames plus
// its ground truth, so a person can look at what the rig sees. Usage: slrig-render --help.
#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "png_writer.hpp"
#include "scene_build.hpp"
#include "slrig/rig.hpp"

namespace {

constexpr const char* kUsage = R"(slrig-render: render virtual-rig frames and ground truth

usage: slrig-render (--preset NAME | --scene FILE) --out DIR [options]

  --preset NAME      ballbar, plane, sphere, blade, teacup, calibration, shiny_blade or dark_blade
  --small            the 640 x 512 rig instead of 2464 x 2056 (with --preset)
  --scene FILE       a JSON scene file (docs/virtual-rig.md)
  --out DIR          output directory (created if missing)
  --nominal FILE     write the scene objects' true surfaces as a binary STL (turntable frame,
                     mm: the nominal for slscan inspect); --out then optional
  --views LIST       comma-separated view indices into the scene's view angles (default: all)
  --side S           left, right or both (default both)
  --frames LIST      comma-separated pattern indices (default: all 19)
  --no-noise         exact render (no shot or read noise)
  --seed N           noise seed (default: the scene's)
  --bit-depth N      8, 10 or 12 (10/12-bit frames are written as 16-bit PNG)
  --no-truth         skip the ground-truth files
  --exposure-us US   camera exposure (default: the scene's reference, sensor.exposure_us)
  --led-current F    projector LED current, a fraction in (0, 1] (default 1)

Writes DIR/scene.json, DIR/calibration.json and per view DIR/view_K/:
  left_NN_KIND.png, right_NN_KIND.png   the frames (NN = pattern index)
  ambient.png                            both projectors dark
  depth.png                              16-bit z in 0.1 mm units (0 = nothing)
  depth.pfm                              float z in mm (NaN = nothing), Portable FloatMap
  proj_left.pfm, proj_right.pfm          projector coordinate along the coding axis (NaN = unlit)
  truth.ply                              ground-truth points (camera frame) with normals and object id
and DIR/surfaces.ply: the objects' true surfaces in the turntable frame (0.5 mm spacing).
Exit codes: 0 ok, 1 bad usage or scene, 2 render or write failure.
)";

struct Options {
  std::string preset, scene_path, out, nominal;
  bool small = false, noise = true, truth = true;
  std::vector<int> views, frames;
  int sides = 3;  // bit 0 left, bit 1 right
  long long seed = -1;
  int bit_depth = 0;
  slrig::Exposure exposure;
};

bool parse_number(const std::string& text, double& out) {
  try {
    std::size_t used = 0;
    out = std::stod(text, &used);
    return used == text.size() && std::isfinite(out);
  } catch (...) {
    return false;
  }
}

bool parse_list(const std::string& text, std::vector<int>& out) {
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      std::size_t used = 0;
      const int v = std::stoi(item, &used);
      if (used != item.size() || v < 0) return false;
      out.push_back(v);
    } catch (...) {
      return false;
    }
  }
  return !out.empty();
}

int usage_error(const std::string& message) {
  std::cerr << "slrig-render: " << message << "\n(see slrig-render --help)\n";
  return 1;
}

bool make_dir(const std::string& path, std::string& error) {
  std::error_code ec;
  std::filesystem::create_directories(path, ec);
  if (!ec && std::filesystem::is_directory(path, ec)) return true;
  error = path + ": cannot create directory (" + (ec ? ec.message() : std::string("not a directory")) + ")";
  return false;
}

slproto::Status write_png(const std::string& path, int w, int h, int depth, std::span<const std::uint8_t> data) {
  auto png = slrig::tools::encode_png_gray(w, h, depth, data);
  if (!png) return png.error();
  return slproto::write_file_atomically(path, *png);
}

slproto::Status write_pfm(const std::string& path, int w, int h, const std::vector<float>& values, int stride,
                          int component) {
  std::string bytes = "Pf\n" + std::to_string(w) + " " + std::to_string(h) + "\n-1.0\n";
  // PFM rows run bottom to top.
  for (int y = h - 1; y >= 0; --y)
    for (int x = 0; x < w; ++x) {
      const float v = values[(static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x)) *
                                 static_cast<std::size_t>(stride) +
                             static_cast<std::size_t>(component)];
      bytes.append(reinterpret_cast<const char*>(&v), sizeof v);
    }
  return slproto::write_file_atomically(path, bytes);
}

slproto::Status write_truth_ply(const std::string& path, const slrig::ViewGroundTruth& truth) {
  std::size_t count = 0;
  const std::size_t n = static_cast<std::size_t>(truth.width) * static_cast<std::size_t>(truth.height);
  for (std::size_t i = 0; i < n; ++i) count += truth.object_id[i] >= 0;
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\ncomment slrig ground truth, camera frame, mm\nelement vertex " +
      std::to_string(count) +
      "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
      "property float nz\nproperty short object_id\nend_header\n";
  bytes.reserve(bytes.size() + count * 26);
  for (std::size_t i = 0; i < n; ++i) {
    if (truth.object_id[i] < 0) continue;
    bytes.append(reinterpret_cast<const char*>(&truth.points[3 * i]), 12);
    bytes.append(reinterpret_cast<const char*>(&truth.normals[3 * i]), 12);
    bytes.append(reinterpret_cast<const char*>(&truth.object_id[i]), 2);
  }
  return slproto::write_file_atomically(path, bytes);
}

slproto::Status write_surfaces_ply(const std::string& path, const slrig::SurfaceSample& s) {
  const std::size_t count = s.object_id.size();
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\ncomment slrig object surfaces, turntable frame, mm\n"
      "element vertex " +
      std::to_string(count) +
      "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
      "property float nz\nproperty short object_id\nend_header\n";
  for (std::size_t i = 0; i < count; ++i) {
    bytes.append(reinterpret_cast<const char*>(&s.points[3 * i]), 12);
    bytes.append(reinterpret_cast<const char*>(&s.normals[3 * i]), 12);
    bytes.append(reinterpret_cast<const char*>(&s.object_id[i]), 2);
  }
  return slproto::write_file_atomically(path, bytes);
}

const char* kind_suffix(const slproto::Pattern& p) {
  switch (p.kind) {
    case slproto::PatternKind::white:
      return "white";
    case slproto::PatternKind::black:
      return "black";
    case slproto::PatternKind::gray_bit:
      return "gray";
    case slproto::PatternKind::complementary_bit:
      return "comp";
    case slproto::PatternKind::gray_bit_inverse:
      return "gray_inv";
    case slproto::PatternKind::complementary_bit_inverse:
      return "comp_inv";
    case slproto::PatternKind::phase_step:
      return "phase";
  }
  return "pattern";
}

// The scene objects' true surfaces as one binary STL in the turntable frame (mm), the nominal
// for `slscan inspect` (docs/inspection.md): spheres as level-6 icospheres (chord error < 1 um
// at 25 mm), the blade's and teacup's own meshes, a mesh object's file. Other kinds are refused.
void icosphere(double r, const slrig::detail::V3& c, std::vector<slrig::detail::Triangle>& out) {
  using slrig::detail::V3;
  const double t = (1 + std::sqrt(5.0)) / 2;
  std::vector<V3> v = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                       {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  std::vector<std::array<int, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                       {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                       {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                       {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (auto& p : v) p = slrig::detail::normalized(p);
  for (int level = 0; level < 6; ++level) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      if (auto it = mid.find(key); it != mid.end()) return it->second;
      v.push_back(slrig::detail::normalized(v[static_cast<std::size_t>(a)] + v[static_cast<std::size_t>(b)]));
      return mid[key] = static_cast<int>(v.size() - 1);
    };
    std::vector<std::array<int, 3>> next;
    for (const auto& tri : f) {
      const int ab = midpoint(tri[0], tri[1]), bc = midpoint(tri[1], tri[2]), ca = midpoint(tri[2], tri[0]);
      next.push_back({tri[0], ab, ca});
      next.push_back({tri[1], bc, ab});
      next.push_back({tri[2], ca, bc});
      next.push_back({ab, bc, ca});
    }
    f = std::move(next);
  }
  for (const auto& tri : f)
    out.push_back({c + r * v[static_cast<std::size_t>(tri[0])], c + r * v[static_cast<std::size_t>(tri[1])],
                   c + r * v[static_cast<std::size_t>(tri[2])]});
}

int write_nominal(const Options& opt) {
  auto scene = !opt.preset.empty()
                   ? slrig::scene_preset(opt.preset, opt.small ? slrig::RigSize::small : slrig::RigSize::full)
                   : slrig::load_scene(opt.scene_path);
  if (!scene) return usage_error(scene.error().message);
  std::vector<slrig::detail::Triangle> triangles;
  for (const slrig::SceneObject& o : scene->objects) {
    std::vector<slrig::detail::Triangle> local;
    switch (o.kind) {
      case slrig::ObjectKind::sphere:
        icosphere(o.radius, {0, 0, 0}, local);
        break;
      case slrig::ObjectKind::blade:
        local = slrig::detail::blade_mesh(o);
        break;
      case slrig::ObjectKind::teacup:
        local = slrig::detail::teacup_mesh(o);
        break;
      case slrig::ObjectKind::mesh: {
        auto loaded = slrig::detail::load_mesh_file(o.mesh_path);
        if (!loaded) return usage_error(loaded.error().message);
        for (auto& t : *loaded) t = {o.mesh_scale * t.a, o.mesh_scale * t.b, o.mesh_scale * t.c};
        local = std::move(*loaded);
        break;
      }
      default:
        return usage_error("--nominal: object '" + o.name +
                           "' is not a sphere, blade, teacup or mesh (the kinds with a nominal to write)");
    }
    if (!o.on_turntable) return usage_error("--nominal: object '" + o.name + "' is not on the turntable");
    const slrig::detail::Frame frame(o.table_from_object);
    for (const auto& t : local) triangles.push_back({frame.apply(t.a), frame.apply(t.b), frame.apply(t.c)});
  }
  std::string bytes(80, '\0');
  const std::string header = "slrig nominal, turntable frame, mm";
  std::memcpy(bytes.data(), header.data(), header.size());
  const auto count = static_cast<std::uint32_t>(triangles.size());
  bytes.append(reinterpret_cast<const char*>(&count), 4);
  for (const auto& t : triangles) {
    const slrig::detail::V3 n = slrig::detail::cross(t.b - t.a, t.c - t.a);
    const double len = slrig::detail::norm(n);
    const slrig::detail::V3 u = len > 0 ? (1 / len) * n : n;
    for (const slrig::detail::V3& p : {u, t.a, t.b, t.c})
      for (int k = 0; k < 3; ++k) {
        const auto f = static_cast<float>(p[k]);
        bytes.append(reinterpret_cast<const char*>(&f), 4);
      }
    bytes.append(2, '\0');
  }
  const std::string tmp = opt.nominal + ".partial";
  std::FILE* file = std::fopen(tmp.c_str(), "wb");
  if (file == nullptr || std::fwrite(bytes.data(), 1, bytes.size(), file) != bytes.size() || std::fclose(file) != 0) {
    std::cerr << "slrig-render: cannot write " << tmp << ": " << std::strerror(errno) << "\n";
    return 2;
  }
  std::filesystem::rename(tmp, opt.nominal);
  std::cout << "wrote " << opt.nominal << ": " << triangles.size() << " triangles, turntable frame, mm\n";
  return 0;
}

int run(const Options& opt) {
  slproto::Result<slrig::Scene> scene = slproto::make_error(slproto::Errc::invalid_argument, "no scene");
  if (!opt.preset.empty())
    scene = slrig::scene_preset(opt.preset, opt.small ? slrig::RigSize::small : slrig::RigSize::full);
  else
    scene = slrig::load_scene(opt.scene_path);
  if (!scene) return usage_error(scene.error().message);
  if (!opt.noise) scene->sensor.noise = false;
  if (opt.seed >= 0) scene->sensor.seed = static_cast<std::uint64_t>(opt.seed);
  if (opt.bit_depth != 0) scene->sensor.bit_depth = opt.bit_depth;
  if (auto status = slrig::check_scene(*scene); !status) return usage_error(status.error().message);

  std::string error;
  if (!make_dir(opt.out, error)) {
    std::cerr << "slrig-render: " << error << "\n";
    return 2;
  }
  auto fail = [](const slproto::Status& s) {
    std::cerr << "slrig-render: " << s.error().message << "\n";
    return 2;
  };
  if (auto s = slproto::write_file_atomically(opt.out + "/scene.json", slrig::format_scene(*scene)); !s) return fail(s);
  if (auto s = slproto::save_calibration(opt.out + "/calibration.json", slrig::ground_truth_calibration(*scene)); !s)
    return fail(s);
  if (opt.truth)
    if (auto s = write_surfaces_ply(opt.out + "/surfaces.ply", slrig::sample_object_surfaces(*scene, 0.5)); !s)
      return fail(s);

  std::vector<int> views = opt.views;
  if (views.empty())
    for (std::size_t i = 0; i < scene->view_angles_deg.size(); ++i) views.push_back(static_cast<int>(i));
  const slproto::PatternPlan plan(scene->pattern_plan);
  std::vector<int> frames = opt.frames;
  if (frames.empty())
    for (std::size_t i = 0; i < plan.size(); ++i) frames.push_back(static_cast<int>(i));
  for (int f : frames)
    if (static_cast<std::size_t>(f) >= plan.size())
      return usage_error("--frames: pattern " + std::to_string(f) + " is beyond the plan's " +
                         std::to_string(plan.size()));
  for (int view : views) {
    if (static_cast<std::size_t>(view) >= scene->view_angles_deg.size())
      return usage_error("--views: view " + std::to_string(view) + " is beyond the scene's " +
                         std::to_string(scene->view_angles_deg.size()) + " view angles");
    const double angle = scene->view_angles_deg[static_cast<std::size_t>(view)];
    auto renderer = slrig::ViewRenderer::make(*scene, angle, view);
    if (!renderer) return fail(renderer.error());
    const std::string dir = opt.out + "/view_" + std::to_string(view);
    if (!make_dir(dir, error)) {
      std::cerr << "slrig-render: " << error << "\n";
      return 2;
    }
    const int w = renderer->width(), h = renderer->height();
    const int png_depth = scene->sensor.bit_depth > 8 ? 16 : 8;
    std::vector<std::uint8_t> frame(renderer->frame_bytes());
    for (int side = 0; side < 2; ++side) {
      if ((opt.sides & (1 << side)) == 0) continue;
      for (int f : frames) {
        const auto s = static_cast<slproto::ProjectorSide>(side);
        if (auto st = renderer->try_render(s, plan, static_cast<std::size_t>(f), frame, opt.exposure); !st)
          return usage_error(st.error().message);
        char name[96];
        std::snprintf(name, sizeof name, "/%s_%02d_%s.png", side == 0 ? "left" : "right", f,
                      kind_suffix(plan[static_cast<std::size_t>(f)]));
        if (auto st = write_png(dir + name, w, h, png_depth, frame); !st) return fail(st);
      }
    }
    renderer->render_ambient(frame, opt.exposure);
    if (auto st = write_png(dir + "/ambient.png", w, h, png_depth, frame); !st) return fail(st);
    if (opt.truth) {
      const slrig::ViewGroundTruth& truth = renderer->ground_truth();
      std::vector<std::uint8_t> depth(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 2, 0);
      for (std::size_t i = 0; i < depth.size() / 2; ++i) {
        const float z = truth.points[3 * i + 2];
        const long level = std::isfinite(z) ? std::lround(std::clamp(z * 10.0f, 0.0f, 65535.0f)) : 0;
        depth[2 * i] = static_cast<std::uint8_t>(level & 0xFF);
        depth[2 * i + 1] = static_cast<std::uint8_t>(level >> 8);
      }
      if (auto st = write_png(dir + "/depth.png", w, h, 16, depth); !st) return fail(st);
      if (auto st = write_pfm(dir + "/depth.pfm", w, h, truth.points, 3, 2); !st) return fail(st);
      if (auto st = write_pfm(dir + "/proj_left.pfm", w, h, truth.projector_coord[0], 1, 0); !st) return fail(st);
      if (auto st = write_pfm(dir + "/proj_right.pfm", w, h, truth.projector_coord[1], 1, 0); !st) return fail(st);
      if (auto st = write_truth_ply(dir + "/truth.ply", truth); !st) return fail(st);
    }
    std::cout << "view " << view << " (" << angle << " deg): " << dir << "\n";
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  std::vector<std::string> args(argv + 1, argv + argc);
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    auto value = [&](std::string& out) {
      if (i + 1 >= args.size()) return false;
      out = args[++i];
      return true;
    };
    std::string v;
    if (a == "--help" || a == "-h") {
      std::cout << kUsage;
      return 0;
    } else if (a == "--preset") {
      if (!value(opt.preset)) return usage_error("--preset needs a name");
    } else if (a == "--scene") {
      if (!value(opt.scene_path)) return usage_error("--scene needs a file");
    } else if (a == "--out") {
      if (!value(opt.out)) return usage_error("--out needs a directory");
    } else if (a == "--nominal") {
      if (!value(opt.nominal)) return usage_error("--nominal needs a file name (.stl)");
    } else if (a == "--small") {
      opt.small = true;
    } else if (a == "--no-noise") {
      opt.noise = false;
    } else if (a == "--no-truth") {
      opt.truth = false;
    } else if (a == "--views") {
      if (!value(v) || !parse_list(v, opt.views)) return usage_error("--views needs a list like 0,1,2");
    } else if (a == "--frames") {
      if (!value(v) || !parse_list(v, opt.frames)) return usage_error("--frames needs a list like 0,1,10");
    } else if (a == "--side") {
      if (!value(v)) return usage_error("--side needs left, right or both");
      if (v == "left")
        opt.sides = 1;
      else if (v == "right")
        opt.sides = 2;
      else if (v == "both")
        opt.sides = 3;
      else
        return usage_error("--side: '" + v + "' is not left, right or both");
    } else if (a == "--seed") {
      std::vector<int> list;
      if (!value(v) || !parse_list(v, list) || list.size() != 1)
        return usage_error("--seed needs a non-negative integer");
      opt.seed = list[0];
    } else if (a == "--bit-depth") {
      std::vector<int> list;
      if (!value(v) || !parse_list(v, list) || list.size() != 1) return usage_error("--bit-depth needs 8, 10 or 12");
      opt.bit_depth = list[0];
    } else if (a == "--exposure-us") {
      if (!value(v) || !parse_number(v, opt.exposure.exposure_us) || !(opt.exposure.exposure_us > 0))
        return usage_error("--exposure-us needs a positive number of microseconds");
    } else if (a == "--led-current") {
      if (!value(v) || !parse_number(v, opt.exposure.led_current) || !(opt.exposure.led_current > 0) ||
          opt.exposure.led_current > 1)
        return usage_error("--led-current needs a fraction in (0, 1], got '" + v + "'");
    } else {
      return usage_error("unknown argument '" + a + "'");
    }
  }
  if (opt.preset.empty() == opt.scene_path.empty()) return usage_error("give exactly one of --preset or --scene");
  if (opt.out.empty() && opt.nominal.empty()) return usage_error("--out (or --nominal) is required");
  try {
    if (!opt.nominal.empty()) {
      if (const int code = write_nominal(opt); code != 0 || opt.out.empty()) return code;
    }
    return run(opt);
  } catch (const std::exception& e) {
    std::cerr << "slrig-render: " << e.what() << "\n";
    return 2;
  }
}
