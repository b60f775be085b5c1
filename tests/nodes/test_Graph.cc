// Tests of the node layer (Graph.h, Node.h): cooks against analytic truths, graph checks.
#include "../TempDir.h"

#include <catch2/catch.hpp>

#include <isouq/MarchingCubes.h>
#include <isouq/VolumeSources.h>
#include <isouq/nodes/Graph.h>

#include <tbb/global_control.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>

using namespace isouq;
using namespace isouq::nodes;

namespace {

NodeValue cook(const std::string& type, const nlohmann::json& parms, std::map<std::string, const NodeValue*> inputs,
    const std::string& port = "mesh")
{
    const NodeType* t = findNodeType(type);
    REQUIRE(t);
    nlohmann::json values = nlohmann::json::object();
    for (const ParmSpec& p : t->parms) values[p.token] = parms.contains(p.token) ? parms[p.token] : p.defaultValue;
    CookContext ctx;
    ctx.nodeId = type;
    ctx.parms = ParmValues(values);
    ctx.inputs = std::move(inputs);
    std::vector<std::string> warnings;
    std::vector<PendingWrite> writes;
    ctx.warnings = &warnings;
    ctx.writes = &writes;
    t->cook(ctx);
    return ctx.outputs.at(port);
}

} // namespace

TEST_CASE("Nodes: error_estimate is the closed form on a quadratic field", "[nodes][estimate]")
{
    openvdb::initialize();
    // f = x^2 + y^2 + z^2 - 0.5 on [-1,1]^3, N = 17, h = 1/8. Along any axis f = x^2 + c, so every
    // second divided difference is 1 and U[i,i+1] = x_i + x_{i+1}: e = h^2 t(1-t) / |x_i + x_{i+1}|,
    // e_b = h^2 / |x_i + x_{i+1}| (SPEC §3).
    VolumeRequest request;
    request.input = "formula:x^2+y^2+z^2-0.5";
    request.resolution = 17;
    NodeValue volume;
    volume.volume = std::make_shared<LoadedVolume>(loadVolume(request));
    MeshSettings settings;
    settings.isovalue = 0.0f;
    settings.provenance = true; // linear only: no estimates yet
    auto mesh = std::make_shared<MeshData>();
    mesh->mesh = extractIsosurface(*volume.volume->grid, settings);
    REQUIRE_FALSE(mesh->mesh.vertexAttributes.has("err_est"));
    NodeValue in;
    in.mesh = mesh;

    const NodeValue out = cook("error_estimate", {}, {{"volume", &volume}, {"mesh", &in}});
    const AttributeTable& a = out.mesh->mesh.vertexAttributes;
    const auto& est = *a.find<float>("err_est");
    const auto& bound = *a.find<float>("err_bound");
    const auto& t = *a.find<float>("t_linear");
    const auto& axis = *a.find<std::uint8_t>("edge_axis");
    const std::vector<std::int32_t>* lower[3] = {a.find<std::int32_t>("edge_i"), a.find<std::int32_t>("edge_j"),
        a.find<std::int32_t>("edge_k")};
    const double h = 2.0 / 16.0;
    REQUIRE(est.size() > 500);
    std::size_t checked = 0;
    for (std::size_t v = 0; v < est.size(); ++v) {
        const int ax = axis[v];
        const double xi = -1.0 + h * (*lower[ax])[v], xj = xi + h;
        const double rhoH2 = h * h / std::fabs(xi + xj);
        // Data rounding (float samples, differences of values near 0.5) allows ~1e-5 relative.
        CHECK(bound[v] == Approx(rhoH2).epsilon(1e-4));
        CHECK(est[v] == Approx(rhoH2 * t[v] * (1.0 - t[v])).epsilon(1e-4).margin(1e-9));
        ++checked;
    }
    CHECK(checked == est.size());
}

TEST_CASE("Nodes: threshold by percentile is numpy's linear percentile", "[nodes][threshold]")
{
    // err_est = 0, 1, ..., 99: the 90th percentile is at rank 0.9 * 99 = 89.1, value 89.1, so
    // exactly the ten values 90..99 are above; by value 50, the 49 values 51..99 (strictly above).
    auto mesh = std::make_shared<MeshData>();
    mesh->mesh.positions.resize(100);
    auto& e = mesh->mesh.vertexAttributes.add<float>("err_est", 100);
    for (int v = 0; v < 100; ++v) e[std::size_t(v)] = float(v);
    NodeValue in;
    in.mesh = mesh;
    SECTION("percentile")
    {
        const NodeValue out = cook("threshold", {{"mode", "percentile"}, {"percentile", 90}}, {{"mesh", &in}}, "cdf");
        CHECK(out.json["threshold"].get<double>() == Approx(89.1).epsilon(1e-12));
        CHECK(out.json["above"] == 10);
    }
    SECTION("value")
    {
        const NodeValue out = cook("threshold", {{"mode", "value"}, {"value", 50.0}}, {{"mesh", &in}});
        const auto& above = *out.mesh->mesh.vertexAttributes.find<std::uint8_t>("above");
        for (int v = 0; v < 100; ++v) CHECK(above[std::size_t(v)] == (v > 50));
    }
}

TEST_CASE("Graph: errors name the node and the parameter", "[nodes][graph]")
{
    const nlohmann::json read = {{"id", "read"}, {"type", "read_volume"}, {"parms", {{"resolution", 1}}}};
    try {
        parseGraph({{"nodes", {read}}});
        FAIL("accepted a resolution outside its hard range");
    } catch (const GraphError& e) {
        CHECK(std::string(e.what()) ==
              "node 'read' (read_volume): parameter 'resolution': 1 is outside the hard range [2, 4096]");
    }
}

TEST_CASE("Graph: a write staged before a failing node leaves no file", "[nodes][graph][atomic]")
{
    // runGraph stages a write while later nodes cook (Graph.h); a later failure must remove its
    // temporary file, whether the write finished, is under way (2 threads) or never ran (1).
    const isouq_test::TempDir tmp;
    const std::filesystem::path& dir = tmp.path;
    const std::string ply = (dir / "sphere.ply").string();
    const nlohmann::json doc = {{"nodes",
        {{{"id", "read"}, {"type", "read_volume"}, {"parms", {{"input", "field:sphere"}, {"resolution", 160}}}},
            {{"id", "mesh"}, {"type", "mesh"}, {"parms", {{"linear_only", true}}}, {"inputs", {{"volume", "read"}}}},
            {{"id", "save"}, {"type", "write_ply"}, {"parms", {{"path", ply}}}, {"inputs", {{"mesh", "mesh"}}}},
            {{"id", "cmp"}, {"type", "compare"}, {"inputs", {{"mesh", "mesh"}}}}}}};
    const Graph graph = parseGraph(doc);
    for (const int threads : {1, 2}) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        INFO(threads << " threads");
        try {
            runGraph(graph);
            FAIL("compared a method a linear-only mesh does not have");
        } catch (const InputError& e) {
            CHECK(std::string(e.what()).find("node 'cmp' (compare)") != std::string::npos);
        }
        CHECK(std::filesystem::is_empty(dir));
    }
    // Without the failing node the file is written, the same with 1 and 2 threads.
    const nlohmann::json fine = {{"nodes", {doc["nodes"][0], doc["nodes"][1], doc["nodes"][2]}}};
    std::string bytes[2];
    for (const int threads : {1, 2}) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        CHECK(runGraph(parseGraph(fine)).written == std::vector<std::string>{ply});
        std::ifstream in(ply, std::ios::binary);
        bytes[threads - 1].assign(std::istreambuf_iterator<char>(in), {});
    }
    CHECK(bytes[0].size() > 100000);
    CHECK(bytes[0] == bytes[1]);
}
