// isouq nodes: the SPEC §8 summary of a mesh (the `--summary` JSON and the C7 view).
#pragma once

#include <isouq/MeshAttributes.h>
#include <isouq/MeshTopology.h>

#include <nlohmann/json.hpp>

#include <cstddef>
#include <limits>
#include <vector>

namespace isouq::nodes {

/// The running sums behind statistics(): folded value by value within a chunk of kSumRows
/// values (add), chunks joined in order (join; isouq/MeshTopology.h), so the same bits for any
/// thread or rank count (SPEC §10 "MPI").
struct StatisticsSums {
    double lo = std::numeric_limits<double>::infinity(), hi = -std::numeric_limits<double>::infinity();
    double sum = 0, sumSq = 0;
    std::size_t count = 0;

    void add(const float* values, std::size_t n);
    void join(const StatisticsSums& next);
    nlohmann::json result() const;
};

/// {min, max, mean, rms, count} of the finite values (nulls and count 0 when there are none).
nlohmann::json statistics(const std::vector<float>& values);

/// Counts, topology and statistics() of every per-vertex measure present (SPEC §6, §8).
nlohmann::json summarizeMesh(const Mesh& mesh);

/// The count and topology keys of summarizeMesh, from counts the caller has: one process's
/// measureTopology, or the sums the MPI ranks carry (Pieces.h).
nlohmann::json summaryCounts(std::size_t vertices, std::size_t triangles, const MeshTopologyStats& topo);

} // namespace isouq::nodes
