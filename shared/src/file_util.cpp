#include "slproto/file_util.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace slproto {

std::string errno_text(int error) {
  return std::string(std::strerror(error)) + " (errno " + std::to_string(error) + ")";
}

Status write_file_atomically(const std::string& path, std::string_view bytes) {
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return make_error(Errc::io_error, tmp + ": cannot create (" + errno_text(errno) + ")");
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const std::string why = errno_text(n < 0 ? errno : ENOSPC);
      ::close(fd);
      ::unlink(tmp.c_str());
      return make_error(Errc::io_error, tmp + ": write failed (" + why + ")");
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) {
    const std::string why = errno_text(errno);
    ::close(fd);
    ::unlink(tmp.c_str());
    return make_error(Errc::io_error, tmp + ": flush failed (" + why + ")");
  }
  if (::close(fd) != 0) {
    const std::string why = errno_text(errno);
    ::unlink(tmp.c_str());
    return make_error(Errc::io_error, tmp + ": flush failed (" + why + ")");
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = errno_text(errno);
    ::unlink(tmp.c_str());
    return make_error(Errc::io_error, path + ": rename failed (" + why + ")");
  }
  return Ok{};
}

Result<std::string> read_whole_file(const std::string& path, std::size_t max_bytes) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return make_error(Errc::io_error, path + ": cannot open (" + errno_text(errno) + ")");
  struct stat info {};
  if (::fstat(fd, &info) != 0) {
    const std::string why = errno_text(errno);
    ::close(fd);
    return make_error(Errc::io_error, path + ": stat failed (" + why + ")");
  }
  if (S_ISDIR(info.st_mode)) {
    ::close(fd);
    return make_error(Errc::io_error, path + ": is a directory, not a file");
  }
  std::string bytes;
  char buffer[65536];
  for (;;) {
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const std::string why = errno_text(errno);
      ::close(fd);
      return make_error(Errc::io_error, path + ": read failed (" + why + ")");
    }
    if (n == 0) break;
    if (bytes.size() + static_cast<std::size_t>(n) > max_bytes) {
      ::close(fd);
      return make_error(Errc::oversized,
                        path + ": larger than " + std::to_string(max_bytes) + " bytes: not a file of this kind");
    }
    bytes.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fd);
  return bytes;
}

}  // namespace slproto
