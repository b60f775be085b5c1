// isouq: the module libisouq_gdcm.so, every GDCM call of the DICOM reader (GdcmServer.h). It
// runs in the reader's child process (Quarantine.h): Debian's GDCM aborts on some damaged files
// and writes past its buffers on others (the fuzz_dicom findings of 3 December 2026).
#include "GdcmServer.h"
#include "Quarantine.h"
#include "SourcesInternal.h"

#include <gdcmDirectionCosines.h>
#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmScanner.h>
#include <gdcmTrace.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <string>
#include <type_traits>
#include <vector>

namespace isouq::sources_internal {
namespace {

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

/// The slice's image (GDCM decodes any compressed transfer syntax it supports).
/// @throw InputError naming the file.
void readImage(gdcm::ImageReader& reader, const std::string& file)
{
    reader.SetFileName(file.c_str());
    if (!reader.Read()) throw InputError("'" + file + "' is not a readable DICOM image");
}

void putHeader(Message& reply, const std::string& file)
{
    gdcm::ImageReader reader;
    readImage(reader, file);
    const gdcm::Image& image = reader.GetImage();
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
    const double* spacing = image.GetSpacing(); // between columns (x), the second PixelSpacing value; rows
    reply.put(image.GetDimension(0)).put(image.GetDimension(1)).put(*type).put(spacing[0]).put(spacing[1]);
    const double* origin = image.GetOrigin();
    // GDCM puts the identity in place of an Image Orientation (Patient) that is not two orthonormal
    // directions (PS3.3 C.7.6.2.1.1): refuse it rather than mesh the scan in a made-up frame.
    const gdcm::DataSet& data = reader.GetFile().GetDataSet();
    const gdcm::Tag orientationTag(0x0020, 0x0037);
    const gdcm::ByteValue* stored =
        data.FindDataElement(orientationTag) ? data.GetDataElement(orientationTag).GetByteValue() : nullptr;
    if (stored) { // a DS value: decimal strings separated by backslashes
        const std::string text(stored->GetPointer(), stored->GetLength());
        std::vector<double> v;
        std::size_t at = 0;
        for (std::size_t end; v.size() < 7 && at <= text.size(); at = end + 1) {
            end = std::min(text.find('\\', at), text.size());
            v.push_back(std::strtod(text.substr(at, end - at).c_str(), nullptr));
        }
        if (v.size() == 6 && !gdcm::DirectionCosines(v.data()).IsValid()) {
            throw InputError("'" + file + "' has an Image Orientation (Patient) " + printedLine(text)
                + " whose row and column directions are not orthonormal (PS3.3 C.7.6.2.1.1)");
        }
    }
    const double* cosines = image.GetDirectionCosines(); // row cosines, then column cosines
    for (int i = 0; i < 3; ++i) reply.put(origin[i]);
    for (int i = 0; i < 6; ++i) reply.put(cosines[i]);
}

/// The answer to request @a code with its arguments @a request (GdcmServer.h).
Message serve(char code, Message& request)
{
    Message reply;
    switch (code) {
    case kScan: {
        std::vector<std::string> files(request.get<std::uint64_t>());
        for (std::string& file : files) file = request.getString();
        const gdcm::Tag seriesTag(0x0020, 0x000e);
        gdcm::Scanner scanner;
        scanner.AddTag(seriesTag);
        if (!scanner.Scan(files)) throw InputError("GDCM cannot scan the folder");
        for (const std::string& file : files) {
            const bool keyed = scanner.IsKey(file.c_str());
            const char* uid = keyed ? scanner.GetValue(file.c_str(), seriesTag) : nullptr;
            reply.put(char(keyed)).putString(uid ? uid : "");
        }
        return reply;
    }
    case kHeader: putHeader(reply, request.getString()); return reply;
    case kPixels: {
        const std::string file = request.getString();
        const auto bytes = request.get<std::uint64_t>();
        gdcm::ImageReader reader;
        readImage(reader, file);
        const gdcm::Image& image = reader.GetImage();
        std::vector<char> buffer(image.GetBufferLength());
        if (buffer.size() < bytes || !image.GetBuffer(buffer.data()))
            throw InputError("cannot read the pixels of '" + file + "' (truncated or unsupported encoding)");
        reply.put(image.GetSlope()).put(image.GetIntercept());
        return Message(reply.bytes() + std::string(buffer.data(), std::size_t(bytes)));
    }
    }
    throw InputError("unknown request");
}

/// @a text in a malloc'd buffer for the caller; false when out of memory.
bool handOver(const std::string& text, char** out, std::size_t* size)
{
    *out = static_cast<char*>(std::malloc(text.empty() ? 1 : text.size()));
    if (!*out) return false;
    std::memcpy(*out, text.data(), text.size());
    *size = text.size();
    return true;
}

} // namespace
} // namespace isouq::sources_internal

extern "C" __attribute__((visibility("default"))) int isouq_gdcm_serve_v1(const char* request, std::size_t size,
    char** reply, std::size_t* replySize)
{
    using namespace isouq::sources_internal;
    static_assert(std::is_same_v<decltype(&isouq_gdcm_serve_v1), GdcmServe>);
    *reply = nullptr;
    *replySize = 0;
    std::string error;
    try {
        gdcm::Trace::WarningOff();
        gdcm::Trace::ErrorOff();
        gdcm::Trace::DebugOff();
        if (size == 0) throw isouq::InputError("an empty request");
        Message arguments(std::string(request + 1, size - 1));
        if (handOver(serve(request[0], arguments).bytes(), reply, replySize)) return 0;
        error = "out of memory for GDCM's reply";
    } catch (const std::exception& e) {
        error = e.what();
    } catch (...) {
        error = "GDCM failed";
    }
    handOver(error, reply, replySize);
    return 1;
}
