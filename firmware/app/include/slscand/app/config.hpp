// slscand's own configuration file (/etc/slscan/slscand.toml in the package): which board file,
// and the network and token settings that differ from the board file's. Command-line options
// override it. Unknown keys and wrong types are errors naming the file, line and key.
#pragma once

#include <optional>
#include <string>

#include "slproto/result.hpp"

namespace slscand {

struct DaemonConfig {
  std::string source_path;                  // the file it came from
  std::string board;                        // board file path (relative paths: to the config's folder)
  std::optional<std::string> bind_address;  // unset = the board file's
  std::optional<int> port;                  // unset = the board file's
  std::string token_file;                   // "" = no token
  std::string timing_log_dir;               // "" = none
  std::optional<bool> realtime;             // unset = true (the board file still decides)
  std::optional<bool> mdns;                 // announce with mDNS/DNS-SD; unset = true
};

slproto::Result<DaemonConfig> parse_daemon_config(const std::string& toml_text, const std::string& source_name);
slproto::Result<DaemonConfig> load_daemon_config(const std::string& path);

// Token files are read by read_token_file (security.hpp), which also checks their mode and owner.

}  // namespace slscand
