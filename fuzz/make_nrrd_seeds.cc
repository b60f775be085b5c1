// Seeds for fuzz_nrrd (docs/hardening.md), written by teem's own nrrdSave: a small volume of each
// sample type in the raw, gzip, bzip2, ascii and hex encodings, both byte orders, with space
// directions or spacings; and detached headers (`.nhdr`) with their data file, joined with the
// separator of fuzz/FuzzCommon.h and the header's `data file:` renamed to `data0`.
//   make_nrrd_seeds OUTDIR
#include "FuzzCommon.h"

#include <teem/nrrd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <iterator>
#include <regex>
#include <vector>

namespace {

std::string slurp(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void spit(const std::string& path, const std::string& bytes)
{
    std::ofstream(path, std::ios::binary) << bytes;
}

/// A 5x4x3 ball of @a type (teem's nrrdType*) with space directions or spacings.
Nrrd* ball(int type, bool space)
{
    Nrrd* n = nrrdNew();
    if (nrrdAlloc_va(n, type, 3, std::size_t(5), std::size_t(4), std::size_t(3))) return nullptr;
    for (int z = 0; z < 3; ++z)
        for (int y = 0; y < 4; ++y)
            for (int x = 0; x < 5; ++x) {
                const double r = std::sqrt((x - 2.0) * (x - 2.0) + (y - 1.5) * (y - 1.5) + (z - 1.0) * (z - 1.0));
                nrrdDInsert[type](n->data, std::size_t(x + 5 * (y + 4 * z)), 40.0 - 10.0 * r);
            }
    if (space) {
        double dirs[3][NRRD_SPACE_DIM_MAX] = {{0.9, 0.1, 0}, {0, 1.1, 0}, {0, 0, 2.5}};
        nrrdSpaceSet(n, nrrdSpaceRightAnteriorSuperior);
        nrrdSpaceOriginSet(n, std::vector<double>{-3, 2, 1}.data());
        nrrdAxisInfoSet_va(n, nrrdAxisInfoSpaceDirection, dirs[0], dirs[1], dirs[2]);
    } else {
        nrrdAxisInfoSet_va(n, nrrdAxisInfoSpacing, 0.5, 1.0, 2.0);
    }
    return n;
}

} // namespace

int main(int argc, char** argv)
{
    if (argc != 2) {
        std::cerr << "usage: make_nrrd_seeds OUTDIR\n";
        return 2;
    }
    const std::string out = argv[1], tmp = out + "/tmp-seed";
    const struct {
        const char* name;
        int type;
        const NrrdEncoding* encoding;
        int endian;
        bool space;
    } cases[] = {
        {"u8_raw", nrrdTypeUChar, nrrdEncodingRaw, airEndianLittle, true},
        {"i16_raw_big", nrrdTypeShort, nrrdEncodingRaw, airEndianBig, true},
        {"f32_gzip", nrrdTypeFloat, nrrdEncodingGzip, airEndianLittle, true},
        {"f64_bzip2", nrrdTypeDouble, nrrdEncodingBzip2, airEndianLittle, false},
        {"u16_ascii", nrrdTypeUShort, nrrdEncodingAscii, airEndianLittle, false},
        {"i32_hex", nrrdTypeInt, nrrdEncodingHex, airEndianBig, true},
        {"u64_raw", nrrdTypeULLong, nrrdEncodingRaw, airEndianLittle, false},
        {"i8_gzip_big", nrrdTypeChar, nrrdEncodingGzip, airEndianBig, false},
    };
    int written = 0;
    for (const auto& c : cases) {
        for (const bool detached : {false, true}) {
            Nrrd* n = ball(c.type, c.space);
            NrrdIoState* io = nrrdIoStateNew();
            io->encoding = c.encoding;
            io->endian = c.endian;
            io->detachedHeader = detached;
            const std::string header = tmp + (detached ? ".nhdr" : ".nrrd");
            if (!n || nrrdSave(header.c_str(), n, io)) {
                char* err = biffGetDone(NRRD);
                std::cerr << "make_nrrd_seeds: " << c.name << ": " << (err ? err : "?") << "\n";
                std::free(err);
                nrrdIoStateNix(io);
                nrrdNuke(n);
                return 1;
            }
            std::string bytes = slurp(header);
            std::remove(header.c_str());
            if (detached) {
                // teem names the data file after the header: tmp-seed.raw, tmp-seed.raw.gz, ...
                std::smatch m;
                const std::regex line("data file: ([^\n]+)\n");
                if (!std::regex_search(bytes, m, line)) return 1;
                const std::string data = out + "/" + m[1].str();
                bytes = std::regex_replace(bytes, line, "data file: data0\n") + std::string(isouq::fuzz::kNextFile)
                    + slurp(data);
                std::remove(data.c_str());
            }
            spit(out + "/" + c.name + (detached ? "_detached" : ""), bytes);
            ++written;
            nrrdIoStateNix(io);
            nrrdNuke(n);
        }
    }
    std::cout << "make_nrrd_seeds: " << written << " seeds in " << out << "\n";
    return 0;
}
