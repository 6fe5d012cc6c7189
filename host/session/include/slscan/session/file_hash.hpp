// SHA-256 of the files a report names (captures, calibrations, configs) and of a batch job's key.
#pragma once

#include <atomic>
#include <future>
#include <string>

namespace slscan::session {

// Sets OpenSSL up and fetches its SHA-256 once, for the whole process: call it first thing, while
// memory is at its least used (OpenSSL's own lazy set-up crashes when it runs out of memory).
// Throws std::bad_alloc if it cannot. The functions below call it too.
void prepare_sha256();

// Lower-case hex SHA-256 of a file's bytes / of a string. Throws io::IoError naming the file.
// `stop`, when set during the read, ends it early with io::IoError ("stopped").
std::string sha256_file(const std::string& path, const std::atomic<bool>* stop = nullptr);
std::string sha256_text(const std::string& text);

// sha256_file on a thread of its own, started at once: a 1 GB capture takes a second to hash
// on one core, which overlaps with its reconstruction instead of following it (docs/scale.md).
// Destroying it before get() stops the read and waits for the thread.
class BackgroundSha256 {
 public:
  explicit BackgroundSha256(std::string path);
  ~BackgroundSha256();
  BackgroundSha256(const BackgroundSha256&) = delete;
  BackgroundSha256& operator=(const BackgroundSha256&) = delete;

  // Waits for the hash; throws what sha256_file threw. Once only.
  std::string get();

 private:
  std::atomic<bool> stop_{false};
  std::future<std::string> digest_;
};

}  // namespace slscan::session
