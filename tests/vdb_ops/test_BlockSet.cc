// The mesher's block set (vdb_ops/src/BlockScratch.h, SPEC §9): the blocks around (or up to)
// every leaf with an active voxel, marked in parallel, against a brute-force set of the same
// blocks; and the huge-page storage of its per-block arrays and the heap, and where a read
// buffer starts in its page (FreshPages.h).
#include "BlockScratch.h"

#include <openvdb/openvdb.h>

#include <catch2/catch.hpp>

#include <tbb/global_control.h>

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>
#include <set>
#include <tuple>

using isouq::mc_internal::BlockReach;
using isouq::mc_internal::BlockSet;
using isouq::mc_internal::PageVector;
using openvdb::Coord;

namespace {

using Key = std::tuple<int, int, int>;

/// Leaves at random places around the origin, many on the borders of the block index's coarse
/// leaves (64 voxels), negative coordinates included; some leaves are emptied again.
openvdb::FloatTree randomLeaves(unsigned seed, int count)
{
    openvdb::FloatTree tree(0.f);
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> coarse(-3, 3), inside(0, 7), edge(0, 3);
    for (int i = 0; i < count; ++i) {
        Coord block;
        for (int a = 0; a < 3; ++a) {
            const int e = edge(rng); // 0: first block of a coarse leaf, 1: last, else anywhere
            block[a] = coarse(rng) * 8 + (e == 0 ? 0 : e == 1 ? 7 : inside(rng));
        }
        const Coord voxel(block[0] * 8 + inside(rng), block[1] * 8 + inside(rng), block[2] * 8 + inside(rng));
        tree.setValueOn(voxel, 1.f);
        if (i % 7 == 0) tree.setValueOff(voxel); // a leaf with no active voxel: no blocks
    }
    return tree;
}

std::set<Key> bruteForce(const openvdb::FloatTree& tree, BlockReach reach)
{
    std::set<Key> blocks;
    const int to = reach == BlockReach::Around ? 1 : 0;
    for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
        if (leaf->isEmpty()) continue;
        const Coord b = leaf->origin() >> 3;
        for (int dx = -1; dx <= to; ++dx)
            for (int dy = -1; dy <= to; ++dy)
                for (int dz = -1; dz <= to; ++dz) blocks.insert({8 * (b[0] + dx), 8 * (b[1] + dy), 8 * (b[2] + dz)});
    }
    return blocks;
}

} // namespace

TEST_CASE("BlockSet: the marked blocks are the brute-force neighbourhoods of the leaves", "[blocks]")
{
    for (unsigned seed = 1; seed <= 6; ++seed) {
        const openvdb::FloatTree tree = randomLeaves(seed, seed < 4 ? 60 : 3000);
        for (BlockReach reach : {BlockReach::Around, BlockReach::Below}) {
            const std::set<Key> expected = bruteForce(tree, reach);
            std::vector<Coord> first;
            for (int threads : {1, 2, 4}) {
                tbb::global_control control(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
                BlockSet blocks;
                isouq::mc_internal::buildBlockSet(tree, blocks, threads > 1, reach);
                CAPTURE(seed, int(reach), threads);
                std::set<Key> got;
                for (std::size_t i = 0; i < blocks.origins.size(); ++i) {
                    const Coord& o = blocks.origins[i];
                    got.insert({o[0], o[1], o[2]});
                    REQUIRE(blocks.find(o) == std::int32_t(i));
                }
                REQUIRE(got.size() == blocks.origins.size());
                REQUIRE(got == expected);
                REQUIRE(blocks.find(Coord(8 * 1000, 0, 0)) == -1);
                // The same numbering whatever the thread count.
                if (first.empty()) first.assign(blocks.origins.begin(), blocks.origins.end());
                else REQUIRE(std::equal(first.begin(), first.end(), blocks.origins.begin(), blocks.origins.end()));
            }
        }
    }
}

TEST_CASE("BlockSet: a per-block array of 1 MiB or more lies in whole 2 MiB pages of its own", "[blocks][pages]")
{
    PageVector<std::uint64_t> big, small;
    isouq::mc_internal::assignFresh(big, (std::size_t(3) << 20) / 8, std::uint64_t(7), true);
    isouq::mc_internal::assignFresh(small, 1000, std::uint64_t(7), true);
    if (!isouq::mc_internal::kSanitized && !isouq::mc_internal::mallocHasHugePages()) // else from malloc
        REQUIRE(reinterpret_cast<std::uintptr_t>(big.data()) % (std::uintptr_t(1) << 21) == 0);
    REQUIRE(std::count(big.begin(), big.end(), std::uint64_t(7)) == std::ptrdiff_t(big.size()));
    REQUIRE(std::count(small.begin(), small.end(), std::uint64_t(7)) == 1000);
    big.push_back(8); // grows through the allocator's larger request
    REQUIRE(big.back() == 8);
    REQUIRE(big[0] == 7);
}

TEST_CASE("FreshPages: populateHeapTop faults in the heap's spare top", "[pages]")
{
    // The CLI's restart tunables (houdini_style_nodes/cli/HugePages.cc), which glibc reads only
    // at process start: without them this case runs itself again in a child that has them.
    constexpr std::size_t kPad = std::size_t(16) << 20;
    if (isouq::mc_internal::kSanitized) return; // a sanitizer's own allocator has no brk heap
    if (!isouq::mc_internal::mallocHasHugePages()) {
        const std::string self = std::filesystem::read_symlink("/proc/self/exe").string();
        const std::string command = "GLIBC_TUNABLES=glibc.malloc.hugetlb=1:glibc.malloc.arena_max=1:"
                                    "glibc.malloc.top_pad=16777216 '"
            + self + "' -w NoTests 'FreshPages: populateHeapTop faults in the heap*' > /dev/null";
        REQUIRE(std::system(command.c_str()) == 0);
        return;
    }
    // Leaf-sized blocks, as a scan's loader allocates: the heap grows by brk, 16 MiB ahead.
    std::vector<std::unique_ptr<char[]>> blocks;
    for (int i = 0; i < 20000; ++i) blocks.emplace_back(new char[2048]);
    const auto end = reinterpret_cast<std::uintptr_t>(::sbrk(0));
    const std::size_t page = std::size_t(::sysconf(_SC_PAGESIZE)), pages = kPad / page;
    auto resident = [&] { // the kernel's word (mincore) on the last kPad bytes below the break
        std::vector<unsigned char> in(pages);
        REQUIRE(::mincore(reinterpret_cast<void*>(end - kPad), kPad, in.data()) == 0);
        return std::size_t(std::count_if(in.begin(), in.end(), [](unsigned char c) { return c & 1; }));
    };
    const std::size_t before = resident();
    isouq::mc_internal::populateHeapTop();
    CHECK(before < pages / 2); // most of the spare top was never touched
    CHECK(resident() == pages);
}

TEST_CASE("FreshPages: a SlabBuffer puts a read's bytes at their file offset within a page", "[pages]")
{
    // The rule (FreshPages.h SlabBuffer): the destination sits 0 bytes, or 64-71 when the type's
    // alignment forbids 0, past the file byte within a 4 KiB page; never 1-63 (the slow copies).
    // Every offset of two pages, for each sample type a scan has, and the whole span writable
    // (the sanitizer build checks that it lies in the buffer).
    auto check = [](auto sample) {
        using T = decltype(sample);
        isouq::mc_internal::SlabBuffer<T> buffer;
        std::size_t wrong = 0;
        for (std::uint64_t offset = 1000000; offset < 1000000 + 8192; ++offset) {
            const std::size_t n = 1 + offset % 3000;
            T* p = buffer.place(n, offset);
            const std::uintptr_t at = reinterpret_cast<std::uintptr_t>(p);
            const std::uint64_t past = (at % 4096 + 4096 - offset % 4096) % 4096;
            const bool aligned = offset % alignof(T) == 0;
            wrong += at % alignof(T) != 0 || (aligned ? past != 0 : past < 64 || past > 71);
            std::fill(p, p + n, T(1));
        }
        INFO(sizeof(T) << "-byte samples");
        CHECK(wrong == 0);
    };
    check(std::uint8_t{});
    check(std::int16_t{});
    check(float{});
    check(double{});
}
