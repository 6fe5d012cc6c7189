// Numbers in messages, as people write them: every part of slscan (board, host) names the
// values it refuses or reports this way.
#pragma once

#include <string>

namespace slproto {

// Up to six significant figures and no trailing zeros: "0.5", "2", "1e-07", "11.8642";
// not std::to_string's "0.500000" or "11.864247".
std::string short_number(double value);

}  // namespace slproto
