// The order statistics of a vertex column over MPI ranks (houdini_style_nodes/src/Pieces.h,
// orderStatisticsOnRanks; the colour map's percentiles, docs/mpi.md) against std::sort of the
// same finite values, on one rank: negatives, -0, subnormals, infinities and NaN, repeats, and
// every position. Several ranks' histograms add up; that, and the percentiles bit-equal to one
// process's, is checked through the CLI by mpi_color_np1..4 (tests/mpi/check_mpi.py).
#include "Pieces.h"

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace {

using isouq::nodes::Words;

/// One rank: every collective returns this rank's words.
class OneRank final : public isouq::nodes::Ranks {
public:
    int rank() const override { return 0; }
    int size() const override { return 1; }
    std::vector<Words> allgather(const Words& words) const override { return {words}; }
    void exchangeInto(const std::vector<Words>& out, std::vector<Words>& in) const override { in = out; }
    std::vector<Words> gather(const Words& words) const override { return {words}; }
    Words broadcast(const Words& words, int) const override { return words; }
    void send(const Words&, int) const override {}
    Words receive(int) const override { return {}; }
    std::unique_ptr<isouq::nodes::SharedFile> openShared(const std::string&, std::uint64_t, std::string&) const override
    {
        return nullptr;
    }
    bool interrupted() const override { return false; }
    std::unique_ptr<isouq::nodes::Ranks> split(int) const override { return std::make_unique<OneRank>(); }
};

} // namespace

TEST_CASE("orderStatisticsOnRanks: every position of the sorted finite values")
{
    const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
    std::vector<float> values = {0.0f, -0.0f, 1.0f, -1.0f, inf, -inf, nan, 1e-45f, -1e-45f,
        std::numeric_limits<float>::max(), -std::numeric_limits<float>::max(), 3.5f, 3.5f, 3.5f};
    std::mt19937 random(7);
    std::normal_distribution<float> normal(0.0f, 1e-3f);
    for (int i = 0; i < 2000; ++i) values.push_back(normal(random));
    std::vector<double> sorted;
    for (float v : values)
        if (std::isfinite(v)) sorted.push_back(v);
    std::sort(sorted.begin(), sorted.end());

    std::vector<std::uint64_t> ks(sorted.size());
    for (std::size_t k = 0; k < ks.size(); ++k) ks[k] = k;
    std::reverse(ks.begin(), ks.end()); // in any order
    const isouq::nodes::nodes_internal::ValuesOnRanks got =
        isouq::nodes::nodes_internal::orderStatisticsOnRanks(OneRank(), values, ks);
    CHECK(got.count == values.size());
    CHECK(got.finite == sorted.size());
    REQUIRE(got.kth.size() == ks.size());
    for (std::size_t i = 0; i < ks.size(); ++i) {
        INFO("k = " << ks[i]);
        CHECK(got.kth[i] == sorted[std::size_t(ks[i])]); // -0 == 0: either may be where the zeros are
    }
}

TEST_CASE("orderStatisticsOnRanks: no finite value")
{
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const isouq::nodes::nodes_internal::ValuesOnRanks got =
        isouq::nodes::nodes_internal::orderStatisticsOnRanks(OneRank(), {nan, nan}, {});
    CHECK(got.count == 2);
    CHECK(got.finite == 0);
    CHECK(got.kth.empty());
}
