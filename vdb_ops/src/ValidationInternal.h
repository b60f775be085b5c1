// isouq (internal): what the truth columns (Truth.cc) and the paper's experiments
// (Validation.cc) share: parallel loops over vertices and the vertices' source edges.
#pragma once

#include "isouq/MeshAttributes.h"
#include "isouq/Columns.h"

#include <openvdb/Exceptions.h>
#include <openvdb/openvdb.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <array>
#include <cstdint>
#include <limits>
#include <vector>

namespace isouq::validation_internal {

using openvdb::Vec3d;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Runs body(begin, end) over [0, n) in parallel or serially; every index is independent.
template <typename BodyT>
void forEachIndex(std::size_t n, bool threaded, const BodyT& body)
{
    if (!threaded) {
        body(std::size_t(0), n);
        return;
    }
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 256),
        [&](const tbb::blocked_range<std::size_t>& r) { body(r.begin(), r.end()); });
}

inline Vec3d toWorld(const std::array<double, 16>& m, const Vec3d& ijk)
{
    return Vec3d(m[0] * ijk[0] + m[1] * ijk[1] + m[2] * ijk[2] + m[3],
        m[4] * ijk[0] + m[5] * ijk[1] + m[6] * ijk[2] + m[7],
        m[8] * ijk[0] + m[9] * ijk[1] + m[10] * ijk[2] + m[11]);
}

/// The provenance columns of a mesh.
struct Provenance {
    const std::vector<std::int32_t> *i, *j, *k;
    const std::vector<std::uint8_t>* axis;

    explicit Provenance(const Mesh& mesh)
    {
        const AttributeTable& a = mesh.vertexAttributes;
        i = a.find<std::int32_t>(col::kEdgeI);
        j = a.find<std::int32_t>(col::kEdgeJ);
        k = a.find<std::int32_t>(col::kEdgeK);
        axis = a.find<std::uint8_t>(col::kEdgeAxis);
        if (!i || !j || !k || !axis)
            OPENVDB_THROW(openvdb::ValueError,
                "validation needs the provenance columns edge_i edge_j edge_k edge_axis "
                "(mesh with settings.provenance or settings.uncertainty)");
    }
    Vec3d lower(std::size_t n) const { return Vec3d((*i)[n], (*j)[n], (*k)[n]); }
    Vec3d along(std::size_t n, double t) const
    {
        Vec3d p = lower(n);
        p[(*axis)[n]] += t;
        return p;
    }
};

} // namespace isouq::validation_internal
