// metadata.cpp -- file and grid metadata (an openvdb::MetaMap either way): listing, reading,
// setting and removing typed values.

#include "nimbus_vdb_internal.h"

using namespace nimbus_bridge;

namespace {

// Where `m` is an M: its kind in `out`, and its value through `store`.
template <class M, class Store>
bool read_as(const vdb::Metadata& m, nimbus_meta_kind kind, nimbus_meta_value* out, Store store)
{
    const M* typed = dynamic_cast<const M*>(&m);
    if (!typed) return false;
    out->kind = kind;
    store(typed->value());
    return true;
}

} // namespace

extern "C" {

// ---- metadata -------------------------------------------------------------------------

// nimbus_meta is an opaque name for openvdb::MetaMap (a grid is one, via GridBase).
const nimbus_meta* nimbus_file_meta(const nimbus_file* file)
{
    return file ? reinterpret_cast<const nimbus_meta*>(&file->meta) : nullptr;
}
nimbus_meta* nimbus_file_meta_mut(nimbus_file* file)
{
    return file ? reinterpret_cast<nimbus_meta*>(&file->meta) : nullptr;
}
const nimbus_meta* nimbus_grid_meta(const nimbus_grid* grid)
{
    return grid ? reinterpret_cast<const nimbus_meta*>(static_cast<const vdb::MetaMap*>(grid->grid.get())) : nullptr;
}
nimbus_meta* nimbus_grid_meta_mut(nimbus_grid* grid)
{
    return grid ? reinterpret_cast<nimbus_meta*>(static_cast<vdb::MetaMap*>(grid->grid.get())) : nullptr;
}

size_t nimbus_meta_count(const nimbus_meta* meta) { return meta ? meta_map(meta)->metaCount() : 0; }

int nimbus_meta_get(const nimbus_meta* meta, size_t index, nimbus_meta_value* out)
{
    return guarded([&] {
        require(meta, "metadata");
        require(out, "output pointer");
        const vdb::MetaMap& map = *meta_map(meta);
        if (index >= map.metaCount()) fail("metadata index out of range");
        auto it = map.beginMeta();
        std::advance(it, long(index));
        const vdb::Metadata& m = *it->second;
        *out = nimbus_meta_value{};
        out->name = it->first.c_str();
        out->type_name = m.typeName().c_str();
        out->kind = NIMBUS_META_UNKNOWN;
        auto integer = [&](auto x) { out->i = int64_t(x); };
        auto real = [&](auto x) { out->f = double(x); };
        auto vec3 = [&](const auto& x) { for (int c = 0; c < 3; ++c) out->v[c] = double(x[c]); };
        auto string = [&](const std::string& s) { out->str = s.data(); out->str_len = s.size(); };
        (void)(read_as<vdb::StringMetadata>(m, NIMBUS_META_STRING, out, string)
            || read_as<vdb::BoolMetadata>(m, NIMBUS_META_BOOL, out, integer)
            || read_as<vdb::Int32Metadata>(m, NIMBUS_META_I32, out, integer)
            || read_as<vdb::Int64Metadata>(m, NIMBUS_META_I64, out, integer)
            || read_as<vdb::FloatMetadata>(m, NIMBUS_META_F32, out, real)
            || read_as<vdb::DoubleMetadata>(m, NIMBUS_META_F64, out, real)
            || read_as<vdb::Vec3IMetadata>(m, NIMBUS_META_VEC3I, out, vec3)
            || read_as<vdb::Vec3SMetadata>(m, NIMBUS_META_VEC3F, out, vec3)
            || read_as<vdb::Vec3DMetadata>(m, NIMBUS_META_VEC3D, out, vec3));
    });
}

int nimbus_meta_set(nimbus_meta* meta, const nimbus_meta_value* value)
{
    return guarded([&] {
        require(meta, "metadata");
        require(value, "value");
        require(value->name, "metadata name");
        vdb::MetaMap& map = *meta_map(meta);
        const std::string name(value->name);
        const double* v = value->v;
        // insertMeta keeps an existing entry's type, so drop it first: set means replace.
        map.removeMeta(name);
        switch (value->kind) {
        case NIMBUS_META_STRING:
            if (!value->str && value->str_len) fail("null string metadata");
            map.insertMeta(name, vdb::StringMetadata(std::string(value->str ? value->str : "", value->str_len)));
            break;
        case NIMBUS_META_BOOL: map.insertMeta(name, vdb::BoolMetadata(value->i != 0)); break;
        case NIMBUS_META_I32: map.insertMeta(name, vdb::Int32Metadata(int32_t(value->i))); break;
        case NIMBUS_META_I64: map.insertMeta(name, vdb::Int64Metadata(value->i)); break;
        case NIMBUS_META_F32: map.insertMeta(name, vdb::FloatMetadata(float(value->f))); break;
        case NIMBUS_META_F64: map.insertMeta(name, vdb::DoubleMetadata(value->f)); break;
        case NIMBUS_META_VEC3I:
            map.insertMeta(name, vdb::Vec3IMetadata(vdb::Vec3i(int(v[0]), int(v[1]), int(v[2]))));
            break;
        case NIMBUS_META_VEC3F:
            map.insertMeta(name, vdb::Vec3SMetadata(vdb::Vec3s(float(v[0]), float(v[1]), float(v[2]))));
            break;
        case NIMBUS_META_VEC3D:
            map.insertMeta(name, vdb::Vec3DMetadata(vdb::Vec3d(v[0], v[1], v[2])));
            break;
        default: fail("metadata '" + name + "': unsupported kind");
        }
    });
}

int nimbus_meta_remove(nimbus_meta* meta, const char* name)
{
    return guarded([&] {
        require(meta, "metadata");
        require(name, "metadata name");
        meta_map(meta)->removeMeta(name);
    });
}

} // extern "C"
