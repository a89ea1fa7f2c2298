// grids.cpp -- dense and vector grids: creating them leaf by leaf, reading them leaf by
// leaf, their transforms and value kinds, and BoxSampler as a reference for tests.

#include "nimbus_vdb_internal.h"

using namespace nimbus_bridge;

namespace nimbus_bridge {

// ---- transforms -----------------------------------------------------------------------

// OpenVDB maps use row vectors (world = index * M), so the index axes are M's rows.
void affine_to_cols(const vdb::math::Mat4d& m, double out[12])
{
    for (int axis = 0; axis < 4; ++axis)
        for (int c = 0; c < 3; ++c) out[axis * 3 + c] = m(axis, c);
}

// The simplest OpenVDB map equal to the given one, with bit-exact coefficients. The
// Transform(MapBase::Ptr) constructor runs math::simplify(), which recovers a diagonal
// map's scale as (s + t) - t and so loses bits when the translation is large. Scaling
// and translating an identity Transform builds [Uniform]Scale[Translate]Map directly.
vdb::math::Transform::Ptr transform_from_cols(const double cols[12])
{
    using namespace vdb::math;
    Mat4d m = Mat4d::identity();
    for (int axis = 0; axis < 4; ++axis)
        for (int c = 0; c < 3; ++c) m(axis, c) = cols[axis * 3 + c];
    const bool diagonal = m(0, 1) == 0 && m(0, 2) == 0 && m(1, 0) == 0 && m(1, 2) == 0 && m(2, 0) == 0 && m(2, 1) == 0;
    if (!diagonal) return std::make_shared<Transform>(std::make_shared<AffineMap>(m));
    auto xform = Transform::createLinearTransform(1.0);
    xform->preScale(Vec3d(m(0, 0), m(1, 1), m(2, 2)));
    const Vec3d translation(m(3, 0), m(3, 1), m(3, 2));
    if (translation != Vec3d::zero()) xform->postTranslate(translation);
    return xform;
}

// ---- value kinds ----------------------------------------------------------------------

nimbus_value_kind kind_of(const GridBase& g)
{
    if (g.isType<vdb::FloatGrid>() || g.isType<vdb::DoubleGrid>()) return NIMBUS_VALUE_FLOAT;
    if (g.isType<vdb::Vec3SGrid>() || g.isType<vdb::Vec3DGrid>()) return NIMBUS_VALUE_VEC3F;
    if (g.isType<PointDataGrid>()) return NIMBUS_VALUE_POINTS;
    return NIMBUS_VALUE_OTHER;
}

const char* kind_name(nimbus_value_kind k)
{
    switch (k) {
    case NIMBUS_VALUE_FLOAT: return "float";
    case NIMBUS_VALUE_VEC3F: return "vec3f";
    case NIMBUS_VALUE_POINTS: return "points";
    default: return "other";
    }
}

std::string grid_label(const GridBase& g) { return "grid '" + g.getName() + "'"; }

void check_kind(const GridBase& g, nimbus_value_kind want)
{
    const nimbus_value_kind have = kind_of(g);
    if (have != want)
        fail(grid_label(g) + " has type " + g.valueType() + ", not readable as " + kind_name(want));
}

} // namespace nimbus_bridge

namespace {

// ---- leaf iteration -------------------------------------------------------------------

struct LeafSource {
    virtual ~LeafSource() = default;
    virtual size_t len() const = 0;
    virtual bool next(int32_t origin[3], float* values, uint64_t mask[8]) = 0;
};

// Walks the leaves of a tree, converting each value to OutT (float or Vec3f) as it copies.
template <class TreeT, class OutT>
class TypedLeafSource : public LeafSource {
    using LeafT = typename TreeT::LeafNodeType;

public:
    explicit TypedLeafSource(std::shared_ptr<const TreeT> tree) : mTree(std::move(tree))
    {
        mLeaves.reserve(mTree->leafCount());
        for (auto it = mTree->cbeginLeaf(); it; ++it) mLeaves.push_back(it.getLeaf());
    }
    size_t len() const override { return mLeaves.size(); }
    bool next(int32_t origin[3], float* values, uint64_t mask[8]) override
    {
        if (mNext >= mLeaves.size()) return false;
        const LeafT& leaf = *mLeaves[mNext++];
        const vdb::Coord o = leaf.origin();
        origin[0] = o.x(); origin[1] = o.y(); origin[2] = o.z();
        constexpr int ch = vdb::VecTraits<OutT>::Size;
        const auto* buf = leaf.buffer().data();
        for (vdb::Index n = 0; n < LeafT::SIZE; ++n) put(values + n * ch, OutT(buf[n]));
        const auto& m = leaf.getValueMask();
        for (vdb::Index w = 0; w < 8; ++w) mask[w] = m.template getWord<uint64_t>(w);
        return true;
    }

private:
    std::shared_ptr<const TreeT> mTree;
    std::vector<const LeafT*> mLeaves;
    size_t mNext = 0;
};

// Leaves of the grid's tree as OutT values. The tree is shared unless it has active tiles;
// then a copy with the tiles voxelized is walked, so every active value is in a leaf.
template <class OutT, class GridT>
std::unique_ptr<LeafSource> leaf_source(const GridT& grid, float* background)
{
    using TreeT = typename GridT::TreeType;
    std::shared_ptr<const TreeT> tree = grid.treePtr();
    if (tree->hasActiveTiles()) {
        auto copy = std::make_shared<TreeT>(*tree);
        copy->voxelizeActiveTiles();
        tree = copy;
    }
    put(background, OutT(tree->background()));
    return std::make_unique<TypedLeafSource<TreeT, OutT>>(tree);
}

// A copy of a tree with another value type, leaf by leaf (OpenVDB's converting Tree
// constructor refuses vec3s -> vec3d). Active tiles are not copied.
template <class OutTreeT, class InTreeT>
typename OutTreeT::Ptr convert_leaves(const InTreeT& in)
{
    using OutV = typename OutTreeT::ValueType;
    auto out = std::make_shared<OutTreeT>(OutV(in.background()));
    for (auto it = in.cbeginLeaf(); it; ++it) {
        auto* leaf = out->touchLeaf(it->origin());
        for (vdb::Index n = 0; n < InTreeT::LeafNodeType::SIZE; ++n) leaf->setValueOnly(n, OutV(it->getValue(n)));
        leaf->setValueMask(it->getValueMask());
    }
    return out;
}

// ---- grids ----------------------------------------------------------------------------

template <class GridT>
void add_leaf(GridT& grid, const int32_t origin[3], const float* values, const uint64_t mask[8])
{
    using LeafT = typename GridT::TreeType::LeafNodeType;
    using ValueT = typename GridT::ValueType;
    constexpr int ch = vdb::VecTraits<ValueT>::Size;
    const vdb::Coord o(origin[0], origin[1], origin[2]);
    if ((o.x() | o.y() | o.z()) & int(LeafT::DIM - 1))
    {
        std::ostringstream msg;
        msg << grid_label(grid) << ": leaf origin " << o << " is not a multiple of 8";
        fail(msg.str());
    }
    auto leaf = std::make_unique<LeafT>(o, grid.background());
    ValueT* buf = leaf->buffer().data();
    for (vdb::Index n = 0; n < LeafT::SIZE; ++n) buf[n] = get<ValueT>(values + n * ch);
    typename LeafT::NodeMaskType m;
    for (vdb::Index w = 0; w < 8; ++w) m.template getWord<uint64_t>(w) = mask[w];
    leaf->setValueMask(m);
    grid.tree().addLeaf(leaf.release());
}

template <class GridT>
vdb::tools::GridSampler<GridT, vdb::tools::BoxSampler> sampler(const GridT& g)
{
    return vdb::tools::GridSampler<GridT, vdb::tools::BoxSampler>(g);
}

template <class GridT>
void sample_box(const GridT& grid, const double* points, size_t count, bool world, float* out)
{
    constexpr int ch = vdb::VecTraits<typename GridT::ValueType>::Size;
    // GridSampler holds a ValueAccessor: one per call, never shared between threads.
    auto s = sampler(grid);
    for (size_t i = 0; i < count; ++i) {
        const vdb::Vec3d p(points[3 * i], points[3 * i + 1], points[3 * i + 2]);
        put(out + i * ch, world ? s.wsSample(p) : s.isSample(p));
    }
}

} // namespace

extern "C" {

// ---- grids ----------------------------------------------------------------------------

int nimbus_grid_get_info(const nimbus_grid* grid, nimbus_grid_info* out)
{
    if (!out) {
        set_error("null output pointer");
        return NIMBUS_ERR;
    }
    *out = nimbus_grid_info{};
    int rc = guarded([&] {
        require(grid, "grid");
        const GridBase& g = *grid->grid;
        out->name = dup_string(g.getName());
        out->type_name = dup_string(g.type());
        out->value_type = dup_string(g.valueType());
        out->map_type = dup_string(g.transform().mapType());
        out->kind = kind_of(g);
        out->grid_class = nimbus_grid_class(g.getGridClass());
        out->is_affine = g.transform().isLinear() ? 1 : 0;
        if (out->is_affine)
            affine_to_cols(g.transform().baseMap()->getAffineMap()->getMat4(), out->index_to_world);
        out->active_voxel_count = g.activeVoxelCount();
        const vdb::CoordBBox bb = g.evalActiveVoxelBoundingBox();
        out->has_bbox = bb.empty() ? 0 : 1;
        for (int c = 0; c < 3; ++c) {
            out->bbox_min[c] = out->has_bbox ? bb.min()[c] : 0;
            out->bbox_max[c] = out->has_bbox ? bb.max()[c] : 0;
        }
        if (out->kind == NIMBUS_VALUE_POINTS)
            out->point_count = vdb::points::pointCount(as_points(g).tree());
        out->saved_as_half = g.saveFloatAsHalf() ? 1 : 0;
    });
    if (rc != NIMBUS_OK) nimbus_grid_info_clear(out);
    return rc;
}

void nimbus_grid_info_clear(nimbus_grid_info* info)
{
    if (!info) return;
    std::free(info->name);
    std::free(info->type_name);
    std::free(info->value_type);
    std::free(info->map_type);
    info->name = info->type_name = info->value_type = info->map_type = nullptr;
}

void nimbus_grid_free(nimbus_grid* grid) { delete grid; }

int nimbus_grid_copy(const nimbus_grid* grid, nimbus_grid** out)
{
    return guarded([&] {
        require(grid, "grid");
        require(out, "output pointer");
        auto h = std::make_unique<nimbus_grid>();
        h->grid = shallow_copy(*grid->grid);
        *out = h.release();
    });
}

int nimbus_grid_new(nimbus_value_kind kind, const char* name, nimbus_grid_class grid_class,
    const float* background, const double index_to_world[12], nimbus_grid** out)
{
    return guarded([&] {
        require(name, "grid name");
        require(background, "background");
        require(index_to_world, "transform");
        require(out, "output pointer");
        auto h = std::make_unique<nimbus_grid>();
        if (kind == NIMBUS_VALUE_FLOAT)
            h->grid = vdb::FloatGrid::create(get<float>(background));
        else if (kind == NIMBUS_VALUE_VEC3F)
            h->grid = vdb::Vec3SGrid::create(get<vdb::Vec3f>(background));
        else
            fail(std::string("grid '") + name + "': cannot create a grid of kind " + kind_name(kind));
        h->grid->setName(name);
        h->grid->setGridClass(vdb::GridClass(grid_class));
        h->grid->setTransform(transform_from_cols(index_to_world));
        *out = h.release();
    });
}

int nimbus_grid_add_leaf(nimbus_grid* grid, const int32_t origin[3], const float* values,
    const uint64_t mask[8])
{
    return guarded([&] {
        require(grid, "grid");
        require(origin, "origin");
        require(values, "values");
        require(mask, "mask");
        GridBase& g = *grid->grid;
        if (g.isType<vdb::FloatGrid>())
            add_leaf(static_cast<vdb::FloatGrid&>(g), origin, values, mask);
        else if (g.isType<vdb::Vec3SGrid>())
            add_leaf(static_cast<vdb::Vec3SGrid&>(g), origin, values, mask);
        else
            fail(grid_label(g) + ": leaves can be added to float and vec3s grids only, not " + g.type());
    });
}

int nimbus_grid_set_vector_type(nimbus_grid* grid, nimbus_vector_type type)
{
    return guarded([&] {
        require(grid, "grid");
        GridBase& g = *grid->grid;
        if (!(g.isType<vdb::Vec3SGrid>() || g.isType<vdb::Vec3DGrid>()))
            fail(grid_label(g) + ": a vector type is for vec3 grids, not " + g.type());
        if (int(type) < 0 || int(type) >= vdb::NUM_VEC_TYPES) fail(grid_label(g) + ": unknown vector type");
        g.setVectorType(vdb::VecType(type));
    });
}

struct nimbus_leaf_iter {
    std::unique_ptr<LeafSource> source;
};

int nimbus_leaf_iter_new(const nimbus_grid* grid, nimbus_value_kind kind, float* background,
    nimbus_leaf_iter** out)
{
    return guarded([&] {
        require(grid, "grid");
        require(background, "background");
        require(out, "output pointer");
        const GridBase& g = *grid->grid;
        check_kind(g, kind);
        auto it = std::make_unique<nimbus_leaf_iter>();
        if (g.isType<vdb::FloatGrid>())
            it->source = leaf_source<float>(static_cast<const vdb::FloatGrid&>(g), background);
        else if (g.isType<vdb::DoubleGrid>())
            it->source = leaf_source<float>(static_cast<const vdb::DoubleGrid&>(g), background);
        else if (g.isType<vdb::Vec3SGrid>())
            it->source = leaf_source<vdb::Vec3f>(static_cast<const vdb::Vec3SGrid&>(g), background);
        else
            it->source = leaf_source<vdb::Vec3f>(static_cast<const vdb::Vec3DGrid&>(g), background);
        *out = it.release();
    });
}

size_t nimbus_leaf_iter_len(const nimbus_leaf_iter* iter) { return iter ? iter->source->len() : 0; }

int nimbus_leaf_iter_next(nimbus_leaf_iter* iter, int32_t origin[3], float* values, uint64_t mask[8])
{
    // Plain copies out of memory the iterator owns: nothing here can throw.
    if (!iter || !origin || !values || !mask) return 0;
    return iter->source->next(origin, values, mask) ? 1 : 0;
}

void nimbus_leaf_iter_free(nimbus_leaf_iter* iter) { delete iter; }

// ---- reference sampling and test fixtures -------------------------------------------

int nimbus_sample_box(const nimbus_grid* grid, nimbus_value_kind kind, const double* points,
    size_t count, int32_t world, float* out)
{
    return guarded([&] {
        require(grid, "grid");
        if ((!points || !out) && count) fail("null points or output");
        const GridBase& g = *grid->grid;
        if (kind == NIMBUS_VALUE_FLOAT && g.isType<vdb::FloatGrid>())
            sample_box(static_cast<const vdb::FloatGrid&>(g), points, count, world != 0, out);
        else if (kind == NIMBUS_VALUE_VEC3F && g.isType<vdb::Vec3SGrid>())
            sample_box(static_cast<const vdb::Vec3SGrid&>(g), points, count, world != 0, out);
        else
            fail(grid_label(g) + ": BoxSampler reference needs a float or vec3s grid of the requested kind, not " + g.type());
    });
}

int nimbus_test_frustum_grid(const char* name, nimbus_grid** out)
{
    return guarded([&] {
        require(name, "grid name");
        require(out, "output pointer");
        auto grid = vdb::FloatGrid::create(0.0f);
        grid->setName(name);
        grid->setGridClass(vdb::GRID_FOG_VOLUME);
        const vdb::BBoxd frustum_bbox(vdb::Vec3d(0, 0, 0), vdb::Vec3d(16, 16, 16));
        grid->setTransform(vdb::math::Transform::createFrustumTransform(frustum_bbox, 0.5, 10.0, 1.0));
        grid->tree().setValue(vdb::Coord(1, 2, 3), 1.0f);
        auto h = std::make_unique<nimbus_grid>();
        h->grid = grid;
        *out = h.release();
    });
}

int nimbus_test_widen_grid(const nimbus_grid* grid, nimbus_grid** out)
{
    return guarded([&] {
        require(grid, "grid");
        require(out, "output pointer");
        const GridBase& g = *grid->grid;
        GridBase::Ptr wide;
        if (g.isType<vdb::FloatGrid>())
            wide = vdb::DoubleGrid::create(convert_leaves<vdb::DoubleTree>(static_cast<const vdb::FloatGrid&>(g).tree()));
        else if (g.isType<vdb::Vec3SGrid>())
            wide = vdb::Vec3DGrid::create(convert_leaves<vdb::Vec3DTree>(static_cast<const vdb::Vec3SGrid&>(g).tree()));
        else
            fail(grid_label(g) + ": only float and vec3s grids can be widened");
        static_cast<vdb::MetaMap&>(*wide) = static_cast<const vdb::MetaMap&>(g);
        wide->setTransform(std::make_shared<vdb::math::Transform>(g.transform()));
        auto h = std::make_unique<nimbus_grid>();
        h->grid = wide;
        *out = h.release();
    });
}

} // extern "C"
