#include "slscan/core/decode_checks.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdio>
#include <numbers>
#include <string>

#include "slscan/core/decode.hpp"

namespace slscan::core {

namespace {

using slproto::PatternKind;
constexpr double kPi = std::numbers::pi;
constexpr double kTwoPi = 2 * std::numbers::pi;

double wrap_pi(double a) {  // to (-pi, pi]
  a = std::fmod(a + kPi, kTwoPi);
  if (a <= 0) a += kTwoPi;
  return a - kPi;
}
double wrap_2pi(double a) {  // to [0, 2 pi)
  a = std::fmod(a, kTwoPi);
  return a < 0 ? a + kTwoPi : a;
}

std::string fixed(double v, int digits) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*f", digits, v);
  return buffer;
}
std::string percent(double share) { return fixed(100 * share, 1) + " %"; }

// The sampled pixels' codes, re-decoded plainly from the frames (double precision).
struct Code {
  bool coded = false;      // the Gray bits read (contrast, not clipped): Gray statistics
  bool valid = false;      // decoded: phase statistics
  double phi = 0;          // wrapped phase in [0, 2 pi), the plan's shifts removed
  std::uint32_t word = 0;  // Gray bits MSB first, then the complementary bit
  std::uint32_t h = 0;     // gray_to_binary(word): half periods with the complementary bit, else orders
  double coordinate = 0;   // the decoder's unsmoothed coordinate
};

struct Planes {
  const std::uint8_t* bytes;
  bool sixteen;
  std::size_t plane;
  double at(int pattern, std::size_t i) const {
    const std::size_t k = static_cast<std::size_t>(pattern) * plane + i;
    return sixteen ? static_cast<double>(reinterpret_cast<const std::uint16_t*>(bytes)[k]) : bytes[k];
  }
};

struct Layout {
  int white = -1, black = -1, complementary = -1, complementary_inverse = -1;
  std::vector<int> gray, gray_inverse, phase;
  std::vector<double> cos_shift, sin_shift;
  bool inverse = false;
  int code_bits() const { return static_cast<int>(gray.size()) + (complementary >= 0 ? 1 : 0); }
};

Layout layout_of(const slproto::PatternPlan& plan) {
  const auto& c = plan.config();
  Layout l;
  l.white = plan.index_of(PatternKind::white);
  l.black = plan.index_of(PatternKind::black);
  l.complementary = plan.index_of(PatternKind::complementary_bit);
  l.complementary_inverse = plan.index_of(PatternKind::complementary_bit_inverse);
  l.inverse = c.inverse_gray;
  for (int b = 0; b < c.gray_bits(); ++b) {
    l.gray.push_back(plan.index_of(PatternKind::gray_bit, b));
    if (c.inverse_gray) l.gray_inverse.push_back(plan.index_of(PatternKind::gray_bit_inverse, b));
  }
  for (int n = 0; n < c.phase_steps; ++n) {
    l.phase.push_back(plan.index_of(PatternKind::phase_step, n));
    l.cos_shift.push_back(std::cos(c.phase_shift_rad(n)));
    l.sin_shift.push_back(std::sin(c.phase_shift_rad(n)));
  }
  return l;
}

Code decode_pixel(const Layout& l, const Planes& f, std::size_t i) {
  Code code;
  double s = 0, c = 0, sum = 0;
  for (std::size_t n = 0; n < l.phase.size(); ++n) {
    const double v = f.at(l.phase[n], i);
    s += v * l.sin_shift[n];
    c += v * l.cos_shift[n];
    sum += v;
  }
  if (!l.phase.empty()) code.phi = wrap_2pi(std::atan2(-s, c));
  double threshold2 = 0;
  if (l.white >= 0 && l.black >= 0)
    threshold2 = f.at(l.white, i) + f.at(l.black, i);
  else if (!l.phase.empty())
    threshold2 = 2 * sum / static_cast<double>(l.phase.size());
  auto bit = [&](int pattern, int inverse) {
    const double v = f.at(pattern, i);
    return (inverse >= 0 ? v > f.at(inverse, i) : 2 * v > threshold2) ? 1u : 0u;
  };
  for (std::size_t b = 0; b < l.gray.size(); ++b)
    code.word = (code.word << 1) | bit(l.gray[b], l.inverse ? l.gray_inverse[b] : -1);
  if (l.complementary >= 0) code.word = (code.word << 1) | bit(l.complementary, l.complementary_inverse);
  code.h = slproto::gray_to_binary(code.word);
  return code;
}

// Shifts of the listed phase frames from their covariance over the sampled pixels: the two
// leading eigenvectors of the N x N covariance of the mean-removed frames place frame n at
// angle theta_n on a circle (up to a common rotation and reflection: the sign is chosen so the
// typical step is positive; the Gray code, not this, tells the direction).
void measure_phase_shifts(const Eigen::MatrixXd& covariance, DecodeChecks& out) {
  const auto n = covariance.rows();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(covariance);
  const Eigen::VectorXd values = solver.eigenvalues();  // ascending
  const double trace = values.sum();
  if (!(trace > 0)) return;
  out.sinusoid_share = (values(n - 1) + values(n - 2)) / trace;
  const Eigen::VectorXd u1 = solver.eigenvectors().col(n - 1) * std::sqrt(std::max(0.0, values(n - 1)));
  const Eigen::VectorXd u2 = solver.eigenvectors().col(n - 2) * std::sqrt(std::max(0.0, values(n - 2)));
  // The frames lie on a circle in that plane; its centre is off the origin when the listed
  // frames do not cover the period evenly (the mean removed is then not the sinusoid's), so
  // fit the circle (Kasa: x^2 + y^2 + D x + E y + F = 0, least squares) and take the angles
  // about its centre.
  Eigen::MatrixXd design(n, 3);
  Eigen::VectorXd rhs(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    design(k, 0) = u1(k);
    design(k, 1) = u2(k);
    design(k, 2) = 1;
    rhs(k) = -(u1(k) * u1(k) + u2(k) * u2(k));
  }
  const Eigen::Vector3d circle = design.colPivHouseholderQr().solve(rhs);
  const double cx = std::isfinite(circle(0)) ? -0.5 * circle(0) : 0.0;
  const double cy = std::isfinite(circle(1)) ? -0.5 * circle(1) : 0.0;
  std::vector<double> angle(static_cast<std::size_t>(n));
  for (Eigen::Index k = 0; k < n; ++k) angle[static_cast<std::size_t>(k)] = std::atan2(u2(k) - cy, u1(k) - cx);
  std::vector<double> steps;
  for (std::size_t k = 1; k < angle.size(); ++k) steps.push_back(wrap_pi(angle[k] - angle[k - 1]));
  std::vector<double> sorted = steps;
  std::sort(sorted.begin(), sorted.end());
  const double sign = sorted.empty() || sorted[sorted.size() / 2] >= 0 ? 1.0 : -1.0;
  out.phase_shift_deg.clear();
  for (double a : angle) out.phase_shift_deg.push_back(wrap_2pi(sign * (a - angle[0])) * 180 / kPi);
}

void phase_frame_findings(const slproto::PatternPlan& plan, const DecodeCheckLimits& limits, DecodeChecks& out) {
  const int n = plan.config().phase_steps;
  if (out.sinusoid_share < limits.min_sinusoid_share) {
    out.findings.push_back(
        {"phase_frames",
         "the listed phase frames are not one phase-shift sequence (a sinusoid explains " +
             percent(out.sinusoid_share) + " of them)",
         "check phase.files: each must be a frame of the one fringe period, none a Gray, white or black frame"});
    return;
  }
  const double expected = 360.0 / n;
  // Steps between consecutive listed frames, and the one closing the circle (last -> first):
  // an N-step sequence has N steps of 360 / N; with a frame missing the closing one is twice
  // as long, with one too many it is ~0.
  std::vector<double> steps;
  for (std::size_t k = 1; k < out.phase_shift_deg.size(); ++k)
    steps.push_back(std::fmod(out.phase_shift_deg[k] - out.phase_shift_deg[k - 1] + 720.0, 360.0));
  const double closing = std::fmod(360.0 - out.phase_shift_deg.back() + 720.0, 360.0);
  bool regular_as_planned = std::abs(closing - expected) <= limits.max_step_error_deg;
  for (double s : steps) regular_as_planned &= std::abs(s - expected) <= limits.max_step_error_deg;
  if (regular_as_planned) return;
  std::vector<double> sorted = steps;
  std::sort(sorted.begin(), sorted.end());
  const double typical = sorted[sorted.size() / 2];
  bool regular = true;
  for (double s : steps) regular &= std::abs(s - typical) <= limits.max_step_error_deg;
  const int m = typical > 1 ? static_cast<int>(std::lround(360.0 / typical)) : 0;
  if (regular && m != n && m >= 3) {
    const int d = std::abs(m - n);
    out.findings.push_back({"phase_frames",
                            "the " + std::to_string(n) + " listed phase frames step by " + fixed(typical, 1) +
                                " deg each: an " + std::to_string(m) + "-step sequence with " + std::to_string(d) +
                                " frame" + (d > 1 ? "s" : "") + (m > n ? " missing" : " too many"),
                            "list all " + std::to_string(m) + " frames of the sequence in phase.files"});
    return;
  }
  // Out of order: the order by measured shift.
  std::vector<int> order(static_cast<std::size_t>(n));
  for (int k = 0; k < n; ++k) order[static_cast<std::size_t>(k)] = k;
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
    return out.phase_shift_deg[static_cast<std::size_t>(a)] < out.phase_shift_deg[static_cast<std::size_t>(b)];
  });
  std::string listed, shifts;
  for (int k : order) listed += (listed.empty() ? "" : ", ") + std::to_string(k);
  for (double s : out.phase_shift_deg) shifts += (shifts.empty() ? "" : ", ") + fixed(s, 0);
  out.findings.push_back({"phase_frames",
                          "the phase frames are out of order (their shifts, measured from the data, are " + shifts +
                              " deg in the listed order)",
                          "list them in the order " + listed + " of the present list"});
}

// The phase offset `measured` (data against the plan) as a fix of the description.
DecodeFinding offset_finding(const slproto::PatternPlanConfig& c, double measured) {
  const int n = c.phase_steps;
  const double step = kTwoPi / n;
  // The frames' own origin, as listed: the plan's total offset plus what is measured.
  const double data = wrap_pi(c.phase_offset_rad - step * c.phase_offset_steps + measured);
  const int s = static_cast<int>(((std::lround(-data / step) % n) + n) % n);
  const double rest = wrap_pi(data + step * s);
  const std::string origin =
      fixed(measured, 2) + " rad (" + fixed(measured / kTwoPi * c.period_px, 2) + " projector px) from the Gray code's";
  if (s != 0 && std::abs(rest) <= 0.1) {
    const int from = ((s - c.phase_offset_steps) % n + n) % n;
    return {"phase_offset",
            "the phase frames look rotated by " + std::to_string(s) + " step" + (s > 1 ? "s" : "") +
                " (their phase origin is " + origin + ")",
            "list them from frame " + std::to_string(from) + ", or set phase.offset_steps = " + std::to_string(s) +
                (rest != 0 && std::abs(c.phase_offset_rad) > 0 ? " and phase.offset_rad = 0" : "")};
  }
  return {"phase_offset", "the phase origin is " + origin,
          "set phase.offset_rad = " + fixed(data, 3) + " (with phase.offset_steps = 0)"};
}

}  // namespace

DecodeChecks check_decoded_view(const slproto::PatternPlan& plan, const FramePlanes& frames,
                                const std::vector<float>& unsmoothed, const DecodedView& view,
                                const DecodeOptions& options, const DecodeCheckLimits& limits) {
  (void)options;
  DecodeChecks out;
  const int w = frames.width, h = frames.height;
  if (w < 2 || h < 2 || frames.data == nullptr) return out;
  const auto& config = plan.config();
  const Layout layout = layout_of(plan);
  const Planes planes{static_cast<const std::uint8_t*>(frames.data), frames.sixteen_bit,
                      static_cast<std::size_t>(w) * static_cast<std::size_t>(h)};
  const bool with_phase = !layout.phase.empty();
  const bool with_complementary = layout.complementary >= 0;
  const int bits = layout.code_bits();
  const int n_steps = static_cast<int>(layout.phase.size());
  // ~64 k pixels in pairs of rows, whatever the image size.
  out.row_step = std::max(2, static_cast<int>((2 * static_cast<long long>(w) * h + 65535) / 65536));
  out.ran = true;

  // Accumulators (fixed order: deterministic).
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(n_steps, n_steps);
  Eigen::VectorXd intensities(n_steps);
  std::complex<double> offset_sum = 0;
  std::size_t offset_count = 0, direction_pairs = 0, direction_agree = 0, comp_count = 0, comp_agree = 0;
  std::size_t order_changes = 0, order_steps = 0, pairs = 0, coded_pairs = 0, jumps = 0, wraps = 0;
  std::vector<std::size_t> flips(static_cast<std::size_t>(bits), 0);
  const double period = config.period_px;
  const double quarter_pi_over_p = kPi / period;  // the half pixel between a Gray edge and the phase wrap
  const double jump_limit = with_phase ? 0.5 * period : 1.5 * (with_complementary ? 0.5 * period : period);

  std::vector<Code> rows[2];
  rows[0].resize(static_cast<std::size_t>(w));
  rows[1].resize(static_cast<std::size_t>(w));
  auto pair = [&](const Code& a, const Code& b) {
    if (!a.coded || !b.coded) return;
    // Gray statistics over every pixel whose bits read, decoded or not: a wrong bit order
    // throws many pixels out of range, and judging only the rest would hide it.
    ++coded_pairs;
    const std::uint32_t differ = a.word ^ b.word;
    for (int j = 0; j < bits; ++j) flips[static_cast<std::size_t>(j)] += (differ >> (bits - 1 - j)) & 1u;
    const bool one = a.h + 1 == b.h || b.h + 1 == a.h;
    if (a.h != b.h) {
      ++order_changes;
      order_steps += one ? 1 : 0;
    }
    if (!a.valid || !b.valid) return;
    ++pairs;
    if (std::abs(static_cast<double>(a.coordinate) - b.coordinate) > jump_limit) ++jumps;
    if (with_phase && a.h != b.h && one) {
      const double dphi = wrap_pi(b.phi - a.phi);
      if (std::abs(dphi) > 1e-6) {
        ++direction_pairs;
        direction_agree += (dphi > 0) == (b.h > a.h) ? 1 : 0;
      }
      if (!with_complementary) {
        // The Gray edge sits half a pixel before the phase wrap.
        const std::complex<double> edge = std::polar(1.0, a.phi) + std::polar(1.0, b.phi);
        if (std::abs(edge) > 1e-9) {
          offset_sum += std::polar(1.0, std::arg(edge) + quarter_pi_over_p);
          ++offset_count;
        }
      }
    }
    if (with_phase && std::abs(b.phi - a.phi) > kPi) ++wraps;
  };

  for (int v = out.row_step / 2; v + 1 < h; v += out.row_step) {
    for (int r = 0; r < 2; ++r)
      for (int u = 0; u < w; ++u) {
        const std::size_t i =
            static_cast<std::size_t>(v + r) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u);
        Code& code = rows[r][static_cast<std::size_t>(u)];
        const DecodeMask mask = view.mask[i];
        code.valid = mask == DecodeMask::valid;
        code.coded = code.valid || mask == DecodeMask::out_of_range || mask == DecodeMask::low_modulation;
        if (!code.coded) continue;
        const Code decoded = decode_pixel(layout, planes, i);
        code.phi = decoded.phi;
        code.word = decoded.word;
        code.h = decoded.h;
        code.coordinate = unsmoothed[i];
        if (!code.valid) continue;
        ++out.sampled_pixels;
        if (with_phase) {
          double mean = 0;
          for (int k = 0; k < n_steps; ++k) {
            intensities(k) = planes.at(layout.phase[static_cast<std::size_t>(k)], i);
            mean += intensities(k);
          }
          intensities.array() -= mean / n_steps;
          covariance.noalias() += intensities * intensities.transpose();
          if (with_complementary) {
            // Half period h covers [h P / 2 - 0.5, (h + 1) P / 2 - 0.5): its centre's phase is
            // pi h + pi / 2 - pi / P.
            offset_sum += std::polar(1.0, code.phi - (kPi * (code.h & 1u) + 0.5 * kPi - quarter_pi_over_p));
            ++offset_count;
            const double psi = wrap_2pi(code.phi + quarter_pi_over_p);  // half-period edges at 0 and pi
            const double from_edge = std::min({psi, std::abs(psi - kPi), kTwoPi - psi});
            if (from_edge >= 0.25 * kPi) {
              ++comp_count;
              comp_agree += ((code.h & 1u) != 0) == (psi >= kPi) ? 1 : 0;
            }
          }
        }
      }
    for (int r = 0; r < 2; ++r)
      for (int u = 0; u + 1 < w; ++u)
        pair(rows[r][static_cast<std::size_t>(u)], rows[r][static_cast<std::size_t>(u) + 1]);
    for (int u = 0; u < w; ++u) pair(rows[0][static_cast<std::size_t>(u)], rows[1][static_cast<std::size_t>(u)]);
  }

  if (out.sampled_pixels < limits.min_pixels || pairs == 0) return out;
  out.period_jump_rate = static_cast<double>(jumps) / static_cast<double>(pairs);
  for (int j = 0; j < bits; ++j)
    out.gray_flip_rate.push_back(static_cast<double>(flips[static_cast<std::size_t>(j)]) /
                                 static_cast<double>(coded_pairs));
  if (order_changes >= 50) {
    out.has_gray = true;
    out.gray_continuity = static_cast<double>(order_steps) / static_cast<double>(order_changes);
  }
  if (with_phase) {
    out.has_phase = true;
    measure_phase_shifts(covariance, out);
    if (offset_count >= 50) {
      const std::complex<double> mean = offset_sum / static_cast<double>(offset_count);
      out.has_offset = true;
      out.phase_offset_rad = std::arg(mean);
      // A correct capture's residual is uniform over a half period (mean resultant 2 / pi)
      // with the complementary bit; at the Gray edges it is one value.
      out.phase_offset_consistency = std::min(1.0, std::abs(mean) / (with_complementary ? 2.0 / kPi : 1.0));
    }
    if (direction_pairs >= 50) {
      out.has_direction = true;
      out.phase_direction_agreement = static_cast<double>(direction_agree) / static_cast<double>(direction_pairs);
    }
    if (comp_count >= 50) {
      out.has_complementary = true;
      out.complementary_agreement = static_cast<double>(comp_agree) / static_cast<double>(comp_count);
    }
  }

  // Findings, the most specific first. The phase frames among themselves need nothing else;
  // the Gray code must be right before the phase can be judged against it.
  if (out.has_phase) phase_frame_findings(plan, limits, out);
  const bool phase_frames_bad = out.flagged();

  // Which bit each Gray frame shows, from its flip rate: bit i + 1 flips twice as often as
  // bit i, and the finest Gray bit as often as the phase wraps.
  bool gray_bad = false;
  {
    const int gray_bits = static_cast<int>(layout.gray.size());
    std::vector<std::pair<int, double>> reliable;  // slot, log2 rate
    for (int j = 0; j < gray_bits; ++j)
      if (flips[static_cast<std::size_t>(j)] >= 100)
        reliable.emplace_back(j, std::log2(out.gray_flip_rate[static_cast<std::size_t>(j)]));
    double slope = 0;
    if (reliable.size() >= 3) {
      double sj = 0, sl = 0, sjj = 0, sjl = 0;
      for (auto [j, l] : reliable) {
        sj += j;
        sl += l;
        sjj += j * j;
        sjl += j * l;
      }
      const double k = static_cast<double>(reliable.size());
      slope = (k * sjl - sj * sl) / (k * sjj - sj * sj);
    }
    double shift = 0;  // median of (estimated bit - slot)
    if (with_phase && wraps >= 100 && reliable.size() >= 3 && !phase_frames_bad) {
      // Wraps over decoded pairs, flips over coded ones: both are rates per neighbouring pair.
      const double wrap_rate = static_cast<double>(wraps) / static_cast<double>(pairs);
      std::vector<double> d;
      // Slot j (MSB first) of an m-bit reflected Gray code flips once every 2^(m - j) periods.
      for (auto [j, l] : reliable) d.push_back(gray_bits + (l - std::log2(wrap_rate)) - j);
      std::sort(d.begin(), d.end());
      shift = d[d.size() / 2];
    }
    const bool discontinuous = out.has_gray && out.gray_continuity < limits.min_gray_continuity;
    if (reliable.size() >= 3 && slope < -0.5) {
      out.findings.push_back({"gray_order",
                              "the Gray frames look listed least significant bit first (each flips about half as "
                              "often as the one before it; Gray continuity " +
                                  percent(out.gray_continuity) + ")",
                              "reverse gray.bit_order (msb_first <-> lsb_first)"});
      gray_bad = true;
    } else if (std::abs(shift) >= 0.6) {
      const bool late = shift > 0;
      out.findings.push_back(
          {"gray_order",
           std::string("the Gray frames look shifted by one: the frame listed as bit i shows bit i ") +
               (late ? "+ 1 (the list starts one frame late)" : "- 1 (the list starts one frame early)"),
           std::string("start gray.files one frame ") + (late ? "earlier" : "later")});
      gray_bad = true;
    } else if (discontinuous) {
      const bool constant_first = !out.gray_flip_rate.empty() && flips[0] == 0 && reliable.size() >= 3;
      out.findings.push_back(
          {"gray_order",
           "the Gray code is not continuous: only " + percent(out.gray_continuity) +
               " of the order changes between neighbouring pixels are by one" +
               (constant_first ? " (the first Gray frame never changes: a white or black frame?)" : ""),
           constant_first ? "start gray.files one frame later"
                          : "check gray.files (the frames of one Gray code, in bit order), gray.bit_order and the "
                            "first frame"});
      gray_bad = true;
    }
  }

  if (out.has_phase && !phase_frames_bad && !gray_bad) {
    bool phase_bad = false;
    if (out.has_direction && out.phase_direction_agreement < limits.min_direction_agreement) {
      const bool reversed = out.phase_direction_agreement < 1 - limits.min_direction_agreement;
      const int n = config.phase_steps;
      out.findings.push_back({"phase_direction",
                              reversed ? "the phase runs against the Gray code (it advances the other way at " +
                                             percent(1 - out.phase_direction_agreement) + " of the period edges)"
                                       : "the phase and the Gray code do not agree on a direction (" +
                                             percent(out.phase_direction_agreement) + " of the period edges)",
                              reversed ? "the frames use the opposite shift direction: list them as 0, " +
                                             std::to_string(n - 1) + ", " + std::to_string(n - 2) + ", ..., 1"
                                       : "check the order of the phase and the Gray frames"});
      phase_bad = true;
    }
    if (!phase_bad && out.has_offset && out.phase_offset_consistency >= limits.min_offset_consistency &&
        std::abs(out.phase_offset_rad) > limits.max_offset_rad) {
      out.findings.push_back(offset_finding(config, out.phase_offset_rad));
      phase_bad = true;
    }
    if (!phase_bad && out.has_complementary && out.complementary_agreement < limits.min_complementary_agreement) {
      out.findings.push_back({"complementary",
                              "the complementary frame agrees with the phase's half period at only " +
                                  percent(out.complementary_agreement) + " of the pixels",
                              "check complementary: the Gray code's half-period bit, the frame after the last Gray "
                              "bit in our plans"});
      phase_bad = true;
    }
    if (!phase_bad && out.has_offset && out.phase_offset_consistency < limits.min_offset_consistency) {
      out.findings.push_back({"phase_offset",
                              "the phase and the Gray code have no common origin (consistency " +
                                  fixed(out.phase_offset_consistency, 2) + ")",
                              "check phase.period_px and that the phase and Gray frames belong to one sequence"});
    }
  }
  if (!out.flagged() && out.period_jump_rate > limits.max_period_jump_rate)
    out.findings.push_back({"period_jumps",
                            "the decoded coordinate jumps by more than " + fixed(jump_limit, 1) + " projector px at " +
                                percent(out.period_jump_rate) + " of neighbouring pixels",
                            "check the description: phase.period_px, the order of the Gray and phase frames"});
  return out;
}

}  // namespace slscan::core
