#!/usr/bin/python3
"""Independent OpenVDB reader and fixture writer for crates/vdb tests, using pyopenvdb.

Run with Debian's /usr/bin/python3 (python3-openvdb), not another interpreter.

    pyvdb.py describe FILE      print JSON: file metadata and, per grid, name, value type,
                                class, transform, active bbox and count, metadata and every
                                active value (tiles expanded), for small test grids
    pyvdb.py fixtures FILE      write third-party style inputs: active tiles, a grid saved
                                as half floats, a frustum-transform grid
"""
import json
import sys

import pyopenvdb as vdb


def plain(value):
    """Metadata and values as JSON-friendly lists and scalars."""
    if isinstance(value, (tuple, list)):
        return [plain(v) for v in value]
    return value


def describe(path):
    grids, file_meta = vdb.readAll(path)
    out = {"metadata": {k: plain(v) for k, v in file_meta.items()}, "grids": []}
    for grid in grids:
        xform = grid.transform
        origin = xform.indexToWorld((0, 0, 0))
        axes = [
            [a - o for a, o in zip(xform.indexToWorld(e), origin)]
            for e in ((1, 0, 0), (0, 1, 0), (0, 0, 1))
        ]
        lo, hi = grid.evalActiveVoxelBoundingBox()
        values = []
        for item in grid.citerOnValues():
            (x0, y0, z0), (x1, y1, z1) = item.min, item.max
            for x in range(x0, x1 + 1):
                for y in range(y0, y1 + 1):
                    for z in range(z0, z1 + 1):
                        values.append([[x, y, z], plain(item.value)])
        out["grids"].append({
            "name": grid.name,
            "value_type": grid.valueTypeName,
            "class": grid.gridClass,
            "map_type": xform.typeName,
            "index_axes": axes,
            "translation": list(origin),
            "bbox": [list(lo), list(hi)],
            "active_voxel_count": grid.activeVoxelCount(),
            "background": plain(grid.background),
            "metadata": {k: plain(v) for k, v in grid.metadata.items()},
            "values": values,
        })
    json.dump(out, sys.stdout)


def fixtures(path):
    # Active tiles: a 64^3 fill at a node boundary becomes internal-node tiles, not leaves.
    tiles = vdb.FloatGrid(0.0)
    tiles.name = "tiles"
    tiles.gridClass = vdb.GridClass.FOG_VOLUME
    tiles.fill((0, 0, 0), (63, 63, 63), 0.5, True)
    tiles.getAccessor().setValueOn((100, 3, 4), 2.0)
    tiles.transform = vdb.createLinearTransform(0.25)

    vtiles = vdb.Vec3SGrid((0.0, 0.0, 0.0))
    vtiles.name = "vtiles"
    vtiles.fill((-16, -16, -16), (-1, -1, -1), (1.0, 2.0, 3.0), True)

    # Half: values exactly representable in binary16 come back exactly; 0.1 does not.
    half = vdb.FloatGrid(0.0)
    half.name = "half"
    half.saveFloatAsHalf = True
    acc = half.getAccessor()
    acc.setValueOn((1, 2, 3), 0.5)
    acc.setValueOn((4, 5, 6), 1.25)
    acc.setValueOn((7, 8, 9), 0.1)

    frustum = vdb.FloatGrid(0.0)
    frustum.name = "frustum"
    frustum.transform = vdb.createFrustumTransform((0, 0, 0), (16, 16, 16), 0.5, 10.0)
    frustum.getAccessor().setValueOn((1, 2, 3), 1.0)

    vdb.write(path, grids=[tiles, vtiles, half, frustum], metadata={"made_by": "pyvdb.py"})


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] not in ("describe", "fixtures"):
        sys.exit(__doc__)
    {"describe": describe, "fixtures": fixtures}[sys.argv[1]](sys.argv[2])
