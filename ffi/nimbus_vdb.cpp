// nimbus_vdb.cpp -- the OpenVDB 10 side of the bridge declared in nimbus_vdb.h.
//
// Every extern "C" entry point runs its body through guarded(), which turns any C++
// exception into NIMBUS_ERR plus a thread-local message: unwinding into Rust is
// undefined behaviour, so nothing may escape.

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

namespace {

thread_local std::string g_last_error;

void set_error(const char* msg) noexcept
{
    try {
        g_last_error = msg;
    } catch (...) {
        // Out of memory while reporting: keep whatever was there.
    }
}

void ensure_initialized()
{
    static std::once_flag once;
    std::call_once(once, [] { vdb::initialize(); });
}

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

const vdb::MetaMap* meta_map(const nimbus_meta* m) { return reinterpret_cast<const vdb::MetaMap*>(m); }
vdb::MetaMap* meta_map(nimbus_meta* m) { return reinterpret_cast<vdb::MetaMap*>(m); }

[[noreturn]] void fail(const std::string& msg) { throw std::runtime_error(msg); }

void require(const void* p, const char* what)
{
    if (!p) fail(std::string("null ") + what);
}

char* dup_string(const std::string& s)
{
    char* out = static_cast<char*>(std::malloc(s.size() + 1));
    if (!out) throw std::bad_alloc();
    std::memcpy(out, s.c_str(), s.size() + 1);
    return out;
}

// ---- streams over memory ------------------------------------------------------------

// Read-only streambuf over caller memory, so reading bytes needs no copy.
class MemInBuf : public std::streambuf {
public:
    MemInBuf(const uint8_t* data, size_t len)
    {
        char* p = const_cast<char*>(reinterpret_cast<const char*>(data));
        setg(p, p, p + len);
    }

protected:
    pos_type seekoff(off_type off, std::ios_base::seekdir dir, std::ios_base::openmode) override
    {
        char* base = dir == std::ios_base::beg ? eback() : dir == std::ios_base::cur ? gptr() : egptr();
        const off_type target = (base - eback()) + off;
        if (target < 0 || target > egptr() - eback()) return pos_type(off_type(-1));
        setg(eback(), eback() + target, egptr());
        return pos_type(target);
    }
    pos_type seekpos(pos_type pos, std::ios_base::openmode which) override
    {
        return seekoff(off_type(pos), std::ios_base::beg, which);
    }
};

// Seekable, growable output streambuf: the archive writer seeks back to fill in grid
// offsets, which makes the bytes a regular .vdb file that io::File can also read.
class VecOutBuf : public std::streambuf {
public:
    std::vector<char> data;

protected:
    std::streamsize xsputn(const char* s, std::streamsize n) override
    {
        const size_t end = mPos + size_t(n);
        if (end > data.size()) data.resize(end);
        std::memcpy(data.data() + mPos, s, size_t(n));
        mPos = end;
        return n;
    }
    int_type overflow(int_type c) override
    {
        if (!traits_type::eq_int_type(c, traits_type::eof())) {
            const char ch = traits_type::to_char_type(c);
            xsputn(&ch, 1);
        }
        return traits_type::not_eof(c);
    }
    pos_type seekoff(off_type off, std::ios_base::seekdir dir, std::ios_base::openmode) override
    {
        const off_type base = dir == std::ios_base::beg ? 0
            : dir == std::ios_base::cur ? off_type(mPos) : off_type(data.size());
        const off_type target = base + off;
        if (target < 0) return pos_type(off_type(-1));
        mPos = size_t(target);
        return pos_type(target);
    }
    pos_type seekpos(pos_type pos, std::ios_base::openmode which) override
    {
        return seekoff(off_type(pos), std::ios_base::beg, which);
    }

private:
    size_t mPos = 0;
};

// ---- archives -------------------------------------------------------------------------

// io::File::write is Archive::write(stream, grids, seekable=true, meta) on an ofstream
// whose errors it does not check. Deriving from Archive gives the same file format on
// any seekable stream, including ones with exceptions enabled.
class SeekableWriter : public vdb::io::Archive {
public:
    void writeTo(std::ostream& os, const vdb::GridCPtrVec& grids, const vdb::MetaMap& meta) const
    {
        Archive::write(os, grids, /*seekable=*/true, meta);
    }
};

// A grid sharing `g`'s tree, with copies of its metadata and transform. copyGrid() alone
// would copy the transform through Transform::copy(), whose map simplification perturbs
// the scale of translated maps (see transform_from_cols); Transform's copy constructor
// keeps the map as it is.
GridBase::Ptr shallow_copy(GridBase& g)
{
    GridBase::Ptr copy = g.copyGrid();
    copy->setTransform(std::make_shared<vdb::math::Transform>(g.transform()));
    return copy;
}

uint32_t compression_flags(nimbus_compression c)
{
    switch (c) {
    case NIMBUS_COMPRESS_ZIP: return vdb::io::COMPRESS_ZIP | vdb::io::COMPRESS_ACTIVE_MASK;
    case NIMBUS_COMPRESS_BLOSC:
        if (!vdb::io::Archive::hasBloscCompression())
            fail("this OpenVDB build has no blosc compression");
        return vdb::io::COMPRESS_BLOSC | vdb::io::COMPRESS_ACTIVE_MASK;
    case NIMBUS_COMPRESS_NONE: return vdb::io::COMPRESS_ACTIVE_MASK;
    }
    fail("unknown compression option");
}

void write_archive(const nimbus_file& file, std::ostream& os, nimbus_compression compression,
    bool half)
{
    SeekableWriter writer;
    uint32_t flags = compression_flags(compression);
    // OpenVDB never ZIP-compresses the voxels of fog volumes and level sets
    // (Archive::setGridCompression), yet OpenVDB 10 still deflates every leaf of them to
    // record compressed sizes in its delayed-load metadata: 0.5 s for a 4M-voxel density
    // grid, for bytes that are then written uncompressed. When ZIP could not apply to any
    // grid in the file, it is not asked for; the voxel data written is the same.
    const bool zip_applies = std::any_of(file.grids.begin(), file.grids.end(), [](const auto& g) {
        const vdb::GridClass c = g->grid->getGridClass();
        return c != vdb::GRID_FOG_VOLUME && c != vdb::GRID_LEVEL_SET;
    });
    if (!zip_applies) flags &= ~uint32_t(vdb::io::COMPRESS_ZIP);
    writer.setCompression(flags);
    vdb::GridCPtrVec grids;
    grids.reserve(file.grids.size());
    for (const auto& g : file.grids) {
        // A shallow copy (shared tree) carries the half flag without touching the
        // caller's grid: half is an option of this write, not a property of the data.
        GridBase::Ptr copy = shallow_copy(*g->grid);
        copy->setSaveFloatAsHalf(half);
        grids.push_back(copy);
    }
    writer.writeTo(os, grids, file.meta);
    os.flush();
}

// ---- layout check ---------------------------------------------------------------------

// OpenVDB trusts the lengths a file states. io::readString() does std::string(size, ' ')
// on a uint32 it has just read, and string or unknown-type metadata resize a buffer to the
// value size the file gives, all before reading the bytes. A corrupt or truncated file thus
// makes it allocate and zero-fill up to 4 GiB before the short read fails. LayoutCheck walks
// the parts of a file that hold such lengths -- the header, the file metadata, the grid
// descriptors and each grid's metadata and transform type -- and refuses any length that
// runs past the data, before io::Stream sees the file. It reads only fixed-size fields and
// short type names, seeking over everything else, so it costs a few reads per item.
// Layout as read by OpenVDB 10: io/Archive.cc (readHeader, readGridCompression, readGrid),
// io/Stream.cc, io/GridDescriptor.cc (read), MetaMap.cc (readMeta), Metadata.h.
class LayoutCheck {
public:
    LayoutCheck(std::streambuf& buf, uint64_t size) : mBuf(buf), mSize(size) {}

    void run()
    {
        // Header (Archive::readHeader).
        if (mSize < 8 || i64("magic number") != vdb::OPENVDB_MAGIC) fail("not a VDB file");
        uint32_t version = u32("file format version");
        if (version < 211) {
            // Before 211 the version was stored as major, minor, patch.
            const uint32_t minor = u32("file format version"), patch = u32("file format version");
            version = 100 * version + 10 * minor + patch;
        } else {
            skip(8, "library version");
        }
        bool offsets = true; // grid offsets, implied before 212
        if (version >= 212) offsets = byte("grid offsets flag") != 0;
        if (version >= vdb::OPENVDB_FILE_VERSION_SELECTIVE_COMPRESSION
            && version < vdb::OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION)
            skip(1, "compression flag");
        if (version >= vdb::OPENVDB_FILE_VERSION_BOOST_UUID) {
            // ASCII, read with `is >> uuid`, which skips leading white space first.
            while (std::isspace(static_cast<unsigned char>(byte("UUID")))) {}
            --mPos;
            skip(36, "UUID");
        } else {
            skip(16, "UUID");
        }

        meta_map("file metadata", mSize);

        // Grids (Stream::Stream reads them in sequence).
        const int32_t count = i32("grid count");
        const bool instancing = version >= vdb::OPENVDB_FILE_VERSION_GRID_INSTANCING;
        // Each grid takes at least its descriptor: 2 or 3 string lengths and 3 offsets.
        const uint64_t min_grid = (instancing ? 3 : 2) * 4 + 24;
        if (count < 0 || uint64_t(count) > remaining(mSize) / min_grid)
            fail(at("grid count " + std::to_string(count), mPos - 4) + " does not fit in the "
                + std::to_string(mSize) + " bytes of data (truncated or corrupt file)");
        for (int32_t i = 0; i < count; ++i) {
            const std::string label = "grid " + std::to_string(i + 1) + " of " + std::to_string(count);
            string(label + " name", mSize);
            string(label + " type", mSize);
            if (instancing) string(label + " instance parent name", mSize);
            const uint64_t desc_end = mPos + 24;
            const int64_t grid_pos = i64(label + " grid offset");
            i64(label + " block offset");
            const int64_t end_pos = i64(label + " end offset");
            // Without offsets the next grid starts where this one's tree ends, which only
            // parsing the tree finds: check this grid's metadata and stop.
            uint64_t limit = mSize;
            if (offsets) {
                // Offsets are absolute; the grid lies between its descriptor and the end.
                // (The block offset is not used by a sequential read.)
                if (grid_pos < int64_t(desc_end) || end_pos < grid_pos || uint64_t(end_pos) > mSize)
                    fail(at(label + " offsets (grid " + std::to_string(grid_pos) + ", end "
                        + std::to_string(end_pos) + ")", desc_end - 24) + " lie outside the "
                        + std::to_string(mSize) + " bytes of data (truncated or corrupt file)");
                limit = uint64_t(end_pos);
            }
            // Archive::readGrid: compression flags, the grid's metadata, then (from 216
            // on) the transform, which begins with its map type name.
            if (version >= vdb::OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION)
                skip(4, label + " compression flags", limit);
            meta_map(label + " metadata", limit);
            if (instancing) string(label + " transform type", limit);
            if (!offsets) break;
            mPos = uint64_t(end_pos);
        }
    }

private:
    std::streambuf& mBuf;
    const uint64_t mSize;
    uint64_t mPos = 0;
    uint64_t mAt = ~uint64_t(0); // where the streambuf reads next, when known
    const std::string* mMap = nullptr; // the metadata map being checked
    uint32_t mItem = 0, mItems = 0;

    uint64_t remaining(uint64_t limit) const { return limit > mPos ? limit - mPos : 0; }

    static std::string at(const std::string& what, uint64_t pos)
    {
        return what + " at byte " + std::to_string(pos);
    }

    // Inside a metadata map, `what` names a part of the current item; the full label is
    // composed only on failure, as a corrupt map may state billions of tiny items.
    std::string label(const std::string& what) const
    {
        if (!mMap) return what;
        return *mMap + " item " + std::to_string(mItem) + " of " + std::to_string(mItems) + " " + what;
    }

    // Fails unless n bytes remain before `limit` (the data's or the grid's end).
    void need(uint64_t n, const std::string& what, uint64_t limit)
    {
        if (n <= remaining(limit)) return;
        std::string msg = at(label(what), mPos) + " needs " + std::to_string(n) + " bytes but only "
            + std::to_string(remaining(limit)) + " remain";
        if (limit != mSize) msg += " before the grid's end offset";
        fail(msg + " (truncated or corrupt file)");
    }
    void skip(uint64_t n, const std::string& what, uint64_t limit)
    {
        need(n, what, limit);
        if (n <= 256 && mAt == mPos) {
            // Reading a short field beats seeking past it (see read()).
            char scratch[256];
            read(scratch, size_t(n), what, limit);
        } else {
            mPos += n;
        }
    }
    void skip(uint64_t n, const std::string& what) { skip(n, what, mSize); }
    void read(void* out, size_t n, const std::string& what, uint64_t limit)
    {
        need(n, what, limit);
        // Seek only after a skip: a seek drops a filebuf's buffer, and items are small.
        if ((mAt != mPos && mBuf.pubseekpos(std::streampos(std::streamoff(mPos)), std::ios_base::in) == std::streampos(-1))
            || mBuf.sgetn(static_cast<char*>(out), std::streamsize(n)) != std::streamsize(n))
            fail(at(label(what), mPos) + ": read failed");
        mPos += n;
        mAt = mPos;
    }
    template <class T> T scalar(const std::string& what, uint64_t limit)
    {
        T v;
        read(&v, sizeof v, what, limit);
        return v;
    }
    uint32_t u32(const std::string& what, uint64_t limit) { return scalar<uint32_t>(what, limit); }
    uint32_t u32(const std::string& what) { return u32(what, mSize); }
    int32_t i32(const std::string& what) { return scalar<int32_t>(what, mSize); }
    int64_t i64(const std::string& what) { return scalar<int64_t>(what, mSize); }
    char byte(const std::string& what) { return scalar<char>(what, mSize); }

    // io::readString: a uint32 length, then that many bytes. Returns the text when it is
    // short (type names are), else an empty string.
    std::string string(const std::string& what, uint64_t limit)
    {
        const uint32_t n = u32(what, limit);
        std::string s;
        if (n <= 64) {
            s.resize(n);
            read(s.data(), n, what, limit);
        } else {
            skip(n, what, limit);
        }
        return s;
    }

    // MetaMap::readMeta: a uint32 count, then per item a name, a type name, a uint32 value
    // size and the value (Metadata::read). Fixed-size types read sizeof(T) whatever the
    // stated size; strings and unregistered types read the stated size.
    void meta_map(const std::string& what, uint64_t limit)
    {
        const uint32_t count = u32(what + " count", limit);
        mMap = &what;
        mItems = count;
        for (uint32_t i = 0; i < count; ++i) {
            mItem = i + 1;
            // MetaMap::insertMeta refuses an empty name; refusing it here too stops a
            // corrupt count from making this loop over a file of zeros.
            const uint32_t name = u32("name", limit);
            if (name == 0) fail(label("has an empty name (corrupt file)"));
            skip(name, "name", limit);
            const std::string type = string("type name", limit);
            const uint32_t stated = u32("value size", limit);
            uint64_t n = stated;
            if (!type.empty() && vdb::Metadata::isRegisteredType(type)) {
                // A fresh TypedMetadata has size sizeof(T); a fresh string has size 0.
                const vdb::Index32 fixed = vdb::Metadata::createMetadata(type)->size();
                if (fixed != 0) n = fixed;
            }
            skip(n, type.empty() ? "value" : "value (" + type + ")", limit);
        }
        mMap = nullptr;
    }
};

std::unique_ptr<nimbus_file> read_archive(std::istream& is)
{
    // Both entry points hand over a stream positioned at the start of the data.
    std::streambuf& buf = *is.rdbuf();
    const std::streampos end = buf.pubseekoff(0, std::ios_base::end, std::ios_base::in);
    if (end == std::streampos(-1)) {
        // Not seekable (a pipe given as a path, e.g. /dev/fd/N): read it all into memory,
        // as stdin is, so the layout can be checked before OpenVDB parses it.
        std::vector<char> bytes{std::istreambuf_iterator<char>(is), std::istreambuf_iterator<char>()};
        MemInBuf mem(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
        std::istream ms(&mem);
        ms.exceptions(std::ios_base::failbit | std::ios_base::badbit);
        return read_archive(ms);
    }
    LayoutCheck(buf, uint64_t(std::streamoff(end))).run();
    is.seekg(0);

    // No delayed loading: everything is in memory when this returns, so the source can
    // be overwritten (a tool may write its output over its input).
    vdb::io::Stream stream(is, /*delayLoad=*/false);
    auto file = std::make_unique<nimbus_file>();
    if (auto meta = stream.getMetadata()) file->meta = *meta;
    if (auto grids = stream.getGrids()) {
        for (auto& g : *grids) {
            auto h = std::make_unique<nimbus_grid>();
            h->grid = g;
            file->grids.push_back(std::move(h));
        }
    }
    return file;
}

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

// Values as flat floats: 1 per float voxel, 3 per vec3 voxel.
inline void put(float* out, float v) { out[0] = v; }
inline void put(float* out, const vdb::Vec3f& v) { out[0] = v[0]; out[1] = v[1]; out[2] = v[2]; }
template <class T> T get(const float* in);
template <> inline float get<float>(const float* in) { return in[0]; }
template <> inline vdb::Vec3f get<vdb::Vec3f>(const float* in) { return vdb::Vec3f(in[0], in[1], in[2]); }

std::string grid_label(const GridBase& g) { return "grid '" + g.getName() + "'"; }

void check_kind(const GridBase& g, nimbus_value_kind want)
{
    const nimbus_value_kind have = kind_of(g);
    if (have != want)
        fail(grid_label(g) + " has type " + g.valueType() + ", not readable as " + kind_name(want));
}

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

// ---- points ---------------------------------------------------------------------------

const PointDataGrid& as_points(const GridBase& g)
{
    if (!g.isType<PointDataGrid>()) fail(grid_label(g) + " is not a points grid (type " + g.type() + ")");
    return static_cast<const PointDataGrid&>(g);
}

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

} // namespace

// =======================================================================================
extern "C" {

const char* nimbus_last_error(void) { return g_last_error.c_str(); }
void nimbus_string_free(char* s) { std::free(s); }
void nimbus_bytes_free(uint8_t* data) { std::free(data); }

int32_t nimbus_has_blosc(void)
{
    return vdb::io::Archive::hasBloscCompression() ? 1 : 0;
}

// ---- files ----------------------------------------------------------------------------

int nimbus_file_new(nimbus_file** out)
{
    return guarded([&] {
        require(out, "output pointer");
        *out = new nimbus_file();
    });
}

void nimbus_file_free(nimbus_file* file) { delete file; }

int nimbus_file_read_path(const char* path, nimbus_file** out)
{
    return guarded([&] {
        require(path, "path");
        require(out, "output pointer");
        std::ifstream is(path, std::ios_base::in | std::ios_base::binary);
        if (!is) fail(std::string("cannot open for reading: ") + std::strerror(errno));
        is.exceptions(std::ios_base::failbit | std::ios_base::badbit);
        *out = read_archive(is).release();
    });
}

int nimbus_file_read_bytes(const uint8_t* data, size_t len, nimbus_file** out)
{
    return guarded([&] {
        require(out, "output pointer");
        if (!data && len) fail("null data");
        MemInBuf buf(data, len);
        std::istream is(&buf);
        is.exceptions(std::ios_base::failbit | std::ios_base::badbit);
        *out = read_archive(is).release();
    });
}

int nimbus_file_write_path(const nimbus_file* file, const char* path,
    nimbus_compression compression, int32_t half)
{
    return guarded([&] {
        require(file, "file");
        require(path, "path");
        std::ofstream os(path, std::ios_base::out | std::ios_base::binary | std::ios_base::trunc);
        if (!os) fail(std::string("cannot open for writing: ") + std::strerror(errno));
        // Exceptions on: a full disk must fail the write, not leave a silently short file.
        os.exceptions(std::ios_base::failbit | std::ios_base::badbit);
        write_archive(*file, os, compression, half != 0);
        os.close();
    });
}

int nimbus_file_write_bytes(const nimbus_file* file, nimbus_compression compression,
    int32_t half, uint8_t** data, size_t* len)
{
    return guarded([&] {
        require(file, "file");
        require(data, "output pointer");
        require(len, "output length");
        VecOutBuf buf;
        std::ostream os(&buf);
        os.exceptions(std::ios_base::failbit | std::ios_base::badbit);
        write_archive(*file, os, compression, half != 0);
        uint8_t* out = static_cast<uint8_t*>(std::malloc(buf.data.size() ? buf.data.size() : 1));
        if (!out) throw std::bad_alloc();
        std::memcpy(out, buf.data.data(), buf.data.size());
        *data = out;
        *len = buf.data.size();
    });
}

size_t nimbus_file_grid_count(const nimbus_file* file) { return file ? file->grids.size() : 0; }

const nimbus_grid* nimbus_file_grid(const nimbus_file* file, size_t index)
{
    return file && index < file->grids.size() ? file->grids[index].get() : nullptr;
}

nimbus_grid* nimbus_file_grid_mut(nimbus_file* file, size_t index)
{
    return file && index < file->grids.size() ? file->grids[index].get() : nullptr;
}

int nimbus_file_insert_grid(nimbus_file* file, nimbus_grid* grid)
{
    std::unique_ptr<nimbus_grid> owned(grid);
    return guarded([&] {
        require(file, "file");
        require(owned.get(), "grid");
        owned->point_index.reset(); // building is over: the index is dead weight now
        const std::string name = owned->grid->getName();
        for (auto& g : file->grids) {
            if (g->grid->getName() == name) {
                g = std::move(owned);
                return;
            }
        }
        file->grids.push_back(std::move(owned));
    });
}

void nimbus_file_remove_grid(nimbus_file* file, size_t index)
{
    if (file && index < file->grids.size()) file->grids.erase(file->grids.begin() + long(index));
}

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
        if (auto s = dynamic_cast<const vdb::StringMetadata*>(&m)) {
            out->kind = NIMBUS_META_STRING;
            out->str = s->value().data();
            out->str_len = s->value().size();
        } else if (auto b = dynamic_cast<const vdb::BoolMetadata*>(&m)) {
            out->kind = NIMBUS_META_BOOL;
            out->i = b->value() ? 1 : 0;
        } else if (auto i32 = dynamic_cast<const vdb::Int32Metadata*>(&m)) {
            out->kind = NIMBUS_META_I32;
            out->i = i32->value();
        } else if (auto i64 = dynamic_cast<const vdb::Int64Metadata*>(&m)) {
            out->kind = NIMBUS_META_I64;
            out->i = i64->value();
        } else if (auto f32 = dynamic_cast<const vdb::FloatMetadata*>(&m)) {
            out->kind = NIMBUS_META_F32;
            out->f = f32->value();
        } else if (auto f64 = dynamic_cast<const vdb::DoubleMetadata*>(&m)) {
            out->kind = NIMBUS_META_F64;
            out->f = f64->value();
        } else if (auto v3i = dynamic_cast<const vdb::Vec3IMetadata*>(&m)) {
            out->kind = NIMBUS_META_VEC3I;
            for (int c = 0; c < 3; ++c) out->v[c] = v3i->value()[c];
        } else if (auto v3f = dynamic_cast<const vdb::Vec3SMetadata*>(&m)) {
            out->kind = NIMBUS_META_VEC3F;
            for (int c = 0; c < 3; ++c) out->v[c] = v3f->value()[c];
        } else if (auto v3d = dynamic_cast<const vdb::Vec3DMetadata*>(&m)) {
            out->kind = NIMBUS_META_VEC3D;
            for (int c = 0; c < 3; ++c) out->v[c] = v3d->value()[c];
        }
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
        require(grid, "grid");
        require(name, "attribute name");
        if (!out && count) fail("null output");
        const PointDataGrid& points = as_points(*grid->grid);
        const std::string label = grid_label(points) + " attribute '" + name + "'";
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
        require(grid, "grid");
        require(name, "group name");
        if (!out && count) fail("null output");
        const PointDataGrid& points = as_points(*grid->grid);
        const std::string label = grid_label(points) + " group '" + name + "'";
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
