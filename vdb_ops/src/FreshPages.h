// isouq (internal): fresh storage faulted in before its first write (DESIGN.md "Memory and
// allocation"; docs/mesher.md "Memory pages"). On the virtual machines isouq is measured on a
// 4 KiB page faulted by its first write costs about 11 us, the same page faulted in by
// MADV_POPULATE_WRITE (one call for a whole range, which writes nothing) about 1 us, and a 2 MiB
// page 0.12-0.17 ms (bench/page_cost.py). Used by the mesher (one process and bricks) for every
// per-block array, mask list and output column it allocates afresh: at N = 1024 a call's page
// faults went from about 5 300 to 185 (bench/journal/2026-12-04.md, 11:42). Also where in a
// page a buffer that pread fills starts (SlabBuffer).
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <memory>
#include <new>
#include <sstream>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

namespace isouq::mc_internal {

constexpr std::size_t kHugePage = std::size_t(1) << 21;
constexpr std::size_t kPopulateFrom = std::size_t(1) << 16;   // smaller: a few faults, not worth a call
constexpr std::size_t kHugeFrom = 4 * kHugePage;                // 8 MiB: advised 2 MiB pages
constexpr std::size_t kHugeArrayFrom = kHugePage / 2;           // 1 MiB: a PageVector in 2 MiB pages

/// @a x rounded up to a multiple of @a unit, a power of two.
constexpr std::uintptr_t roundUp(std::uintptr_t x, std::uintptr_t unit) { return (x + unit - 1) & ~(unit - 1); }

/// The value glibc reads at process start for tunable @a name ("glibc.malloc.hugetlb"), from
/// GLIBC_TUNABLES; empty when it is not set.
inline std::string mallocTunable(std::string_view name)
{
    const char* all = std::getenv("GLIBC_TUNABLES");
    if (!all) return {};
    const std::string_view t(all);
    for (std::size_t at = 0; at <= t.size();) { // name=value pairs split by ':'
        const std::size_t end = std::min(t.find(':', at), t.size());
        const std::string_view pair = t.substr(at, end - at);
        if (pair.size() > name.size() && pair.substr(0, name.size()) == name && pair[name.size()] == '=')
            return std::string(pair.substr(name.size() + 1));
        at = end + 1;
    }
    return {};
}

/// Whether malloc's heap comes in huge pages already: glibc's glibc.malloc.hugetlb tunable, read
/// at process start (the CLI sets it for large inputs: docs/mesher.md "Memory pages").
inline bool mallocHasHugePages()
{
    static const bool set = [] {
        const std::string v = mallocTunable("glibc.malloc.hugetlb");
        return v == "1" || v == "2";
    }();
    return set;
}

/// A stretch of memory to fault in: [data, data + bytes).
struct PageRange {
    const void* data = nullptr;
    std::size_t bytes = 0;
};

/// A stretch of whole pages: [first, second).
using PagePiece = std::pair<std::uintptr_t, std::uintptr_t>;

/// Appends to @a pieces the pages of @a range (none under kPopulateFrom) in pieces of at most
/// 2 MiB on 2 MiB boundaries. A range of 8 MiB or more first has its whole 2 MiB pages advised
/// MADV_HUGEPAGE, unless malloc advises its heap itself (THP "madvise", Debian's default, or
/// "always"). Returns whether the range is in huge pages, so that a first write faults in 2 MiB.
inline bool piecesOf(const PageRange& range, std::vector<PagePiece>& pieces)
{
    if (range.bytes < kPopulateFrom) return false;
    const std::uintptr_t page = std::uintptr_t(::sysconf(_SC_PAGESIZE));
    const std::uintptr_t lo = reinterpret_cast<std::uintptr_t>(range.data) & ~(page - 1);
    const std::uintptr_t hi = roundUp(reinterpret_cast<std::uintptr_t>(range.data) + range.bytes, page);
    const bool huge = range.bytes >= kHugeFrom;
    // Malloc's heap in huge pages is advised already; advising it again takes the address
    // space's write lock, which waits for the other threads' faults in progress (8-15 ms a
    // call on the 1 GiB raw scan, while a core idles: bench/journal/2026-12-04.md, 23:43).
#if defined(MADV_HUGEPAGE)
    if (huge && !mallocHasHugePages()) {
        const std::uintptr_t hugeLo = roundUp(lo, kHugePage), hugeHi = hi & ~(kHugePage - 1);
        if (hugeHi > hugeLo) ::madvise(reinterpret_cast<void*>(hugeLo), hugeHi - hugeLo, MADV_HUGEPAGE);
    }
#endif
    for (std::uintptr_t from = lo, to; from < hi; from = to) {
        to = std::min(hi, (from / kHugePage + 1) * kHugePage);
        pieces.emplace_back(from, to);
    }
    return huge;
}

/// Faults in @a piece, which writes nothing. A kernel without MADV_POPULATE_WRITE (before
/// 5.14) faults on first write instead.
inline void populatePiece(const PagePiece& piece)
{
#if defined(MADV_POPULATE_WRITE)
    ::madvise(reinterpret_cast<void*>(piece.first), piece.second - piece.first, MADV_POPULATE_WRITE);
#else
    (void)piece;
#endif
}

/// Faults in the pages of @a ranges, which must be this process's own writable memory (piecesOf).
/// Pages another allocation shares are only faulted in, never written.
inline void populatePages(const std::vector<PageRange>& ranges, bool threaded)
{
    // The pieces of every range in one loop, so that the threads share the zeroing however
    // the ranges' sizes differ.
    std::vector<PagePiece> pieces;
    for (const PageRange& range : ranges) piecesOf(range, pieces);
    auto populate = [&](std::size_t i) { populatePiece(pieces[i]); };
    // Isolated: a caller's task (one output column of several) waits for its own pieces only and
    // does not take up a sibling task meanwhile, which ran the columns one after the other (at
    // N = 1024, 15 ms instead of 8: bench/journal/2026-12-04.md, 15:02).
    if (threaded && pieces.size() > 1)
        tbb::this_task_arena::isolate([&] { tbb::parallel_for(std::size_t(0), pieces.size(), populate); });
    else for (std::size_t i = 0; i < pieces.size(); ++i) populate(i);
}

/// Runs @a resize(i) for each column i whose new storage is @a fresh[i] (reserveStorage: not yet
/// faulted in), a task each, largest first; resize() writes every element (std::vector's value
/// initialisation), column by column. A column in huge pages is faulted in by its resize, front
/// to back, while the other threads fault it in from the back (as do the resize tasks once
/// done); a smaller column is faulted in by its task first (MADV_POPULATE_WRITE costs a tenth
/// of a first write's fault per 4 KiB page). Each page is thus zeroed once by the kernel and
/// once by resize, and the threads share both however the columns' sizes differ (populating
/// every column first, then resizing a task per column, zeroed in two rounds and left a thread
/// idle while the largest column, the triangles at N = 1024, was written: issue 15).
template <typename Resize>
void resizeFaultingIn(const std::vector<PageRange>& fresh, Resize&& resize, bool threaded)
{
    const std::size_t n = fresh.size();
    std::vector<std::vector<PagePiece>> pieces(n);
    std::vector<bool> huge(n);
    for (std::size_t i = 0; i < n; ++i) huge[i] = piecesOf(fresh[i], pieces[i]);
    std::vector<std::size_t> order(n);
    for (std::size_t i = 0; i < n; ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return fresh[a].bytes > fresh[b].bytes; });
    const std::unique_ptr<std::atomic<bool>[]> done(new std::atomic<bool>[n]);
    const std::unique_ptr<std::atomic<std::size_t>[]> fromBack(new std::atomic<std::size_t>[n]);
    for (std::size_t i = 0; i < n; ++i) done[i] = false, fromBack[i] = 0;
    auto help = [&] {
        for (const std::size_t c : order)
            while (huge[c] && !done[c].load(std::memory_order_relaxed)) {
                const std::size_t k = fromBack[c].fetch_add(1, std::memory_order_relaxed);
                if (k >= pieces[c].size()) break;
                populatePiece(pieces[c][pieces[c].size() - 1 - k]);
            }
    };
    auto task = [&](std::size_t i) { // i < n: column order[i]'s resize; then helpers
        if (i >= n) return help();
        const std::size_t c = order[i];
        if (!huge[c]) for (const PagePiece& piece : pieces[c]) populatePiece(piece);
        resize(c);
        done[c].store(true, std::memory_order_relaxed);
        help();
    };
    const std::size_t helpers = threaded ? std::size_t(std::max(tbb::this_task_arena::max_concurrency(), 1)) - 1 : 0;
    if (threaded && n + helpers > 1) {
        tbb::this_task_arena::isolate([&] {
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n + helpers, 1), [&](const tbb::blocked_range<std::size_t>& r) {
                for (std::size_t i = r.begin(); i < r.end(); ++i) task(i);
            }, tbb::simple_partitioner());
        });
    } else {
        for (std::size_t i = 0; i < n; ++i) task(i);
    }
}

/// Whether this build runs under a sanitizer, which should see every array as heap memory.
constexpr bool kSanitized =
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || __has_feature(memory_sanitizer)
    true;
#else
    false;
#endif
#else
    false;
#endif

/// With malloc's heap in huge pages and grown by brk with glibc.malloc.top_pad bytes to spare
/// (the CLI's restart: docs/mesher.md "Memory pages"), faults in that spare top of the heap now,
/// outside malloc's lock. Else the allocation that first reaches a fresh 2 MiB page zeroes it
/// while holding the one arena's lock, and every other thread's allocation waits: loading the
/// 1 GiB raw scan, 45 waits of 1-4 ms a run (bench/journal/2026-12-04.md, 23:43). For loops that
/// allocate many small blocks on every thread (a scan's leaves); at most top_pad bytes more are
/// resident, most of which the next allocations use.
inline void populateHeapTop()
{
    if (kSanitized || !mallocHasHugePages()) return;
    static const std::uintptr_t pad = std::strtoull(mallocTunable("glibc.malloc.top_pad").c_str(), nullptr, 10);
    static const std::uintptr_t start = [] { // start_brk, field 47 of /proc/self/stat (Linux 3.3)
        std::ifstream in("/proc/self/stat");
        std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        std::istringstream fields(stat.substr(std::min(stat.rfind(')') + 2, stat.size()))); // after the name
        std::string field;
        for (int i = 3; i <= 47 && fields >> field; ++i) // the first field after the name is the 3rd
            if (i == 47) return std::uintptr_t(std::strtoull(field.c_str(), nullptr, 10));
        return std::uintptr_t(0);
    }();
    const auto end = reinterpret_cast<std::uintptr_t>(::sbrk(0));
    if (pad == 0 || start == 0 || end <= start) return;
    const std::uintptr_t from = end - std::min(pad, end - start);
    populatePages({PageRange{reinterpret_cast<const void*>(from), end - from}}, false);
}

/// The allocator of PageVector: a request of 1 MiB or more is mapped on its own in whole 2 MiB
/// pages, advised MADV_HUGEPAGE, so that faulting it in costs a huge-page fault per 2 MiB rather
/// than 512 small ones (the mesher's per-block arrays of 1-2 MB at N = 1024: bench/journal/
/// 2026-12-04.md, 15:02). At most one 2 MiB page per array is partly unused. Smaller
/// requests come from malloc, and so does every request under a sanitizer (which checks heap
/// arrays) or when malloc's heap is in huge pages already: it then reuses what the run freed
/// before (the 1 GiB raw scan's peak was 5-10 MB higher with the arrays mapped on their own).
template <typename T>
struct HugePageAllocator {
    using value_type = T;
    HugePageAllocator() = default;
    template <typename U>
    HugePageAllocator(const HugePageAllocator<U>&) {}

    T* allocate(std::size_t n)
    {
        if (n > std::size_t(-1) / 2 / sizeof(T)) throw std::bad_alloc();
        const std::size_t bytes = n * sizeof(T);
        if (fromMalloc(bytes)) {
            void* p = std::malloc(std::max<std::size_t>(bytes, 1));
            if (!p) throw std::bad_alloc();
            return static_cast<T*>(p);
        }
        const std::size_t huge = roundUp(bytes, kHugePage);
        void* raw = ::mmap(nullptr, huge + kHugePage, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (raw == MAP_FAILED) throw std::bad_alloc();
        // Keep the 2 MiB-aligned stretch of `huge` bytes; unmap the rest.
        const std::uintptr_t from = reinterpret_cast<std::uintptr_t>(raw), to = from + huge + kHugePage;
        const std::uintptr_t start = roundUp(from, kHugePage);
        if (start > from) ::munmap(raw, start - from);
        if (to > start + huge) ::munmap(reinterpret_cast<void*>(start + huge), to - start - huge);
#if defined(MADV_HUGEPAGE)
        ::madvise(reinterpret_cast<void*>(start), huge, MADV_HUGEPAGE);
#endif
        return reinterpret_cast<T*>(start);
    }
    void deallocate(T* p, std::size_t n)
    {
        const std::size_t bytes = n * sizeof(T);
        if (fromMalloc(bytes)) std::free(p);
        else ::munmap(p, roundUp(bytes, kHugePage));
    }

    template <typename U>
    bool operator==(const HugePageAllocator<U>&) const { return true; }
    template <typename U>
    bool operator!=(const HugePageAllocator<U>&) const { return false; }

private:
    static bool fromMalloc(std::size_t bytes) { return kSanitized || bytes < kHugeArrayFrom || mallocHasHugePages(); }
};

/// A per-block array of the mesher (block origins, counts, offsets, mask pointers), or a chunk of
/// a ChunkList.
template <typename T>
using PageVector = std::vector<T, HugePageAllocator<T>>;

/// Gives @a v room for n elements. Storage it already has is kept (and an empty range
/// returned); new storage, its contents dropped, is returned, not yet faulted in.
template <typename T, typename A>
PageRange reserveStorage(std::vector<T, A>& v, std::size_t n)
{
    if (n <= v.capacity()) return {};
    std::vector<T, A>().swap(v);
    v.reserve(n);
    return {v.data(), n * sizeof(T)};
}

/// Gives @a v room for n elements: storage it already has is kept; new storage (its contents
/// dropped) is faulted in first (populatePages).
template <typename T, typename A>
void reserveFresh(std::vector<T, A>& v, std::size_t n, bool threaded)
{
    populatePages({reserveStorage(v, n)}, threaded);
}

/// Gives @a v n elements to be overwritten (their values unspecified).
template <typename T, typename A>
void resizeForFill(std::vector<T, A>& v, std::size_t n, bool threaded)
{
    static_assert(std::is_trivially_copyable_v<T>);
    reserveFresh(v, n, threaded);
    v.resize(n);
}

/// @a v becomes n copies of @a value.
template <typename T, typename A>
void assignFresh(std::vector<T, A>& v, std::size_t n, const T& value, bool threaded)
{
    reserveFresh(v, n, threaded);
    v.assign(n, value);
}

/// An append-only list of trivially copyable records whose addresses never change (a growing
/// std::vector faults in and copies about twice what it keeps). Chunks double from 16 KiB (a
/// small grid's list stays small) up to 512 KiB, then are one 2 MiB page each; each is a
/// PageVector reserved and faulted in when taken, and never grows past what it reserved. One per
/// thread; not thread-safe.
template <typename T>
class ChunkList {
    static_assert(std::is_trivially_copyable_v<T> && sizeof(T) <= kHugePage);

public:
    void push(const T& value)
    {
        if (mChunks.empty() || mChunks.back().size() == capacity(mChunks.size() - 1)) {
            mChunks.emplace_back();
            reserveFresh(mChunks.back(), capacity(mChunks.size() - 1), false);
        }
        mChunks.back().push_back(value);
    }

    template <typename F>
    void forEach(F&& f) const
    {
        for (const PageVector<T>& chunk : mChunks)
            for (const T& record : chunk) f(record);
    }

private:
    /// Records in chunk @a c: from malloc while under kHugeArrayFrom, then a whole 2 MiB page.
    static std::size_t capacity(std::size_t c)
    {
        constexpr std::size_t first = std::max<std::size_t>(1, (std::size_t(1) << 14) / sizeof(T));
        const std::size_t records = first << std::min<std::size_t>(c, 7);
        return records * sizeof(T) >= kHugeArrayFrom ? kHugePage / sizeof(T) : records;
    }
    std::vector<PageVector<T>> mChunks;
};

/// Storage that a pread fills at copy speed. The kernel copies file pages to user memory with
/// `rep movsb`, which on the AMD EPYC (Zen 3) isouq is measured on runs 3.4x slower when the
/// destination sits 8-24 bytes past the source within a 4 KiB page (0 and 32 or more are fast;
/// glibc's memcpy avoids the case): every block that malloc maps on its own starts at page + 16.
/// 1 GiB read in 8 MiB preads: 510 against 150 ms (bench/journal/2026-12-07.md, "Reads at copy
/// speed"). place() puts @a n values where the bytes read from file byte @a fileOffset land at
/// that byte's offset within a page (or 64-71 bytes past it when alignof(T) forbids); what it
/// held before is dropped.
template <typename T>
class SlabBuffer {
public:
    T* place(std::size_t n, std::uint64_t fileOffset)
    {
        constexpr std::size_t kPage = 4096, kSlack = (2 * kPage + sizeof(T) - 1) / sizeof(T);
        if (mStore.size() < n + kSlack) {
            std::vector<T>().swap(mStore);
            mStore.resize(n + kSlack);
        }
        const std::uintptr_t at = reinterpret_cast<std::uintptr_t>(mStore.data());
        std::uintptr_t shift = (fileOffset % kPage + kPage - at % kPage) % kPage;
        if (shift % alignof(T)) shift = shift + alignof(T) - shift % alignof(T) + 64;
        return reinterpret_cast<T*>(at + shift);
    }

private:
    std::vector<T> mStore;
};

} // namespace isouq::mc_internal
