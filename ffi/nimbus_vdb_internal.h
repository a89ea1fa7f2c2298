// nimbus_vdb_internal.h -- what the parts of the bridge share; not part of the C API.
//
// The bridge is split by job: nimbus_vdb.cpp (errors, files and their streams), grids.cpp,
// points.cpp and metadata.cpp. Each entry point runs its body through guarded(), which turns
// any C++ exception into NIMBUS_ERR plus a thread-local message: unwinding into Rust is
// undefined behaviour, so nothing may escape.

#pragma once

#include "nimbus_vdb.h"

#include <openvdb/openvdb.h>
#include <openvdb/io/Archive.h>
#include <openvdb/io/Stream.h>
#include <openvdb/math/Maps.h>
#include <openvdb/points/PointAttribute.h>
#include <openvdb/points/PointConversion.h>
#include <openvdb/points/PointCount.h>
#include <openvdb/points/PointDataGrid.h>
#include <openvdb/points/PointGroup.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/PointIndexGrid.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <memory>
#include <mutex>
#include <sstream>
#include <streambuf>
#include <string>
#include <vector>

namespace vdb = openvdb;
using vdb::GridBase;
using vdb::points::PointDataGrid;

struct nimbus_grid {
    GridBase::Ptr grid;
    // Set only while a points grid is being built: populateAttribute() needs the index
    // that ordered the positions, so attributes can follow the caller's point order.
    vdb::tools::PointIndexGrid::Ptr point_index;
    size_t point_count = 0;
};

struct nimbus_file {
    std::vector<std::unique_ptr<nimbus_grid>> grids;
    vdb::MetaMap meta;
};

namespace nimbus_bridge {

void set_error(const char* msg) noexcept;
void ensure_initialized();

// Runs f, converting every exception into NIMBUS_ERR and a message for nimbus_last_error.
template <class F>
int guarded(F&& f) noexcept
{
    try {
        ensure_initialized();
        f();
        return NIMBUS_OK;
    } catch (const std::ios_base::failure&) {
        // Streams are opened with exceptions on: a short read means the data ends early.
        set_error("unexpected end of data or I/O failure (truncated or corrupt file?)");
    } catch (const vdb::Exception& e) {
        set_error(e.what());
    } catch (const std::bad_alloc&) {
        set_error("out of memory (corrupt file?)");
    } catch (const std::exception& e) {
        set_error(e.what());
    } catch (...) {
        set_error("unknown C++ exception");
    }
    return NIMBUS_ERR;
}

inline const vdb::MetaMap* meta_map(const nimbus_meta* m) { return reinterpret_cast<const vdb::MetaMap*>(m); }
inline vdb::MetaMap* meta_map(nimbus_meta* m) { return reinterpret_cast<vdb::MetaMap*>(m); }

[[noreturn]] inline void fail(const std::string& msg) { throw std::runtime_error(msg); }

inline void require(const void* p, const char* what)
{
    if (!p) fail(std::string("null ") + what);
}

inline char* dup_string(const std::string& s)
{
    char* out = static_cast<char*>(std::malloc(s.size() + 1));
    if (!out) throw std::bad_alloc();
    std::memcpy(out, s.c_str(), s.size() + 1);
    return out;
}

// A grid sharing `g`'s tree, with copies of its metadata and transform (nimbus_vdb.cpp).
GridBase::Ptr shallow_copy(GridBase& g);

// Transforms as the C API passes them, 12 doubles: the index axes, then the translation
// (grids.cpp).
void affine_to_cols(const vdb::math::Mat4d& m, double out[12]);
vdb::math::Transform::Ptr transform_from_cols(const double cols[12]);

// Value kinds (grids.cpp).
nimbus_value_kind kind_of(const GridBase& g);
const char* kind_name(nimbus_value_kind k);
std::string grid_label(const GridBase& g);
void check_kind(const GridBase& g, nimbus_value_kind want);
// The points grid `g` is, or a failure naming it (points.cpp).
const PointDataGrid& as_points(const GridBase& g);

// Values as flat floats: 1 per float voxel, 3 per vec3 voxel.
inline void put(float* out, float v) { out[0] = v; }
inline void put(float* out, const vdb::Vec3f& v) { out[0] = v[0]; out[1] = v[1]; out[2] = v[2]; }
template <class T> T get(const float* in);
template <> inline float get<float>(const float* in) { return in[0]; }
template <> inline vdb::Vec3f get<vdb::Vec3f>(const float* in) { return vdb::Vec3f(in[0], in[1], in[2]); }

} // namespace nimbus_bridge
