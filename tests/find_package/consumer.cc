// Meshes a level-set sphere through the installed isouq package (SPEC §8 library contract).
#include <isouq/MarchingCubes.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <cmath>
#include <cstdio>

int main()
{
    openvdb::initialize();
    const float radius = 1.0f, voxelSize = 0.05f;
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(radius, {0, 0, 0}, voxelSize);
    isouq::MeshSettings settings;
    settings.isovalue = 0.0f;
    settings.uncertainty = false;
    isouq::Mesh mesh = isouq::extractIsosurface(*grid, settings);
    double worst = 0.0;
    for (const openvdb::Vec3s& p : mesh.positions) worst = std::max(worst, std::abs(double(p.length()) - radius));
    std::printf("consumer: %zu vertices, %zu triangles, max |r - 1| = %g\n", mesh.positions.size(),
        mesh.triangles.size(), worst);
    return (mesh.triangles.empty() || worst > 0.5 * voxelSize) ? 1 : 0;
}
