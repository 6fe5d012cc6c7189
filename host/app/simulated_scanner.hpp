// The virtual rig as a scanner: slscand started on the sim board for one command (`slscan demo`,
// `slscan calibrate --virtual`). The host drives it over loopback exactly as it drives a real
// scanner and never links the rig itself: the sim board renders the frames, places the
// checkerboard at each calibration pose and, asked, writes its exact calibration.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <filesystem>
#include <string>

namespace slscan::app {

// slscand: `given` when set, else the build tree's (firmware/app/slscand beside host/app/slscan),
// else the one installed beside slscan. Throws io::IoError naming where it looked.
std::string find_slscand(const std::string& given);

// The virtual rig's two sizes, as the sim board's [sim] rig_size names them.
enum class VirtualRigSize { small, full };

// Writes a board file for the sim board: `template_path` ("" = boards/sim.toml of the source
// tree, else the installed /usr/share/slscan/boards/sim.toml) with its scene, rig size and the camera format that size
// renders. Throws io::IoError.
void write_sim_board(const std::string& template_path, const std::string& scene, VirtualRigSize size,
                     const std::filesystem::path& board_path);

// `slscand --board BOARD --write-true-calibration OUT`: the sim board's exact calibration.
// Throws DeviceError with slscand's own message.
void write_true_calibration(const std::string& slscand, const std::filesystem::path& board_path,
                            const std::filesystem::path& out_path);

// slscand serving `board_path` on an ephemeral loopback port, stopped (SIGTERM, then SIGKILL)
// when this goes. Its stderr goes to `log_path`.
class SimulatedScanner {
 public:
  SimulatedScanner(const std::string& slscand, const std::filesystem::path& board_path,
                   const std::filesystem::path& log_path);
  ~SimulatedScanner();
  SimulatedScanner(const SimulatedScanner&) = delete;
  SimulatedScanner& operator=(const SimulatedScanner&) = delete;

  void stop();
  const std::string& host() const { return host_; }
  std::uint16_t port() const { return port_; }

 private:
  pid_t pid_ = -1;
  std::string host_;
  std::uint16_t port_ = 0;
};

// A folder of its own under the system's temporary directory, removed with everything in it.
class TemporaryFolder {
 public:
  explicit TemporaryFolder(const std::string& prefix);
  ~TemporaryFolder();
  TemporaryFolder(const TemporaryFolder&) = delete;
  TemporaryFolder& operator=(const TemporaryFolder&) = delete;
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

}  // namespace slscan::app
