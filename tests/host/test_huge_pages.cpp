// slscan re-runs itself with glibc's malloc asking for 2 MB pages (slscan/core/huge_pages.hpp).
// The re-run is observed from a forked child: it re-executes this test binary, filtered to
// ReportsItsTunables, which writes the GLIBC_TUNABLES it started with to a file.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "slscan/core/huge_pages.hpp"

// The environment is changed only in a forked child, which has one thread.
// NOLINTBEGIN(concurrency-mt-unsafe)
namespace {

constexpr const char* kReportTo = "SLSCAN_TEST_TUNABLES_REPORT";

// What a child that called run_with_huge_pages wrote: its GLIBC_TUNABLES after the re-run, or
// "returned" when the call came back without re-running.
std::string run_child(const char* tunables, const char* opt_out) {
  const std::filesystem::path report =
      std::filesystem::temp_directory_path() / ("slscan_tunables_" + std::to_string(getpid()));
  std::filesystem::remove(report);
  const pid_t child = fork();
  if (child == 0) {
    if (tunables != nullptr)
      setenv("GLIBC_TUNABLES", tunables, 1);
    else
      unsetenv("GLIBC_TUNABLES");
    if (opt_out != nullptr)
      setenv("SLSCAN_HUGE_PAGES", opt_out, 1);
    else
      unsetenv("SLSCAN_HUGE_PAGES");
    setenv(kReportTo, report.c_str(), 1);
    std::string self = std::filesystem::read_symlink("/proc/self/exe");
    std::string filter = "--gtest_filter=HugePages.ReportsItsTunables";
    char* argv[] = {self.data(), filter.data(), nullptr};
    slscan::core::run_with_huge_pages(argv);
    std::ofstream(report) << "returned";
    _exit(0);
  }
  int status = 0;
  waitpid(child, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "child status " << status;
  std::ifstream in(report);
  std::stringstream text;
  text << in.rdbuf();
  std::filesystem::remove(report);
  return text.str();
}

// Only does something in the re-run child.
TEST(HugePages, ReportsItsTunables) {
  const char* report = std::getenv(kReportTo);
  if (report == nullptr) GTEST_SKIP() << "runs only as the re-executed child of the tests below";
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  std::ofstream(report) << (tunables != nullptr ? tunables : "(unset)");
}

TEST(HugePages, TheProgramIsReRunWithMallocAskingForHugePages) {
  EXPECT_EQ(run_child(nullptr, nullptr), "glibc.malloc.hugetlb=1");
}

TEST(HugePages, TunablesAlreadySetAreKept) {
  EXPECT_EQ(run_child("glibc.malloc.arena_max=2", nullptr), "glibc.malloc.arena_max=2:glibc.malloc.hugetlb=1");
}

TEST(HugePages, AUserChoiceOfHugetlbIsLeftAloneAndNotReRun) {
  EXPECT_EQ(run_child("glibc.malloc.hugetlb=0", nullptr), "returned");
}

TEST(HugePages, SlscanHugePagesZeroOptsOut) { EXPECT_EQ(run_child(nullptr, "0"), "returned"); }

}  // namespace
// NOLINTEND(concurrency-mt-unsafe)
