#!/usr/bin/python3
"""Writes a small validation scene for the peer comparisons: an off-centre soft ball plus a
smaller lump in one corner (so any flip of an image or grid axis shows), on an index box that
does not start at 0, with a translated world transform and nimbus:* metadata for the medium,
a sun from the side and a camera. Run with /usr/bin/python3 (pyopenvdb)."""
import argparse

import numpy as np
import pyopenvdb as vdb

ap = argparse.ArgumentParser(description=__doc__)
ap.add_argument("output")
ap.add_argument("--n", type=int, default=32, help="voxels per side")
ap.add_argument("--voxel", type=float, default=0.05)
ap.add_argument("--peak", type=float, default=1.0, help="density at the ball's centre")
args = ap.parse_args()

n = args.n
x = (np.arange(n) + 0.5) / n        # unit coordinates of the voxels
X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
ball = np.clip(1 - np.sqrt((X - 0.45) ** 2 + (Y - 0.5) ** 2 + (Z - 0.55) ** 2) / 0.38, 0, 1)
lump = np.clip(1 - np.sqrt((X - 0.8) ** 2 + (Y - 0.3) ** 2 + (Z - 0.2) ** 2) / 0.15, 0, 1)
dens = (args.peak * (ball ** 1.5 + 1.5 * lump)).astype(np.float32)

grid = vdb.FloatGrid()
grid.name = "density"
grid.gridClass = vdb.GridClass.FOG_VOLUME
lo = (3, -2, 5)
grid.copyFromArray(dens, ijk=lo)
xform = vdb.createLinearTransform(voxelSize=args.voxel)
xform.translate((0.1, 0.2, -0.3))
grid.transform = xform

# World centre of the index box, for the camera.
c = np.array(xform.indexToWorld(tuple(l + (n - 1) / 2 for l in lo)))
eye = c + np.array([0.6, -3.2, 0.9])
meta = {
    "nimbus:medium": "extinction=6,albedo=0.95,0.8,0.6,g=0.4",
    "nimbus:lights": "dir=-0.8,0.3,-0.5,irradiance=3,2.8,2.5",
    "nimbus:camera": "eye={},look-at={},up=0,0,1,fov=35,width=64,height=48".format(
        ",".join(f"{v:.6g}" for v in eye), ",".join(f"{v:.6g}" for v in c)),
}
vdb.write(args.output, grids=[grid], metadata=meta)
print(f"wrote {args.output}: {n}^3 voxels from {lo}, centre {c}")
