// isouq: volume inputs (SPEC §5, §8; design and measurements in docs/inputs.md): INPUT to the
// source type that reads it.
#include "SourcesInternal.h"
#include "Stage.h"

#include <algorithm>
#include <cctype>
#include <filesystem>

namespace isouq {
namespace sources_internal {

namespace fs = std::filesystem;

std::uint64_t fileSize(const std::string& path)
{
    std::error_code ec;
    if (!fs::exists(path, ec)) throw InputError("cannot open '" + path + "': no such file");
    if (fs::is_directory(path, ec)) throw InputError("'" + path + "' is a directory, not a volume");
    if (!fs::is_regular_file(path, ec))
        throw InputError("cannot open '" + path + "': not a regular file (a device, FIFO or socket)");
    const std::uintmax_t size = fs::file_size(path, ec);
    if (ec) throw InputError("cannot open '" + path + "': " + ec.message());
    if (size == 0) throw InputError("'" + path + "' is empty");
    return size;
}


bool endsWith(const std::string& s, const std::string& suffix)
{
    return s.size() >= suffix.size()
        && std::equal(suffix.rbegin(), suffix.rend(), s.rbegin(),
            [](char a, char b) { return std::tolower(a) == std::tolower(b); });
}

ScanReader scanReaderOf(const std::string& input)
{
    if (endsWith(input, ".nii") || endsWith(input, ".nii.gz")) return readNifti;
    if (endsWith(input, ".nrrd") || endsWith(input, ".nhdr")) return readNrrd;
    if (endsWith(input, ".tif") || endsWith(input, ".tiff")) return readTiff;
    std::error_code ec;
    if (fs::is_directory(input, ec)) return isTiffFolder(input) ? readTiff : readDicom;
    return nullptr;
}

} // namespace sources_internal

namespace {

LoadedVolume loadSource(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    namespace si = sources_internal;
    const std::string& input = request.input;
    if (const std::optional<si::FieldInput> field = si::fieldInput(request)) return si::loadField(*field, request, interrupter);
    if (input.rfind("memory:", 0) == 0) return si::loadMemory(request, interrupter);
    if (si::endsWith(input, ".vdb")) return si::loadVdb(request);
    if (si::endsWith(input, ".raw")) return si::loadRaw(request, interrupter);
    if (const si::ScanReader read = si::scanReaderOf(input)) {
        return read(request, interrupter, [&](si::SliceSource& source, const si::ScanHeader& header) {
            DensePiece whole;
            whole.volume = si::loadScan(source, request, header, interrupter);
            return whole;
        }).volume;
    }
    si::fileSize(input); // a missing file says so first
    throw InputError("cannot tell what '" + input
        + "' is: expected a .vdb, .raw, .nii, .nii.gz, .nrrd, .nhdr, .tif or .tiff file, a folder of TIFF slices or of a DICOM series, field:NAME or formula:EXPR");
}

} // namespace

std::vector<std::string> volumeInputFiles(const std::string& input)
{
    namespace si = sources_internal;
    std::vector<std::string> files;
    std::error_code ec;
    try {
        if (si::endsWith(input, ".nrrd") || si::endsWith(input, ".nhdr")) files = si::nrrdDataFiles(input);
    } catch (const InputError&) {
    }
    if (std::filesystem::is_directory(input, ec))
        for (const auto& entry : std::filesystem::directory_iterator(input, ec))
            if (entry.is_regular_file(ec)) files.push_back(entry.path().string());
    return files;
}

LoadedVolume loadVolume(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    openvdb::initialize();
    const InterrupterStage stage(interrupter, "Loading volume");
    LoadedVolume volume = loadSource(request, interrupter);
    volume.input = request.input;
    return volume;
}

DensePiece loadDensePiece(const VolumeRequest& request, const PieceComm& comm, openvdb::util::NullInterrupter* interrupter)
{
    namespace si = sources_internal;
    openvdb::initialize();
    const InterrupterStage stage(interrupter, "Loading volume");
    DensePiece piece;
    if (const std::optional<si::FieldInput> field = si::fieldInput(request))
        piece = si::loadFieldPiece(*field, request, comm, interrupter);
    else if (si::endsWith(request.input, ".raw"))
        piece = si::loadRawPiece(request, comm, interrupter);
    else if (const si::ScanReader read = si::scanReaderOf(request.input))
        piece = read(request, interrupter, [&](si::SliceSource& source, const si::ScanHeader& header) {
            return si::loadScanPiece(source, request, header, comm, interrupter);
        });
    else
        throw InputError("INPUT '" + request.input + "' is not read by layers (a scan, field:NAME or formula:EXPR)");
    piece.volume.input = request.input;
    return piece;
}

bool isDensePieceInput(const std::string& input)
{
    return input.rfind("field:", 0) == 0 || input.rfind("formula:", 0) == 0 || sources_internal::endsWith(input, ".raw")
        || sources_internal::scanReaderOf(input);
}

} // namespace isouq
