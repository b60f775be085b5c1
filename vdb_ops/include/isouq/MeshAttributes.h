// isouq: the indexed triangle mesh and its named per-vertex / per-face attributes (SPEC §6).
#pragma once

#include <openvdb/Types.h> // openvdb::Vec3s, Vec3I

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

namespace isouq {

/// One attribute column: structure-of-arrays, so PLY writers and numpy readers stream it as is.
using AttributeData =
    std::variant<std::vector<float>, std::vector<std::int32_t>, std::vector<std::uint8_t>>;

struct Attribute {
    std::string name;
    AttributeData data;
};

/// An ordered set of named columns of equal length. Column order is the PLY property order.
class AttributeTable {
public:
    /// Adds (or replaces) a column of @a size default-initialised values and returns it.
    /// An existing column of the same type keeps its storage (and its address), so meshing
    /// again into the same Mesh allocates nothing new.
    template <typename T>
    std::vector<T>& add(std::string_view name, std::size_t size)
    {
        if (Attribute* existing = findColumn(name)) {
            if (auto* same = std::get_if<std::vector<T>>(&existing->data)) {
                same->assign(size, T());
                return *same;
            }
            existing->data = std::vector<T>(size);
            return std::get<std::vector<T>>(existing->data);
        }
        mColumns.push_back(Attribute{std::string(name), std::vector<T>(size)});
        return std::get<std::vector<T>>(mColumns.back().data);
    }

    /// The column called @a name of type T with its content if it exists, else a new empty one:
    /// for a caller that resizes it and overwrites every value (the mesher meshing again into
    /// the same Mesh), so a reused column is not filled first.
    template <typename T>
    std::vector<T>& reuse(std::string_view name)
    {
        if (Attribute* existing = findColumn(name))
            if (auto* same = std::get_if<std::vector<T>>(&existing->data)) return *same;
        return add<T>(name, 0);
    }

    /// The column called @a name if it exists with element type T, else nullptr.
    template <typename T>
    const std::vector<T>* find(std::string_view name) const
    {
        for (const Attribute& a : mColumns)
            if (a.name == name) return std::get_if<std::vector<T>>(&a.data);
        return nullptr;
    }
    template <typename T>
    std::vector<T>* find(std::string_view name)
    {
        Attribute* a = findColumn(name);
        return a ? std::get_if<std::vector<T>>(&a->data) : nullptr;
    }

    bool has(std::string_view name) const
    {
        for (const Attribute& a : mColumns)
            if (a.name == name) return true;
        return false;
    }
    const std::vector<Attribute>& columns() const { return mColumns; }
    std::vector<Attribute>& columns() { return mColumns; }
    void clear() { mColumns.clear(); }
    /// Removes every column whose name is not in @a names (order of the rest kept).
    void retainOnly(const std::vector<std::string>& names)
    {
        std::vector<Attribute> kept;
        for (Attribute& a : mColumns)
            for (const std::string& n : names)
                if (a.name == n) {
                    kept.push_back(std::move(a));
                    break;
                }
        mColumns = std::move(kept);
    }

private:
    Attribute* findColumn(std::string_view name)
    {
        for (Attribute& a : mColumns)
            if (a.name == name) return &a;
        return nullptr;
    }
    std::vector<Attribute> mColumns;
};

/// Number of elements of a column, whatever its type.
inline std::size_t attributeSize(const AttributeData& data)
{
    return std::visit([](const auto& v) { return v.size(); }, data);
}

/// An indexed triangle mesh in world space with named attributes (SPEC §6 names:
/// `t_linear`, `edge_i`, `err_est`, ... per vertex; `hidden` per face).
struct Mesh {
    std::vector<openvdb::Vec3s> positions;
    std::vector<openvdb::Vec3I> triangles;
    AttributeTable vertexAttributes;
    AttributeTable faceAttributes;
    /// The grid's index-to-world map, row-major, column-vector convention:
    /// world = M * (i, j, k, 1). With `edge_i/j/k`, `edge_axis` and `t_<method>` it lets a viewer
    /// place any method's crossing (C3) without the volume. Written to PLY as a header comment.
    std::array<double, 16> indexToWorld{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

    std::size_t vertexCount() const { return positions.size(); }
    std::size_t triangleCount() const { return triangles.size(); }
};

} // namespace isouq
