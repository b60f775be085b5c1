// isouq nodes: the SPEC §8 summary of a mesh (the `--summary` JSON and the C7 view).
#pragma once

#include <isouq/MeshAttributes.h>

#include <nlohmann/json.hpp>

#include <vector>

namespace isouq::nodes {

/// {min, max, mean, rms, count} of the finite values (nulls and count 0 when there are none).
nlohmann::json statistics(const std::vector<float>& values);

/// Counts, topology and statistics() of every per-vertex measure present (SPEC §6, §8).
nlohmann::json summarizeMesh(const Mesh& mesh);

} // namespace isouq::nodes
