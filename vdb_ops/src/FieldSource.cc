// isouq: field:NAME (SPEC §5) and formula:EXPR (muParser) inputs, sampled on N^3 points.
#include "SourcesInternal.h"

#include "isouq/Bricks.h"

#include <muParser.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <regex>

namespace isouq {
namespace sources_internal {

/// N^3 samples of an analytic field at lo + i*h (the grid transform's exact index->world map).
/// A non-finite sample is an error naming the first one (SPEC §5 fields are finite).
class FieldSlices : public SliceSource {
public:
    FieldSlices(const AnalyticField& field, int n) : mField(field), mH(field.spacing(n))
    {
        dims = Coord(n);
    }

    double world(int i) const { return double(i) * mH + mField.lo; }

    void read(int z0, int count, float* out) override
    {
        const int nx = dims.x(), ny = dims.y();
        std::atomic<std::size_t> firstBad{std::numeric_limits<std::size_t>::max()};
        tbb::parallel_for(tbb::blocked_range<int>(0, ny * count), [&](const tbb::blocked_range<int>& r) {
            for (int row = r.begin(); row != r.end(); ++row) {
                const int y = row % ny, z = z0 + row / ny;
                float* dst = out + std::size_t(row) * nx;
                for (int x = 0; x < nx; ++x) {
                    const double v = mField(world(x), world(y), world(z));
                    dst[x] = float(v);
                    if (!std::isfinite(dst[x])) {
                        std::size_t bad = std::size_t(row) * nx + x, seen = firstBad.load();
                        while (bad < seen && !firstBad.compare_exchange_weak(seen, bad)) {}
                    }
                }
            }
        });
        if (firstBad.load() == std::numeric_limits<std::size_t>::max()) return;
        const std::size_t bad = firstBad.load();
        const int x = int(bad % nx), y = int(bad / nx % ny), z = z0 + int(bad / nx / ny);
        throw InputError(mField.name + " '" + mField.expression + "' is " + fmt(out[bad])
            + " (not finite) at x=" + fmt(world(x)) + " y=" + fmt(world(y)) + " z=" + fmt(world(z))
            + " (voxel " + std::to_string(x) + "," + std::to_string(y) + "," + std::to_string(z)
            + ") on [" + fmt(mField.lo) + ", " + fmt(mField.hi) + "]^3");
    }

private:
    const AnalyticField& mField;
    double mH;
};


std::optional<FieldInput> fieldInput(const VolumeRequest& request)
{
    const std::string& input = request.input;
    FieldInput out;
    if (input.rfind("field:", 0) == 0) {
        const std::string name = input.substr(6);
        const AnalyticField* field = findAnalyticField(name);
        if (!field) {
            std::string names;
            for (const AnalyticField& f : analyticFields()) names += (names.empty() ? "" : ", ") + f.name;
            throw InputError("unknown field '" + name + "'; fields: " + names);
        }
        out = {std::make_shared<AnalyticField>(*field), request.resolution.value_or(field->resolution), "SPEC §5 default"};
    } else if (input.rfind("formula:", 0) == 0) {
        const auto [lo, hi] = request.domain.value_or(std::make_pair(-1.0, 1.0));
        out = {makeFormulaField(input.substr(8), lo, hi), request.resolution.value_or(64), "formula default"};
    } else {
        return std::nullopt;
    }
    if (out.n < 2) throw InputError("--resolution must be at least 2, got " + std::to_string(out.n));
    if (out.n > std::numeric_limits<std::int32_t>::max() - kBlock) throw InputError("--resolution is too large");
    return out;
}

namespace {

/// The grid's name and transform, the source, the description and the truth of a field's volume.
void finishField(LoadedVolume& volume, const FieldInput& input, const VolumeRequest& request)
{
    const AnalyticField& field = *input.field;
    volume.isovalueSource = request.isovalue ? "given" : input.defaultSource;
    volume.grid->setName(field.name);
    auto transform = openvdb::math::Transform::createLinearTransform(field.spacing(input.n));
    transform->postTranslate(openvdb::Vec3d(field.lo));
    volume.grid->setTransform(transform);
    volume.description = field.name + " " + field.expression + " on [" + fmt(field.lo) + ", " + fmt(field.hi)
        + "]^3: " + volume.description;
    volume.truth = input.field;
}

} // namespace

LoadedVolume loadField(const FieldInput& input, const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    FieldSlices source(*input.field, input.n);
    checkLayersFit(source, request.input);
    LoadedVolume volume = buildDense(source, request, request.isovalue.value_or(float(input.field->isovalue)), interrupter);
    finishField(volume, input, request);
    return volume;
}

DensePiece loadFieldPiece(const FieldInput& input, const VolumeRequest& request, const PieceComm& comm,
    openvdb::util::NullInterrupter* interrupter)
{
    FieldSlices source(*input.field, input.n);
    checkLayersFit(source, request.input);
    const float isovalue = request.isovalue.value_or(float(input.field->isovalue));
    if (!std::isfinite(isovalue)) throw InputError("isovalue " + fmt(isovalue) + " is not finite");
    const int layers = (source.dims.z() + kBlock - 1) / kBlock;
    SparseResult sparse;
    comm.agree([&] {
        sparse = sparsify(source, request.keep, isovalue, interrupter, firstLayerOf(layers, comm.rank(), comm.size()),
            firstLayerOf(layers, comm.rank() + 1, comm.size()));
    });
    DensePiece piece = spreadLayers(std::move(sparse), source.dims, isovalue, comm);
    finishField(piece.volume, input, request);
    return piece;
}


/// One muParser per thread: parsers hold pointers to their x, y, z.
struct ParserSlot {
    explicit ParserSlot(const std::string& expression)
    {
        parser.DefineVar("x", &x);
        parser.DefineVar("y", &y);
        parser.DefineVar("z", &z);
        parser.SetExpr(expression);
    }
    mu::Parser parser;
    double x = 0.0, y = 0.0, z = 0.0;
};


} // namespace sources_internal

std::shared_ptr<const AnalyticField> makeFormulaField(const std::string& expression,
    double lo, double hi)
{
    using sources_internal::ParserSlot;
    if (!(std::isfinite(lo) && std::isfinite(hi) && lo < hi)) {
        throw InputError("--domain needs finite LO < HI, got " + sources_internal::fmt(lo) + ","
            + sources_internal::fmt(hi));
    }
    try {
        ParserSlot probe(expression);
        probe.parser.Eval(); // parses: syntax and unknown names fail here
    } catch (const mu::ParserError& e) {
        // muParser's message ends with its own 0-based "at position N"; say it once, 1-based.
        const std::string message = std::regex_replace(e.GetMsg(), std::regex(" at position [0-9]+\\.?$"), "");
        std::string where;
        if (e.GetPos() >= 0) {
            where = " at character " + std::to_string(std::min<std::size_t>(e.GetPos(), expression.size()) + 1)
                + (e.GetToken().empty() ? "" : " ('" + e.GetToken() + "')");
        }
        throw InputError("cannot parse formula '" + expression + "'" + where + ": " + message);
    }
    auto parsers = std::make_shared<tbb::enumerable_thread_specific<std::unique_ptr<ParserSlot>>>();
    auto field = std::make_shared<AnalyticField>();
    field->name = "formula";
    field->expression = expression;
    field->lo = lo;
    field->hi = hi;
    field->isovalue = 0.0;
    field->resolution = 64;
    field->f = [parsers, expression](double x, double y, double z) {
        std::unique_ptr<ParserSlot>& slot = parsers->local();
        if (!slot) slot = std::make_unique<ParserSlot>(expression);
        slot->x = x, slot->y = y, slot->z = z;
        return slot->parser.Eval();
    };
    return field;
}


} // namespace isouq
