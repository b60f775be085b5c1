// isouq nodes: frame sequences (Sequence.h; SPEC §10 "Sequences"; docs/sequences.md).
#include "isouq/nodes/Sequence.h"

#include "isouq/nodes/Graph.h"
#include "isouq/nodes/Ranks.h"
#include "isouq/nodes/Summary.h"

#include <isouq/Columns.h>
#include <isouq/MeshIO.h>
#include <isouq/VolumeSources.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <exception>
#include <filesystem>
#include <map>
#include <mutex>
#include <regex>
#include <set>
#include <thread>

namespace isouq::nodes {
namespace {

namespace fs = std::filesystem;

/// @a path with symlinks, "..", "." resolved, so two spellings of one file compare equal.
std::string resolvedPath(const std::string& path)
{
    std::error_code ec;
    const fs::path r = fs::weakly_canonical(fs::absolute(path), ec);
    return ec ? fs::absolute(path).lexically_normal().string() : r.string();
}

/// "5-7, 12" for {5, 6, 7, 12}.
std::string rangesText(const std::vector<int>& frames)
{
    std::string text;
    for (std::size_t i = 0; i < frames.size();) {
        std::size_t j = i;
        while (j + 1 < frames.size() && frames[j + 1] == frames[j] + 1) ++j;
        text += (text.empty() ? "" : ", ") + std::to_string(frames[i]) + (j > i ? "-" + std::to_string(frames[j]) : "");
        i = j + 1;
    }
    return text;
}

/// The frames of @a pattern that exist: file names prefix, digits (at least width; no extra
/// leading zeros), suffix.
std::set<int> framesOnDisk(const FramePattern& pattern)
{
    const fs::path first(pattern.path(0));
    const fs::path dir = first.parent_path().empty() ? fs::path(".") : first.parent_path();
    const std::string head = fs::path(pattern.prefix + "#").filename().string();
    const std::string stem = head.substr(0, head.size() - 1);
    std::set<int> frames;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir, ec)) {
        const std::string name = entry.path().filename().string();
        if (name.size() <= stem.size() + pattern.suffix.size() || name.compare(0, stem.size(), stem) != 0 ||
            name.compare(name.size() - pattern.suffix.size(), pattern.suffix.size(), pattern.suffix) != 0)
            continue;
        const std::string digits = name.substr(stem.size(), name.size() - stem.size() - pattern.suffix.size());
        if (digits.size() > 9 || int(digits.size()) < pattern.width ||
            !std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; }))
            continue;
        const int frame = std::stoi(digits);
        if (fs::path(pattern.path(frame)).filename() == name) frames.insert(frame);
    }
    return frames;
}

/// The per-frame entry of the sequence summary from a frame's mesh summary.
nlohmann::json frameEntry(int frame, const std::string& file, const std::string& output, const nlohmann::json& s)
{
    nlohmann::json e = {{"frame", frame}, {"file", file}, {"output", output}, {"vertices", s.at("vertices")},
        {"triangles", s.at("triangles")}, {"components", s.at("components")},
        {"boundary_edges", s.at("boundary_edges")}, {"empty", s.at("vertices").get<std::size_t>() == 0}};
    for (const ColumnInfo& c : columnTable())
        if (c.summary && s.contains(std::string(c.name))) e[std::string(c.name)] = s[std::string(c.name)];
    if (s.contains("grid")) e["grid"] = s["grid"]; // not for a frame kept by --resume
    if (s.contains("ranks")) e["ranks"] = s["ranks"]; // under MPI (SPEC §10 "MPI")
    if (s.contains("hidden"))
        e["hidden"] = {{"components_before", s["hidden"].at("components_before")},
            {"components_after", s["hidden"].at("components_after")}};
    return e;
}

/// The frames of a run and the missing ones (listed before any work), with every output
/// checked: none is an input or another output, each can be written; the output folders made.
struct FramePlan {
    std::vector<int> range, frames, missing;
};

FramePlan planFrames(const SequenceRequest& request, const FramePattern& in, const FramePattern& out,
    const std::optional<FramePattern>& hidden)
{
    const std::string inputPattern = request.frame.read.value("input", std::string());
    FramePlan plan;
    std::vector<int>& range = plan.range;
    std::vector<int>& frames = plan.frames;
    std::vector<int>& missing = plan.missing;
    // The frames, and the missing ones listed before any work.
    const std::set<int> onDisk = framesOnDisk(in);
    if (!request.frames.empty()) range = parseFrameRange(request.frames);
    else if (!onDisk.empty()) {
        if (*onDisk.rbegin() - *onDisk.begin() >= 1000000)
            throw InputError("'" + inputPattern + "': the frames on disk span " + std::to_string(*onDisk.begin()) + "-" +
                std::to_string(*onDisk.rbegin()) + ", more than a million; give --frames");
        for (int f = *onDisk.begin(); f <= *onDisk.rbegin(); ++f) range.push_back(f);
    }
    else throw InputError("no file matches '" + inputPattern + "'");
    for (int f : range) (fs::is_regular_file(in.path(f)) ? frames : missing).push_back(f);
    if (!missing.empty() && (!request.skipMissing || frames.empty()))
        throw InputError("'" + inputPattern + "': frame" + (missing.size() > 1 ? "s " : " ") + rangesText(missing) +
            " of " + std::to_string(range.front()) + "-" + std::to_string(range.back()) +
            (range.size() > 1 && range[1] - range[0] > 1 ? ":" + std::to_string(range[1] - range[0]) : "") + " missing (" +
            std::to_string(missing.size()) + " of " + std::to_string(range.size()) + ")" +
            (frames.empty() ? "" : "; --skip-missing meshes the others"));

    // No output of any frame may be an input of any frame (or what it reads, volumeInputFiles)
    // or another output: frame 1 of out_1### would replace input frame 1001 before it is read.
    std::map<std::string, std::string> inputs, outputs;
    for (int f : frames) {
        inputs.emplace(resolvedPath(in.path(f)), in.path(f));
        for (const std::string& file : volumeInputFiles(in.path(f))) inputs.emplace(resolvedPath(file), file);
    }
    auto addOutput = [&](const std::string& flag, const std::string& path) {
        const std::string r = resolvedPath(path);
        if (auto i = inputs.find(r); i != inputs.end())
            throw InputError(flag + " " + path + " is the input '" + i->second + "'; refusing to overwrite an input");
        if (auto [o, fresh] = outputs.emplace(r, path); !fresh)
            throw InputError(flag + " " + path + " is also the output '" + o->second + "'");
    };
    for (int f : frames) {
        addOutput("-o", out.path(f));
        if (hidden) addOutput("--hidden-out", hidden->path(f));
    }
    if (!request.frame.summaryPath.empty()) addOutput("--summary", request.frame.summaryPath);

    // Caches go to folders of their own: make the output folders (the summary's too), as
    // Blender and Houdini do.
    for (const std::string& path : {out.path(0), hidden ? hidden->path(0) : "", request.frame.summaryPath}) {
        std::error_code error;
        if (const fs::path folder = fs::path(path).parent_path(); !folder.empty() && !fs::create_directories(folder, error) && error)
            throw IoError("cannot write " + path + ": cannot make its folder " + folder.string() + ": " + error.message());
    }
    // Every output checked as one output is, before any frame is meshed: a FIFO there would
    // block --resume's read, a folder fail that frame after the frames before it.
    for (const auto& [resolved, path] : outputs) checkWritable(path);
    return plan;
}

/// Frames [next, count) in one process, or on ranks one at a time, each by every rank: @a jobs
/// threads (ranks: 1) take the next frame in turn; the first failure stops them and is rethrown.
void runFrameThreads(int jobs, std::size_t next, std::size_t count, const std::function<void(std::size_t)>& mesh)
{
    std::atomic<std::size_t> cursor{next};
    std::mutex mutex;
    std::exception_ptr failure;
    std::atomic<bool> failed{false};
    auto worker = [&] {
        for (std::size_t i; !failed && (i = cursor++) < count;) try {
                mesh(i);
            } catch (...) {
                std::lock_guard<std::mutex> lock(mutex);
                if (!failure) failure = std::current_exception();
                failed = true;
            }
    };
    std::vector<std::thread> workers;
    for (int j = 1; j < std::min<int>(jobs, int(count - std::min(next, count))); ++j) workers.emplace_back(worker);
    worker();
    for (std::thread& t : workers) t.join();
    if (failure) std::rethrow_exception(failure);
}

/// Frames [next, count) under MPI with @a jobs frame jobs (docs/mpi.md "Sequences"): the ranks
/// split into @a jobs groups (rank r in group r mod jobs, whose rank 0 is rank g), and in each
/// round group g meshes frame next + jobs k + g with @a mesh, which leaves its entry on the
/// group's rank 0. A round ends on every rank together (a failure or Ctrl-C in any group is one
/// on every rank); then rank 0 gathers the round's entries and warnings and @a report s them in
/// frame order.
void runFrameJobs(const Ranks& ranks, int jobs, std::size_t next, std::size_t count, std::vector<nlohmann::json>& entries,
    std::vector<std::string>* warnings, const std::function<void(std::size_t, const Ranks&)>& mesh,
    const std::function<void(std::size_t)>& report)
{
    const std::size_t g = std::size_t(ranks.rank() % jobs);
    const std::unique_ptr<Ranks> group = ranks.split(int(g));
    for (std::size_t round = next; round < count; round += std::size_t(jobs)) {
        const std::size_t i = round + g, before = warnings ? warnings->size() : 0;
        ranks.step([&] {
            if (i < count) mesh(i, *group);
        });
        nlohmann::json mine = nlohmann::json::object();
        if (ranks.rank() != 0 && group->rank() == 0 && i < count) {
            mine = {{"entry", entries[i]}, {"warnings", nlohmann::json::array()}};
            for (std::size_t w = before; warnings && w < warnings->size(); ++w) mine["warnings"].push_back((*warnings)[w]);
        }
        const std::vector<Words> all = ranks.gather(wordsOfText(mine.dump()));
        for (std::size_t j = 1; j < all.size() && j < std::size_t(jobs) && round + j < count; ++j) {
            const nlohmann::json theirs = nlohmann::json::parse(textOfWords(all[j]));
            entries[round + j] = theirs["entry"];
            if (warnings)
                for (const nlohmann::json& w : theirs["warnings"]) warnings->push_back(w.get<std::string>());
        }
        if (ranks.rank() == 0)
            for (std::size_t j = 0; j < std::size_t(jobs) && round + j < count; ++j) report(round + j);
    }
}

} // namespace

std::string FramePattern::path(int frame) const
{
    std::string digits = std::to_string(frame < 0 ? -frame : frame);
    if (int(digits.size()) < width) digits.insert(0, std::size_t(width) - digits.size(), '0');
    return prefix + (frame < 0 ? "-" : "") + digits + suffix;
}

std::optional<FramePattern> parseFramePattern(const std::string& path)
{
    const std::size_t slash = path.find_last_of('/');
    const std::size_t nameStart = slash == std::string::npos ? 0 : slash + 1;
    const std::string name = path.substr(nameStart);
    // The placeholders of @a text; "%%" is a literal % (printf), matched first so that "%%04d" is none.
    const auto placeholders = [](const std::string& text) {
        static const std::regex placeholder(R"(%%|#+|%(0?)([0-9]*)d)");
        std::vector<std::smatch> found;
        for (auto it = std::sregex_iterator(text.begin(), text.end(), placeholder); it != std::sregex_iterator(); ++it)
            if (it->str() != "%%") found.push_back(*it);
        return found;
    };
    const std::vector<std::smatch> inName = placeholders(name);
    if (inName.size() > 1)
        throw InputError("'" + path + "': two frame numbers (#### or %04d) in the file name; a sequence has one");
    if (inName.empty()) {
        const std::string folders = path.substr(0, nameStart);
        if (!placeholders(folders).empty())
            throw InputError("'" + path + "': the frame number (#### or %04d) must be in the file name, not a folder");
        return std::nullopt;
    }
    const std::smatch& last = inName.front();
    FramePattern p;
    p.prefix = path.substr(0, nameStart + std::size_t(last.position()));
    p.suffix = path.substr(nameStart + std::size_t(last.position() + last.length()));
    const std::string text = last.str();
    if (text[0] == '%') // a printf pattern: its "%%" are single % in the file names
        for (std::string* part : {&p.prefix, &p.suffix})
            for (std::size_t at = part->find("%%"); at != std::string::npos; at = part->find("%%", at + 1))
                part->erase(at, 1);
    p.width = text[0] == '#' ? int(text.size()) : last[2].length() > 2 ? 0 : last[2].length() ? std::stoi(last[2].str()) : 1;
    if (p.width < 1 || p.width > 9) throw InputError("'" + path + "': frame numbers are padded to 1-9 digits");
    return p;
}

std::vector<int> parseFrameRange(const std::string& text)
{
    static const std::regex form(R"(^([0-9]{1,9})(?:-([0-9]{1,9})(?::([0-9]{1,9}))?)?$)");
    std::smatch m;
    if (!std::regex_match(text, m, form))
        throw InputError("--frames '" + text + "': expected A, A-B or A-B:STEP (e.g. 1-240 or 1-240:2)");
    const int first = std::stoi(m[1].str()), last = m[2].matched ? std::stoi(m[2].str()) : first,
              step = m[3].matched ? std::stoi(m[3].str()) : 1;
    if (last < first) throw InputError("--frames '" + text + "': the last frame is before the first");
    if (step < 1) throw InputError("--frames '" + text + "': the step must be at least 1");
    if ((last - first) / step >= 1000000) throw InputError("--frames '" + text + "': more than a million frames");
    std::vector<int> frames;
    for (int f = first; f <= last; f += step) frames.push_back(f);
    return frames;
}

nlohmann::json runSequence(const SequenceRequest& request, openvdb::util::NullInterrupter* interrupter,
    const FrameCallback& onFrame, std::vector<std::string>* warnings, const Ranks* ranks)
{
    const auto start = std::chrono::steady_clock::now();
    const bool root = !ranks || ranks->rank() == 0;
    if (ranks && request.frameJobs > ranks->size())
        throw InputError("--frame-jobs " + std::to_string(request.frameJobs) + " with " + std::to_string(ranks->size()) +
            " MPI ranks: under MPI each frame job is a group of ranks, so at most one job a rank (docs/mpi.md)");
    // What rank 0 alone does on ranks (the checks and listings, reading back resumed frames, the
    // summary), agreed by every rank (Ranks::step): a failure there is an error on every rank.
    const auto onRoot = [&](const std::function<void()>& body) {
        if (ranks) ranks->step([&] { if (root) body(); });
        else body();
    };
    const std::string inputPattern = request.frame.read.value("input", std::string());
    const std::optional<FramePattern> in = parseFramePattern(inputPattern);
    if (!in) throw InputError("'" + inputPattern + "' is not a sequence (no #### or %04d in the file name)");
    const std::optional<FramePattern> out = parseFramePattern(request.frame.output);
    if (!out)
        throw InputError("-o " + request.frame.output + ": the output of a sequence needs a frame placeholder "
                         "too (#### or %04d), e.g. out/mesh.####.ply");
    std::optional<FramePattern> hidden;
    if (!request.frame.hiddenOutput.empty() && !(hidden = parseFramePattern(request.frame.hiddenOutput)))
        throw InputError("--hidden-out " + request.frame.hiddenOutput + ": needs a frame placeholder (####)");
    FramePlan plan;
    onRoot([&] { plan = planFrames(request, *in, *out, hidden); });
    const std::vector<int>& range = plan.range;     // rank 0's
    const std::vector<int>& missing = plan.missing; // rank 0's
    std::vector<int>& frames = plan.frames;
    if (ranks) { // rank 0's frames, on every rank
        Words words;
        for (int f : frames) words.push_back(std::uint64_t(std::int64_t(f)));
        frames.clear();
        for (std::uint64_t w : ranks->broadcast(words, 0)) frames.push_back(int(std::int64_t(w)));
    }

    MeshGraphRequest base = request.frame;
    base.read["allow_empty"] = true;
    base.summaryPath.clear();
    nlohmann::json isovalueSource = base.read.contains("isovalue") ? nlohmann::json("given") : nlohmann::json();

    // What a kept frame's PLY header must show of this run's settings: its isovalue (below), the
    // method, the encoding and the colour columns of --color-by. What the file does not record
    // (the grid, hidden-feature settings) is not compared (docs/sequences.md "Resuming").
    const auto given = [](const nlohmann::json& parms, const char* node, const char* token) {
        return parms.value(token, findNodeType(node)->findParm(token)->defaultValue.get<std::string>());
    };
    const std::string wantMethod =
        request.frame.mesh.value("linear_only", false) ? std::string("linear") : given(request.frame.mesh, "mesh", "method");
    const bool wantAscii = given(request.frame.write, "write_ply", "format") == "ascii";
    const bool wantColor = request.frame.color.contains("measure") && !request.frame.color["measure"].is_null();

    std::vector<nlohmann::json> entries(frames.size());
    std::mutex mutex;
    std::size_t done = 0;
    nlohmann::json method;
    // Meshes frame i on @a rk (every rank, or a frame job's group; or reads it back with
    // --resume) into entries[i] on rk's rank 0; returns its mesh summary's isovalue source,
    // isovalue and grid (none for a kept frame).
    auto runFrame = [&](std::size_t i, const MeshGraphRequest& with, const Ranks* rk) {
        const int f = frames[i];
        const bool lead = !rk || rk->rank() == 0;
        const auto onLead = [&](const std::function<void()>& body) {
            if (rk) rk->step([&] { if (lead) body(); });
            else body();
        };
        MeshGraphRequest r = with;
        r.read["input"] = in->path(f);
        r.output = out->path(f);
        r.hiddenOutput = hidden ? hidden->path(f) : "";
        nlohmann::json s = nlohmann::json::object(), entry; // s: rank 0's alone for a kept frame
        std::string source;
        // Outputs appear atomically, so one that reads back is complete (one that does not, a copy
        // cut short, is meshed again); it is kept if its header shows this run's settings.
        bool keep = false;
        if (request.resume) {
            onLead([&] {
                PlyInfo info;
                Mesh kept;
                if (fs::exists(r.output) && (r.hiddenOutput.empty() || fs::exists(r.hiddenOutput))) try {
                        kept = pathExtension(r.output) == ".vtp" ? readVtp(r.output, &info) : readPly(r.output, &info);
                    } catch (const IoError& e) {
                        info = PlyInfo();
                        std::lock_guard<std::mutex> lock(mutex);
                        if (warnings) warnings->push_back("frame " + std::to_string(f) + ": meshed again, as " + e.what());
                    }
                keep = info.isovalue &&
                    (!with.read.contains("isovalue") || float(with.read["isovalue"].get<double>()) == *info.isovalue) &&
                    info.method == wantMethod && (info.format == "ascii") == wantAscii &&
                    kept.vertexAttributes.has(col::kRed) == wantColor;
                if (!keep) return;
                s = summarizeMesh(kept);
                s["isovalue"] = *info.isovalue;
                std::lock_guard<std::mutex> lock(mutex);
                if (method.is_null()) method = info.method;
                // An empty frame's file holds the isovalue it was meshed at, not the run's: the
                // run's comes from the first frame with data (an empty first frame of a cache
                // made every later frame be meshed again at its 0).
                source = kept.vertexCount() == 0 ? "empty grid" : "resumed";
                entry = frameEntry(f, r.read["input"], r.output, s);
                entry["resumed"] = true;
            });
            if (rk) keep = rk->broadcast({std::uint64_t(keep)}, 0)[0] != 0;
        }
        if (!keep) {
            GraphResult result;
            // A frame that fails ends the run; the frames written so far stay (as after Ctrl-C).
            const auto failed = [&](const char* what) {
                return "frame " + std::to_string(f) + ": " + what + " (the frames finished before it are written; "
                    "--resume keeps them)";
            };
            try {
                result = runGraph(parseGraph(meshGraph(r)), interrupter, {}, rk);
            } catch (const IoError& e) {
                throw IoError(failed(e.what()));
            } catch (const InputError& e) {
                throw InputError(failed(e.what()));
            }
            s = result.outputs.at(kMeshGraphSummary).at("summary"); // on ranks other than 0, no counts
            source = s.value("isovalue_source", std::string());
            if (lead) entry = frameEntry(f, r.read["input"], r.output, s);
            std::lock_guard<std::mutex> lock(mutex);
            if (warnings)
                for (const std::string& w : result.warnings) warnings->push_back("frame " + std::to_string(f) + ": " + w);
            method = s.value("method", nlohmann::json());
        }
        {
            std::lock_guard<std::mutex> lock(mutex);
            entries[i] = entry;
        }
        auto outcome = std::make_tuple(source, s.value("isovalue", 0.0), s.value("grid", std::string()));
        if (rk) { // rank 0's, which alone reads a resumed frame back
            const nlohmann::json j = nlohmann::json::parse(textOfWords(rk->broadcast(
                wordsOfText(nlohmann::json::array({source, std::get<1>(outcome), std::get<2>(outcome)}).dump()), 0)));
            outcome = std::make_tuple(j[0].get<std::string>(), j[1].get<double>(), j[2].get<std::string>());
        }
        return outcome;
    };
    const auto report = [&](std::size_t i) {
        std::lock_guard<std::mutex> lock(mutex);
        if (onFrame && root) onFrame(++done, frames.size(), frames[i], entries[i]);
    };

    // One isovalue for every frame: given, or the default of the first frame that has data. One
    // grid for every frame of a .vdb cache: --grid, or the one the first frame meshed (its first
    // float grid), so that a frame whose grids come in another order meshes the same field.
    std::size_t next = 0;
    nlohmann::json isovalue = base.read.contains("isovalue") ? base.read["isovalue"] : nlohmann::json();
    bool findGrid = !base.read.contains("grid") && pathExtension(in->path(0)) == ".vdb";
    while ((isovalue.is_null() || findGrid) && next < frames.size()) {
        const auto [source, k, grid] = runFrame(next, base, ranks);
        report(next++);
        if (findGrid && !grid.empty()) {
            base.read["grid"] = grid;
            findGrid = false;
            if (warnings)
                warnings->push_back("grid '" + grid + "' (the first float grid of frame " + std::to_string(frames[next - 1]) +
                    ") for every frame; set it with --grid");
        }
        if (!isovalue.is_null() || source == "empty grid") continue;
        isovalue = k;
        isovalueSource = source + " of frame " + std::to_string(frames[next - 1]);
        base.read["isovalue"] = k;
        if (warnings)
            warnings->push_back("isovalue " + nlohmann::json(k).dump() + " (" + isovalueSource.get<std::string>() +
                ") for every frame; set it with --isovalue");
    }

    // The rest, frameJobs at a time; each frame is independent and uses every thread (rank).
    if (ranks && request.frameJobs > 1)
        runFrameJobs(*ranks, request.frameJobs, next, frames.size(), entries, warnings,
            [&](std::size_t i, const Ranks& group) { runFrame(i, base, &group); }, report);
    else
        runFrameThreads(request.frameJobs, next, frames.size(), [&](std::size_t i) {
            runFrame(i, base, ranks);
            report(i);
        });

    nlohmann::json summary = nlohmann::json::object(); // on ranks other than 0, empty
    onRoot([&] {
        nlohmann::json totals = {{"frames", frames.size()}, {"vertices", 0}, {"triangles", 0}, {"empty", 0},
            {"resumed", 0}, {"missing", missing}};
        for (const nlohmann::json& e : entries) {
            totals["vertices"] = totals["vertices"].get<std::size_t>() + e["vertices"].get<std::size_t>();
            totals["triangles"] = totals["triangles"].get<std::size_t>() + e["triangles"].get<std::size_t>();
            totals["empty"] = totals["empty"].get<int>() + int(e["empty"].get<bool>());
            totals["resumed"] = totals["resumed"].get<int>() + int(e.value("resumed", false));
        }
        summary = {{"frames", entries}, {"totals", totals}, {"isovalue", isovalue},
            {"isovalue_source", isovalueSource}, {"method", method},
            {"sequence", {{"input", inputPattern}, {"output", request.frame.output}, {"first", range.front()},
                             {"last", range.back()}, {"step", range.size() > 1 ? range[1] - range[0] : 1}}}};
        if (hidden) summary["sequence"]["hidden_output"] = request.frame.hiddenOutput;
        if (base.read.contains("grid")) summary["sequence"]["grid"] = base.read["grid"];
        summary["timings_ms"] = {{"total", std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count()}};
        if (!request.frame.summaryPath.empty()) writeTextFileAtomic(request.frame.summaryPath, summary.dump(2) + "\n");
    });
    return summary;
}

} // namespace isouq::nodes
