// isouq: the surface inside the cells the hidden-feature pass replaces (paper sec. 4.2, Figs.
// 5-7; SPEC §4; docs/hidden-features.md "Refinement" and "No cracks").
//
// A refined cell is cut into m^3 subcells whose corner values come from the tricubic
// interpolant (Tricubic.h) and meshed with the case tables (McTables.h, inside is >= k). Every
// unrefined cell sharing a face or an edge with a refined one is a transition cell: its surface
// is rebuilt from the loops its six faces' segments form (faces and edges shared with refined
// cells contribute their subdivided segments) and each loop is fanned to its centre, the
// paper's fan patch. New vertices are subcell-edge crossings, computed bit for bit alike by every
// cell that has the edge, so neighbours meet exactly.
#include "HiddenInternal.h"

#include "isouq/McTables.h"
#include "isouq/Tricubic.h"

#include <tbb/enumerable_thread_specific.h>

#include <algorithm>
#include <cstring>

namespace isouq {
namespace hidden_internal {
namespace {

using Accessor = openvdb::tree::ValueAccessor<const openvdb::FloatTree>;

/// Index of sub-point (p, q, r) in refineCell's output.
inline std::size_t subIndex(int p, int q, int r, int n) { return std::size_t((p * n + q) * n + r); }

/// The 4x4x4 voxels around the cell at @a c (Tricubic.h layout): a row of four from one leaf
/// buffer when it has one, else voxel by voxel.
void gatherStencil(const Accessor& acc, const Coord& c, float* stencil)
{
    using Leaf = openvdb::FloatTree::LeafNodeType;
    for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b) {
            const Coord p = c.offsetBy(a - 1, b - 1, -1);
            float* out = stencil + 16 * a + 4 * b;
            if ((p[2] & 7) <= 4) {
                if (const Leaf* leaf = acc.probeConstLeaf(p)) {
                    std::memcpy(out, leaf->buffer().data() + Leaf::coordToOffset(p), 4 * sizeof(float));
                    continue;
                }
            }
            for (int d = 0; d < 4; ++d) out[d] = acc.getValue(p.offsetBy(0, 0, d));
        }
}

inline Coord times(const Coord& c, int s) { return Coord(c[0] * s, c[1] * s, c[2] * s); }
/// (to - from) / m: a unit step along a cell edge whose ends are in sub-point units.
inline Coord unitStep(const Coord& from, const Coord& to, int m)
{
    return Coord((to[0] - from[0]) / m, (to[1] - from[1]) / m, (to[2] - from[2]) / m);
}

/// Local corner c of a cell, in sub-point units (0 or m per axis).
inline Coord cornerLocal(int c, int m)
{
    const auto& o = kMcCornerOffset[std::size_t(c)];
    return Coord(o.x * m, o.y * m, o.z * m);
}

/// Tricubic values at the sub-points (local coordinates 0..m) of one cell: all of them for a
/// refined cell, those on the given faces and edges (and the corners) for a transition cell.
/// Either way a value is the one refineCell gives, bit for bit (Tricubic.h).
class CellValues {
public:
    CellValues(int m, double k, const Packer& packer) : mM(m), mN(m + 1), mK(k), mPacker(packer)
    {
        for (int s = 0; s <= m; ++s) mWeights.push_back(cubicWeights(s, m));
    }

    void refineAll(const Coord& cell, const float* stencil)
    {
        mCell = cell;
        refineCell(stencil, mM, mValues, mWorkspace);
    }

    void refineParts(const Coord& cell, const float* stencil, const bool (&faces)[6], const bool (&edges)[12])
    {
        mCell = cell;
        mValues.resize(std::size_t(mN) * mN * mN);
        for (int c = 0; c < 8; ++c) { // at the nodes the tricubic reads the voxel (Tricubic.h)
            const Coord p = cornerLocal(c, mM);
            mValues[subIndex(p[0], p[1], p[2], mN)] = double(stencil[16 * (1 + p[0] / mM) + 4 * (1 + p[1] / mM) + 1 + p[2] / mM]);
        }
        for (int f = 0; f < 6; ++f)
            if (faces[f]) evaluateFace(stencil, f);
        for (int e = 0; e < 12; ++e) {
            if (!edges[e]) continue;
            const McEdge& edge = kMcEdges[std::size_t(e)];
            Coord p(edge.dx * mM, edge.dy * mM, edge.dz * mM);
            for (p[edge.axis] = 0; p[edge.axis] <= mM; ++p[edge.axis]) evaluate(stencil, p);
        }
    }

    const Coord& cell() const { return mCell; }
    int m() const { return mM; }
    double value(const Coord& local) const { return mValues[subIndex(local[0], local[1], local[2], mN)]; }
    bool inside(const Coord& local) const { return value(local) >= mK; }
    Coord fine(const Coord& local) const { return times(mCell, mM) + local; }

    /// The crossing of the subcell edge from sub-point @a lo along @a axis: keyed by its lower
    /// fine point and axis, linear (SPEC §2 on the subcell edge, from its lower point). Every
    /// cell sharing the edge computes it from the same values, so the same bits.
    FineCrossing crossing(const Coord& lo, int axis) const
    {
        Coord hi = lo;
        hi[axis] += 1;
        const double f0 = value(lo), f1 = value(hi);
        const double t = std::clamp((mK - f0) / (f1 - f0), 0.0, 1.0);
        return FineCrossing{mPacker.fine(fine(lo), axis), float(t), 0};
    }

    /// Appends every crossing subcell edge of the cell to @a out; crossingRef then finds them.
    void writeCrossings(std::vector<FineCrossing>& out)
    {
        mEdgeRefs.resize(3 * std::size_t(mN) * mN * mN);
        for (int axis = 0; axis < 3; ++axis) {
            Coord hiBound(mM, mM, mM);
            hiBound[axis] = mM - 1;
            Coord p;
            for (p[0] = 0; p[0] <= hiBound[0]; ++p[0])
                for (p[1] = 0; p[1] <= hiBound[1]; ++p[1])
                    for (p[2] = 0; p[2] <= hiBound[2]; ++p[2]) {
                        Coord q = p;
                        q[axis] += 1;
                        if (inside(p) == inside(q)) continue;
                        mEdgeRefs[3 * subIndex(p[0], p[1], p[2], mN) + std::size_t(axis)] = kFineRef | Ref(out.size());
                        out.push_back(crossing(p, axis));
                    }
        }
    }
    /// The Ref of a crossing writeCrossings appended.
    Ref crossingRef(const Coord& lo, int axis) const
    {
        return mEdgeRefs[3 * subIndex(lo[0], lo[1], lo[2], mN) + std::size_t(axis)];
    }

private:
    /// The values on face f (across axis f / 2, at side f % 2): refineFace's, bitwise tricubic()'s.
    void evaluateFace(const float* stencil, int f)
    {
        const int axis = f / 2, side = (f % 2) * mM, n = mN;
        mPartial.resize(std::size_t(4 * n));
        mFace.resize(std::size_t(n * n));
        refineFace(stencil, axis, f % 2, mWeights, mPartial.data(), mFace.data());
        for (int s = 0; s <= mM; ++s)
            for (int t = 0; t <= mM; ++t) {
                const Coord p = axis == 0 ? Coord(side, s, t) : axis == 1 ? Coord(s, side, t) : Coord(s, t, side);
                mValues[subIndex(p[0], p[1], p[2], n)] = mFace[std::size_t(s * n + t)];
            }
    }

    void evaluate(const float* stencil, const Coord& p)
    {
        mValues[subIndex(p[0], p[1], p[2], mN)] = tricubic(stencil, mWeights[std::size_t(p[0])],
            mWeights[std::size_t(p[1])], mWeights[std::size_t(p[2])]);
    }

    int mM, mN;
    double mK;
    const Packer& mPacker;
    Coord mCell;
    std::vector<CubicWeights> mWeights;
    std::vector<double> mValues;
    std::vector<double> mPartial, mFace; // evaluateFace's scratch
    std::vector<Ref> mEdgeRefs; // per (sub-point, axis) of a refined cell: its crossing's Ref
    TricubicWorkspace mWorkspace;
};

/// Marching cubes on the m^3 subcells of a refined cell (McTables.h, inside is >= k).
void meshRefinedCell(CellValues& cv, Patch& patch)
{
    const int m = cv.m();
    cv.writeCrossings(patch.crossings);
    for (int p = 0; p < m; ++p)
        for (int q = 0; q < m; ++q)
            for (int r = 0; r < m; ++r) {
                const Coord base(p, q, r);
                int cubeCase = 0;
                for (int c = 0; c < 8; ++c) {
                    const auto& o = kMcCornerOffset[std::size_t(c)];
                    cubeCase |= int(cv.inside(base.offsetBy(o.x, o.y, o.z))) << c;
                }
                const int count = kMcCases.triangleCount[std::size_t(cubeCase)];
                if (count == 0) continue;
                std::array<Ref, 12> keys{};
                const std::uint16_t crossing = kMcCases.crossingEdges[std::size_t(cubeCase)];
                for (int e = 0; e < 12; ++e) {
                    if (!((crossing >> e) & 1)) continue;
                    const McEdge& edge = kMcEdges[std::size_t(e)];
                    keys[std::size_t(e)] = cv.crossingRef(base.offsetBy(edge.dx, edge.dy, edge.dz), edge.axis);
                }
                const auto& edges = kMcCases.triangleEdges[std::size_t(cubeCase)];
                for (int t = 0; t < count; ++t)
                    patch.triangles.push_back({keys[std::size_t(edges[3 * t])],
                        keys[std::size_t(edges[3 * t + 1])], keys[std::size_t(edges[3 * t + 2])]});
            }
}

/// Bit (dx + 1) * 9 + (dy + 1) * 3 + dz + 1 of a neighbourhood mask: the neighbour u + (dx, dy, dz).
constexpr int neighbourBit(int dx, int dy, int dz) { return (dx + 1) * 9 + (dy + 1) * 3 + dz + 1; }

/// Which faces (-x, +x, -y, +y, -z, +z) and edges of the unrefined cell @a u a refined cell
/// shares, from which of its 18 face and edge neighbours are refined.
void refinedParts(const Coord& u, const BlockCells& refined, BlockFinder& finder, bool (&faces)[6], bool (&edges)[12])
{
    // The neighbours lie in at most 8 blocks: look each up once.
    std::int32_t blockOf[27];
    std::fill_n(blockOf, 27, -2);
    const Coord home = u >> 3;
    std::uint32_t near = 0;
    for (const auto& d : kFaceEdgeNeighbours) {
        const Coord c = u.offsetBy(d[0], d[1], d[2]);
        const Coord o = (c >> 3) - home;
        std::int32_t& block = blockOf[neighbourBit(o[0], o[1], o[2])];
        if (block == -2) block = finder.find(c);
        if (block >= 0 && refined.test(block, BlockFinder::local(c))) near |= 1u << neighbourBit(d[0], d[1], d[2]);
    }
    for (int f = 0; f < 6; ++f) {
        int d[3] = {0, 0, 0};
        d[f / 2] = (f % 2) ? 1 : -1;
        faces[f] = (near >> neighbourBit(d[0], d[1], d[2])) & 1u;
    }
    for (int e = 0; e < 12; ++e) { // the three other cells around the edge
        const McEdge& edge = kMcEdges[std::size_t(e)];
        const int lowCorner[3] = {edge.dx, edge.dy, edge.dz};
        const int a1 = (edge.axis + 1) % 3, a2 = (edge.axis + 2) % 3;
        edges[e] = false;
        for (int d1 = 0; d1 < 2; ++d1)
            for (int d2 = 0; d2 < 2; ++d2) {
                int d[3] = {0, 0, 0};
                d[a1] = lowCorner[a1] - d1;
                d[a2] = lowCorner[a2] - d2;
                if ((d[a1] || d[a2]) && ((near >> neighbourBit(d[0], d[1], d[2])) & 1u)) edges[e] = true;
            }
    }
}

/// The surface of a transition cell: segments on its six faces (walked counter-clockwise from
/// outside, each entering crossing joined to the next leaving one, McTables.h's rule), chained
/// into loops, each fanned to its centre.
struct FaceCrossing {
    Ref key;
    bool enters;
};
/// Per-thread buffers of meshTransitionCell.
struct TransitionScratch {
    std::vector<std::pair<Ref, Ref>> segments;
    std::vector<FaceCrossing> walk;
    std::vector<std::uint8_t> used;
    std::vector<std::pair<Ref, std::size_t>> starts;
    std::vector<std::size_t> loop;
    std::vector<Ref> edgeRefs;          // per (sub-point, axis): its crossing's Ref, once made
    std::vector<std::size_t> edgesMade; // the entries to clear for the next cell
};

void meshTransitionCell(const CellValues& cv, const bool (&faceRefined)[6], const bool (&edgeRefined)[12],
    const Packer& packer, TransitionScratch& scratch, Patch& patch)
{
    using mc_tables_internal::edgeBetween;
    using mc_tables_internal::kFaceCorners;
    const int m = cv.m();
    const Coord& u = cv.cell();
    using Crossing = FaceCrossing;
    std::vector<std::pair<Ref, Ref>>& segments = scratch.segments;
    segments.clear();
    // A subcell edge is walked from two subfaces (or two faces): one Ref for both.
    constexpr Ref kNoRef = ~Ref(0);
    const std::size_t n = std::size_t(m + 1);
    if (scratch.edgeRefs.size() != 3 * n * n * n) scratch.edgeRefs.assign(3 * n * n * n, kNoRef);
    for (std::size_t i : scratch.edgesMade) scratch.edgeRefs[i] = kNoRef;
    scratch.edgesMade.clear();
    auto fineRef = [&](const Coord& a, const Coord& b) {
        const Coord& lo = a < b ? a : b;
        int axis = 0;
        while (a[axis] == b[axis]) ++axis;
        const std::size_t slot = 3 * subIndex(lo[0], lo[1], lo[2], int(n)) + std::size_t(axis);
        Ref& r = scratch.edgeRefs[slot];
        if (r == kNoRef) {
            r = kFineRef | Ref(patch.crossings.size());
            patch.crossings.push_back(cv.crossing(lo, axis));
            scratch.edgesMade.push_back(slot);
        }
        return r;
    };
    auto pairUp = [&segments](const std::vector<Crossing>& walk) {
        for (std::size_t i = 0; i < walk.size(); ++i) {
            if (!walk[i].enters) continue;
            for (std::size_t j = 1; j < walk.size(); ++j) {
                const Crossing& next = walk[(i + j) % walk.size()];
                if (!next.enters) {
                    segments.emplace_back(walk[i].key, next.key);
                    break;
                }
            }
        }
    };
    std::vector<Crossing>& walk = scratch.walk;
    for (int f = 0; f < 6; ++f) {
        const auto& loop = kFaceCorners[std::size_t(f)];
        if (faceRefined[f]) {
            // A face shared with a refined cell: its m x m subfaces, walked the same way.
            const Coord c0 = cornerLocal(loop[0], m);
            const Coord ds = unitStep(c0, cornerLocal(loop[1], m), m), dt = unitStep(c0, cornerLocal(loop[3], m), m);
            for (int s = 0; s < m; ++s)
                for (int t = 0; t < m; ++t) {
                    const Coord corner[4] = {c0 + times(ds, s) + times(dt, t), c0 + times(ds, s + 1) + times(dt, t),
                        c0 + times(ds, s + 1) + times(dt, t + 1), c0 + times(ds, s) + times(dt, t + 1)};
                    walk.clear();
                    for (int i = 0; i < 4; ++i) {
                        const Coord& a = corner[i];
                        const Coord& b = corner[(i + 1) % 4];
                        if (cv.inside(a) != cv.inside(b)) walk.push_back({fineRef(a, b), cv.inside(b)});
                    }
                    pairUp(walk);
                }
            continue;
        }
        walk.clear();
        for (int i = 0; i < 4; ++i) {
            const int ca = loop[std::size_t(i)], cb = loop[std::size_t((i + 1) % 4)];
            const int e = edgeBetween(ca, cb);
            const Coord a = cornerLocal(ca, m), b = cornerLocal(cb, m);
            if (edgeRefined[e]) { // the subdivision of a refined cell's edge, walked from a to b
                const Coord step = unitStep(a, b, m);
                for (int s = 0; s < m; ++s) {
                    const Coord p = a + times(step, s), q = a + times(step, s + 1);
                    if (cv.inside(p) != cv.inside(q)) walk.push_back({fineRef(p, q), cv.inside(q)});
                }
            } else if (cv.inside(a) != cv.inside(b)) { // the standard vertex of this grid edge
                const McEdge& edge = kMcEdges[std::size_t(e)];
                walk.push_back({packer.coarse(u.offsetBy(edge.dx, edge.dy, edge.dz), edge.axis), cv.inside(b)});
            }
        }
        pairUp(walk);
    }
    // Chain the segments into loops (each key starts one segment and ends one) and fan them. A
    // loop of two is the same chord along one refined edge from both faces: it encloses nothing
    // (the surfaces of the cells beyond those faces meet along that chord) and is skipped.
    std::vector<std::uint8_t>& used = scratch.used;
    used.assign(segments.size(), 0);
    std::vector<std::pair<Ref, std::size_t>>& starts = scratch.starts; // (first key, segment), sorted
    starts.clear();
    for (std::size_t i = 0; i < segments.size(); ++i) starts.emplace_back(segments[i].first, i);
    std::sort(starts.begin(), starts.end());
    std::vector<std::size_t>& loop = scratch.loop;
    for (std::size_t first = 0; first < segments.size(); ++first) {
        if (used[first]) continue;
        loop.clear();
        for (std::size_t s = first; !used[s];) {
            used[s] = 1;
            loop.push_back(s);
            const auto next = std::lower_bound(starts.begin(), starts.end(), std::make_pair(segments[s].second, std::size_t(0)));
            if (next == starts.end() || next->first != segments[s].second) break;
            s = next->second;
        }
        if (loop.size() < 3) continue;
        const Ref centre = kCentreRef | Ref(patch.memberEnds.size());
        for (std::size_t s : loop) {
            patch.members.push_back(segments[s].first);
            patch.triangles.push_back({centre, segments[s].first, segments[s].second});
        }
        patch.memberEnds.push_back(std::uint32_t(patch.members.size()));
        patch.centreCells.push_back(u);
    }
}

} // namespace

ReplacedSurface meshReplacedCells(const openvdb::FloatTree& tree, const BlockSet& blocks,
    const std::vector<Coord>& refined, const BlockCells& refinedCells, const std::vector<Coord>& transition,
    const Packer& packer, int m, float k, bool threaded, openvdb::util::NullInterrupter* interrupter)
{
    // Chunks of cells; chunk order is cell order.
    constexpr std::size_t kChunk = 32;
    ReplacedSurface out;
    out.refinedChunks = (refined.size() + kChunk - 1) / kChunk;
    const std::size_t transitionChunks = (transition.size() + kChunk - 1) / kChunk;
    out.patches.resize(out.refinedChunks + transitionChunks);
    struct CellScratch {
        Accessor accessor;
        CellValues values;
        BlockFinder finder;
        TransitionScratch transition;
    };
    tbb::enumerable_thread_specific<CellScratch> scratches(
        [&] { return CellScratch{Accessor(tree), CellValues(m, double(k), packer), BlockFinder(blocks), {}}; });
    forEach(out.patches.size(), 1, threaded, interrupter, [&](std::size_t chunk) {
        const bool isRefined = chunk < out.refinedChunks;
        const std::vector<Coord>& cells = isRefined ? refined : transition;
        const std::size_t first = (isRefined ? chunk : chunk - out.refinedChunks) * kChunk;
        const std::size_t last = std::min(cells.size(), first + kChunk);
        CellScratch& scratch = scratches.local();
        Patch& patch = out.patches[chunk];
        float stencil[64];
        bool faces[6], edges[12];
        for (std::size_t i = first; i < last; ++i) {
            gatherStencil(scratch.accessor, cells[i], stencil);
            if (isRefined) {
                scratch.values.refineAll(cells[i], stencil);
                meshRefinedCell(scratch.values, patch);
            } else {
                refinedParts(cells[i], refinedCells, scratch.finder, faces, edges);
                scratch.values.refineParts(cells[i], stencil, faces, edges);
                meshTransitionCell(scratch.values, faces, edges, packer, scratch.transition, patch);
            }
        }
    });
    return out;
}

} // namespace hidden_internal
} // namespace isouq
