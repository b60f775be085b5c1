// isouq nodes: files installed beside the binary (the report and plot scripts and the PLY
// reader they share), found relative to the running executable so that an installed prefix
// can be moved and names neither the source nor the build tree.
#pragma once

#include <filesystem>
#include <string>

namespace isouq::nodes {

/// `<folder of the running executable>/../share/isouq/<name>`: PREFIX/share/isouq after
/// `cmake --install`, build/share/isouq in a build tree (CMake copies the files there).
std::filesystem::path resourcePath(const std::string& name);

} // namespace isouq::nodes
