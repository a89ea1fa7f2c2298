// nimbus_vdb.cpp -- the OpenVDB 10 side of the bridge declared in nimbus_vdb.h: errors and
// files (reading and writing archives, from paths or memory). Grids, points and metadata
// are in their own files; nimbus_vdb_internal.h holds what they share.

#include "nimbus_vdb_internal.h"

using namespace nimbus_bridge;

namespace {

thread_local std::string g_last_error;

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

} // namespace

namespace nimbus_bridge {

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

} // namespace nimbus_bridge

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

} // extern "C"
