// isouq CLI: large runs take their heap in 2 MiB pages (issue 15; docs/mesher.md "Memory pages").
#pragma once

namespace isouq::cli {

/// When an argument names a regular file of 16 MiB or more, re-executes this program once with
/// glibc's malloc.hugetlb=1, malloc.arena_max=1 and malloc.top_pad=16 MiB tunables added to
/// GLIBC_TUNABLES (read by glibc only at start-up): malloc then asks
/// for transparent huge pages (MADV_HUGEPAGE) on the memory it maps, every thread allocates from
/// the main arena, the one that gets them, and its heap grows 16 MiB ahead, which loaders fault
/// in outside malloc's lock (vdb_ops/src/FreshPages.h populateHeapTop). A fresh
/// 4 KiB page costs about 10 us on the machines isouq is measured on, and loading a 1 GiB scan
/// faults in 30 000 of them for its leaves alone. Does nothing when the tunable is already set
/// (by the user or by the re-executed run), when ISOUQ_HUGE_PAGES=0, when the kernel's THP is
/// "never", under valgrind or a sanitizer (their own allocators), or when the exec fails. Must
/// run first in main(), before MPI starts or any thread, file or handler exists.
void useHugePagesForLargeInputs(int argc, char** argv);

} // namespace isouq::cli
