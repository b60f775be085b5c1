// isouq: marching-cubes case tables, generated at compile time (SPEC §1).
//
// Rather than a hand-copied 256-case table, the triangulation of each case is derived from one
// rule applied per cube face, so two cells that share a face always cut it the same way and a
// closed surface is watertight by construction:
//   * corners with value >= k are "inside" (the one inside rule everywhere, ties included);
//   * on each face, walking its corners counter-clockwise seen from outside the cube, every
//     crossing edge where the walk enters the inside is joined to the next crossing where it
//     leaves, so an ambiguous face (inside corners on a diagonal) keeps its inside corners apart;
//   * the joined crossings form closed loops; each loop is fanned into triangles from the first
//     vertex (walking from its lowest-numbered edge) whose fan adds no diagonal between two
//     vertices on one cube face. Such a diagonal could also appear in the neighbour across that
//     face and make the edge non-manifold; without it, every mesh edge inside a cell belongs to
//     that cell alone and every edge on a face to the two cells sharing it. Triangles face from
//     inside (>= k) towards outside (< k).
// Corners and edges are numbered as in Lorensen & Cline: corner c has offset
// (c&1 ^ (c>>1)&1, (c>>1)&1, (c>>2)&1); see kCornerOffset and kEdgeCorners below.
#pragma once

#include <array>
#include <cstdint>

namespace isouq {
namespace mc_tables_internal {

struct Int3 {
    int x, y, z;
};

constexpr std::array<Int3, 8> kCornerOffset{{
    {0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}}};

constexpr std::array<std::array<int, 2>, 12> kEdgeCorners{{
    {0, 1}, {1, 2}, {3, 2}, {0, 3}, {4, 5}, {5, 6}, {7, 6}, {4, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}}};

/// Faces as corner loops, counter-clockwise seen from outside the cube (-x, +x, -y, +y, -z, +z).
constexpr std::array<std::array<int, 4>, 6> kFaceCorners{{
    {0, 4, 7, 3}, {1, 2, 6, 5}, {0, 1, 5, 4}, {3, 7, 6, 2}, {0, 3, 2, 1}, {4, 5, 6, 7}}};

constexpr int edgeBetween(int a, int b)
{
    for (int e = 0; e < 12; ++e) {
        if ((kEdgeCorners[e][0] == a && kEdgeCorners[e][1] == b) ||
            (kEdgeCorners[e][0] == b && kEdgeCorners[e][1] == a))
            return e;
    }
    return -1;
}

/// Bit f set when edge e lies on face f.
constexpr int faceMaskOf(int e)
{
    int mask = 0;
    for (int f = 0; f < 6; ++f) {
        int ends = 0;
        for (int c : kFaceCorners[f]) ends += (c == kEdgeCorners[e][0]) + (c == kEdgeCorners[e][1]);
        if (ends == 2) mask |= 1 << f;
    }
    return mask;
}

/// The first position of @a loop from which a fan adds no diagonal within one cube face.
constexpr int fanApex(const std::array<int, 12>& loop, int len)
{
    for (int apex = 0; apex < len; ++apex) {
        bool ok = true;
        for (int i = 2; i + 1 < len; ++i)
            if (faceMaskOf(loop[apex]) & faceMaskOf(loop[(apex + i) % len])) ok = false;
        if (ok) return apex;
    }
    return -1; // never: every loop of the 256 cases has such an apex (checked below)
}

constexpr int kMaxTriangles = 10; // a single loop through all 12 edges would give 10

struct CaseTable {
    std::array<std::uint8_t, 256> triangleCount{};
    std::array<std::array<std::int8_t, 3 * kMaxTriangles>, 256> triangleEdges{};
    std::array<std::uint16_t, 256> crossingEdges{}; // bit e set when edge e crosses
    bool valid = true;
};

constexpr CaseTable buildCaseTable()
{
    CaseTable table{};
    for (int cubeCase = 0; cubeCase < 256; ++cubeCase) {
        auto inside = [cubeCase](int corner) { return ((cubeCase >> corner) & 1) != 0; };
        std::array<int, 12> next{};
        for (int e = 0; e < 12; ++e) next[e] = -1;
        std::uint16_t crossing = 0;
        for (int e = 0; e < 12; ++e)
            if (inside(kEdgeCorners[e][0]) != inside(kEdgeCorners[e][1])) crossing |= std::uint16_t(1u << e);
        for (const auto& face : kFaceCorners) {
            // Crossings in walk order, and whether the walk enters the inside there.
            std::array<int, 4> edgeAt{};
            std::array<bool, 4> enters{};
            int n = 0;
            for (int i = 0; i < 4; ++i) {
                const int a = face[i], b = face[(i + 1) % 4];
                if (inside(a) != inside(b)) {
                    edgeAt[n] = edgeBetween(a, b);
                    enters[n] = inside(b);
                    ++n;
                }
            }
            for (int i = 0; i < n; ++i) {
                if (!enters[i]) continue;
                for (int j = 1; j < n; ++j) { // the next crossing that leaves
                    const int m = (i + j) % n;
                    if (!enters[m]) {
                        next[edgeAt[i]] = edgeAt[m];
                        break;
                    }
                }
            }
        }
        // Walk the loops; fan each from its lowest-numbered edge.
        std::array<bool, 12> visited{};
        int tri = 0;
        for (int start = 0; start < 12; ++start) {
            if (!((crossing >> start) & 1) || visited[start]) continue;
            std::array<int, 12> loop{};
            int len = 0;
            for (int e = start; !visited[e]; e = next[e]) {
                visited[e] = true;
                loop[len++] = e;
            }
            const int apex = fanApex(loop, len);
            if (apex < 0) table.valid = false;
            for (int i = 1; i + 1 < len; ++i) {
                table.triangleEdges[cubeCase][3 * tri + 0] = std::int8_t(loop[apex]);
                table.triangleEdges[cubeCase][3 * tri + 1] = std::int8_t(loop[(apex + i) % len]);
                table.triangleEdges[cubeCase][3 * tri + 2] = std::int8_t(loop[(apex + i + 1) % len]);
                ++tri;
            }
        }
        table.triangleCount[cubeCase] = std::uint8_t(tri);
        table.crossingEdges[cubeCase] = crossing;
    }
    return table;
}

} // namespace mc_tables_internal

/// The 256 cases: triangle count, triangles as triples of cube edges, crossing-edge bits.
inline constexpr mc_tables_internal::CaseTable kMcCases = mc_tables_internal::buildCaseTable();
static_assert(kMcCases.valid, "every marching-cubes loop must have a fan apex free of face diagonals");

/// Edge e of a cell: its axis (0 x, 1 y, 2 z) and the offset of its lower voxel from the cell's
/// minimum corner. The vertex on that edge is keyed by (lower voxel, axis) (SPEC §1, §6).
struct McEdge {
    std::uint8_t axis;
    std::uint8_t dx, dy, dz;
};
inline constexpr std::array<McEdge, 12> kMcEdges{{{0, 0, 0, 0}, {1, 1, 0, 0}, {0, 0, 1, 0},
    {1, 0, 0, 0}, {0, 0, 0, 1}, {1, 1, 0, 1}, {0, 0, 1, 1}, {1, 0, 0, 1}, {2, 0, 0, 0},
    {2, 1, 0, 0}, {2, 1, 1, 0}, {2, 0, 1, 0}}};

/// Offset of corner c from the cell's minimum corner.
inline constexpr std::array<mc_tables_internal::Int3, 8> kMcCornerOffset =
    mc_tables_internal::kCornerOffset;

} // namespace isouq
