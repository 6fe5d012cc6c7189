#include "slscand/app/security.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

namespace slscand {

using slproto::Errc;
using slproto::make_error;

bool is_loopback_address(const std::string& address) {
  if (address == "localhost") return true;
  in_addr v4{};
  if (::inet_pton(AF_INET, address.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  in6_addr v6{};
  if (::inet_pton(AF_INET6, address.c_str(), &v6) == 1) {
    if (IN6_IS_ADDR_LOOPBACK(&v6)) return true;
    return IN6_IS_ADDR_V4MAPPED(&v6) && v6.s6_addr[12] == 127;
  }
  return false;  // a host name: it may resolve to anything
}

slproto::Result<std::string> read_token_file(const std::string& path) {
  auto refuse = [&](const std::string& why) {
    return make_error(Errc::invalid_argument, "token file " + path + ": " + why);
  };
  // O_NOFOLLOW: the checks below are about the file itself, not about a link to it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
  if (fd < 0) return refuse(std::string("cannot open (") + std::strerror(errno) + ")");
  struct stat info {};
  if (::fstat(fd, &info) != 0) {
    const int error = errno;
    ::close(fd);
    return refuse(std::string("cannot stat (") + std::strerror(error) + ")");
  }
  std::string text;
  if (S_ISREG(info.st_mode) && (info.st_mode & 077) == 0 && info.st_size <= 4096) {
    text.resize(static_cast<std::size_t>(info.st_size));
    std::size_t got = 0;
    while (got < text.size()) {
      const ssize_t n = ::read(fd, text.data() + got, text.size() - got);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) break;
      got += static_cast<std::size_t>(n);
    }
    text.resize(got);
  }
  ::close(fd);
  if (!S_ISREG(info.st_mode)) return refuse("not a regular file");
  if ((info.st_mode & 077) != 0) {
    char mode[8];
    std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(info.st_mode & 07777));
    return refuse(std::string("mode ") + mode +
                  " lets the group or others access the token; make it readable by its owner only (chmod 600)");
  }
  if (info.st_uid != 0 && info.st_uid != ::geteuid()) {
    return refuse("owned by uid " + std::to_string(info.st_uid) + ", neither root nor this process's user (uid " +
                  std::to_string(::geteuid()) + ")");
  }
  if (info.st_size > 4096) return refuse("larger than 4096 bytes; a token file holds one line");
  const std::size_t end_of_line = text.find('\n');
  std::string token = text.substr(0, end_of_line);
  const auto blank = [](char c) { return c == ' ' || c == '\t' || c == '\r'; };
  while (!token.empty() && blank(token.back())) token.pop_back();
  std::size_t first = 0;
  while (first < token.size() && blank(token[first])) ++first;
  token.erase(0, first);
  if (token.empty()) return refuse("empty; write a random token into it, e.g. `head -c 24 /dev/urandom | base64`");
  if (token.size() < kMinTokenLength) {
    return refuse("the token has " + std::to_string(token.size()) + " characters; at least " +
                  std::to_string(kMinTokenLength) + " are needed (e.g. `head -c 24 /dev/urandom | base64`)");
  }
  return token;
}

slproto::Status check_listen_policy(const std::string& address, bool have_token, bool insecure_no_token) {
  if (is_loopback_address(address) || have_token || insecure_no_token) return slproto::Ok{};
  return make_error(Errc::unauthorized,
                    "refusing to listen on " + address +
                        " without a token: anyone who can reach it could drive the scanner. Pass --token-file FILE "
                        "(mode 600; hosts present the same token), bind to loopback (--bind 127.0.0.1), or, on a "
                        "network you trust completely, --insecure-no-token");
}

}  // namespace slscand
