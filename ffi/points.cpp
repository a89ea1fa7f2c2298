// points.cpp -- OpenVDB points grids: building one from positions and attributes in the
// caller's order, and reading positions, attributes and groups back in leaf order.

#include "nimbus_vdb_internal.h"

using namespace nimbus_bridge;

namespace nimbus_bridge {

const PointDataGrid& as_points(const GridBase& g)
{
    if (!g.isType<PointDataGrid>()) fail(grid_label(g) + " is not a points grid (type " + g.type() + ")");
    return static_cast<const PointDataGrid&>(g);
}

} // namespace nimbus_bridge

namespace {

nimbus_value_kind attribute_kind(const vdb::points::AttributeArray& a)
{
    if (a.hasValueType<float>() || a.hasValueType<double>()) return NIMBUS_VALUE_FLOAT;
    if (a.hasValueType<vdb::Vec3f>() || a.hasValueType<vdb::Vec3d>()) return NIMBUS_VALUE_VEC3F;
    return NIMBUS_VALUE_OTHER;
}

// Copies one attribute, any codec, converted to OutT (float or Vec3f), leaf order.
template <class InT, class OutT>
void copy_attribute(const PointDataGrid& grid, size_t pos, float* out, size_t count)
{
    constexpr int ch = vdb::VecTraits<OutT>::Size;
    size_t i = 0;
    for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
        vdb::points::AttributeHandle<InT> h(leaf->constAttributeArray(pos));
        const size_t n = leaf->pointCount();
        if (i + n > count) fail(grid_label(grid) + ": more points than the caller expected");
        for (size_t k = 0; k < n; ++k, ++i) put(out + i * ch, OutT(h.get(vdb::Index(k))));
    }
    if (i != count) fail(grid_label(grid) + ": fewer points than the caller expected");
}

// What a read of `count` values of the points' `what` (attribute, group) `name` into `out`
// starts from: the arguments checked, the points grid, and the read's label for its errors.
std::pair<const PointDataGrid&, std::string> points_read(const nimbus_grid* grid, const std::string& what, const char* name,
    const void* out, size_t count)
{
    require(grid, "grid");
    require(name, (what + " name").c_str());
    if (!out && count) fail("null output");
    const PointDataGrid& points = as_points(*grid->grid);
    return {points, grid_label(points) + " " + what + " '" + name + "'"};
}

} // namespace

extern "C" {

// ---- points ---------------------------------------------------------------------------

int nimbus_points_new(const char* name, const double* positions, size_t count, double voxel_size,
    nimbus_grid** out)
{
    return guarded([&] {
        require(name, "grid name");
        require(out, "output pointer");
        if (!positions && count) fail("null positions");
        std::vector<vdb::Vec3d> p(count);
        for (size_t i = 0; i < count; ++i) p[i] = vdb::Vec3d(positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]);
        const vdb::points::PointAttributeVector<vdb::Vec3d> wrapper(p);
        if (!(voxel_size > 0.0)) voxel_size = vdb::points::computeVoxelSize(wrapper, /*pointsPerVoxel=*/8);
        auto xform = vdb::math::Transform::createLinearTransform(voxel_size);
        auto h = std::make_unique<nimbus_grid>();
        h->point_index = vdb::tools::createPointIndexGrid<vdb::tools::PointIndexGrid>(wrapper, *xform);
        auto grid = vdb::points::createPointDataGrid<vdb::points::NullCodec, PointDataGrid>(
            *h->point_index, wrapper, *xform);
        grid->setName(name);
        h->grid = grid;
        h->point_count = count;
        *out = h.release();
    });
}

int nimbus_points_add_attribute(nimbus_grid* grid, const char* name, nimbus_value_kind kind,
    const float* values, size_t count)
{
    return guarded([&] {
        require(grid, "grid");
        require(name, "attribute name");
        if (!values && count) fail("null attribute values");
        auto& points = const_cast<PointDataGrid&>(as_points(*grid->grid));
        const std::string label = grid_label(points) + " attribute '" + name + "'";
        if (!grid->point_index) fail(label + ": attributes can only be added while building the grid");
        if (count != grid->point_count)
            fail(label + ": " + std::to_string(count) + " values for " + std::to_string(grid->point_count) + " points");
        if (std::string(name) == "P") fail(label + ": P is the position attribute");
        auto& tree = points.tree();
        if (kind == NIMBUS_VALUE_FLOAT) {
            std::vector<float> v(values, values + count);
            vdb::points::appendAttribute<float>(tree, name);
            vdb::points::populateAttribute(tree, grid->point_index->tree(), name,
                vdb::points::PointAttributeVector<float>(v));
        } else if (kind == NIMBUS_VALUE_VEC3F) {
            std::vector<vdb::Vec3f> v(count);
            for (size_t i = 0; i < count; ++i) v[i] = get<vdb::Vec3f>(values + 3 * i);
            vdb::points::appendAttribute<vdb::Vec3f>(tree, name);
            vdb::points::populateAttribute(tree, grid->point_index->tree(), name,
                vdb::points::PointAttributeVector<vdb::Vec3f>(v));
        } else {
            fail(label + ": only float and vec3f attributes can be written");
        }
    });
}

size_t nimbus_points_attribute_count(const nimbus_grid* grid)
{
    if (!grid || !grid->grid->isType<PointDataGrid>()) return 0;
    auto leaf = static_cast<const PointDataGrid&>(*grid->grid).tree().cbeginLeaf();
    return leaf ? leaf->attributeSet().descriptor().size() : 0;
}

int nimbus_points_attribute_info(const nimbus_grid* grid, size_t index, char** name,
    char** type_name, char** codec, nimbus_value_kind* kind)
{
    return guarded([&] {
        require(grid, "grid");
        require(name, "output pointer");
        require(type_name, "output pointer");
        require(codec, "output pointer");
        require(kind, "output pointer");
        const PointDataGrid& points = as_points(*grid->grid);
        auto leaf = points.tree().cbeginLeaf();
        if (!leaf || index >= leaf->attributeSet().descriptor().size())
            fail(grid_label(points) + ": attribute index out of range");
        const auto& desc = leaf->attributeSet().descriptor();
        std::string attr_name;
        for (const auto& [n, pos] : desc.map())
            if (pos == index) attr_name = n;
        const vdb::NamePair& type = desc.type(index);
        *kind = attribute_kind(*leaf->attributeSet().getConst(index));
        *name = dup_string(attr_name);
        *type_name = dup_string(type.first);
        *codec = dup_string(type.second);
    });
}

int nimbus_points_read_positions(const nimbus_grid* grid, double* out, size_t count)
{
    return guarded([&] {
        require(grid, "grid");
        if (!out && count) fail("null output");
        const PointDataGrid& points = as_points(*grid->grid);
        const vdb::math::Transform& xform = points.transform();
        size_t i = 0;
        for (auto leaf = points.tree().cbeginLeaf(); leaf; ++leaf) {
            const size_t pos = leaf->attributeSet().find("P");
            if (pos == vdb::points::AttributeSet::INVALID_POS)
                fail(grid_label(points) + " has no P attribute");
            vdb::points::AttributeHandle<vdb::Vec3f> h(leaf->constAttributeArray(pos));
            // Points are stored voxel by voxel: the leaf's value at voxel n is the end of
            // that voxel's index range, and P is the offset from the voxel centre.
            vdb::Index begin = 0;
            for (vdb::Index n = 0; n < vdb::points::PointDataTree::LeafNodeType::SIZE; ++n) {
                const vdb::Index end = leaf->getValue(n);
                if (end == begin) continue;
                const vdb::Vec3d ijk = leaf->offsetToGlobalCoord(n).asVec3d();
                for (vdb::Index k = begin; k < end; ++k, ++i) {
                    if (i >= count) fail(grid_label(points) + ": more points than the caller expected");
                    const vdb::Vec3d w = xform.indexToWorld(ijk + vdb::Vec3d(h.get(k)));
                    out[3 * i] = w[0]; out[3 * i + 1] = w[1]; out[3 * i + 2] = w[2];
                }
                begin = end;
            }
        }
        if (i != count) fail(grid_label(points) + ": fewer points than the caller expected");
    });
}

int nimbus_points_read_attribute(const nimbus_grid* grid, const char* name, nimbus_value_kind kind,
    float* out, size_t count)
{
    return guarded([&] {
        const auto [points, label] = points_read(grid, "attribute", name, out, count);
        auto leaf = points.tree().cbeginLeaf();
        if (!leaf) {
            if (count) fail(label + ": the grid has no points");
            return;
        }
        const size_t pos = leaf->attributeSet().find(name);
        if (pos == vdb::points::AttributeSet::INVALID_POS) fail(label + " does not exist");
        const vdb::points::AttributeArray& a = *leaf->attributeSet().getConst(pos);
        if (attribute_kind(a) != kind)
            fail(label + " has type " + a.type().first + ", not readable as " + kind_name(kind));
        if (a.hasValueType<float>()) copy_attribute<float, float>(points, pos, out, count);
        else if (a.hasValueType<double>()) copy_attribute<double, float>(points, pos, out, count);
        else if (a.hasValueType<vdb::Vec3f>()) copy_attribute<vdb::Vec3f, vdb::Vec3f>(points, pos, out, count);
        else copy_attribute<vdb::Vec3d, vdb::Vec3f>(points, pos, out, count);
    });
}

int nimbus_points_group_names(const nimbus_grid* grid, char** names)
{
    return guarded([&] {
        require(grid, "grid");
        require(names, "output pointer");
        const PointDataGrid& points = as_points(*grid->grid);
        std::vector<std::pair<size_t, std::string>> groups;
        if (auto leaf = points.tree().cbeginLeaf()) {
            for (const auto& [name, index] : leaf->attributeSet().descriptor().groupMap())
                groups.emplace_back(index, name);
        }
        std::sort(groups.begin(), groups.end());
        std::string text;
        for (const auto& g : groups) text += g.second + "\n";
        *names = dup_string(text);
    });
}

int nimbus_points_read_group(const nimbus_grid* grid, const char* name, uint8_t* out, size_t count)
{
    return guarded([&] {
        const auto [points, label] = points_read(grid, "group", name, out, count);
        size_t i = 0;
        for (auto leaf = points.tree().cbeginLeaf(); leaf; ++leaf) {
            if (!leaf->attributeSet().descriptor().hasGroup(name)) fail(label + " does not exist");
            const vdb::points::GroupHandle h = leaf->groupHandle(name);
            const size_t n = leaf->pointCount();
            if (i + n > count) fail(label + ": more points than the caller expected");
            for (size_t k = 0; k < n; ++k, ++i) out[i] = h.get(vdb::Index(k)) ? 1 : 0;
        }
        if (i != count) fail(label + ": fewer points than the caller expected");
    });
}

int nimbus_test_houdini_points(const char* name, const double* positions, const float* v,
    const float* temperature, const uint8_t* in_group, size_t count, double voxel_size,
    const char* group, nimbus_grid** out)
{
    return guarded([&] {
        require(name, "grid name");
        require(group, "group name");
        require(out, "output pointer");
        if ((!positions || !v || !temperature || !in_group) && count) fail("null input");
        std::vector<vdb::Vec3d> p(count);
        std::vector<vdb::Vec3f> vel(count);
        std::vector<float> temp(temperature, temperature + count);
        std::vector<short> member(count);
        for (size_t i = 0; i < count; ++i) {
            p[i] = vdb::Vec3d(positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]);
            vel[i] = vdb::Vec3f(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
            member[i] = in_group[i] ? 1 : 0;
        }
        const vdb::points::PointAttributeVector<vdb::Vec3d> wrapper(p);
        auto xform = vdb::math::Transform::createLinearTransform(voxel_size);
        auto index = vdb::tools::createPointIndexGrid<vdb::tools::PointIndexGrid>(wrapper, *xform);
        using Fixed16 = vdb::points::FixedPointCodec</*OneByte=*/false, vdb::points::PositionRange>;
        auto grid = vdb::points::createPointDataGrid<Fixed16, PointDataGrid>(*index, wrapper, *xform);
        auto& tree = grid->tree();
        vdb::points::appendAttribute<vdb::Vec3f, vdb::points::TruncateCodec>(tree, "v");
        vdb::points::populateAttribute(tree, index->tree(), "v", vdb::points::PointAttributeVector<vdb::Vec3f>(vel));
        vdb::points::appendAttribute<float>(tree, "temperature");
        vdb::points::populateAttribute(tree, index->tree(), "temperature", vdb::points::PointAttributeVector<float>(temp));
        vdb::points::appendGroup(tree, group);
        vdb::points::setGroup(tree, index->tree(), member, group);
        grid->setName(name);
        auto h = std::make_unique<nimbus_grid>();
        h->grid = grid;
        h->point_count = count;
        *out = h.release();
    });
}

} // extern "C"
