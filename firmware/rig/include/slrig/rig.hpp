// The virtual rig: a physically based simulator of the dual-projector turntable scanner.
// It is the firmware's sim backend, the source of ground truth for every accuracy test and the
// workload of every benchmark. No OpenCV (it links into slscand); Eigen is allowed in the .cpp.
//
// Conventions are the project's (docs/conventions.md): mm, OpenCV camera frame, pixel centres
// at integers, target_from_source poses, turntable frame z up along the axis, CCW angles.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "slproto/calibration.hpp"
#include "slproto/pattern_plan.hpp"
#include "slproto/result.hpp"

namespace slrig {

using slproto::ProjectorSide;
using slproto::Vec3;

struct SensorModel {
  int bit_depth = 8;  // 8, 10 or 12; 10/12-bit frames are little-endian uint16
  double full_well_electrons = 10000;
  double read_noise_dn = 1.5;
  double dark_level_dn = 0;  // black offset added before clipping
  // A white matte surface facing a full-white projector at the platform centre, no ambient,
  // reads white_level_dn at exposure_us and full LED current; the signal scales with both.
  double white_level_dn = 200;
  double exposure_us = 8333;  // the reference exposure (one 8-bit DLP pattern), and a render's default
  // Charge above the full well that spills into the 4 neighbours (a quarter each), the rest
  // drained by the anti-blooming gate; one hop, no cascade. 0: none.
  double blooming = 0.3;
  std::uint64_t seed = 1;
  bool noise = true;  // false: an exact, noise-free render (for closed-form tests)
};

// How one frame is exposed. The defaults reproduce the scene's reference exposure exactly.
struct Exposure {
  double exposure_us = 0;  // camera exposure; 0 = the sensor's exposure_us
  double led_current = 1;  // projector LED current relative to the white level's (0, 1]
  // Time the projector's pattern lights the scene within the exposure (the sim board's DLP
  // window overlapping the camera's); 0 = the whole exposure.
  double projector_us = 0;
  double start_s = 0;  // exposure start, seconds on any clock: the phase of the ambient flicker
};

// Room light: uniform, unshadowed, `level` x projector white on every surface (times its
// albedo) at the reference exposure. With flicker the lamps' intensity is
// level x (1 + depth cos(2 pi 2 mains_hz t + phase)): 100 or 120 Hz, integrated over each
// exposure, so an exposure of a whole number of flicker periods sees no flicker at all.
struct AmbientLight {
  double level = 0.05;
  double flicker_depth = 0;  // 0 = steady; 1 = the lamps go dark twice per mains cycle
  double mains_hz = 50;
  double phase_deg = 0;
};

// Surface finishes: albedo (diffuse), specular strength and Blinn-Phong exponent.
enum class Material : std::uint8_t { matte, glazed, polished_metal, brushed_metal, dark_plastic };
const char* material_name(Material material) noexcept;
slproto::Result<Material> parse_material(std::string_view name);

struct ProjectorModel {
  slproto::PinholeModel intrinsics;  // DMD resolution, coding axis along width by default
  slproto::RigidTransform cam_from_proj;
  double gamma = 2.2;
  double defocus_sigma_px = 0.7;  // Gaussian blur of the pattern, projector pixels
  double brightness = 1.0;        // relative to the white level
};

struct TurntableModel {
  slproto::RigidTransform cam_from_table;  // table frame at angle 0
  double platform_radius_mm = 150;
  double albedo = 0.5;               // matte: it shows up in the cloud, on purpose
  double angle_error_sigma_deg = 0;  // random error of each commanded move
  double axis_wobble_deg = 0;        // tilt of the axis, varying with angle
  double settle_time_ms = 200;
};

enum class ObjectKind : std::uint8_t { sphere, ballbar, plane, blade, teacup, checkerboard, mesh };

// One object, placed in the turntable frame (table_from_object), rotating with the table
// unless `on_turntable` is false (then `table_from_object` is read in the camera frame).
struct SceneObject {
  ObjectKind kind = ObjectKind::sphere;
  std::string name;
  slproto::RigidTransform table_from_object;
  bool on_turntable = true;
  double albedo = 0.8;
  double specular = 0;  // strength of a specular lobe (0 = matte)
  double specular_power = 50;
  // Shape parameters (mm); which are used depends on kind:
  double radius = 15;                                                          // sphere
  double radius_a = 15.0004, radius_b = 15.00075, centre_distance = 150.1164;  // ballbar (radii = diameters / 2)
  double width = 100, height = 100;  // plane, blade span/chord, checkerboard extent
  int squares_x = 9, squares_y = 7;  // checkerboard squares (inner corners = squares - 1)
  double square_mm = 10;
  std::string mesh_path;  // mesh: PLY/OBJ/STL
  // Added by the rig (defaults are the presets'):
  double bar_radius = 5, stand_radius = 4, stand_height = 80;  // ballbar: bar, and the post under its centre
  double thickness = 3;                                        // checkerboard plate thickness; teacup wall thickness
  double dark_albedo = 0.05;                                   // checkerboard dark squares (light squares use `albedo`)
  double twist_deg = 35;                                       // blade twist from root to tip
  double mesh_scale = 1;                                       // mesh: file units -> mm
};

// Sets albedo, specular and specular_power to a finish (docs/virtual-rig.md, "Surfaces").
void apply_material(SceneObject& object, Material material);

// Inner corners of a checkerboard object in its own frame (z = 0 is the printed face, z points
// into the board, corner (i, j) at (i * square_mm, j * square_mm, 0), i fastest; the square
// left of and above corner (0, 0) is dark, as in OpenCV).
std::vector<Vec3> checkerboard_corners(const SceneObject& board);

struct Scene {
  std::string name;
  slproto::PinholeModel camera;
  SensorModel sensor;
  std::array<ProjectorModel, 2> projectors;  // indexed by ProjectorSide
  TurntableModel turntable;
  std::vector<SceneObject> objects;
  AmbientLight ambient;
  // One bounce of projector light between diffuse surfaces (concave parts, an object over the
  // platform): each pixel gathers `interreflection_samples` cosine-distributed rays.
  bool interreflection = false;
  int interreflection_samples = 64;
  bool background_wall = true;
  double wall_distance_mm = 400;  // behind the turntable axis, along the camera's view
  slproto::PatternPlanConfig pattern_plan;
  std::vector<double> view_angles_deg{0, 60, 120, 180, 240, 300};
  double wall_albedo = 0.6;
};

// Validates a scene: every field that would make a render impossible, named.
slproto::Status check_scene(const Scene& scene);

enum class RigSize : std::uint8_t { full, small };  // 2464 x 2056, or 640 x 512 for unit tests

// Scene presets: "ballbar", "plane", "sphere", "blade", "teacup", "calibration", and the
// finishes that make exposure matter: "shiny_blade" (polished metal) and "dark_blade" (dark plastic).
slproto::Result<Scene> scene_preset(std::string_view name, RigSize size = RigSize::full);
slproto::Result<Scene> load_scene(const std::string& path);  // JSON scene file
slproto::Result<Scene> parse_scene(std::string_view json_text, std::string_view origin = "scene");
std::string format_scene(const Scene& scene);  // JSON text that parse_scene reads back

// The exact calibration of a scene, in the host's calibration file format.
slproto::RigCalibration ground_truth_calibration(const Scene& scene);

// Per-pixel truth of one view, in the camera frame. NaN where the camera sees nothing.
struct ViewGroundTruth {
  int width = 0, height = 0;
  double commanded_angle_deg = 0, actual_angle_deg = 0;
  std::vector<float> points;            // 3 per pixel (x, y, z) mm, camera frame
  std::vector<float> normals;           // 3 per pixel, unit, facing the camera
  std::vector<std::int16_t> object_id;  // -1 nothing, 0 turntable, 1 wall, 2 + i scene object i
  std::vector<std::uint8_t> part_id;    // part of the object (ballbar: 0 sphere a, 1 sphere b, 2 bar, 3 stand)
  std::array<std::vector<float>, 2> projector_coord;  // coding-axis coordinate per side, NaN where unlit
  std::array<std::vector<std::uint8_t>, 2> lit;       // 1 where that projector lights the point
  slproto::RigidTransform cam_from_table;             // the table pose actually reached
};

// Renders the frames of one view. The constructor casts the camera rays once and tests
// shadows once per projector; each frame is then look-ups plus the sensor model.
class ViewRenderer {
 public:
  // Throws std::invalid_argument if check_scene fails; use make() on outside input.
  ViewRenderer(const Scene& scene, double commanded_angle_deg, int view_index);
  static slproto::Result<ViewRenderer> make(const Scene& scene, double commanded_angle_deg, int view_index);
  ~ViewRenderer();
  ViewRenderer(ViewRenderer&&) noexcept;
  ViewRenderer& operator=(ViewRenderer&&) noexcept;

  int width() const;
  int height() const;
  std::size_t frame_bytes() const;  // width * height * (1 or 2)

  // The camera frame while projector `side` shows pattern `pattern_index` of `plan` (the
  // scene's own plan when omitted), exposed as `exposure` says (the scene's reference exposure
  // when omitted). The other projector is dark. Noise is seeded by (scene seed, view, side,
  // pattern) and, away from the reference, the exposure and LED current, so a render is
  // reproducible.
  void render(ProjectorSide side, std::size_t pattern_index, std::span<std::uint8_t> out) const;
  void render(ProjectorSide side, const slproto::PatternPlan& plan, std::size_t pattern_index,
              std::span<std::uint8_t> out, const Exposure& exposure = {}) const;
  // Both projectors dark: ambient light only (what a camera calibration image sees).
  void render_ambient(std::span<std::uint8_t> out, const Exposure& exposure = {}) const;
  // The render() preconditions (out.size() >= frame_bytes(), pattern_index < plan.size(), the
  // plan's coded extent equal to the projector's, a possible exposure) are programming errors:
  // render() throws std::invalid_argument. try_render() returns them as a Status instead (for
  // the firmware).
  slproto::Status try_render(ProjectorSide side, const slproto::PatternPlan& plan, std::size_t pattern_index,
                             std::span<std::uint8_t> out, const Exposure& exposure = {}) const;

  const ViewGroundTruth& ground_truth() const;

 private:
  struct Impl;
  explicit ViewRenderer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// A dense sample of each object's true surface in the turntable frame, for point-to-surface
// error: points and normals, `spacing_mm` apart.
struct SurfaceSample {
  std::vector<float> points;   // 3 per point
  std::vector<float> normals;  // 3 per point
  std::vector<std::int16_t> object_id;
  std::vector<std::uint8_t> part_id;
};
SurfaceSample sample_object_surfaces(const Scene& scene, double spacing_mm);

}  // namespace slrig
