// isouq: what memory a run may still take, so that inputs implying more are refused with one
// line before anything is allocated (SPEC §10 "Errors"; issue 14 "Resource limits";
// docs/hardening.md).
#pragma once

#include "isouq/Errors.h"

#include <sys/resource.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>

namespace isouq::memory_internal {

/// Bytes this process can still allocate: the kernel's MemAvailable; under an address-space
/// limit (ulimit -v) at most what is left of it; with ISOUQ_MEMORY_LIMIT_MB set, at most that
/// (a budget on a shared machine, and the fuzzers' own below ASan's malloc limit). 0 if unknown.
inline std::uint64_t availableMemory()
{
    std::uint64_t available = 0;
    std::ifstream meminfo("/proc/meminfo");
    for (std::string key; meminfo >> key;) {
        std::uint64_t kib = 0;
        meminfo >> kib;
        if (key == "MemAvailable:") {
            available = kib * 1024;
            break;
        }
        meminfo.ignore(std::numeric_limits<std::streamsize>::max(), '\n');
    }
    const auto cap = [&](std::uint64_t bytes) { available = available ? std::min(available, bytes) : bytes; };
    rlimit limit{};
    std::uint64_t pages = 0;
    if (::getrlimit(RLIMIT_AS, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY && (std::ifstream("/proc/self/statm") >> pages)) {
        const std::uint64_t used = pages * std::uint64_t(::sysconf(_SC_PAGESIZE));
        cap(limit.rlim_cur > used ? limit.rlim_cur - used : 1);
    }
    if (const char* mb = std::getenv("ISOUQ_MEMORY_LIMIT_MB"); mb && *mb) {
        char* end = nullptr;
        const unsigned long long v = std::strtoull(mb, &end, 10);
        if (*end == '\0' && v > 0 && v < (1ull << 44)) cap(std::uint64_t(v) << 20);
    }
    return available;
}

/// @a bytes in GiB with three significant digits.
inline std::string gib(std::uint64_t bytes)
{
    std::ostringstream os;
    os.precision(3);
    os << double(bytes) / double(1ull << 30);
    return os.str();
}

/// @throw InputError "@a what needs N GiB, more than the M GiB of memory available" when
/// @a bytes does not fit what availableMemory() says (unknown: no check).
inline void checkFits(std::uint64_t bytes, const std::string& what)
{
    const std::uint64_t available = availableMemory();
    if (available == 0 || bytes <= available) return;
    throw InputError(what + " needs " + gib(bytes) + " GiB, more than the " + gib(available) + " GiB of memory available");
}

} // namespace isouq::memory_internal
