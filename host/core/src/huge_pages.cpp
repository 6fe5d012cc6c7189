#include "slscan/core/huge_pages.hpp"

#include <cstdlib>
#include <string>
#include <string_view>

#if defined(__linux__) && defined(__GLIBC__)
#include <unistd.h>
#endif

namespace slscan::core {

// Called first thing in main(), before any thread exists: getenv / setenv are safe there.
// NOLINTBEGIN(concurrency-mt-unsafe)
void run_with_huge_pages(char** argv) {
#if defined(__linux__) && defined(__GLIBC__)
  if (argv == nullptr || argv[0] == nullptr) return;
  const char* opt_out = std::getenv("SLSCAN_HUGE_PAGES");
  if (opt_out != nullptr && std::string_view(opt_out) == "0") return;
  const char* current = std::getenv("GLIBC_TUNABLES");
  const std::string before = current != nullptr ? current : "";
  // Already set (by us one exec ago, or by the user either way): never loop.
  if (before.find("glibc.malloc.hugetlb") != std::string::npos) return;
  const std::string tunables = before.empty() ? "glibc.malloc.hugetlb=1" : before + ":glibc.malloc.hugetlb=1";
  if (setenv("GLIBC_TUNABLES", tunables.c_str(), 1) != 0) return;
  execv("/proc/self/exe", argv);
  // Still here: the re-execution failed. Run as we are, and leave the environment as it was.
  if (current != nullptr)
    setenv("GLIBC_TUNABLES", before.c_str(), 1);
  else
    unsetenv("GLIBC_TUNABLES");
#else
  (void)argv;
#endif
}
// NOLINTEND(concurrency-mt-unsafe)

}  // namespace slscan::core
