// isouq: a DICOM series, a folder of one series' slices, through GDCM (libgdcm; SPEC §10
// "Formats"; docs/inputs.md). Slices are sorted by their Image Position (Patient) along the
// normal of the Image Orientation (Patient); values are RescaleSlope * v + RescaleIntercept of
// each slice; world coordinates are DICOM's patient coordinates (LPS millimetres): column i
// along the row cosines times the column spacing, row j along the column cosines times the row
// spacing, slice k along the step between the first and the last positions.
#include "SourcesInternal.h"

#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmScanner.h>
#include <gdcmTrace.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <optional>
#include <set>
#include <vector>

namespace isouq::sources_internal {
namespace {

namespace fs = std::filesystem;

using Vec3 = openvdb::Vec3d;

std::optional<SampleType> sampleTypeOf(const gdcm::PixelFormat& format)
{
    switch (format.GetScalarType()) {
    case gdcm::PixelFormat::UINT8: return SampleType::UInt8;
    case gdcm::PixelFormat::INT8: return SampleType::Int8;
    case gdcm::PixelFormat::UINT12:
    case gdcm::PixelFormat::UINT16: return SampleType::UInt16;
    case gdcm::PixelFormat::INT12:
    case gdcm::PixelFormat::INT16: return SampleType::Int16;
    case gdcm::PixelFormat::UINT32: return SampleType::UInt32;
    case gdcm::PixelFormat::INT32: return SampleType::Int32;
    case gdcm::PixelFormat::FLOAT32: return SampleType::Float32;
    case gdcm::PixelFormat::FLOAT64: return SampleType::Float64;
    default: return std::nullopt;
    }
}

/// What isouq needs of one slice's header.
struct Slice {
    std::string file;
    unsigned columns = 0, rows = 0;
    SampleType type = SampleType::UInt16;
    Vec3 position, rowCosines, columnCosines;
    double columnSpacing = 1, rowSpacing = 1;
    double along = 0; ///< position along the slice normal
};

/// The slice's image (GDCM decodes any compressed transfer syntax it supports).
/// @throw InputError naming the file.
void readImage(gdcm::ImageReader& reader, const std::string& file)
{
    reader.SetFileName(file.c_str());
    if (!reader.Read()) throw InputError("'" + file + "' is not a readable DICOM image");
}

/// GDCM reads a file cut inside its native Pixel Data (7FE0,0010) without an error (the value
/// keeps its declared length), so the file must hold the whole encoded data set: the file meta
/// information with its preamble (GetFullLength), then every element of the data set.
void checkWholeFile(const gdcm::ImageReader& reader, const std::string& file)
{
    const gdcm::File& f = reader.GetFile();
    const gdcm::DataSet& ds = f.GetDataSet();
    if (!ds.GetDataElement(gdcm::Tag(0x7fe0, 0x0010)).GetByteValue()) return; // encapsulated: decoder checks
    const bool implicit = f.GetHeader().GetDataSetTransferSyntax().IsImplicit();
    const std::uint64_t length = implicit ? std::uint64_t(ds.GetLength<gdcm::ImplicitDataElement>())
                                          : std::uint64_t(ds.GetLength<gdcm::ExplicitDataElement>());
    const std::uint64_t expected = std::uint64_t(f.GetHeader().GetFullLength()) + length;
    std::error_code ec;
    const std::uint64_t size = fs::file_size(file, ec);
    if (!ec && size < expected) {
        throw InputError("'" + file + "' is truncated: its elements need " + std::to_string(expected)
            + " bytes, the file has " + std::to_string(size));
    }
}

Slice readSlice(const std::string& file)
{
    gdcm::ImageReader reader;
    readImage(reader, file);
    checkWholeFile(reader, file);
    const gdcm::Image& image = reader.GetImage();
    Slice s;
    s.file = file;
    if (image.GetNumberOfDimensions() != 2 && !(image.GetNumberOfDimensions() == 3 && image.GetDimension(2) == 1))
        throw InputError("'" + file + "' is a multi-frame image; isouq reads a series of single-frame slices");
    if (image.GetPixelFormat().GetSamplesPerPixel() != 1)
        throw InputError("'" + file + "' has " + std::to_string(image.GetPixelFormat().GetSamplesPerPixel())
            + " samples per pixel; isouq reads grey (MONOCHROME) images");
    const std::optional<SampleType> type = sampleTypeOf(image.GetPixelFormat());
    if (!type) {
        throw InputError("'" + file + "' has pixels of type " + image.GetPixelFormat().GetScalarTypeAsString()
            + "; isouq reads 8, 12, 16 and 32-bit integers and 32 or 64-bit floats");
    }
    s.type = *type;
    s.columns = image.GetDimension(0);
    s.rows = image.GetDimension(1);
    const double* origin = image.GetOrigin();
    const double* cosines = image.GetDirectionCosines();
    const double* spacing = image.GetSpacing();
    s.position = Vec3(origin[0], origin[1], origin[2]);
    s.rowCosines = Vec3(cosines[0], cosines[1], cosines[2]);
    s.columnCosines = Vec3(cosines[3], cosines[4], cosines[5]);
    s.columnSpacing = spacing[0]; // between columns (x), the second PixelSpacing value
    s.rowSpacing = spacing[1];
    return s;
}

class DicomSlices : public SliceSource {
public:
    explicit DicomSlices(std::vector<Slice> slices) : mSlices(std::move(slices))
    {
        dims = Coord(int(mSlices[0].columns), int(mSlices[0].rows), int(mSlices.size()));
    }

    void read(int z0, int count, float* out) override
    {
        const std::size_t slice = std::size_t(dims.x()) * dims.y();
        for (int z = z0; z < z0 + count; ++z) {
            gdcm::ImageReader reader;
            readImage(reader, mSlices[z].file);
            const gdcm::Image& image = reader.GetImage();
            const std::size_t bytes = slice * sampleBytes(mSlices[z].type);
            mBuffer.resize(image.GetBufferLength());
            if (mBuffer.size() < bytes || !image.GetBuffer(mBuffer.data()))
                throw InputError("cannot read the pixels of '" + mSlices[z].file + "' (truncated or unsupported encoding)");
            // GDCM gives the pixels in host byte order; each slice has its own rescale (PS3.3 C.11.1).
            decodeSamples(mBuffer.data(), slice, mSlices[z].type, __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__,
                image.GetSlope(), image.GetIntercept(), out + std::size_t(z - z0) * slice);
        }
    }

private:
    std::vector<Slice> mSlices;
    std::vector<char> mBuffer;
};

} // namespace

LoadedVolume loadDicom(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    const std::string& path = request.input;
    rejectRawFlags(request, "a DICOM series", false);
    gdcm::Trace::WarningOff();
    gdcm::Trace::ErrorOff();
    gdcm::Trace::DebugOff();
    // The folder's regular files (symlinks followed). Not gdcm::Directory: it stops listing at
    // the first entry that is neither a file nor a folder (a FIFO, a device), which would mesh
    // a shorter series, and a FIFO would block the reads below.
    std::vector<std::string> listed;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(path, ec))
        if (entry.is_regular_file(ec)) listed.push_back(entry.path().string());
    if (ec) throw InputError("cannot list the folder '" + path + "': " + ec.message());
    std::sort(listed.begin(), listed.end());
    // Group the DICOM files by Series Instance UID (0020,000E); other files are ignored.
    const gdcm::Tag seriesTag(0x0020, 0x000e);
    gdcm::Scanner scanner;
    scanner.AddTag(seriesTag);
    if (!scanner.Scan(listed)) throw InputError("cannot read the folder '" + path + "' as a DICOM series");
    // A file with the DICOM preamble that GDCM cannot parse is a damaged slice, not a stranger.
    const std::vector<std::string> keys = scanner.GetKeys();
    for (const std::string& file : listed) {
        if (std::find(keys.begin(), keys.end(), file) != keys.end()) continue;
        char head[132] = {};
        std::ifstream in(file, std::ios::binary);
        if (in.read(head, sizeof(head)) && std::string(head + 128, 4) == "DICM")
            throw InputError("'" + file + "' is a damaged DICOM file (truncated or corrupt)");
    }
    std::set<std::string> series;
    std::vector<std::string> files;
    for (const std::string& file : keys) {
        files.push_back(file);
        const char* uid = scanner.GetValue(file.c_str(), seriesTag);
        series.insert(uid ? uid : "");
    }
    if (files.empty())
        throw InputError("the folder '" + path + "' holds no TIFF slices and no DICOM files");
    if (series.size() > 1) {
        throw InputError("the folder '" + path + "' holds " + std::to_string(series.size())
            + " DICOM series; give a folder of one series");
    }
    if (files.size() < 2) throw InputError("the folder '" + path + "' holds one DICOM slice; a volume needs two or more");

    std::vector<Slice> slices;
    for (const std::string& file : files) slices.push_back(readSlice(file));
    const Slice& first = slices.front();
    const Vec3 normal = first.rowCosines.cross(first.columnCosines);
    if (!(std::fabs(normal.length() - 1.0) < 1e-3))
        throw InputError("'" + first.file + "' has no usable Image Orientation (Patient)");
    for (Slice& s : slices) {
        if (s.columns != first.columns || s.rows != first.rows || s.type != first.type) {
            throw InputError("'" + s.file + "' is " + std::to_string(s.columns) + "x" + std::to_string(s.rows) + " "
                + toString(s.type) + ", but '" + first.file + "' is " + std::to_string(first.columns) + "x"
                + std::to_string(first.rows) + " " + toString(first.type) + ": every slice of a series must match");
        }
        if ((s.rowCosines - first.rowCosines).length() > 1e-4 || (s.columnCosines - first.columnCosines).length() > 1e-4)
            throw InputError("'" + s.file + "' has another orientation than '" + first.file + "'");
        s.along = s.position.dot(normal);
    }
    std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.along < b.along; });
    // Evenly spaced slices only: the grid has one step (PS3.3 C.7.6.2.1.1).
    const double step = (slices.back().along - slices.front().along) / double(slices.size() - 1);
    if (!(step > 0.0)) throw InputError("the slices of '" + path + "' share one position");
    for (std::size_t k = 1; k < slices.size(); ++k) {
        const double gap = slices[k].along - slices[k - 1].along;
        if (std::fabs(gap - step) > 1e-3 * step + 1e-6) {
            throw InputError("the slices of '" + path + "' are not evenly spaced: " + fmt(gap) + " mm between '"
                + slices[k - 1].file + "' and '" + slices[k].file + "', " + fmt(step) + " on average");
        }
    }
    const Vec3 x = first.rowCosines * slices.front().columnSpacing, y = first.columnCosines * slices.front().rowSpacing;
    const Vec3 z = (slices.back().position - slices.front().position) / double(slices.size() - 1);
    const Vec3 o = slices.front().position;
    const std::array<double, 16> affine{x[0], y[0], z[0], o[0], x[1], y[1], z[1], o[1], x[2], y[2], z[2], o[2], 0, 0, 0, 1};
    const SampleType type = first.type;
    const std::size_t count = slices.size();
    DicomSlices source(std::move(slices));
    std::string name = fs::path(path).filename().string();
    if (name.empty()) name = fs::path(path).parent_path().filename().string();
    const std::string what = name + ": DICOM series of " + std::to_string(count) + " slices, " + toString(type);
    return loadScan(source, request, name, affine, "DICOM image position and orientation (LPS)", what, interrupter);
}

} // namespace isouq::sources_internal
