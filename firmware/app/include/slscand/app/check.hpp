// `slscand --check`: what a board file needs on this machine, item by item, each present or
// missing with the fix. It goes on past a missing device so one run lists everything to do.
#pragma once

#include <string>
#include <vector>

#include "slscand/hal/board.hpp"

namespace slscand {

enum class CheckState { ok, missing, skipped };

struct CheckItem {
  std::string name;  // "gpio chip", "camera", "network bind", ...
  CheckState state = CheckState::ok;
  std::string detail;  // what was found, or the error
  std::string fix;     // for missing items: what to do about it
};

struct CheckReport {
  std::string board_name;
  std::string board_path;
  std::vector<CheckItem> items;
  bool all_ok() const;  // no item missing (skipped items follow from a missing one or from the configuration)
  std::string to_text() const;
  const CheckItem* find(const std::string& name) const;
};

struct CheckOptions {
  std::string bind_address;  // "" = the board's
  int port = -1;             // -1 = the board's
  std::string token_file;    // "" = none configured
  bool token_given = false;  // a token came another way (--token)
  bool realtime = true;      // false: --no-realtime / realtime = false in the configuration
};

CheckReport check_board(const hal::BoardConfig& board, const CheckOptions& options);

}  // namespace slscand
