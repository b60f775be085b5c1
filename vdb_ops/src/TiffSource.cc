// isouq: TIFF stacks through libtiff (SPEC §10 "Formats"; docs/inputs.md): one multi-page
// `.tif`/`.tiff` (page z is slice z) or a folder of single-page slices sorted by the number in
// their names. One sample per pixel, 8/16/32/64-bit unsigned or signed integers, 32/64-bit
// floats, strips or tiles, any compression libtiff decodes. x is the column, y the row (row 0
// first, the top of the image), z the page or slice. Spacing: --spacing, else ImageJ's
// (1/XResolution, 1/YResolution, `spacing=`), else 1.
#include "SourcesInternal.h"

#include "Memory.h"

#include <tiffio.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <new>
#include <optional>
#include <vector>

namespace isouq::sources_internal {
namespace {

namespace fs = std::filesystem;

/// libtiff's errors on one file become the InputError's text instead of lines on stderr;
/// warnings are dropped. The handlers belong to the file (TIFFOpenExt, libtiff 4.5): nothing
/// global changes in a process that loads isouq (Python, Blender), and no thread-local state
/// is needed when threads read different files.
int keepError(TIFF*, void* error, const char* module, const char* format, va_list args)
{
    char text[512];
    std::vsnprintf(text, sizeof(text), format, args);
    *static_cast<std::string*>(error) = printedLine((module ? std::string(module) + ": " : std::string()) + text);
    return 1; // handled: libtiff's process-wide handlers are not called
}
int dropWarning(TIFF*, void*, const char*, const char*, va_list) { return 1; }

/// An open TIFF file and the last error libtiff reported on it.
class TiffFile {
public:
    /// @throw InputError when libtiff cannot open @a path.
    explicit TiffFile(const std::string& path)
    {
        std::unique_ptr<TIFFOpenOptions, void (*)(TIFFOpenOptions*)> options(TIFFOpenOptionsAlloc(), TIFFOpenOptionsFree);
        if (!options) throw std::bad_alloc();
        TIFFOpenOptionsSetErrorHandlerExtR(options.get(), keepError, &mError);
        TIFFOpenOptionsSetWarningHandlerExtR(options.get(), dropWarning, nullptr);
        mTif = TIFFOpenExt(path.c_str(), "r", options.get());
        if (!mTif) throw InputError("'" + path + "' is not a readable TIFF file: " + mError);
    }
    ~TiffFile() { TIFFClose(mTif); }
    TiffFile(const TiffFile&) = delete;
    TiffFile& operator=(const TiffFile&) = delete;

    TIFF* get() const { return mTif; }
    /// libtiff's last error on this file since clearError(); empty when none.
    const std::string& error() const { return mError; }
    void clearError() { mError.clear(); }

private:
    std::string mError; // the handlers' target: its address is fixed for the file's life
    TIFF* mTif = nullptr;
};

/// What one page holds.
struct Page {
    std::uint32_t width = 0, height = 0;
    SampleType type = SampleType::UInt8;
    bool operator==(const Page& o) const { return width == o.width && height == o.height && type == o.type; }
};

std::string describe(const Page& p)
{
    return std::to_string(p.width) + "x" + std::to_string(p.height) + " " + toString(p.type);
}

/// The current directory of @a tif as a Page. @throw InputError naming @a where.
Page readPage(TIFF* tif, const std::string& where)
{
    std::uint32_t width = 0, height = 0;
    std::uint16_t bits = 1, format = SAMPLEFORMAT_UINT, samples = 1;
    TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &width);
    TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &height);
    TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bits);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &format);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &samples);
    if (samples != 1) {
        throw InputError(where + " has " + std::to_string(samples)
            + " samples per pixel (colour?); isouq reads one-channel (grey) TIFF stacks");
    }
    std::optional<SampleType> type;
    if (format == SAMPLEFORMAT_UINT) {
        type = bits == 8 ? SampleType::UInt8 : bits == 16 ? SampleType::UInt16 : bits == 32 ? SampleType::UInt32
            : bits == 64 ? std::optional(SampleType::UInt64) : std::nullopt;
    } else if (format == SAMPLEFORMAT_INT) {
        type = bits == 8 ? SampleType::Int8 : bits == 16 ? SampleType::Int16 : bits == 32 ? SampleType::Int32
            : bits == 64 ? std::optional(SampleType::Int64) : std::nullopt;
    } else if (format == SAMPLEFORMAT_IEEEFP) {
        type = bits == 32 ? SampleType::Float32 : bits == 64 ? std::optional(SampleType::Float64) : std::nullopt;
    }
    if (!type) {
        throw InputError(where + " has " + std::to_string(bits) + "-bit samples of format " + std::to_string(format)
            + "; isouq reads 8, 16, 32 or 64-bit integers and 32 or 64-bit floats");
    }
    if (width < 1 || height < 1 || width > kMaxDim || height > kMaxDim)
        throw InputError(where + " is " + std::to_string(width) + "x" + std::to_string(height) + " pixels");
    return {width, height, *type};
}

/// The last run of digits in a file name, for sorting numbered slices; -1 without one.
long long sliceNumber(const std::string& name)
{
    std::size_t end = name.find_last_of("0123456789");
    if (end == std::string::npos) return -1;
    std::size_t begin = end;
    while (begin > 0 && std::isdigit(static_cast<unsigned char>(name[begin - 1]))) --begin;
    const std::string digits = name.substr(begin, std::min<std::size_t>(end + 1 - begin, 18));
    return std::stoll(digits);
}

/// The pages of a stack, read one slice at a time (one open file per multi-page stack).
class TiffSlices : public SliceSource {
public:
    /// @a files: one multi-page file, or one file per slice.
    explicit TiffSlices(std::vector<std::string> files) : mFiles(std::move(files))
    {
        if (mFiles.size() == 1) {
            mStack = std::make_unique<TiffFile>(mFiles[0]);
            int z = 0;
            do {
                const Page p = readPage(mStack->get(), where(z));
                if (z == 0) mPage = p;
                else if (!(p == mPage)) mismatch(z, p);
                ++z;
            } while (TIFFReadDirectory(mStack->get()));
            // The chain of pages ends at a damaged, missing or looping directory (libtiff stops
            // at a loop without an error): not a shorter stack.
            if (!mStack->error().empty()) fail(z, *mStack);
            if (!TIFFLastDirectory(mStack->get())) {
                throw InputError("cannot read " + where(z) + ": the directory of page " + std::to_string(z - 1)
                    + " points to one that cannot be read or was read before");
            }
            dims = Coord(int(mPage.width), int(mPage.height), z);
        } else {
            for (std::size_t z = 0; z < mFiles.size(); ++z) {
                const Page p = readPage(TiffFile(mFiles[z]).get(), where(int(z)));
                if (z == 0) mPage = p;
                else if (!(p == mPage)) mismatch(int(z), p);
            }
            dims = Coord(int(mPage.width), int(mPage.height), int(mFiles.size()));
        }
    }

    SampleType type() const { return mPage.type; }

    void read(int z0, int count, float* out) override
    {
        const std::size_t slice = std::size_t(dims.x()) * dims.y();
        for (int z = z0; z < z0 + count; ++z) {
            std::optional<TiffFile> single;
            TiffFile* file = mStack.get();
            if (!file) file = &single.emplace(mFiles[z]);
            else if (!TIFFSetDirectory(file->get(), tdir_t(z))) fail(z, *file);
            readPixels(*file, z);
            decodeSamples(mPixels.data(), slice, mPage.type, __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__, 1.0, 0.0,
                out + std::size_t(z - z0) * slice);
        }
    }

private:
    std::string where(int z) const
    {
        return mFiles.size() == 1 ? "page " + std::to_string(z) + " of '" + mFiles[0] + "'" : "'" + mFiles[z] + "'";
    }
    [[noreturn]] void mismatch(int z, const Page& p) const
    {
        throw InputError(where(z) + " is " + describe(p) + ", but " + where(0) + " is " + describe(mPage)
            + ": every slice of a stack must match");
    }
    [[noreturn]] void fail(int z, const TiffFile& file) const
    {
        throw InputError("cannot read " + where(z) + ": " + (file.error().empty() ? "read error" : file.error()));
    }

    /// The page's pixels, row by row, in native byte order (libtiff swaps), into mPixels.
    void readPixels(TiffFile& file, int z)
    {
        file.clearError();
        TIFF* tif = file.get();
        const std::size_t bytes = sampleBytes(mPage.type), rowBytes = std::size_t(mPage.width) * bytes;
        mPixels.resize(rowBytes * mPage.height);
        if (TIFFIsTiled(tif)) {
            std::uint32_t tw = 0, th = 0;
            TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tw);
            TIFFGetField(tif, TIFFTAG_TILELENGTH, &th);
            if (tw == 0 || th == 0) fail(z, file);
            memory_internal::checkFits(std::uint64_t(TIFFTileSize64(tif)), where(z) + " (tiles of " + std::to_string(tw)
                + "x" + std::to_string(th) + " pixels)");
            std::vector<char> tile(TIFFTileSize(tif));
            if (tile.size() < std::size_t(tw) * th * bytes) fail(z, file);
            for (std::uint32_t y0 = 0; y0 < mPage.height; y0 += th) {
                for (std::uint32_t x0 = 0; x0 < mPage.width; x0 += tw) {
                    if (TIFFReadTile(tif, tile.data(), x0, y0, 0, 0) < 0) fail(z, file);
                    const std::uint32_t w = std::min(tw, mPage.width - x0), h = std::min(th, mPage.height - y0);
                    for (std::uint32_t r = 0; r < h; ++r)
                        std::copy_n(tile.data() + std::size_t(r) * tw * bytes, std::size_t(w) * bytes,
                            mPixels.data() + (std::size_t(y0) + r) * rowBytes + std::size_t(x0) * bytes);
                }
            }
        } else {
            if (std::size_t(TIFFScanlineSize(tif)) != rowBytes) fail(z, file);
            for (std::uint32_t y = 0; y < mPage.height; ++y)
                if (TIFFReadScanline(tif, mPixels.data() + std::size_t(y) * rowBytes, y) < 0) fail(z, file);
        }
        if (!file.error().empty()) fail(z, file); // libtiff reported damage but returned data
    }

    std::vector<std::string> mFiles;
    std::unique_ptr<TiffFile> mStack;
    Page mPage;
    std::vector<char> mPixels;
};

/// ImageJ's description (`ImageJ=...`, `spacing=...`, `unit=...`) and resolution tags.
std::optional<std::pair<openvdb::Vec3d, std::string>> imageJSpacing(const std::string& path)
{
    const TiffFile tif(path);
    const char* text = nullptr;
    if (!TIFFGetField(tif.get(), TIFFTAG_IMAGEDESCRIPTION, &text) || !text) return std::nullopt;
    const std::string description = text;
    if (description.rfind("ImageJ=", 0) != 0) return std::nullopt;
    auto value = [&](const std::string& key) -> std::string {
        const std::size_t at = description.find("\n" + key + "=");
        if (at == std::string::npos) return "";
        const std::size_t start = at + key.size() + 2;
        return description.substr(start, description.find('\n', start) - start);
    };
    openvdb::Vec3d spacing(1.0);
    float xres = 0, yres = 0;
    if (TIFFGetField(tif.get(), TIFFTAG_XRESOLUTION, &xres) && xres > 0) spacing[0] = 1.0 / xres;
    if (TIFFGetField(tif.get(), TIFFTAG_YRESOLUTION, &yres) && yres > 0) spacing[1] = 1.0 / yres;
    if (const std::string z = value("spacing"); !z.empty()) spacing[2] = std::strtod(z.c_str(), nullptr);
    const std::string unit = value("unit");
    return std::make_pair(spacing, "ImageJ description" + (unit.empty() ? std::string() : " (unit " + unit + ")"));
}

} // namespace

bool isTiffFolder(const std::string& path)
{
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(path, ec))
        if (entry.is_regular_file() && (endsWith(entry.path().string(), ".tif") || endsWith(entry.path().string(), ".tiff")))
            return true;
    return false;
}

DensePiece readTiff(const VolumeRequest& request, openvdb::util::NullInterrupter* /*interrupter*/, const ScanLoader& load)
{
    const std::string& path = request.input;
    rejectRawFlags(request, "a TIFF stack", /*spacingAllowed=*/true);
    std::vector<std::string> files;
    std::error_code ec;
    if (fs::is_directory(path, ec)) {
        std::vector<std::pair<long long, std::string>> slices;
        for (const auto& entry : fs::directory_iterator(path, ec)) {
            const std::string name = entry.path().filename().string();
            if (entry.is_regular_file() && (endsWith(name, ".tif") || endsWith(name, ".tiff")))
                slices.emplace_back(sliceNumber(name), entry.path().string());
        }
        std::sort(slices.begin(), slices.end());
        for (std::size_t i = 1; i < slices.size(); ++i) {
            if (slices[i].first == slices[i - 1].first && slices[i].first >= 0) {
                throw InputError("'" + slices[i - 1].second + "' and '" + slices[i].second
                    + "' have the same slice number " + std::to_string(slices[i].first));
            }
        }
        for (auto& s : slices) files.push_back(std::move(s.second));
    } else {
        fileSize(path);
        files.push_back(path);
    }
    TiffSlices source(files);
    openvdb::Vec3d spacing(1.0);
    std::string geometry = "TIFF: spacing 1 (give --spacing)";
    if (request.spacing) {
        spacing = *request.spacing;
        geometry = "--spacing";
    } else if (auto imagej = imageJSpacing(files[0])) {
        std::tie(spacing, geometry) = *imagej;
    }
    for (int a = 0; a < 3; ++a) {
        if (!(std::isfinite(spacing[a]) && spacing[a] > 0.0))
            throw InputError("the spacing of '" + path + "' (" + geometry + ") must be positive and finite, got " + fmt(spacing[a]));
    }
    const std::array<double, 16> affine{spacing[0], 0, 0, 0, 0, spacing[1], 0, 0, 0, 0, spacing[2], 0, 0, 0, 0, 1};
    const std::string name = fs::path(path).filename().empty() ? fs::path(path).parent_path().filename().string()
                                                               : fs::path(path).stem().string();
    const std::string what = fs::path(files[0]).filename().string()
        + (files.size() > 1 ? " and " + std::to_string(files.size() - 1) + " more slices" : std::string())
        + ": TIFF " + toString(source.type());
    return load(source, {name, affine, geometry, what});
}

} // namespace isouq::sources_internal
