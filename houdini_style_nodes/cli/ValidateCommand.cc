// isouq CLI: `isouq validate` — the paper's Figs. 3 and 4 as tables and plots (SPEC §3, §5;
// docs/validation.md). The numbers come from isouq/Validation.h; this file only runs the
// cases and writes them as JSON, CSV and Markdown, then calls plot_validation.py (Resources.h).
#include "ValidateCommand.h"

#include <isouq/Columns.h>
#include <isouq/Errors.h>
#include <isouq/MarchingCubes.h>
#include <isouq/MeshIO.h>
#include <isouq/Validation.h>
#include <isouq/VolumeSources.h>
#include <isouq/nodes/Resources.h>

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <map>
#include <sstream>

namespace isouq::cli {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

/// Per-vertex columns whose max / mean / RMS the tables list, in table order.
const std::string_view kStatColumns[] = {col::kErrTrueLinear, col::kDistTrueLinear, col::kDistMetroLinear,
    col::kErrEst, col::kErrBound, col::kErrBest, col::kErrBestSurface, col::kErrTrueCubic, col::kDistTrueCubic,
    col::kErrEstCubic, col::kErrTrueWeno, col::kDistTrueWeno, col::kErrEstWeno, col::kErrTrueWenoPaper,
    col::kDistTrueWenoPaper, col::kDistTrue, col::kDLc, col::kDLw, col::kDCw};

/// Estimate against measured error: the comparisons of the paper's Fig. 4 and issue 3.
const std::pair<std::string_view, std::string_view> kComparisons[] = {
    {col::kErrEst, col::kErrTrueLinear}, {col::kErrBound, col::kErrTrueLinear},
    {col::kErrEst, col::kDistTrueLinear}, {col::kErrBound, col::kDistTrueLinear},
    {col::kErrBest, col::kErrTrueLinear}, {col::kErrBestSurface, col::kDistTrueLinear},
    {col::kErrEstCubic, col::kErrTrueCubic}, {col::kErrEstWeno, col::kErrTrueWeno},
    {col::kDistMetroLinear, col::kDistTrueLinear}};

struct Scan {
    const char* name;
    const char* file;
    float isovalue;
    const char* isovalueNote;
    openvdb::Vec3d spacing;
};
const Scan kScans[] = {{"fuel", "fuel_64x64x64_uint8.raw", 62.0f, "Otsu", {1, 1, 1}},
    {"engine", "engine_256x256x128_uint8.raw", 71.0f, "Otsu", {1, 1, 1}},
    {"skull", "skull_64x64x64_float32.raw", 2.9f, "documented", {3.943050, 3.943050, 3.650790}}};

std::string sci(double v, int digits = 3)
{
    std::ostringstream os;
    os << std::setprecision(digits) << v;
    return os.str();
}

json statsJson(const ErrorStats& s) { return {{"max", s.max}, {"mean", s.mean}, {"rms", s.rms}, {"count", s.count}}; }

void writeText(const fs::path& path, const std::string& text)
{
    std::ofstream out(path);
    out << text;
    if (!out) throw std::runtime_error("cannot write " + path.string());
}

double seconds(std::chrono::steady_clock::time_point since)
{
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

/// The source tree, for the default data folder (../shared/data beside it): the first ancestor
/// of the executable or of the working directory that holds scripts/plot_validation.py.
fs::path sourceRoot()
{
    std::error_code ec;
    for (fs::path start : {fs::read_symlink("/proc/self/exe", ec).parent_path(), fs::current_path(ec)}) {
        for (fs::path p = start; !p.empty(); p = p.parent_path()) {
            if (fs::exists(p / "scripts" / "plot_validation.py", ec)) return p;
            if (p == p.parent_path()) break;
        }
    }
    return {};
}

struct Options {
    std::string outDir = "docs/validation";
    std::string meshDir;
    std::string dataDir;
    bool quick = false;
    bool plots = true;
};

json runCases(const Options& o, std::ostringstream& md, std::ostringstream& statsCsv, std::ostringstream& agreeCsv)
{
    json cases = json::array();
    statsCsv << "field,resolution,isovalue,measure,max,mean,rms,count\n";
    agreeCsv << "field,resolution,estimate,measured,rms_ratio,spearman,count\n";
    std::ostringstream statsMd, agreeMd;
    statsMd << "| field | N | measure | max | mean | RMS |\n|---|---|---|---|---|---|\n";
    agreeMd << "| field | N | estimate | measured | RMS ratio | Spearman |\n|---|---|---|---|---|---|\n";
    for (ValidationCase spec : paperCases()) {
        if (o.quick) spec.referenceResolution = 4 * spec.resolution;
        const auto start = std::chrono::steady_clock::now();
        const ValidationResult r = runValidationCase(spec);
        std::fprintf(stderr, "isouq validate: %s %d^3: %zu vertices (%.1f s)\n", spec.field.c_str(),
            spec.resolution, r.mesh.positions.size(), seconds(start));
        json c = {{"field", spec.field}, {"resolution", spec.resolution}, {"isovalue", r.isovalue},
            {"reference_resolution", spec.referenceResolution}, {"reference_triangles", r.referenceTriangles},
            {"vertices", r.mesh.positions.size()}, {"triangles", r.mesh.triangles.size()},
            {"multi_root_edges", r.truth.multiRootEdges}, {"no_root_edges", r.truth.noRootEdges},
            {"failed_projections", r.truth.failedProjections}};
        for (const std::string_view column : kStatColumns) {
            const auto* values = r.mesh.vertexAttributes.find<float>(column);
            if (!values) continue;
            const ErrorStats s = errorStats(*values);
            c["stats"][std::string(column)] = statsJson(s);
            statsCsv << spec.field << ',' << spec.resolution << ',' << r.isovalue << ',' << column << ','
                     << sci(s.max, 6) << ',' << sci(s.mean, 6) << ',' << sci(s.rms, 6) << ',' << s.count << '\n';
            statsMd << "| " << spec.field << " | " << spec.resolution << " | `" << column << "` | "
                    << sci(s.max) << " | " << sci(s.mean) << " | " << sci(s.rms) << " |\n";
        }
        for (const auto& [estimate, measured] : kComparisons) {
            const auto* a = r.mesh.vertexAttributes.find<float>(estimate);
            const auto* b = r.mesh.vertexAttributes.find<float>(measured);
            if (!a || !b) continue;
            const Agreement g = compareColumns(*a, *b);
            c["agreement"].push_back({{"estimate", std::string(estimate)}, {"measured", std::string(measured)},
                {"rms_ratio", g.rmsRatio}, {"spearman", g.spearman}, {"count", g.count}});
            agreeCsv << spec.field << ',' << spec.resolution << ',' << estimate << ',' << measured << ','
                     << sci(g.rmsRatio, 6) << ',' << sci(g.spearman, 6) << ',' << g.count << '\n';
            agreeMd << "| " << spec.field << " | " << spec.resolution << " | `" << estimate << "` | `"
                    << measured << "` | " << sci(g.rmsRatio) << " | " << sci(g.spearman) << " |\n";
        }
        if (!o.meshDir.empty()) {
            const fs::path ply = fs::path(o.meshDir) / (spec.field + "_" + std::to_string(spec.resolution) + ".ply");
            PlyOptions options;
            options.isovalue = r.isovalue;
            options.method = "weno";
            writePly(r.mesh, ply.string(), options);
            c["mesh"] = fs::absolute(ply).string();
        }
        cases.push_back(c);
    }
    md << "## Measured errors and estimates (paper Figs. 3-4)\n\n" << statsMd.str()
       << "\n## Estimates against measured errors\n\n" << agreeMd.str();
    return cases;
}

json runConvergence(const Options& o, std::ostringstream& md, std::ostringstream& csv)
{
    const std::vector<int> sizes = o.quick ? std::vector<int>{32, 64, 128} : std::vector<int>{32, 64, 128, 256};
    const char* const fields[] = {"tangle", "torus", "torus-paper", "marschner-lobb", "teardrop", "tubey", "sphere"};
    json rows;
    csv << "field,resolution,spacing,edges,source,method,rms,order\n";
    md << "\n## Convergence (interior edges: full six-point stencil)\n\n"
       << "RMS edge-crossing error; in brackets the observed order log(RMS(h1)/RMS(h2)) / log(h1/h2); "
          "**bold**: the least-squares order over all resolutions. "
          "`mesher`: the mesh's float t columns; `exact`: the same interpolators in double on the "
          "analytic samples.\n\n"
       << "| field | N | edges | source | linear | cubic | weno | weno-paper |\n|---|---|---|---|---|---|---|---|\n";
    for (const char* field : fields) {
        std::vector<ConvergenceRow> list;
        for (int n : sizes) {
            const auto start = std::chrono::steady_clock::now();
            list.push_back(convergenceRow(field, n));
            std::fprintf(stderr, "isouq validate: convergence %s %d^3 (%.1f s)\n", field, n, seconds(start));
        }
        json fitted;
        for (int source = 0; source < 2; ++source) {
            const char* sourceName = source ? "exact" : "mesher";
            md << "| " << field << " | fit " << list.front().resolution << ".." << list.back().resolution
               << " | | " << sourceName;
            for (int m = 0; m < 4; ++m) {
                std::vector<double> errors, spacings;
                for (const ConvergenceRow& row : list) {
                    errors.push_back(source ? row.exact[m] : row.mesher[m]);
                    spacings.push_back(row.spacing);
                }
                const double order = fittedOrder(errors, spacings);
                fitted[sourceName][std::string(columnSuffix(kAllMethods[m]))] = order;
                md << " | **" << sci(order) << "**";
            }
            md << " |\n";
        }
        for (std::size_t i = 0; i < list.size(); ++i) {
            const ConvergenceRow& row = list[i];
            json jr = {{"field", row.field}, {"resolution", row.resolution}, {"spacing", row.spacing}, {"edges", row.edges}};
            for (int source = 0; source < 2; ++source) {
                const auto& rms = source ? row.exact : row.mesher;
                const char* sourceName = source ? "exact" : "mesher";
                md << "| " << row.field << " | " << row.resolution << " | " << row.edges << " | " << sourceName;
                for (int m = 0; m < 4; ++m) {
                    double order = std::nan("");
                    if (i > 0) {
                        const auto& prev = source ? list[i - 1].exact : list[i - 1].mesher;
                        order = observedOrder(prev[m], list[i - 1].spacing, rms[m], row.spacing);
                    }
                    jr[sourceName][std::string(columnSuffix(kAllMethods[m]))] = {{"rms", rms[m]}, {"order", i > 0 ? json(order) : json(nullptr)}};
                    csv << row.field << ',' << row.resolution << ',' << sci(row.spacing, 8) << ',' << row.edges << ','
                        << sourceName << ',' << std::string(columnSuffix(kAllMethods[m])) << ',' << sci(rms[m], 6) << ','
                        << (i > 0 ? sci(order, 4) : "") << '\n';
                    md << " | " << sci(rms[m]) << (i > 0 ? " (" + sci(order, 3) + ")" : "");
                }
                md << " |\n";
            }
            rows["rows"].push_back(jr);
        }
        rows["fitted"][field] = fitted;
    }
    return rows;
}

json runScans(const Options& o, std::ostringstream& md, std::ostringstream& csv)
{
    json scans = json::array();
    csv << "scan,isovalue,measure,max,mean,rms,count\n";
    md << "\n## Scans: estimate e against the methods' differences\n\n"
       << "| scan | k | vertices | RMS e | RMS d_lc | RMS d_lw | RMS d_cw | RMS d_lw / RMS e | Spearman(e, d_lw) |\n"
       << "|---|---|---|---|---|---|---|---|---|\n";
    for (const Scan& scan : kScans) {
        const fs::path path = fs::path(o.dataDir) / scan.file;
        if (!fs::exists(path)) {
            std::fprintf(stderr, "isouq validate: skipping %s (no %s; set --data-dir)\n", scan.name, path.c_str());
            continue;
        }
        VolumeRequest request;
        request.input = path.string();
        request.isovalue = scan.isovalue;
        request.spacing = scan.spacing;
        const LoadedVolume volume = loadVolume(request);
        MeshSettings settings;
        settings.isovalue = volume.isovalue;
        settings.uncertainty = true;
        const Mesh mesh = extractIsosurface(*volume.grid, settings);
        json s = {{"scan", scan.name}, {"file", scan.file}, {"isovalue", scan.isovalue},
            {"isovalue_source", scan.isovalueNote}, {"vertices", mesh.positions.size()}};
        for (const std::string_view column : {col::kErrEst, col::kErrBound, col::kDLc, col::kDLw, col::kDCw}) {
            const ErrorStats st = errorStats(*mesh.vertexAttributes.find<float>(column));
            s["stats"][std::string(column)] = statsJson(st);
            csv << scan.name << ',' << scan.isovalue << ',' << column << ',' << sci(st.max, 6) << ','
                << sci(st.mean, 6) << ',' << sci(st.rms, 6) << ',' << st.count << '\n';
        }
        const Agreement g = compareColumns(*mesh.vertexAttributes.find<float>(col::kDLw),
            *mesh.vertexAttributes.find<float>(col::kErrEst));
        s["rms_d_lw_over_e"] = g.rmsRatio;
        s["spearman_e_d_lw"] = g.spearman;
        const auto rms = [&](std::string_view c) { return s["stats"][std::string(c)]["rms"].get<double>(); };
        md << "| " << scan.name << " | " << scan.isovalue << " (" << scan.isovalueNote << ") | "
           << mesh.positions.size() << " | " << sci(rms(col::kErrEst)) << " | " << sci(rms(col::kDLc)) << " | "
           << sci(rms(col::kDLw)) << " | " << sci(rms(col::kDCw)) << " | " << sci(g.rmsRatio) << " | "
           << sci(g.spearman) << " |\n";
        scans.push_back(s);
    }
    return scans;
}

int runValidate(const Options& o)
{
    fs::create_directories(o.outDir);
    if (!o.meshDir.empty()) fs::create_directories(o.meshDir);
    std::ostringstream md, statsCsv, agreeCsv, convCsv, scanCsv;
    md << "<!-- generated by `isouq validate" << (o.quick ? " --quick" : "")
       << "`; see docs/validation.md -->\n# isouq validate: tables\n\n";
    json report;
    report["quick"] = o.quick;
    report["cases"] = runCases(o, md, statsCsv, agreeCsv);
    report["convergence"] = runConvergence(o, md, convCsv);
    report["scans"] = runScans(o, md, scanCsv);
    const fs::path out(o.outDir);
    writeText(out / "validation.json", report.dump(1) + "\n");
    writeText(out / "tables.md", md.str());
    writeText(out / "stats.csv", statsCsv.str());
    writeText(out / "agreement.csv", agreeCsv.str());
    writeText(out / "convergence.csv", convCsv.str());
    writeText(out / "scans.csv", scanCsv.str());
    std::printf("wrote %s/{validation.json,tables.md,stats.csv,agreement.csv,convergence.csv,scans.csv}\n",
        isouq::oneLine(o.outDir, std::string::npos).c_str());

    const std::string script = nodes::resourcePath("plot_validation.py").string();
    const std::string command = "/usr/bin/python3 '" + script + "' '" + (out / "validation.json").string() + "'";
    if (!o.plots) {
        std::printf("plots: %s\n", command.c_str());
    } else if (fs::exists("/usr/bin/python3") && fs::exists(script)
        && std::system("/usr/bin/python3 -c 'import matplotlib' 2>/dev/null") == 0) {
        if (std::system(command.c_str()) != 0) std::fprintf(stderr, "isouq validate: plotting failed: %s\n", command.c_str());
    } else {
        std::printf("no python3 with matplotlib; for the plots run: %s\n", command.c_str());
    }
    return 0;
}

} // namespace

void addValidateCommand(CLI::App& app, int& exitStatus)
{
    auto options = std::make_shared<Options>();
    if (const char* data = std::getenv("ISOUQ_DATA_DIR")) options->dataDir = data;
    else if (const fs::path root = sourceRoot(); !root.empty())
        options->dataDir = (root.parent_path() / "shared" / "data").string();
    options->meshDir = (fs::temp_directory_path() / "isouq-validate").string();
    CLI::App* validate = app.add_subcommand("validate",
        "Reproduce the paper's accuracy study (Figs. 3, 4): measured errors against e and e_b on "
        "the synthetic fields, convergence orders, and the scans");
    validate->add_option("--out-dir,-d", options->outDir, "Folder for tables (JSON, CSV, Markdown) and plots")
        ->capture_default_str();
    validate->add_flag("--quick", options->quick, "Smaller run: METRO reference at 4x, convergence up to 128^3");
    validate->add_option("--data-dir", options->dataDir, "Folder of the scans (fuel, engine, skull)")
        ->capture_default_str();
    validate->add_option("--mesh-dir", options->meshDir,
        "Folder for the validated meshes (PLY with every column; the plots read them)")->capture_default_str();
    validate->add_flag("!--no-plots", options->plots, "Do not run scripts/plot_validation.py; print its command");
    validate->callback([options, &exitStatus] {
        try {
            exitStatus = runValidate(*options);
        } catch (const std::exception& e) { // main.cc prints "isouq: error: ..." and exits 2
            throw CLI::RuntimeError(std::string("validate: ") + e.what(), 2);
        }
    });
}

} // namespace isouq::cli
