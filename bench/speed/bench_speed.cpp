// Speed against the peers, side by side in one run (issue 10, docs/benchmarks.md):
//  1. decode + triangulate one full-resolution projector-view (2464 x 2056, 19 frames of the
//     virtual rig's teacup) against the memory floor (reading the same bytes, same threads) and
//     OpenCV contrib structured_light: GrayCodePattern (its per-pixel getProjPixel, the decode
//     its decode() runs per camera, on its own 44-frame code seen at the same resolution) and
//     SinusoidalPattern (3-step PSP phase map + its spatial unwrapping);
//  2. statistical and radius outlier removal, k-NN normals and point-to-plane ICP against PCL
//     1.13 and Open3D 0.16 on the same synthetic scanner-like clouds, with how their results
//     agree with ours.
// Built only with -DSLSCAN_BENCH_PEERS=ON (scripts/bench-setup.sh installs the peers).
// Run: bench_speed [--repeats N] [--points N] [--out FILE.md]
#include <sys/resource.h>
#include <sys/utsname.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_reduce.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <numeric>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/structured_light.hpp>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/cloud_filters.hpp"
#include "slscan/core/decode.hpp"
#include "slscan/core/normals.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/core/triangulate.hpp"

#ifdef SLSCAN_HAVE_PCL
#include <pcl/features/normal_3d_omp.h>
#include <pcl/filters/radius_outlier_removal.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/pcl_config.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/icp.h>
#endif
#ifdef SLSCAN_HAVE_OPEN3D
#include <open3d/Open3D.h>
#endif

namespace {

using Clock = std::chrono::steady_clock;
using slscan::core::PointCloud;

double ms_since(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

std::string strf(const char* format, auto... args) {
  char buffer[1024];
  std::snprintf(buffer, sizeof buffer, format, args...);
  return buffer;
}

// User + system CPU time of the whole process (every thread), ms: on a shared machine it is
// disturbed far less than the wall clock, and it shows what a tool costs, not just how it waits.
double process_cpu_ms() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  auto ms = [](const timeval& t) {
    return 1e3 * static_cast<double>(t.tv_sec) + 1e-3 * static_cast<double>(t.tv_usec);
  };
  return ms(usage.ru_utime) + ms(usage.ru_stime);
}

struct Series {
  std::vector<double> ms;
  std::vector<double> cpu_ms;
  double min() const { return *std::min_element(ms.begin(), ms.end()); }
  double max() const { return *std::max_element(ms.begin(), ms.end()); }
  double median() const {
    std::vector<double> s = ms;
    std::sort(s.begin(), s.end());
    return s.size() % 2 ? s[s.size() / 2] : 0.5 * (s[s.size() / 2 - 1] + s[s.size() / 2]);
  }
};

Series time_it(int repeats, const std::function<void()>& f) {
  Series s;
  for (int r = 0; r < repeats; ++r) {
    const double cpu0 = process_cpu_ms();
    const auto t0 = Clock::now();
    f();
    s.ms.push_back(ms_since(t0));
    s.cpu_ms.push_back(process_cpu_ms() - cpu0);
  }
  return s;
}

double median_of(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? NAN : v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

std::string ms_cell(const Series& s) {
  auto one = [](double v) { return v >= 100 ? strf("%.0f", v) : strf("%.1f", v); };
  return one(s.min()) + " / " + one(s.median()) + " / " + one(s.max()) +
         (s.cpu_ms.empty() ? std::string() : "; CPU " + one(median_of(s.cpu_ms)));
}
// "N x slower" by wall median, and by CPU median.
std::string slower(const Series& peer, const Series& us) {
  return strf("%.1f x slower; CPU %.1f x", peer.median() / us.median(), median_of(peer.cpu_ms) / median_of(us.cpu_ms));
}

std::uint64_t read_all(const std::vector<std::vector<std::uint8_t>>& frames) {
  std::uint64_t total = 0;
  for (const auto& frame : frames) {
    const auto* words = reinterpret_cast<const std::uint64_t*>(frame.data());
    const std::size_t n = frame.size() / 8;
    total += tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, 1 << 14), std::uint64_t{0},
        [&](const tbb::blocked_range<std::size_t>& r, std::uint64_t acc) {
          for (std::size_t i = r.begin(); i < r.end(); ++i) acc += words[i];
          return acc;
        },
        [](std::uint64_t a, std::uint64_t b) { return a + b; });
  }
  return total;
}

// A projector pattern as a camera of `size` sees it when the projector fills the frame.
std::vector<cv::Mat> as_camera_images(const std::vector<cv::Mat>& patterns, cv::Size size) {
  std::vector<cv::Mat> out(patterns.size());
  for (std::size_t i = 0; i < patterns.size(); ++i) {
    cv::Mat gray = patterns[i];
    if (gray.channels() == 3) cv::cvtColor(gray, gray, cv::COLOR_BGR2GRAY);
    cv::resize(gray, out[i], size, 0, 0, cv::INTER_LINEAR);
  }
  return out;
}

// Area grows with the count so the spacing stays ~0.1 mm, as in a fused scan; 0.5 % outliers
// (bench/registration's cloud).
PointCloud make_surface(std::size_t n, std::uint64_t seed) {
  const double radius = std::sqrt(static_cast<double>(n) * 0.01 / (4 * M_PI));
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0, 1);
  PointCloud cloud;
  cloud.points.reserve(n);
  while (cloud.size() < n) {
    const Eigen::Vector3d d = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const double r = radius * (1 + 0.1 * d.x() * d.y() + 0.08 * std::sin(3 * d.z())) + 0.01 * g(rng);
    cloud.points.push_back((d * r + Eigen::Vector3d(0, 0, radius)).cast<float>());
  }
  std::uniform_real_distribution<double> box(-1.3 * radius, 1.3 * radius);
  for (std::size_t i = 0; i < n / 200; ++i)
    cloud.points[i * 197 % n] = Eigen::Vector3d(box(rng), box(rng), box(rng) + radius).cast<float>();
  cloud.confidence.assign(n, 1.0f);
  cloud.view_id.assign(n, 0);
  return cloud;
}

// Kept-set agreement: how many of `ours` the peer also kept, and how many it kept that we did not.
std::string agreement(const std::vector<std::uint32_t>& ours, std::vector<std::uint32_t> theirs) {
  std::sort(theirs.begin(), theirs.end());
  std::vector<std::uint32_t> common;
  std::set_intersection(ours.begin(), ours.end(), theirs.begin(), theirs.end(), std::back_inserter(common));
  return strf("kept %zu; %zu of ours not kept, %zu not ours", theirs.size(), ours.size() - common.size(),
              theirs.size() - common.size());
}

double mean_normal_angle_deg(const std::vector<Eigen::Vector3f>& a, const std::vector<Eigen::Vector3f>& b) {
  double sum = 0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < a.size() && i < b.size(); ++i) {
    if (!a[i].allFinite() || !b[i].allFinite() || b[i].squaredNorm() < 0.5f) continue;
    sum += std::acos(std::min(1.0, static_cast<double>(std::fabs(a[i].dot(b[i])))));
    ++n;
  }
  return n ? sum / static_cast<double>(n) * 180 / M_PI : NAN;
}

struct Row {
  std::string what, tool, time, ratio, quality;
};

std::string machine_line() {
  std::string cpu = "?";
  std::ifstream f("/proc/cpuinfo");
  for (std::string line; std::getline(f, line);)
    if (line.rfind("model name", 0) == 0) {
      cpu = line.substr(line.find(':') + 2);
      break;
    }
  double load[3] = {0, 0, 0};
  getloadavg(load, 3);
  return strf("%s, %ld cores; load average at the start %.2f / %.2f / %.2f (1 / 5 / 15 min)", cpu.c_str(),
              sysconf(_SC_NPROCESSORS_ONLN), load[0], load[1], load[2]);
}

}  // namespace

int main(int argc, char** argv) try {
  int repeats = 5;
  std::size_t points = 1000000;
  std::string out_path;
  bool skip_pipeline = false, skip_clouds = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--repeats" && i + 1 < argc) {
      repeats = std::max(1, std::atoi(argv[++i]));
    } else if (arg == "--points" && i + 1 < argc) {
      points = static_cast<std::size_t>(std::max(1000L, std::atol(argv[++i])));
    } else if (arg == "--out" && i + 1 < argc) {
      out_path = argv[++i];
    } else if (arg == "--only-clouds") {
      skip_pipeline = true;
    } else if (arg == "--only-pipeline") {
      skip_clouds = true;
    } else {
      std::fprintf(stderr,
                   "usage: bench_speed [--repeats N] [--points N] [--out FILE.md] [--only-clouds|--only-pipeline]\n");
      return 2;
    }
  }
  const int threads = 2;
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  cv::setNumThreads(threads);
  std::ostringstream md;
  const std::time_t now = std::time(nullptr);
  char date[64];
  std::strftime(date, sizeof date, "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
  md << "Measured " << date << " by `bench_speed --repeats " << repeats << " --points " << points
     << "` (release build, -O3 -march=native), " << threads << " threads for every tool.\n\n"
     << "- Machine: " << machine_line() << " (shared: compare the ratios, measured in the same run)\n"
     << "- Versions: GCC " << __VERSION__ << ", OpenCV " << CV_VERSION
#ifdef SLSCAN_HAVE_PCL
     << ", PCL " << PCL_VERSION_PRETTY
#endif
#ifdef SLSCAN_HAVE_OPEN3D
     << ", Open3D " << OPEN3D_VERSION
#endif
     << "\n\n| operation | tool | wall min / median / max (ms); CPU median (ms, all threads) | median vs ours: "
        "wall; CPU | result compared |\n|---|---|---:|---:|---|\n";
  std::vector<Row> rows;
  auto flush = [&](const std::string& title) {
    for (const auto& r : rows)
      md << "| " << r.what << " | " << r.tool << " | " << r.time << " | " << r.ratio << " | " << r.quality << " |\n";
    rows.clear();
    std::printf("%s done\n", title.c_str());
    std::fflush(stdout);
  };

  if (!skip_pipeline) {
    // 1. One projector-view.
    const slrig::Scene scene = slrig::scene_preset("teacup", slrig::RigSize::full).value();
    const slproto::RigCalibration calibration = slrig::ground_truth_calibration(scene);
    const slproto::PatternPlan plan(calibration.pattern_plan);
    const int width = scene.camera.width, height = scene.camera.height;
    std::vector<std::vector<std::uint8_t>> frames;
    {
      const slrig::ViewRenderer renderer(scene, scene.view_angles_deg.at(0), 0);
      frames.assign(plan.size(), std::vector<std::uint8_t>(renderer.frame_bytes()));
      for (std::size_t p = 0; p < plan.size(); ++p) renderer.render(slproto::ProjectorSide::left, p, frames[p]);
    }
    const auto rays =
        std::make_shared<const slscan::core::CameraRayTable>(slscan::core::CameraRayTable::build(calibration.camera));
    const slscan::core::ProjectorTriangulator triangulator(rays, calibration.projectors[0], plan.config().axis);
    slscan::core::ProjectorViewDecoder decoder(plan, width, height);
    slscan::core::DecodedView decoded;
    slscan::core::OrganizedCloud cloud;
    std::uint64_t sink = 0;
    Series floor, ours;
    slscan::core::TriangulateCounts counts;
    for (int r = 0; r < repeats; ++r) {
      double cpu0 = process_cpu_ms();
      auto t0 = Clock::now();
      sink += read_all(frames);
      floor.ms.push_back(ms_since(t0));
      floor.cpu_ms.push_back(process_cpu_ms() - cpu0);
      cpu0 = process_cpu_ms();
      t0 = Clock::now();
      for (std::size_t p = 0; p < plan.size(); ++p)
        decoder.add_frame(p, frames[p].data(), static_cast<std::size_t>(width));
      decoder.finish(decoded);
      counts = triangulator.triangulate(decoded, cloud);
      ours.ms.push_back(ms_since(t0));
      ours.cpu_ms.push_back(process_cpu_ms() - cpu0);
    }
    const double mb = static_cast<double>(plan.size()) * width * height / 1e6;
    const std::string view = strf("one projector-view %d x %d", width, height);
    rows.push_back(
        {view + strf(", read the %zu frames (%.1f MB)", plan.size(), mb), "memory floor", ms_cell(floor),
         strf("%.2f x; CPU %.2f x", floor.median() / ours.median(), median_of(floor.cpu_ms) / median_of(ours.cpu_ms)),
         strf("checksum %llu", (unsigned long long)(sink % 997))});
    rows.push_back({view + ", decode + triangulate (frames copied in, 19 frames)", "slscan", ms_cell(ours), "1",
                    strf("%zu pixels decoded, %zu points", decoded.counts.valid, counts.valid)});

    // OpenCV GrayCodePattern: its code for a 1140 x 912 projector (both axes, with inverses:
    // 44 frames incl. white and black), seen at the camera's resolution.
    const int pw = calibration.projectors[0].intrinsics.width, ph = calibration.projectors[0].intrinsics.height;
    cv::structured_light::GrayCodePattern::Params gp;
    gp.width = pw;
    gp.height = ph;
    auto gray = cv::structured_light::GrayCodePattern::create(gp);
    std::vector<cv::Mat> patterns;
    gray->generate(patterns);
    cv::Mat white, black;
    gray->getImagesForShadowMasks(black, white);
    std::vector<cv::Mat> stack = as_camera_images(patterns, {width, height});
    const auto wb = as_camera_images({white, black}, {width, height});
    const std::size_t n_gray = stack.size() + 2;
    std::atomic<std::size_t> decoded_cv{0};
    std::atomic<std::size_t> wrong{0};
    const Series cv_pixel = time_it(std::max(1, repeats / 2), [&] {
      decoded_cv = 0;
      wrong = 0;
      // getProjPixel is per pixel and single-threaded; rows go to both threads here.
      cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rr) {
        std::size_t ok = 0, bad = 0;
        for (int y = rr.start; y < rr.end; ++y)
          for (int x = 0; x < width; ++x) {
            // OpenCV's own shadow test (white - black above its black threshold, 40 by default).
            if (wb[0].at<std::uint8_t>(y, x) - wb[1].at<std::uint8_t>(y, x) <= 40) continue;
            cv::Point p;
            if (!gray->getProjPixel(stack, x, y, p)) {
              ++ok;
              const int expect = (x * pw) / width;
              bad += std::abs(p.x - expect) > 1 ? 1 : 0;
            }
          }
        decoded_cv += ok;
        wrong += bad;
      });
    });
    rows.push_back({view + strf(", decode (%zu frames, both axes)", n_gray),
                    "OpenCV GrayCodePattern::getProjPixel, every pixel", ms_cell(cv_pixel), slower(cv_pixel, ours),
                    strf("%zu pixels decoded (%zu off the expected column by > 1)", decoded_cv.load(), wrong.load())});
    std::vector<cv::Mat> blacks{wb[1], wb[1]}, whites{wb[0], wb[0]};
    cv::Mat disparity;
    bool decode_ok = false;
    const Series cv_decode = time_it(std::max(1, repeats / 3), [&] {
      std::vector<std::vector<cv::Mat>> both{stack, stack};
      decode_ok = gray->decode(both, disparity, blacks, whites, cv::structured_light::DECODE_3D_UNDERWORLD);
    });
    rows.push_back({view + ", decode, two cameras (OpenCV's decode() is stereo only), per camera",
                    "OpenCV GrayCodePattern::decode / 2",
                    ms_cell(Series{{cv_decode.min() / 2, cv_decode.median() / 2, cv_decode.max() / 2},
                                   {median_of(cv_decode.cpu_ms) / 2}}),
                    slower(Series{{cv_decode.median() / 2}, {median_of(cv_decode.cpu_ms) / 2}}, ours),
                    decode_ok ? "disparity map (no triangulation)" : "decode() returned false"});
    stack.clear();

    // SinusoidalPattern, 3-step PSP, its own spatial unwrapping.
    cv::structured_light::SinusoidalPattern::Params sp;
    sp.width = pw;
    sp.height = ph;
    sp.nbrOfPeriods = 143;  // our fringe period: 8 projector pixels over 1140
    sp.methodId = cv::structured_light::PSP;
    auto sinus = cv::structured_light::SinusoidalPattern::create(
        cv::makePtr<cv::structured_light::SinusoidalPattern::Params>(sp));
    std::vector<cv::Mat> fringes;
    sinus->generate(fringes);
    const auto fringe_stack = as_camera_images(fringes, {width, height});
    cv::Mat wrapped, unwrapped, shadow;
    const Series cv_sinus = time_it(std::max(1, repeats / 3), [&] {
      sinus->computePhaseMap(fringe_stack, wrapped, shadow);
      sinus->unwrapPhaseMap(wrapped, unwrapped, cv::Size(width, height), shadow);
    });
    rows.push_back({view + strf(", phase (%zu frames) + spatial unwrap", fringe_stack.size()),
                    "OpenCV SinusoidalPattern (PSP)", ms_cell(cv_sinus), slower(cv_sinus, ours),
                    strf("unwrapped phase map %d x %d (no triangulation)", unwrapped.cols, unwrapped.rows)});
    flush("pipeline");
  }

  if (!skip_clouds) {
    // 2. Point clouds.
    const PointCloud cloud = make_surface(points, points);
    const std::string n_label = strf("%.1fM points", static_cast<double>(points) / 1e6);
    slscan::core::FilterResult sor_ours, radius_ours;
    const Series sor = time_it(repeats, [&] {
      sor_ours = slscan::core::statistical_outlier_removal(cloud, {20, 1.0});
    });
    const Series rad = time_it(repeats, [&] { radius_ours = slscan::core::radius_outlier_removal(cloud, {0.5, 5}); });
    std::vector<Eigen::Vector3f> normals_ours;
    slscan::core::PcaNormalOptions normal_options;
    const Series nrm = time_it(repeats, [&] { normals_ours = slscan::core::pca_normals(cloud, normal_options); });
    PointCloud target = cloud;
    target.normals = normals_ours;
    Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
    motion.linear() = Eigen::AngleAxisd(0.5 * M_PI / 180, Eigen::Vector3d(0.2, 1, 0.3).normalized()).toRotationMatrix();
    motion.translation() = Eigen::Vector3d(0.3, -0.3, 0.3);
    const PointCloud source = slscan::core::transform_cloud(target, motion.inverse());
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const auto& p : target.points) centroid += p.cast<double>() / static_cast<double>(target.size());
    auto icp_error = [&](const Eigen::Isometry3d& target_from_source) {
      const Eigen::Isometry3d err = target_from_source * motion.inverse();
      return strf("residual motion %.4f deg / %.4f mm", slscan::core::rotation_angle_deg(err),
                  (err * centroid - centroid).norm());
    };
    const std::size_t icp_source = std::min<std::size_t>(100000, points / 10);
    slscan::core::IcpOptions icp_options;
    icp_options.source_points_per_view = icp_source;
    slscan::core::IcpResult icp_ours;
    const Series icp = time_it(repeats, [&] {
      icp_ours = slscan::core::icp_point_to_plane(source, target, Eigen::Isometry3d::Identity(), icp_options);
    });
    // The peers' source: the same number of random source points.
    std::vector<std::uint32_t> subsample(source.size());
    std::iota(subsample.begin(), subsample.end(), 0u);
    std::shuffle(subsample.begin(), subsample.end(), std::mt19937_64(5));
    subsample.resize(icp_source);

    const std::string sor_what = "statistical outlier removal, k = 20, 1.0 sigma, " + n_label;
    const std::string rad_what = "radius outlier removal, 0.5 mm, >= 5 neighbours, " + n_label;
    const std::string nrm_what = "normals, k = 20 PCA, " + n_label;
    const std::string icp_what = strf("point-to-plane ICP, %zuk -> %.1fM, moved 0.5 deg / 0.52 mm", icp_source / 1000,
                                      static_cast<double>(points) / 1e6);
    std::vector<Row> sor_rows{{sor_what, "slscan", ms_cell(sor), "1", strf("kept %zu", sor_ours.kept_indices.size())}};
    std::vector<Row> rad_rows{
        {rad_what, "slscan", ms_cell(rad), "1", strf("kept %zu", radius_ours.kept_indices.size())}};
    std::vector<Row> nrm_rows{{nrm_what, "slscan", ms_cell(nrm), "1", "reference"}};
    std::vector<Row> icp_rows{{icp_what, "slscan (gates 2 / 0.5 / 0.2 mm)", ms_cell(icp), "1",
                               icp_error(icp_ours.target_from_source) + strf(", %d iterations", icp_ours.iterations)}};
    auto ratio = [](const Series& peer, const Series& us) { return slower(peer, us); };

#ifdef SLSCAN_HAVE_PCL
    {
      pcl::PointCloud<pcl::PointXYZ>::Ptr pc(new pcl::PointCloud<pcl::PointXYZ>);
      pc->reserve(cloud.size());
      for (const auto& p : cloud.points) pc->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
      pcl::Indices kept;
      const Series t = time_it(repeats, [&] {
        pcl::StatisticalOutlierRemoval<pcl::PointXYZ> f;
        f.setInputCloud(pc);
        f.setMeanK(20);
        f.setStddevMulThresh(1.0);
        f.filter(kept);
      });
      sor_rows.push_back({sor_what, "PCL StatisticalOutlierRemoval", ms_cell(t), ratio(t, sor),
                          agreement(sor_ours.kept_indices, {kept.begin(), kept.end()})});
      const Series tr = time_it(repeats, [&] {
        pcl::RadiusOutlierRemoval<pcl::PointXYZ> f;
        f.setInputCloud(pc);
        f.setRadiusSearch(0.5);
        f.setMinNeighborsInRadius(5);
        f.filter(kept);
      });
      rad_rows.push_back({rad_what, "PCL RadiusOutlierRemoval", ms_cell(tr), ratio(tr, rad),
                          agreement(radius_ours.kept_indices, {kept.begin(), kept.end()})});
      pcl::PointCloud<pcl::Normal> pn;
      const Series tn = time_it(repeats, [&] {
        pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal> ne(threads);
        ne.setInputCloud(pc);
        ne.setKSearch(20);
        ne.compute(pn);
      });
      std::vector<Eigen::Vector3f> peer(pn.size());
      for (std::size_t i = 0; i < pn.size(); ++i) peer[i] = {pn[i].normal_x, pn[i].normal_y, pn[i].normal_z};
      nrm_rows.push_back({nrm_what, "PCL NormalEstimationOMP", ms_cell(tn), ratio(tn, nrm),
                          strf("mean angle to ours %.3f deg", mean_normal_angle_deg(normals_ours, peer))});
      pcl::PointCloud<pcl::PointNormal>::Ptr tgt(new pcl::PointCloud<pcl::PointNormal>),
          src(new pcl::PointCloud<pcl::PointNormal>);
      auto to_pn = [](const Eigen::Vector3f& p, const Eigen::Vector3f& n) {
        pcl::PointNormal q;
        q.x = p.x(), q.y = p.y(), q.z = p.z(), q.normal_x = n.x(), q.normal_y = n.y(), q.normal_z = n.z();
        return q;
      };
      for (std::size_t i = 0; i < target.size(); ++i) tgt->push_back(to_pn(target.points[i], target.normals[i]));
      for (const auto i : subsample) src->push_back(to_pn(source.points[i], source.normals[i]));
      Eigen::Matrix4f final_pcl = Eigen::Matrix4f::Identity();
      bool converged = false;
      const Series ti = time_it(std::max(1, repeats / 2), [&] {
        pcl::IterativeClosestPointWithNormals<pcl::PointNormal, pcl::PointNormal> reg;
        reg.setInputSource(src);
        reg.setInputTarget(tgt);
        reg.setMaxCorrespondenceDistance(2.0);  // the same first gate as ours; PCL's default has none
        reg.setMaximumIterations(50);
        reg.setTransformationEpsilon(1e-12);
        reg.setEuclideanFitnessEpsilon(1e-14);
        pcl::PointCloud<pcl::PointNormal> aligned;
        reg.align(aligned);
        final_pcl = reg.getFinalTransformation();
        converged = reg.hasConverged();
      });
      Eigen::Isometry3d tp(final_pcl.cast<double>());
      icp_rows.push_back({icp_what, "PCL IterativeClosestPointWithNormals (2 mm gate, k-d tree build included)",
                          ms_cell(ti), ratio(ti, icp), icp_error(tp) + (converged ? "" : " (not converged)")});
    }
#endif
#ifdef SLSCAN_HAVE_OPEN3D
    {
      open3d::geometry::PointCloud pc;
      pc.points_.reserve(cloud.size());
      for (const auto& p : cloud.points) pc.points_.push_back(p.cast<double>());
      std::vector<std::size_t> kept;
      const Series t = time_it(repeats, [&] { kept = std::get<1>(pc.RemoveStatisticalOutliers(20, 1.0)); });
      sor_rows.push_back({sor_what, "Open3D RemoveStatisticalOutliers (k includes the point)", ms_cell(t),
                          ratio(t, sor), agreement(sor_ours.kept_indices, {kept.begin(), kept.end()})});
      const Series tr = time_it(repeats, [&] { kept = std::get<1>(pc.RemoveRadiusOutliers(6, 0.5)); });
      rad_rows.push_back({rad_what, "Open3D RemoveRadiusOutliers (6 incl. the point)", ms_cell(tr), ratio(tr, rad),
                          agreement(radius_ours.kept_indices, {kept.begin(), kept.end()})});
      open3d::geometry::PointCloud pn = pc;
      const Series tn = time_it(repeats, [&] {
        pn.normals_.clear();
        pn.EstimateNormals(open3d::geometry::KDTreeSearchParamKNN(20), false);
      });
      std::vector<Eigen::Vector3f> peer(pn.normals_.size());
      for (std::size_t i = 0; i < peer.size(); ++i) peer[i] = pn.normals_[i].cast<float>();
      nrm_rows.push_back({nrm_what, "Open3D EstimateNormals", ms_cell(tn), ratio(tn, nrm),
                          strf("mean angle to ours %.3f deg", mean_normal_angle_deg(normals_ours, peer))});
      open3d::geometry::PointCloud tgt, src;
      for (std::size_t i = 0; i < target.size(); ++i) {
        tgt.points_.push_back(target.points[i].cast<double>());
        tgt.normals_.push_back(target.normals[i].cast<double>());
      }
      for (const auto i : subsample) src.points_.push_back(source.points[i].cast<double>());
      Eigen::Matrix4d final_o3d = Eigen::Matrix4d::Identity();
      const Series ti = time_it(repeats, [&] {
        const auto r = open3d::pipelines::registration::RegistrationICP(
            src, tgt, 2.0, Eigen::Matrix4d::Identity(),
            open3d::pipelines::registration::TransformationEstimationPointToPlane(),
            open3d::pipelines::registration::ICPConvergenceCriteria(1e-10, 1e-10, 50));
        final_o3d = r.transformation_;
      });
      icp_rows.push_back({icp_what, "Open3D RegistrationICP point-to-plane (2 mm, k-d tree build included)",
                          ms_cell(ti), ratio(ti, icp), icp_error(Eigen::Isometry3d(final_o3d))});
    }
#endif
    for (auto* group : {&sor_rows, &rad_rows, &nrm_rows, &icp_rows})
      rows.insert(rows.end(), group->begin(), group->end());
    flush("clouds");
  }

  std::printf("\n%s", md.str().c_str());
  if (!out_path.empty()) {
    const std::string tmp = out_path + ".tmp";
    {
      std::ofstream f(tmp, std::ios::binary);
      if (!(f << md.str())) throw std::runtime_error("cannot write " + tmp);
    }
    std::filesystem::rename(tmp, out_path);
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_speed: %s\n", e.what());
  return 1;
}
