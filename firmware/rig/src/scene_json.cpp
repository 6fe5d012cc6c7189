// Scene files (JSON). Every field is optional over a base (a preset, or the default rig with no
// objects); unknown keys and wrong types are errors that name the field.
#include <cmath>
#include <cstdint>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <set>
#include <sstream>

#include "slproto/calibration_file.hpp"
#include "slproto/json_fields.hpp"
#include "slrig/rig.hpp"

namespace slrig {

namespace {

using json = nlohmann::json;
using slproto::Errc;

constexpr int kSceneFormatVersion = 1;
constexpr double kDeg = std::numbers::pi / 180.0;

struct ParseError {
  std::string message;
};

// A JSON object being read: records which keys were used so the rest can be reported.
class Reader {
 public:
  Reader(const json& node, std::string path) : node_(node), path_(std::move(path)) {
    if (!node_.is_object()) throw ParseError{where("") + "expected an object"};
  }
  std::string where(const std::string& key) const {
    const std::string full = key.empty() ? path_ : (path_.empty() ? key : path_ + "." + key);
    return (full.empty() ? std::string("scene") : full) + ": ";
  }
  std::string child_path(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }
  const json* get(const std::string& key) {
    used_.insert(key);
    auto it = node_.find(key);
    return it == node_.end() ? nullptr : &*it;
  }
  void number(const std::string& key, double& out) {
    if (const json* v = get(key)) {
      if (!v->is_number()) throw ParseError{where(key) + "expected a number"};
      out = v->get<double>();
      if (!std::isfinite(out)) throw ParseError{where(key) + "not a finite number"};
    }
  }
  void integer(const std::string& key, int& out) {
    if (const json* v = get(key)) {
      if (!v->is_number_integer()) throw ParseError{where(key) + "expected an integer"};
      // A value past INT64_MAX is stored unsigned; read as long long it would wrap (2^64 - 1 is
      // -1), so the unsigned one is compared as such.
      const bool in_range = v->is_number_unsigned()
                                ? v->get<std::uint64_t>() <= 1000000000ULL
                                : v->get<long long>() >= -1000000000LL && v->get<long long>() <= 1000000000LL;
      if (!in_range)
        throw ParseError{where(key) + v->dump() + " is out of range (an integer from -1000000000 to 1000000000)"};
      out = static_cast<int>(v->get<long long>());
    }
  }
  void boolean(const std::string& key, bool& out) {
    if (const json* v = get(key)) {
      if (!v->is_boolean()) throw ParseError{where(key) + "expected true or false"};
      out = v->get<bool>();
    }
  }
  void string(const std::string& key, std::string& out) {
    if (const json* v = get(key)) {
      if (!v->is_string()) throw ParseError{where(key) + "expected a string"};
      out = v->get<std::string>();
    }
  }
  std::vector<double> numbers(const std::string& key, const json& v, std::size_t count) const {
    if (!v.is_array() || (count != 0 && v.size() != count))
      throw ParseError{where(key) + "expected an array of " + (count ? std::to_string(count) + " " : "") + "numbers"};
    std::vector<double> out;
    for (const json& x : v) {
      if (!x.is_number() || !std::isfinite(x.get<double>())) throw ParseError{where(key) + "expected finite numbers"};
      out.push_back(x.get<double>());
    }
    return out;
  }
  void finish() const {
    for (auto it = node_.begin(); it != node_.end(); ++it)
      if (!used_.count(it.key())) throw ParseError{where(it.key()) + "unknown field"};
  }

 private:
  const json& node_;
  std::string path_;
  std::set<std::string> used_;
};

void read_pose(Reader& parent, const std::string& key, slproto::RigidTransform& pose) {
  const json* v = parent.get(key);
  if (v == nullptr) return;
  Reader r(*v, parent.child_path(key));
  if (const json* R = r.get("R")) {
    const auto values = r.numbers("R", *R, 9);
    for (std::size_t i = 0; i < 9; ++i) pose.R[i] = values[i];
  }
  if (const json* deg = r.get("rotation_deg")) {
    if (v->contains("R")) throw ParseError{r.where("rotation_deg") + "give R or rotation_deg, not both"};
    // Extrinsic rotations about x, then y, then z (R = Rz Ry Rx), degrees.
    const auto a = r.numbers("rotation_deg", *deg, 3);
    const auto rx = slproto::RigidTransform::rotation_about_axis({1, 0, 0}, {0, 0, 0}, a[0] * kDeg);
    const auto ry = slproto::RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, a[1] * kDeg);
    const auto rz = slproto::RigidTransform::rotation_about_axis({0, 0, 1}, {0, 0, 0}, a[2] * kDeg);
    pose.R = (rz * ry * rx).R;
  }
  if (const json* t = r.get("t")) {
    const auto values = r.numbers("t", *t, 3);
    pose.t = {values[0], values[1], values[2]};
  }
  r.finish();
  if (auto s = pose.check(parent.child_path(key)); !s) throw ParseError{s.error().message};
}

void read_pinhole(Reader& parent, const std::string& key, slproto::PinholeModel& m) {
  const json* v = parent.get(key);
  if (v == nullptr) return;
  Reader r(*v, parent.child_path(key));
  r.integer("width", m.width);
  r.integer("height", m.height);
  r.number("fx", m.fx);
  r.number("fy", m.fy);
  r.number("cx", m.cx);
  r.number("cy", m.cy);
  if (const json* d = r.get("distortion")) {
    if (d->is_object()) {
      // slproto's spelling (calibration files): {"k1": ..., "k2": ..., "p1": ..., "p2": ..., "k3": ...}.
      Reader k(*d, r.child_path("distortion"));
      k.number("k1", m.distortion.k1);
      k.number("k2", m.distortion.k2);
      k.number("p1", m.distortion.p1);
      k.number("p2", m.distortion.p2);
      k.number("k3", m.distortion.k3);
      k.finish();
    } else {
      // Scene files written before format_scene used slproto's spelling: [k1, k2, p1, p2, k3].
      const auto k = r.numbers("distortion", *d, 5);
      m.distortion = {k[0], k[1], k[2], k[3], k[4]};
    }
  }
  r.finish();
}

ObjectKind parse_kind(const std::string& name, const std::string& where) {
  static const std::pair<const char*, ObjectKind> kinds[] = {
      {"sphere", ObjectKind::sphere}, {"ballbar", ObjectKind::ballbar}, {"plane", ObjectKind::plane},
      {"blade", ObjectKind::blade},   {"teacup", ObjectKind::teacup},   {"checkerboard", ObjectKind::checkerboard},
      {"mesh", ObjectKind::mesh}};
  for (const auto& [n, k] : kinds)
    if (name == n) return k;
  throw ParseError{where + "unknown kind '" + name + "' (sphere, ballbar, plane, blade, teacup, checkerboard, mesh)"};
}

const char* kind_name(ObjectKind kind) {
  switch (kind) {
    case ObjectKind::sphere:
      return "sphere";
    case ObjectKind::ballbar:
      return "ballbar";
    case ObjectKind::plane:
      return "plane";
    case ObjectKind::blade:
      return "blade";
    case ObjectKind::teacup:
      return "teacup";
    case ObjectKind::checkerboard:
      return "checkerboard";
    case ObjectKind::mesh:
      return "mesh";
  }
  return "sphere";
}

SceneObject read_object(const json& node, const std::string& path, const std::string& base_dir) {
  Reader r(node, path);
  SceneObject o;
  std::string kind;
  r.string("kind", kind);
  if (kind.empty()) throw ParseError{r.where("kind") + "missing"};
  o.kind = parse_kind(kind, r.where("kind"));
  r.string("name", o.name);
  if (o.name.empty()) o.name = kind;
  read_pose(r, "pose", o.table_from_object);
  r.boolean("on_turntable", o.on_turntable);
  std::string material;
  r.string("material", material);
  if (!material.empty()) {
    auto finish = parse_material(material);
    if (!finish) throw ParseError{r.where("material") + finish.error().message};
    apply_material(o, *finish);  // explicit albedo / specular fields below override it
  }
  r.number("albedo", o.albedo);
  r.number("specular", o.specular);
  r.number("specular_power", o.specular_power);
  r.number("radius", o.radius);
  r.number("radius_a", o.radius_a);
  r.number("radius_b", o.radius_b);
  r.number("centre_distance", o.centre_distance);
  r.number("width", o.width);
  r.number("height", o.height);
  r.integer("squares_x", o.squares_x);
  r.integer("squares_y", o.squares_y);
  r.number("square_mm", o.square_mm);
  r.string("mesh_path", o.mesh_path);
  if (!o.mesh_path.empty() && o.mesh_path.front() != '/' && !base_dir.empty())
    o.mesh_path = base_dir + "/" + o.mesh_path;
  r.number("bar_radius", o.bar_radius);
  r.number("stand_radius", o.stand_radius);
  r.number("stand_height", o.stand_height);
  r.number("thickness", o.thickness);
  r.number("dark_albedo", o.dark_albedo);
  r.number("twist_deg", o.twist_deg);
  r.number("mesh_scale", o.mesh_scale);
  r.finish();
  return o;
}

Scene read_scene(const json& root, const std::string& base_dir) {
  Reader r(root, "");
  int version = kSceneFormatVersion;
  r.integer("format_version", version);
  if (version != kSceneFormatVersion)
    throw ParseError{"format_version: " + std::to_string(version) + " is not supported (this build reads " +
                     std::to_string(kSceneFormatVersion) + ")"};
  std::string preset, size_name = "full";
  r.string("preset", preset);
  r.string("size", size_name);
  if (size_name != "full" && size_name != "small") throw ParseError{"size: '" + size_name + "' is not full or small"};
  const RigSize size = size_name == "small" ? RigSize::small : RigSize::full;
  Scene scene;
  if (!preset.empty()) {
    auto base = scene_preset(preset, size);
    if (!base) throw ParseError{"preset: " + base.error().message};
    scene = std::move(*base);
  } else {
    auto base = scene_preset("plane", size);  // the default rig; its objects are dropped
    scene = std::move(*base);
    scene.objects.clear();
    scene.name = "scene";
  }
  r.string("name", scene.name);
  read_pinhole(r, "camera", scene.camera);
  if (const json* v = r.get("sensor")) {
    Reader s(*v, "sensor");
    SensorModel& m = scene.sensor;
    s.integer("bit_depth", m.bit_depth);
    s.number("full_well_electrons", m.full_well_electrons);
    s.number("read_noise_dn", m.read_noise_dn);
    s.number("dark_level_dn", m.dark_level_dn);
    s.number("white_level_dn", m.white_level_dn);
    s.number("exposure_us", m.exposure_us);
    s.number("blooming", m.blooming);
    double seed = static_cast<double>(m.seed);
    s.number("seed", seed);
    if (seed < 0 || seed > 9007199254740992.0 || seed != std::floor(seed))
      throw ParseError{"sensor.seed: expected a non-negative integer"};
    m.seed = static_cast<std::uint64_t>(seed);
    s.boolean("noise", m.noise);
    s.finish();
  }
  if (const json* v = r.get("projectors")) {
    if (!v->is_array() || v->size() != 2) throw ParseError{"projectors: expected an array of two (left, right)"};
    for (std::size_t i = 0; i < 2; ++i) {
      const std::string path = "projectors[" + std::to_string(i) + "]";
      Reader p((*v)[i], path);
      ProjectorModel& m = scene.projectors[i];
      std::string side;
      p.string("side", side);
      if (!side.empty() && side != (i == 0 ? "left" : "right"))
        throw ParseError{path + ".side: '" + side + "' but index " + std::to_string(i) + " is the " +
                         (i == 0 ? "left" : "right") + " projector"};
      read_pinhole(p, "intrinsics", m.intrinsics);
      read_pose(p, "cam_from_proj", m.cam_from_proj);
      p.number("gamma", m.gamma);
      p.number("defocus_sigma_px", m.defocus_sigma_px);
      p.number("brightness", m.brightness);
      p.finish();
    }
  }
  if (const json* v = r.get("turntable")) {
    Reader t(*v, "turntable");
    TurntableModel& m = scene.turntable;
    read_pose(t, "cam_from_table", m.cam_from_table);
    t.number("platform_radius_mm", m.platform_radius_mm);
    t.number("albedo", m.albedo);
    t.number("angle_error_sigma_deg", m.angle_error_sigma_deg);
    t.number("axis_wobble_deg", m.axis_wobble_deg);
    t.number("settle_time_ms", m.settle_time_ms);
    t.finish();
  }
  if (const json* v = r.get("objects")) {
    if (!v->is_array()) throw ParseError{"objects: expected an array"};
    scene.objects.clear();
    for (std::size_t i = 0; i < v->size(); ++i)
      scene.objects.push_back(read_object((*v)[i], "objects[" + std::to_string(i) + "]", base_dir));
  }
  if (const json* v = r.get("ambient")) {
    if (v->is_number()) {
      scene.ambient.level = v->get<double>();  // the older form: the level alone
      if (!std::isfinite(scene.ambient.level)) throw ParseError{"ambient: not a finite number"};
    } else {
      Reader a(*v, "ambient");
      a.number("level", scene.ambient.level);
      a.number("flicker_depth", scene.ambient.flicker_depth);
      a.number("mains_hz", scene.ambient.mains_hz);
      a.number("phase_deg", scene.ambient.phase_deg);
      a.finish();
    }
  }
  r.boolean("interreflection", scene.interreflection);
  r.integer("interreflection_samples", scene.interreflection_samples);
  r.boolean("background_wall", scene.background_wall);
  r.number("wall_distance_mm", scene.wall_distance_mm);
  r.number("wall_albedo", scene.wall_albedo);
  if (const json* v = r.get("pattern_plan")) {
    Reader p(*v, "pattern_plan");
    slproto::PatternPlanConfig& c = scene.pattern_plan;
    p.integer("projector_width", c.projector_width);
    p.integer("projector_height", c.projector_height);
    std::string axis;
    p.string("axis", axis);
    if (!axis.empty()) {
      if (axis == "columns")
        c.axis = slproto::CodingAxis::columns;
      else if (axis == "rows")
        c.axis = slproto::CodingAxis::rows;
      else
        throw ParseError{"pattern_plan.axis: '" + axis + "' is not columns or rows"};
    }
    p.integer("period_px", c.period_px);
    p.integer("phase_steps", c.phase_steps);
    p.boolean("complementary_bit", c.complementary_bit);
    p.boolean("with_white_black", c.with_white_black);
    p.boolean("inverse_gray", c.inverse_gray);
    std::string convention;
    p.string("gray_low_bits", convention);
    if (convention == "slstudio_parity")
      c.gray_low_bits = slproto::GrayLowBits::slstudio_parity;
    else if (!convention.empty() && convention != "centre")
      throw ParseError{"pattern_plan.gray_low_bits: '" + convention + "' is not centre or slstudio_parity"};
    p.finish();
  }
  if (const json* v = r.get("view_angles_deg")) scene.view_angles_deg = r.numbers("view_angles_deg", *v, 0);
  r.finish();
  return scene;
}

}  // namespace

slproto::Result<Scene> parse_scene(std::string_view json_text, std::string_view origin) {
  {
    std::string base_dir;
    const std::string origin_str(origin);
    if (const auto slash = origin_str.find_last_of('/'); slash != std::string::npos)
      base_dir = origin_str.substr(0, slash);
    json root;
    try {
      root = slproto::parse_json_strict(json_text);
    } catch (const slproto::JsonFieldError& e) {  // syntax, duplicate keys, numbers beyond double
      return slproto::make_error(Errc::malformed, origin_str + ": " + e.what());
    }
    Scene scene;
    try {
      scene = read_scene(root, base_dir);
    } catch (const ParseError& e) {
      return slproto::make_error(Errc::invalid_argument, origin_str + ": " + e.message);
    } catch (const std::exception& e) {
      return slproto::make_error(Errc::invalid_argument, origin_str + ": " + e.what());
    }
    if (auto status = check_scene(scene); !status)
      return slproto::make_error(Errc::invalid_argument, origin_str + ": " + status.error().message);
    return scene;
  }
}

slproto::Result<Scene> load_scene(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return slproto::make_error(Errc::io_error, path + ": cannot open the scene file");
  std::ostringstream ss;
  ss << in.rdbuf();
  return parse_scene(ss.str(), path);
}

std::string format_scene(const Scene& scene) {
  json root;
  root["format_version"] = kSceneFormatVersion;
  root["name"] = scene.name;
  root["camera"] = slproto::pinhole_to_json(scene.camera);
  const SensorModel& s = scene.sensor;
  root["sensor"] = {{"bit_depth", s.bit_depth},
                    {"full_well_electrons", s.full_well_electrons},
                    {"read_noise_dn", s.read_noise_dn},
                    {"dark_level_dn", s.dark_level_dn},
                    {"white_level_dn", s.white_level_dn},
                    {"exposure_us", s.exposure_us},
                    {"blooming", s.blooming},
                    {"seed", s.seed},
                    {"noise", s.noise}};
  json projectors = json::array();
  for (std::size_t i = 0; i < 2; ++i) {
    const ProjectorModel& p = scene.projectors[i];
    projectors.push_back({{"side", i == 0 ? "left" : "right"},
                          {"intrinsics", slproto::pinhole_to_json(p.intrinsics)},
                          {"cam_from_proj", slproto::pose_to_json(p.cam_from_proj)},
                          {"gamma", p.gamma},
                          {"defocus_sigma_px", p.defocus_sigma_px},
                          {"brightness", p.brightness}});
  }
  root["projectors"] = projectors;
  const TurntableModel& t = scene.turntable;
  root["turntable"] = {{"cam_from_table", slproto::pose_to_json(t.cam_from_table)},
                       {"platform_radius_mm", t.platform_radius_mm},
                       {"albedo", t.albedo},
                       {"angle_error_sigma_deg", t.angle_error_sigma_deg},
                       {"axis_wobble_deg", t.axis_wobble_deg},
                       {"settle_time_ms", t.settle_time_ms}};
  json objects = json::array();
  for (const SceneObject& o : scene.objects) {
    json j = {
        {"kind", kind_name(o.kind)},         {"name", o.name},     {"pose", slproto::pose_to_json(o.table_from_object)},
        {"on_turntable", o.on_turntable},    {"albedo", o.albedo}, {"specular", o.specular},
        {"specular_power", o.specular_power}};
    switch (o.kind) {
      case ObjectKind::sphere:
        j["radius"] = o.radius;
        break;
      case ObjectKind::ballbar:
        j["radius_a"] = o.radius_a;
        j["radius_b"] = o.radius_b;
        j["centre_distance"] = o.centre_distance;
        j["bar_radius"] = o.bar_radius;
        j["stand_radius"] = o.stand_radius;
        j["stand_height"] = o.stand_height;
        break;
      case ObjectKind::plane:
        j["width"] = o.width;
        j["height"] = o.height;
        break;
      case ObjectKind::blade:
        j["width"] = o.width;
        j["height"] = o.height;
        j["twist_deg"] = o.twist_deg;
        break;
      case ObjectKind::teacup:
        j["radius"] = o.radius;
        j["height"] = o.height;
        j["thickness"] = o.thickness;
        break;
      case ObjectKind::checkerboard:
        j["squares_x"] = o.squares_x;
        j["squares_y"] = o.squares_y;
        j["square_mm"] = o.square_mm;
        j["width"] = o.width;
        j["height"] = o.height;
        j["thickness"] = o.thickness;
        j["dark_albedo"] = o.dark_albedo;
        break;
      case ObjectKind::mesh:
        j["mesh_path"] = o.mesh_path;
        j["mesh_scale"] = o.mesh_scale;
        break;
    }
    objects.push_back(j);
  }
  root["objects"] = objects;
  root["ambient"] = {{"level", scene.ambient.level},
                     {"flicker_depth", scene.ambient.flicker_depth},
                     {"mains_hz", scene.ambient.mains_hz},
                     {"phase_deg", scene.ambient.phase_deg}};
  root["interreflection"] = scene.interreflection;
  root["interreflection_samples"] = scene.interreflection_samples;
  root["background_wall"] = scene.background_wall;
  root["wall_distance_mm"] = scene.wall_distance_mm;
  root["wall_albedo"] = scene.wall_albedo;
  const auto& c = scene.pattern_plan;
  root["pattern_plan"] = {{"projector_width", c.projector_width},
                          {"projector_height", c.projector_height},
                          {"axis", c.axis == slproto::CodingAxis::columns ? "columns" : "rows"},
                          {"period_px", c.period_px},
                          {"phase_steps", c.phase_steps},
                          {"complementary_bit", c.complementary_bit},
                          {"with_white_black", c.with_white_black},
                          {"inverse_gray", c.inverse_gray},
                          {"gray_low_bits", slproto::gray_low_bits_name(c.gray_low_bits)}};
  root["view_angles_deg"] = scene.view_angles_deg;
  return root.dump(2) + "\n";
}

}  // namespace slrig
