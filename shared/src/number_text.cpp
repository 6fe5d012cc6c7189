#include "slproto/number_text.hpp"

#include <cstdio>

namespace slproto {

std::string short_number(double value) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", value);
  return text;
}

}  // namespace slproto
