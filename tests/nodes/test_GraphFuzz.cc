// Graph inputs that the fuzzer (fuzz/fuzz_graph.cc, docs/hardening.md) found mishandled: each
// must now be a GraphError with one line, not another exception or a crash. The raw inputs are
// also in fuzz/regressions/fuzz_graph/, replayed by scripts/fuzz.sh.
#include <catch2/catch.hpp>

#include <isouq/nodes/Graph.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>

using namespace isouq::nodes;
namespace fs = std::filesystem;

namespace {

/// loadGraph on @a text written to a temporary file: the GraphError's message, or "" if it loads.
std::string loadError(const std::string& text)
{
    const fs::path path = fs::temp_directory_path() / ("isouq_graph_fuzz_" + std::to_string(::getpid()) + ".json");
    std::ofstream(path, std::ios::binary) << text;
    std::string message;
    try {
        loadGraph(path.string());
    } catch (const GraphError& e) {
        message = e.what();
    }
    fs::remove(path);
    return message;
}

} // namespace

TEST_CASE("GraphFuzz: a description that is not a string is a GraphError", "[nodes][graph][fuzz]")
{
    // Was nlohmann::json::type_error 302 from doc.value("description", "").
    for (const char* description : {"5", "null", "[]", "{}", "true"}) {
        const std::string message = loadError(std::string("{\"description\": ") + description + ", \"nodes\": []}");
        CHECK(message.find("\"description\" must be a string") != std::string::npos);
        CHECK(message.find('\n') == std::string::npos);
    }
    CHECK(loadError("{\"description\": \"fine\", \"nodes\": []}").empty());
}

TEST_CASE("GraphFuzz: a number too large for a double is a GraphError", "[nodes][graph][fuzz]")
{
    // Was nlohmann::json::out_of_range 406 ("number overflow parsing '1e999'"): loadGraph
    // caught only parse_error.
    for (const char* number : {"1e999", "-1e999", "1e400"}) {
        const std::string message = loadError(std::string("{\"nodes\": [], \"description\": ") + number + "}");
        CHECK(message.find("not valid JSON") != std::string::npos);
        CHECK(message.find('\n') == std::string::npos);
    }
}
