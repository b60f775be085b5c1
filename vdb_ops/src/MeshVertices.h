// isouq (internal): what the mesher writes per vertex (SPEC §6): the primary method's position,
// provenance, every method's crossing (paper sec. 3.2-3.4, SPEC §2), the closed-form estimates
// (paper sec. 4.1, SPEC §3) and the method differences. Used by MarchingCubes.cc only.
#pragma once

#include "isouq/EdgeInterp.h"
#include "isouq/Columns.h"
#include "isouq/ErrorEstimate.h"
#include "isouq/MarchingCubes.h"

#include "FreshPages.h"

#include <openvdb/math/Transform.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <type_traits>
#include <variant>
#include <vector>

namespace isouq::mc_internal {

/// Index-to-world map, applied without a virtual call when the transform is affine.
class WorldMap {
public:
    explicit WorldMap(const openvdb::math::Transform& xform) : mTransform(xform)
    {
        mAffine = xform.isLinear();
        if (mAffine) mMatrix = xform.baseMap()->getAffineMap()->getMat4();
    }
    openvdb::Vec3s operator()(const openvdb::Vec3d& ijk) const
    {
        return openvdb::Vec3s(mAffine ? mMatrix.transform(ijk) : mTransform.indexToWorld(ijk));
    }
    /// Row-major, column-vector convention (Mesh::indexToWorld).
    std::array<double, 16> rowMajor() const
    {
        const openvdb::Mat4d m = mAffine ? mMatrix : openvdb::Mat4d::identity();
        std::array<double, 16> out{};
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c) out[4 * r + c] = m(c, r); // OpenVDB multiplies row vectors
        return out;
    }

private:
    const openvdb::math::Transform& mTransform;
    bool mAffine = false;
    openvdb::Mat4d mMatrix;
};

/// Output columns the fill pass writes into (null when not requested).
struct VertexColumns {
    openvdb::Vec3s* positions = nullptr;
    std::int32_t *edgeI = nullptr, *edgeJ = nullptr, *edgeK = nullptr;
    std::uint8_t* edgeAxis = nullptr;
    float* tLinear = nullptr;
    // With uncertainty:
    float *tCubic = nullptr, *tWeno = nullptr, *tWenoPaper = nullptr;
    std::uint8_t* order = nullptr;
    float *errEst = nullptr, *errBound = nullptr, *errBest = nullptr, *errBestSurface = nullptr;
    float *errEstCubic = nullptr, *errEstWeno = nullptr;
    float *dLc = nullptr, *dLw = nullptr, *dCw = nullptr, *maxVar = nullptr;

    /// Sizes positions, triangles and the columns this pass writes, drops the columns it does
    /// not write (a reused mesh's leftovers), and points at them. The columns are sized side by
    /// side, a task each (resize()'s zero fill is serial within one column), their pages faulted
    /// in by all threads (resizeFaultingIn). The pointers are to the columns' storage, which
    /// moving a column (the table growing or shrinking) does not move.
    static VertexColumns allocate(Mesh& mesh, std::size_t vertices, std::size_t triangles, bool provenance,
        const MeshSettings& settings, bool threaded)
    {
        std::vector<std::string_view> names;
        declare(provenance, settings, names);
        AttributeTable& a = mesh.vertexAttributes;
        for (std::string_view name : names) { // reused as they are: the fill writes every value
            const ColumnType type = findColumnInfo(name)->type;
            if (type == ColumnType::UInt8) a.reuse<std::uint8_t>(name);
            else if (type == ColumnType::Int32) a.reuse<std::int32_t>(name);
            else a.reuse<float>(name);
        }
        a.retainOnly(std::vector<std::string>(names.begin(), names.end()));
        mesh.faceAttributes.clear();

        auto each = [&](std::size_t i, auto&& f) { // 0 positions, 1 triangles, then the vertex columns
            if (i == 0) return f(mesh.positions, vertices);
            if (i == 1) return f(mesh.triangles, triangles);
            return std::visit([&](auto& v) { return f(v, vertices); }, a.columns()[i - 2].data);
        };
        const std::size_t count = 2 + a.columns().size();
        // Storage first, one column after the other (malloc's lock, and the address space's for
        // new mappings), then the columns' sizes and pages on all threads (resizeFaultingIn).
        std::vector<PageRange> fresh;
        for (std::size_t i = 0; i < count; ++i)
            fresh.push_back(each(i, [](auto& v, std::size_t n) { return reserveStorage(v, n); }));
        resizeFaultingIn(fresh, [&](std::size_t i) { each(i, [](auto& v, std::size_t n) { v.resize(n); }); }, threaded);

        VertexColumns c;
        c.positions = mesh.positions.data();
        auto at = [&](auto*& out, std::string_view name) {
            using T = std::remove_pointer_t<std::remove_reference_t<decltype(out)>>;
            if (auto* column = a.find<T>(name)) out = column->data();
        };
        at(c.edgeI, col::kEdgeI), at(c.edgeJ, col::kEdgeJ), at(c.edgeK, col::kEdgeK);
        at(c.edgeAxis, col::kEdgeAxis), at(c.tLinear, col::kTLinear);
        at(c.errEst, col::kErrEst), at(c.errBound, col::kErrBound);
        at(c.tCubic, col::kTCubic), at(c.tWeno, col::kTWeno), at(c.tWenoPaper, col::kTWenoPaper);
        at(c.order, col::kOrder), at(c.errBest, col::kErrBest), at(c.errBestSurface, col::kErrBestSurface);
        at(c.errEstCubic, col::kErrEstCubic), at(c.errEstWeno, col::kErrEstWeno);
        at(c.dLc, col::kDLc), at(c.dLw, col::kDLw), at(c.dCw, col::kDCw), at(c.maxVar, col::kMaxVar);
        return c;
    }

private:
    /// The names of the vertex columns this pass writes (SPEC §6), in PLY order.
    static void declare(bool provenance, const MeshSettings& settings, std::vector<std::string_view>& names)
    {
        if (provenance)
            names.insert(names.end(), {col::kEdgeI, col::kEdgeJ, col::kEdgeK, col::kEdgeAxis, col::kTLinear});
        if (!settings.uncertainty) return;
        names.insert(names.end(), {col::kErrEst, col::kErrBound});
        if (!settings.highOrder) return;
        names.insert(names.end(), {col::kTCubic, col::kTWeno});
        if (settings.method == EdgeMethod::WenoPaper) names.push_back(col::kTWenoPaper);
        names.insert(names.end(), {col::kOrder, col::kErrBest, col::kErrBestSurface, col::kErrEstCubic,
                                      col::kErrEstWeno, col::kDLc, col::kDLw, col::kDCw, col::kMaxVar});
    }
};

/// What every vertex of one extraction shares.
struct VertexContext {
    float isovalue;
    const WorldMap& toWorld;
    openvdb::Vec3d spacing; ///< world length of one voxel along each index axis
    std::optional<openvdb::CoordBBox> bounds;
    StencilPolicy stencil;
    EdgeMethod method;
    bool uncertainty;
};

/// Every method's crossing, the primary method's crossing @a t and order, the method
/// differences and the estimates beyond the paper, for vertex @a n (SPEC §2, §6;
/// docs/error-estimates.md).
template <typename ScratchT>
void writeHighOrder(const ScratchT& s, int x, int y, int z, int axis, std::size_t n,
    const std::array<float, 6>& f, std::uint8_t available, float tLinear, const VertexContext& ctx,
    const VertexColumns& out, float& t)
{
    const float k = ctx.isovalue, h = float(ctx.spacing[axis]);
    const EdgeCrossing cubic = CubicEdge::crossing(f, available, k);
    const EdgeCrossing weno = WenoEdge::crossing(f, available, k);
    EdgeCrossing primary{tLinear, 2};
    switch (ctx.method) {
    case EdgeMethod::Linear: break;
    case EdgeMethod::Cubic: primary = cubic; break;
    case EdgeMethod::Weno: primary = weno; break;
    case EdgeMethod::WenoPaper:
        primary = WenoPaperEdge::crossing(f, available, k);
        out.tWenoPaper[n] = primary.t;
        break;
    }
    t = primary.t;
    out.tCubic[n] = cubic.t;
    out.tWeno[n] = weno.t;
    out.order[n] = primary.order;
    const CrossingSpread spread = crossingSpread(tLinear, cubic.t, weno.t, h);
    out.dLc[n] = spread.dLc;
    out.dLw[n] = spread.dLw;
    out.dCw[n] = spread.dCw;
    out.maxVar[n] = spread.maxVar;
    // Beyond the paper: the linear error estimated by the next higher order's crossing, and its
    // distance to the surface through the angle between the edge and the gradient (central
    // differences at both ends, interpolated at t).
    out.errBest[n] = spread.dLc;
    double gradient[3] = {0.0, 0.0, 0.0};
    const int sx = s.stride(0), sy = s.stride(1), step = s.stride(axis);
    for (int end = 0; end < 2; ++end) {
        const float* v = s.at(x, y, z) + end * step;
        const double w = end == 0 ? 1.0 - tLinear : double(tLinear);
        gradient[0] += w * (v[sx] - v[-sx]) / ctx.spacing[0];
        gradient[1] += w * (v[sy] - v[-sy]) / ctx.spacing[1];
        gradient[2] += w * (v[1] - v[-1]) / ctx.spacing[2];
    }
    const float cosine = edgeNormalCosine(float(gradient[axis]), float(gradient[0]), float(gradient[1]),
        float(gradient[2]));
    out.errBestSurface[n] = surfaceDistance(spread.dLc, cosine);
    out.errEstCubic[n] = cubicErrorEstimate(f, available, cubic.t, h);
    out.errEstWeno[n] = wenoErrorEstimate(f, available, weno.t, h);
}

/// Computes and writes vertex @a n on the edge from voxel (x, y, z) of the block at @a origin
/// along @a axis. @a s gives values (and active states) up to three voxels around the block.
template <typename ScratchT>
void writeVertex(const ScratchT& s, const openvdb::Coord& origin, int x, int y, int z, int axis,
    std::size_t n, const VertexContext& ctx, const VertexColumns& out)
{
    const int dx = axis == 0, dy = axis == 1, dz = axis == 2;
    const float* v = s.at(x, y, z);
    const int step = s.stride(axis);
    const float f0 = v[0], f1 = v[step];
    // SPEC §2 linear crossing, always measured from the lower end of the edge.
    const float tLinear = std::clamp((ctx.isovalue - f0) / (f1 - f0), 0.0f, 1.0f);
    const openvdb::Coord ijk = origin.offsetBy(x, y, z);
    float t = tLinear;
    if (out.edgeI) {
        out.edgeI[n] = ijk[0];
        out.edgeJ[n] = ijk[1];
        out.edgeK[n] = ijk[2];
        out.edgeAxis[n] = std::uint8_t(axis);
        out.tLinear[n] = tLinear;
    }
    if (ctx.uncertainty) {
        // Stencil f_{i-2..i+3} along the edge; a voxel outside the data, inactive under the
        // ActiveOnly policy, or not finite (an inactive NaN the input checks do not see) is
        // missing and the methods fall back (SPEC §1, §2).
        // The stencil's voxels differ only along the axis: the other two coordinates are tested
        // once, the axis coordinate per voxel.
        bool across = true;
        int lo = std::numeric_limits<int>::min(), hi = std::numeric_limits<int>::max();
        if (ctx.bounds) {
            for (int a = 0; a < 3; ++a)
                if (a != axis && (ijk[a] < ctx.bounds->min()[a] || ijk[a] > ctx.bounds->max()[a])) across = false;
            lo = ctx.bounds->min()[axis];
            hi = ctx.bounds->max()[axis];
        }
        std::array<float, 6> f{};
        std::uint8_t available = 0;
        for (int j = 0; j < 6; ++j) {
            const int o = j - 2;
            f[j] = v[o * step];
            const bool inData = across && ijk[axis] + o >= lo && ijk[axis] + o <= hi;
            const bool usable = std::isfinite(f[j]) &&
                (ctx.stencil == StencilPolicy::TreeValues || s.isActive(x + o * dx, y + o * dy, z + o * dz));
            if ((inData && usable) || j == 2 || j == 3) available |= std::uint8_t(1u << j);
        }
        const LinearError linear = linearError(f, available, tLinear, float(ctx.spacing[axis]));
        out.errEst[n] = linear.estimate;
        out.errBound[n] = linear.bound;
        if (out.tCubic) writeHighOrder(s, x, y, z, axis, n, f, available, tLinear, ctx, out, t);
    }
    openvdb::Vec3d p(ijk[0], ijk[1], ijk[2]);
    p[axis] += double(t);
    out.positions[n] = ctx.toWorld(p);
}

} // namespace isouq::mc_internal
