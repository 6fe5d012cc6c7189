// Large buffers in 2 MB pages for the whole process: a scan allocates hundreds of MB per view
// (organised clouds, normals, decode planes), and each first touch of a 4 kB page is a page
// fault. On the 2-core VM our figures come from a fault costs ~14 us: the full-resolution ball
// bar took 1.33M of them (10 s of system time in a 24 s run); with glibc's malloc asking for
// transparent huge pages, 165k, and last frame -> model went from 1.36 to 0.98 s (docs/scale.md
// "Memory in 2 MB pages").
#pragma once

namespace slscan::core {

// glibc reads its tunables once, at start-up: so, called first thing in main(), this sets
// GLIBC_TUNABLES=glibc.malloc.hugetlb=1 (kept beside any tunables already set) and re-executes
// the program with the same arguments. It returns, doing nothing, when the setting is already
// there, when SLSCAN_HUGE_PAGES=0 is set (the opt-out), off Linux / glibc, or if the re-execution
// fails (the program then runs in plain pages). Transparent huge pages stay the kernel's choice:
// with /sys/kernel/mm/transparent_hugepage/enabled at "never" the setting changes nothing.
void run_with_huge_pages(char** argv);

}  // namespace slscan::core
