#include "slscan/session/file_hash.hpp"

#include <fcntl.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <cerrno>
#include <memory>
#include <new>
#include <stdexcept>
#include <vector>

#include "slproto/file_util.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::session {

namespace {

std::string hex(const unsigned char* bytes, unsigned size) {
  static const char digits[] = "0123456789abcdef";
  std::string out;
  out.reserve(size * 2);
  for (unsigned i = 0; i < size; ++i) {
    out.push_back(digits[bytes[i] >> 4]);
    out.push_back(digits[bytes[i] & 15]);
  }
  return out;
}

struct DigestDeleter {
  void operator()(EVP_MD_CTX* context) const { EVP_MD_CTX_free(context); }
};

// OpenSSL 3 sets itself up (its library context, its locks, the SHA-256 implementation) on
// first use, and when that runs out of memory (a tight ulimit -v) it does not fail cleanly: a
// later call dereferences a lock it could not allocate (seen: SIGSEGV in EVP_MD_fetch on the
// hash thread of a reprocess at 312 MiB). So SHA-256 is fetched once, checked, and kept for
// the process; slscan does it first thing in main() (prepare_sha256).
const EVP_MD* sha256_md() {
  static const EVP_MD* const md = [] {
    if (OPENSSL_init_crypto(0, nullptr) != 1) throw std::bad_alloc();
    const EVP_MD* fetched = EVP_MD_fetch(nullptr, "SHA2-256", nullptr);
    if (fetched == nullptr) throw std::bad_alloc();
    return fetched;
  }();
  return md;
}

class Sha256 {
 public:
  Sha256() : context_(EVP_MD_CTX_new()) {
    if (!context_ || EVP_DigestInit_ex(context_.get(), sha256_md(), nullptr) != 1)
      throw std::runtime_error("OpenSSL: cannot start a SHA-256");
  }
  void update(const void* data, std::size_t size) {
    if (EVP_DigestUpdate(context_.get(), data, size) != 1) throw std::runtime_error("OpenSSL: SHA-256 update failed");
  }
  std::string finish() {
    unsigned char digest[EVP_MAX_MD_SIZE];
    unsigned size = 0;
    if (EVP_DigestFinal_ex(context_.get(), digest, &size) != 1) throw std::runtime_error("OpenSSL: SHA-256 failed");
    return hex(digest, size);
  }

 private:
  std::unique_ptr<EVP_MD_CTX, DigestDeleter> context_;
};

class FileDescriptor {
 public:
  explicit FileDescriptor(int fd) : fd_(fd) {}
  ~FileDescriptor() {
    if (fd_ >= 0) ::close(fd_);
  }
  FileDescriptor(const FileDescriptor&) = delete;
  FileDescriptor& operator=(const FileDescriptor&) = delete;
  int get() const { return fd_; }

 private:
  int fd_;
};

}  // namespace

void prepare_sha256() { (void)sha256_md(); }

std::string sha256_file(const std::string& path, const std::atomic<bool>* stop) {
  const FileDescriptor file(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (file.get() < 0) throw io::IoError("cannot open " + path + ": " + slproto::errno_text(errno));
  Sha256 digest;
  std::vector<unsigned char> buffer(std::size_t{8} << 20);
  for (;;) {
    if (stop != nullptr && stop->load(std::memory_order_relaxed)) throw io::IoError("hashing " + path + ": stopped");
    const ssize_t n = ::read(file.get(), buffer.data(), buffer.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      throw io::IoError("reading " + path + ": " + slproto::errno_text(errno));
    }
    if (n == 0) break;
    digest.update(buffer.data(), static_cast<std::size_t>(n));
  }
  return digest.finish();
}

std::string sha256_text(const std::string& text) {
  Sha256 digest;
  digest.update(text.data(), text.size());
  return digest.finish();
}

BackgroundSha256::BackgroundSha256(std::string path)
    : digest_(std::async(std::launch::async, [this, path = std::move(path)] {
        // The lowest priority: the hash takes the cores the reconstruction leaves idle, and
        // does not delay the model. A thread's nice value is its own on Linux.
        (void)::setpriority(PRIO_PROCESS, static_cast<id_t>(::syscall(SYS_gettid)), 19);
        return sha256_file(path, &stop_);
      })) {}

BackgroundSha256::~BackgroundSha256() {
  stop_.store(true, std::memory_order_relaxed);
  if (digest_.valid()) digest_.wait();
}

std::string BackgroundSha256::get() { return digest_.get(); }

}  // namespace slscan::session
