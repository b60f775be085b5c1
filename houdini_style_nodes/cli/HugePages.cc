// isouq CLI: re-execution with glibc's malloc tunables (huge pages, one arena, the heap's growth)
// for large inputs
// (HugePages.h).
#include "HugePages.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>

namespace isouq::cli {

namespace {

bool sanitized()
{
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    return true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || __has_feature(memory_sanitizer)
    return true;
#else
    return false;
#endif
#else
    return false;
#endif
}

bool hasLargeFileArgument(int argc, char** argv)
{
    constexpr off_t kLarge = off_t(16) << 20;
    for (int i = 1; i < argc; ++i) {
        struct stat st {};
        if (::stat(argv[i], &st) == 0 && S_ISREG(st.st_mode) && st.st_size >= kLarge) return true;
    }
    return false;
}

} // namespace

void useHugePagesForLargeInputs(int argc, char** argv)
{
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 35)) && defined(__linux__)
    const char* tunables = std::getenv("GLIBC_TUNABLES");
    if (sanitized() || (tunables && std::strstr(tunables, "glibc.malloc.hugetlb"))) return;
    if (const char* opt = std::getenv("ISOUQ_HUGE_PAGES"); opt && std::strcmp(opt, "0") == 0) return;
    if (const char* preload = std::getenv("LD_PRELOAD"); preload && std::strstr(preload, "vgpreload")) return;
    if (!hasLargeFileArgument(argc, argv)) return;
    std::string thp;
    std::getline(std::ifstream("/sys/kernel/mm/transparent_hugepage/enabled"), thp);
    if (thp.empty() || thp.find("[never]") != std::string::npos) return;
    const std::string old = tunables ? tunables : "";
    // One malloc arena: glibc gives huge pages to the main arena's heap only; a worker thread's
    // own arena grows in 4 KiB steps and faulted in 17 000 more pages loading the 1 GiB scan
    // (docs/mesher.md "Memory pages"). Its lock is taken only by allocations above tcache's.
    // The heap grows 16 MiB ahead, which the loaders fault in outside that lock
    // (vdb_ops/src/FreshPages.h populateHeapTop). (Setting top_pad also fixes glibc's mmap
    // threshold at 128 KiB; raising it to 32 MiB too made writing sphere800's PLY under MPI
    // 0.6-0.9 s slower, bench/journal/2026-12-04.md, 23:43.)
    std::string value = (old.empty() ? "" : old + ":") + "glibc.malloc.hugetlb=1";
    if (old.find("glibc.malloc.arena_max") == std::string::npos) value += ":glibc.malloc.arena_max=1";
    if (old.find("glibc.malloc.top_pad") == std::string::npos) value += ":glibc.malloc.top_pad=16777216";
    if (::setenv("GLIBC_TUNABLES", value.c_str(), 1) != 0) return;
    ::execv("/proc/self/exe", argv);
    // The exec failed: go on in this process, with the environment as it was.
    if (tunables) ::setenv("GLIBC_TUNABLES", old.c_str(), 1);
    else ::unsetenv("GLIBC_TUNABLES");
#else
    (void)argc, (void)argv;
#endif
}

} // namespace isouq::cli
