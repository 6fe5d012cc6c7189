#include "slscand/app/config.hpp"

#include <sys/stat.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
// As in board.cpp: header-only, errors as values.
#define TOML_HEADER_ONLY 1
#define TOML_EXCEPTIONS 0
#include <toml++/toml.h>

namespace slscand {

using slproto::Errc;
using slproto::make_error;

namespace {

std::string where(const toml::node& node, const std::string& source) {
  return source + ":" + std::to_string(node.source().begin.line);
}

}  // namespace

slproto::Result<DaemonConfig> parse_daemon_config(const std::string& toml_text, const std::string& source_name) {
  toml::parse_result parsed = toml::parse(toml_text, source_name);
  if (!parsed) {
    const auto& err = parsed.error();
    return make_error(Errc::malformed, source_name + ":" + std::to_string(err.source().begin.line) + ":" +
                                           std::to_string(err.source().begin.column) + ": " +
                                           std::string(err.description()));
  }
  DaemonConfig config;
  config.source_path = source_name;
  for (const auto& [key, node] : parsed.table()) {
    const std::string name(key.str());
    auto wrong = [&](const char* want) {
      return make_error(Errc::invalid_argument, where(node, source_name) + ": " + name + " must be " + want);
    };
    if (name == "board" || name == "bind_address" || name == "token_file" || name == "timing_log_dir") {
      const auto* text = node.as_string();
      if (text == nullptr) return wrong("a string");
      std::string value = text->get();
      if (name == "board") {
        if (value.empty()) return wrong("a board file path");
        config.board = value;
      } else if (name == "bind_address") {
        config.bind_address = value;
      } else if (name == "token_file") {
        config.token_file = value;
      } else {
        config.timing_log_dir = value;
      }
    } else if (name == "port") {
      const auto* number = node.as_integer();
      if (number == nullptr || number->get() < 0 || number->get() > 65535) return wrong("an integer in 0..65535");
      config.port = static_cast<int>(number->get());
    } else if (name == "realtime" || name == "mdns") {
      const auto* flag = node.as_boolean();
      if (flag == nullptr) return wrong("true or false");
      (name == "realtime" ? config.realtime : config.mdns) = flag->get();
    } else {
      return make_error(Errc::invalid_argument,
                        where(node, source_name) + ": unknown key '" + name +
                            "' (known: board, bind_address, port, token_file, timing_log_dir, realtime, mdns)");
    }
  }
  if (config.board.empty())
    return make_error(Errc::invalid_argument, source_name + ": no 'board' (the board file slscand drives)");
  // A relative board path means "next to this configuration file", not the daemon's cwd.
  const std::filesystem::path board(config.board);
  if (board.is_relative())
    config.board = (std::filesystem::path(source_name).parent_path() / board).lexically_normal().string();
  return config;
}

slproto::Result<DaemonConfig> load_daemon_config(const std::string& path) {
  std::ifstream in(path);
  if (!in) return make_error(Errc::io_error, path + ": cannot read the configuration: " + std::strerror(errno));
  std::ostringstream text;
  text << in.rdbuf();
  return parse_daemon_config(text.str(), path);
}

}  // namespace slscand
