// isouq: the program users run. It settles its memory pages first (HugePages.h: a large input
// restarts it once with glibc's tunables) while only libc and libstdc++ are loaded, then loads
// the command line module (CliModule.h) and runs it: the restart costs about 1 ms, not a second
// start of OpenVDB (about 70 ms). The module is looked for as installed relative to this
// program (bin/../lib/isouq; the build tree has the same layout), then where `cmake --install`
// put it.
#include "CliModule.h"
#include "HugePages.h"

#include <isouq/Errors.h> // oneLine: header-only

#include <dlfcn.h>
#include <unistd.h>

#include <climits>
#include <cstdio>
#include <string>
#include <vector>

int main(int argc, char** argv)
{
    isouq::cli::useHugePagesForLargeInputs(argc, argv); // may re-execute this program, once
    char self[PATH_MAX];
    const ssize_t length = ::readlink("/proc/self/exe", self, sizeof self - 1);
    const std::string exe = length > 0 ? std::string(self, std::size_t(length)) : std::string();
    std::vector<std::string> places{ISOUQ_MODULE_INSTALLED};
    if (const std::size_t slash = exe.rfind('/'); slash != std::string::npos)
        places.insert(places.begin(), exe.substr(0, slash) + "/" ISOUQ_MODULE_FROM_BIN);
    std::string looked, error;
    for (const std::string& place : places) {
        const std::string path = place + "/" ISOUQ_CLI_MODULE;
        looked += (looked.empty() ? "" : ", ") + place;
        if (::access(path.c_str(), F_OK) != 0) continue;
        // RTLD_GLOBAL: Open MPI's components, loaded later, resolve against the module's libmpi.
        void* module = ::dlopen(path.c_str(), RTLD_NOW | RTLD_GLOBAL);
        const auto run = module ? reinterpret_cast<decltype(&isouq_cli_main)>(::dlsym(module, isouq::cli::kCliMainSymbol))
                                : nullptr;
        if (run) return run(argc, argv);
        const char* why = ::dlerror();
        error = why ? why : path + " cannot be loaded";
        break;
    }
    if (error.empty()) error = std::string(ISOUQ_CLI_MODULE " is in none of ") + looked;
    std::fprintf(stderr, "isouq: error: %s\n",
        isouq::oneLine("cannot start isouq's command line: " + error + " (reinstall isouq)").c_str());
    return 2;
}
