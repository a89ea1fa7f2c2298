/*
 * nimbus_vdb.h -- plain C interface to the OpenVDB 10 bridge (nimbus_vdb.cpp).
 *
 * bindgen reads this header for crates/vdb; nothing here may be C++.
 *
 * Conventions
 * - Every function that can fail returns an int status: NIMBUS_OK (0) or NIMBUS_ERR (1).
 *   On NIMBUS_ERR the message is available from nimbus_last_error() on the same thread
 *   until the next bridge call on that thread. No C++ exception ever leaves the bridge.
 * - Handles are opaque. A nimbus_file owns its grids; a `const nimbus_grid*` obtained
 *   from nimbus_file_grid() is borrowed and stays valid until that grid is removed or
 *   replaced, or the file is freed. A nimbus_grid* returned by a constructor is owned by
 *   the caller until handed to nimbus_file_insert_grid() or freed with nimbus_grid_free().
 * - Strings returned through `char**` are malloc'd by the bridge; release them with
 *   nimbus_string_free(). Byte buffers likewise with nimbus_bytes_free().
 * - Transforms cross the boundary as 12 doubles in glam's DAffine3 column order:
 *   m[0..3] = world image of index +x, m[3..6] = of +y, m[6..9] = of +z,
 *   m[9..12] = translation (world position of index (0,0,0)). The bridge converts to
 *   and from OpenVDB's row-vector Mat4d (world = index * M).
 * - Leaves are OpenVDB LeafNode<T,3>: origin = minimum corner (a multiple of 8),
 *   512 values in LeafNode::coordToOffset order ((x<<6)|(y<<3)|z), vec3 values as
 *   3 consecutive floats, and the value mask as 8 little 64-bit words
 *   (bit n of word n/64 = voxel offset n), as in util::NodeMask<3>.
 */
#ifndef NIMBUS_VDB_H
#define NIMBUS_VDB_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define NIMBUS_OK 0
#define NIMBUS_ERR 1

typedef struct nimbus_file nimbus_file;
typedef struct nimbus_grid nimbus_grid;
typedef struct nimbus_leaf_iter nimbus_leaf_iter;

/* What a grid can be read as. */
typedef enum nimbus_value_kind {
    NIMBUS_VALUE_OTHER = 0,  /* any other grid type: listed and passed through only */
    NIMBUS_VALUE_FLOAT = 1,  /* float (also saved-as-half) and double grids */
    NIMBUS_VALUE_VEC3F = 3,  /* vec3s and vec3d grids */
    NIMBUS_VALUE_POINTS = 4  /* OpenVDB points (PointDataGrid) */
} nimbus_value_kind;

/* openvdb::GridClass values, in the same order. */
typedef enum nimbus_grid_class {
    NIMBUS_CLASS_UNKNOWN = 0,
    NIMBUS_CLASS_LEVEL_SET = 1,
    NIMBUS_CLASS_FOG_VOLUME = 2,
    NIMBUS_CLASS_STAGGERED = 3
} nimbus_grid_class;

/* openvdb::VecType values, in the same order (the `vector_type` grid metadata). */
typedef enum nimbus_vector_type {
    NIMBUS_VEC_INVARIANT = 0,
    NIMBUS_VEC_COVARIANT = 1,
    NIMBUS_VEC_COVARIANT_NORMALIZE = 2,
    NIMBUS_VEC_CONTRAVARIANT_RELATIVE = 3,
    NIMBUS_VEC_CONTRAVARIANT_ABSOLUTE = 4
} nimbus_vector_type;

typedef enum nimbus_compression {
    NIMBUS_COMPRESS_ZIP = 0,
    NIMBUS_COMPRESS_BLOSC = 1,
    NIMBUS_COMPRESS_NONE = 2
} nimbus_compression;

typedef enum nimbus_meta_kind {
    NIMBUS_META_UNKNOWN = 0, /* a type the bridge does not convert: skip it */
    NIMBUS_META_STRING = 1,
    NIMBUS_META_BOOL = 2,
    NIMBUS_META_I32 = 3,
    NIMBUS_META_I64 = 4,
    NIMBUS_META_F32 = 5,
    NIMBUS_META_F64 = 6,
    NIMBUS_META_VEC3I = 7,
    NIMBUS_META_VEC3F = 8,
    NIMBUS_META_VEC3D = 9
} nimbus_meta_kind;

/* One metadata entry. Pointers are borrowed from the metadata owner and valid until it
 * changes. Integers travel in `i` (bool as 0/1), floats in `f`, vec3 in `v` (vec3i and
 * vec3f are exact in doubles). */
typedef struct nimbus_meta_value {
    const char *name;
    const char *type_name; /* OpenVDB's type name, e.g. "string", "vec3s" */
    nimbus_meta_kind kind;
    const char *str;
    size_t str_len;
    int64_t i;
    double f;
    double v[3];
} nimbus_meta_value;

typedef struct nimbus_grid_info {
    char *name;      /* owned: free with nimbus_grid_info_clear */
    char *type_name; /* OpenVDB grid type, e.g. "Tree_float_5_4_3" */
    char *value_type; /* OpenVDB value type, e.g. "float", "vec3s", "ptdataidx32" */
    char *map_type;  /* e.g. "AffineMap", "UniformScaleTranslateMap", "NonlinearFrustumMap" */
    nimbus_value_kind kind;
    nimbus_grid_class grid_class;
    int32_t is_affine;         /* the transform is linear: index_to_world is valid */
    double index_to_world[12]; /* see the transform convention above */
    uint64_t active_voxel_count;
    int32_t has_bbox;          /* 0 for an empty grid */
    int32_t bbox_min[3];       /* inclusive index bbox of active voxels */
    int32_t bbox_max[3];
    uint64_t point_count;      /* points grids only, else 0 */
    int32_t saved_as_half;
} nimbus_grid_info;

/* ---- errors and memory ---------------------------------------------------------- */

/* Message of the last failed call on this thread ("" if none). Borrowed. */
const char *nimbus_last_error(void);
void nimbus_string_free(char *s);
void nimbus_bytes_free(uint8_t *data);
/* Whether this OpenVDB build can write blosc-compressed files. */
int32_t nimbus_has_blosc(void);

/* ---- files ---------------------------------------------------------------------- */

int nimbus_file_new(nimbus_file **out);
void nimbus_file_free(nimbus_file *file);
/* Reads every grid (no delayed loading: the path may be overwritten afterwards). */
int nimbus_file_read_path(const char *path, nimbus_file **out);
/* Reads from bytes in memory (e.g. stdin) through io::Stream. */
int nimbus_file_read_bytes(const uint8_t *data, size_t len, nimbus_file **out);
/* Writes the OpenVDB file format (with grid offsets, as io::File writes it) to `path`,
 * creating or truncating it. Atomic replacement is the caller's job. `half` makes
 * float-based grids save as 16-bit halves. */
int nimbus_file_write_path(const nimbus_file *file, const char *path,
                           nimbus_compression compression, int32_t half);
/* The same bytes into a malloc'd buffer (*data freed with nimbus_bytes_free). */
int nimbus_file_write_bytes(const nimbus_file *file, nimbus_compression compression,
                            int32_t half, uint8_t **data, size_t *len);

size_t nimbus_file_grid_count(const nimbus_file *file);
/* Borrowed grid at index, or NULL when out of range. */
const nimbus_grid *nimbus_file_grid(const nimbus_file *file, size_t index);
nimbus_grid *nimbus_file_grid_mut(nimbus_file *file, size_t index);
/* Takes ownership of `grid` (even on failure). A grid of the same name is replaced in
 * place, else the grid is appended. */
int nimbus_file_insert_grid(nimbus_file *file, nimbus_grid *grid);
/* Removes the grid at index (no-op when out of range). */
void nimbus_file_remove_grid(nimbus_file *file, size_t index);

/* ---- metadata ------------------------------------------------------------------- */

/* A metadata map: the file's, or a grid's (a grid is an openvdb::MetaMap; its name and
 * class live there too, as "name" and "class"). Borrowed from the file or grid. */
typedef struct nimbus_meta nimbus_meta;
const nimbus_meta *nimbus_file_meta(const nimbus_file *file);
nimbus_meta *nimbus_file_meta_mut(nimbus_file *file);
const nimbus_meta *nimbus_grid_meta(const nimbus_grid *grid);
nimbus_meta *nimbus_grid_meta_mut(nimbus_grid *grid);

size_t nimbus_meta_count(const nimbus_meta *meta);
/* Entry `index` in name order. */
int nimbus_meta_get(const nimbus_meta *meta, size_t index, nimbus_meta_value *out);
/* Inserts or replaces; only `name`, `kind` and the matching payload field are read. */
int nimbus_meta_set(nimbus_meta *meta, const nimbus_meta_value *value);
/* Removes `name` if present. */
int nimbus_meta_remove(nimbus_meta *meta, const char *name);

/* ---- grids ---------------------------------------------------------------------- */

int nimbus_grid_get_info(const nimbus_grid *grid, nimbus_grid_info *out);
void nimbus_grid_info_clear(nimbus_grid_info *info);
void nimbus_grid_free(nimbus_grid *grid);
/* A copy to insert into another file: metadata and transform are copied, the tree is
 * shared (the bridge never modifies the tree of a grid that is in a file). */
int nimbus_grid_copy(const nimbus_grid *grid, nimbus_grid **out);

/* A new, empty float or vec3f grid (`kind` 1 or 3 floats of background). The transform
 * is stored as the simplest equivalent OpenVDB linear map. */
int nimbus_grid_new(nimbus_value_kind kind, const char *name, nimbus_grid_class grid_class,
                    const float *background, const double index_to_world[12],
                    nimbus_grid **out);
/* Adds (or replaces) the leaf at `origin`: 512 * kind floats and 8 mask words. */
int nimbus_grid_add_leaf(nimbus_grid *grid, const int32_t origin[3], const float *values,
                         const uint64_t mask[8]);

/* Sets a vec3 grid's vector type (GridBase::setVectorType: how a transform acts on its
 * values; velocity is contravariant relative, as Houdini and Blender write it). */
int nimbus_grid_set_vector_type(nimbus_grid *grid, nimbus_vector_type type);

/* Iterates the leaves of a float or vec3f grid (converting double grids, and voxelizing
 * active tiles so every active value arrives in a leaf). `background` receives `kind`
 * floats. The iterator keeps what it needs alive and may outlive the file. */
int nimbus_leaf_iter_new(const nimbus_grid *grid, nimbus_value_kind kind, float *background,
                         nimbus_leaf_iter **out);
/* Number of leaves the iterator yields in total. */
size_t nimbus_leaf_iter_len(const nimbus_leaf_iter *iter);
/* Copies the next leaf out; returns 1 if one was copied, 0 at the end. */
int nimbus_leaf_iter_next(nimbus_leaf_iter *iter, int32_t origin[3], float *values,
                          uint64_t mask[8]);
void nimbus_leaf_iter_free(nimbus_leaf_iter *iter);

/* ---- points --------------------------------------------------------------------- */

/* A point grid from `count` world positions (xyz doubles). `voxel_size` <= 0 picks one
 * with points::computeVoxelSize (about 8 points per voxel). Positions are stored as
 * float offsets within voxels, so they come back to about 1e-7 voxel. */
int nimbus_points_new(const char *name, const double *positions, size_t count,
                      double voxel_size, nimbus_grid **out);
/* Appends a float (kind 1) or vec3f (kind 3) attribute with one value per point, in the
 * order the positions were given. Only valid on a grid made by nimbus_points_new and
 * not yet inserted into a file. */
int nimbus_points_add_attribute(nimbus_grid *grid, const char *name, nimbus_value_kind kind,
                                const float *values, size_t count);

size_t nimbus_points_attribute_count(const nimbus_grid *grid);
/* Name, OpenVDB value type and codec of attribute `index` (descriptor order); `*kind`
 * is FLOAT or VEC3F when it can be read as such, else OTHER. */
int nimbus_points_attribute_info(const nimbus_grid *grid, size_t index, char **name,
                                 char **type_name, char **codec, nimbus_value_kind *kind);
/* World positions (count xyz doubles, count = info.point_count), in leaf order. */
int nimbus_points_read_positions(const nimbus_grid *grid, double *out, size_t count);
/* An attribute in the same order as nimbus_points_read_positions. */
int nimbus_points_read_attribute(const nimbus_grid *grid, const char *name,
                                 nimbus_value_kind kind, float *out, size_t count);

/* Names of the grid's point groups in descriptor order, each followed by '\n', as one
 * malloc'd string (empty when there are none). */
int nimbus_points_group_names(const nimbus_grid *grid, char **names);
/* Membership of group `name` per point (1 or 0), in the order of nimbus_points_read_positions. */
int nimbus_points_read_group(const nimbus_grid *grid, const char *name, uint8_t *out, size_t count);

/* ---- reference sampling (tests) ------------------------------------------------- */

/* openvdb::tools::BoxSampler on a float or vec3f grid at `count` points (xyz doubles),
 * in index space (world == 0) or world space (world != 0). out: count * kind floats. */
int nimbus_sample_box(const nimbus_grid *grid, nimbus_value_kind kind, const double *points,
                      size_t count, int32_t world, float *out);

/* A float fog grid with a NonlinearFrustumMap transform and one active voxel, for tests
 * that a non-affine transform is refused. */
int nimbus_test_frustum_grid(const char *name, nimbus_grid **out);

/* A points grid as Houdini writes it by default, for tests of reading one: positions with
 * 16-bit fixed-point compression (FixedPointCodec<false, PositionRange>, "ufxpt16"), a vec3f
 * attribute `v` (half-float TruncateCodec), a float attribute `temperature`, and a point
 * group `group` holding the points whose in_group entry is non-zero. count of each. */
int nimbus_test_houdini_points(const char *name, const double *positions, const float *v,
                               const float *temperature, const uint8_t *in_group, size_t count,
                               double voxel_size, const char *group, nimbus_grid **out);

/* A double (from float) or vec3d (from vec3s) copy of a grid, same name, transform and
 * metadata, for tests of reading double-precision grids. */
int nimbus_test_widen_grid(const nimbus_grid *grid, nimbus_grid **out);

#ifdef __cplusplus
}
#endif

#endif /* NIMBUS_VDB_H */
