#include "progress.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>

namespace slscan::app {

std::string format_duration(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) seconds = 0;
  const auto total = static_cast<long long>(std::llround(seconds));
  const long long h = total / 3600, m = total / 60 % 60, s = total % 60;
  char text[48];
  if (total < 60)
    std::snprintf(text, sizeof text, "%lld s", s);
  else if (h == 0)
    std::snprintf(text, sizeof text, "%lld:%02lld", m, s);
  else
    std::snprintf(text, sizeof text, "%lld:%02lld:%02lld", h, m, s);
  return text;
}

std::string format_rate(double per_second, const std::string& unit) {
  if (!std::isfinite(per_second) || per_second < 0) per_second = 0;
  // Three significant figures: the decimals follow the magnitude after rounding (99.96 -> "100").
  int decimals = 0;
  if (per_second > 0) {
    const int magnitude = static_cast<int>(std::floor(std::log10(per_second)));
    decimals = std::max(0, 2 - magnitude);
    const double scale = std::pow(10.0, decimals);
    if (std::round(per_second * scale) / scale >= std::pow(10.0, magnitude + 1)) decimals = std::max(0, decimals - 1);
  }
  char text[64];
  std::snprintf(text, sizeof text, "%.*f %s/s", decimals, per_second, unit.c_str());
  return text;
}

std::string utc_timestamp(std::chrono::system_clock::time_point when) {
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(when.time_since_epoch()).count();
  const std::time_t seconds = static_cast<std::time_t>(ms >= 0 ? ms / 1000 : (ms - 999) / 1000);
  std::tm utc{};
  ::gmtime_r(&seconds, &utc);
  char text[64];
  std::snprintf(text, sizeof text, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", utc.tm_year + 1900, utc.tm_mon + 1,
                utc.tm_mday, utc.tm_hour, utc.tm_min, utc.tm_sec, static_cast<int>(ms - seconds * 1000LL));
  return text;
}

ProgressReading ProgressMeter::update(const session::Progress& progress, Clock::time_point now) {
  if (!started_ || progress.stage != stage_ || progress.total != total_ || progress.done < last_done_) {
    started_ = true;
    stage_ = progress.stage;
    total_ = progress.total;
    first_done_ = progress.done;
    start_ = now;
  }
  last_done_ = progress.done;
  ProgressReading reading;
  reading.elapsed_s = std::max(0.0, std::chrono::duration<double>(now - start_).count());
  if (progress.done > first_done_ && reading.elapsed_s > 0) {
    reading.rate_per_s = static_cast<double>(progress.done - first_done_) / reading.elapsed_s;
    if (!progress.unit.empty() && progress.total > 0 && reading.elapsed_s >= min_eta_s) {
      const std::size_t left = progress.total - std::min(progress.done, progress.total);
      reading.eta_s = static_cast<double>(left) / *reading.rate_per_s;
    }
  }
  return reading;
}

std::string progress_line(const session::Progress& progress, const ProgressReading& reading, int bar_width) {
  const std::size_t done = progress.total > 0 ? std::min(progress.done, progress.total) : progress.done;
  const auto width = static_cast<std::size_t>(std::max(bar_width, 1));
  const std::size_t filled = progress.total > 0 ? width * done / progress.total : 0;
  std::string line = progress.stage + " [" + std::string(filled, '#') + std::string(width - filled, '.') + "] " +
                     std::to_string(progress.done) + "/" + std::to_string(progress.total);
  if (!progress.step.empty()) line += " " + progress.step;
  if (!progress.unit.empty()) {
    if (reading.rate_per_s) line += " " + format_rate(*reading.rate_per_s, progress.unit);
    if (reading.eta_s) line += ", ETA " + format_duration(*reading.eta_s);
  } else {
    line += ", " + format_duration(reading.elapsed_s);
  }
  return line;
}

}  // namespace slscan::app
