// isouq nodes: installed resources (Resources.h).
#include "isouq/nodes/Resources.h"

#include <system_error>

namespace isouq::nodes {

std::filesystem::path resourcePath(const std::string& name)
{
    std::error_code ec;
    const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
    return exe.parent_path().parent_path() / "share" / "isouq" / name;
}

} // namespace isouq::nodes
