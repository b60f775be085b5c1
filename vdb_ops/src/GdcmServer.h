// isouq (internal): GDCM's half of the DICOM reader (DicomSource.cc) lives in a module of its
// own, libisouq_gdcm.so (GdcmServer.cc), loaded the first time a series is read: GDCM builds
// its data dictionary when it is loaded (about 50 ms), which every start of the CLI, of the
// Python module and of Blender's add-on paid before (docs/hardening.md "Quarantine").
#pragma once

#include <cstddef>

namespace isouq::sources_internal {

/// The requests, each a Message (Quarantine.h) of this code and its arguments, and the replies:
/// - kScan, file count, files -> per file: parsed by gdcm::Scanner (char 0/1), Series Instance UID;
/// - kHeader, file -> columns, rows (unsigned), SampleType, column and row spacing, Image
///   Position (Patient), row cosines, column cosines (doubles);
/// - kPixels, file, bytes (uint64) -> RescaleSlope, RescaleIntercept, the samples in host order.
enum GdcmRequest : char { kScan = 'S', kHeader = 'H', kPixels = 'P' };

/// The module's one entry point, named kGdcmServeSymbol: answers one request of @a size bytes;
/// returns 0 and the reply in *reply (malloc'd, the caller frees it), or nonzero and the error
/// message there. The name carries the protocol's version, so a stale module is not used.
using GdcmServe = int (*)(const char* request, std::size_t size, char** reply, std::size_t* replySize);
inline constexpr const char* kGdcmModuleName = "libisouq_gdcm.so";
inline constexpr const char* kGdcmServeSymbol = "isouq_gdcm_serve_v1";

} // namespace isouq::sources_internal
