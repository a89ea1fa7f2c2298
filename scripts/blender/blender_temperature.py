"""Adds the temperature Cycles reads for a Mantaflow domain to a bundled fire VDB.

    blender -b fire.blend -t 1 --python-exit-code 1 -P scripts/blender/blender_temperature.py -- \
        BUNDLE.vdb OUT.vdb

The `temperature` grid in Blender's OpenVDB cache is Mantaflow's heat (advected, cooling,
non-zero over nearly all the smoke). What Cycles' Principled Volume reads as the `temperature`
attribute of a fluid domain is another field (rna_fluid.cc, FluidDomainSettings.temperature_grid,
which Cycles' BlenderSmokeLoader loads): flame_ignition + flame * (flame_max_temp -
flame_ignition) where flame > 0.01, else 0 (the domain's defaults 1.5 and 3.0: 1500 to
3000 K at Temperature 1000), i.e. only where it burns. This script reads that array from the
evaluated domain at the scene's last frame, checks that the bundle's density, flame and
temperature grids are the same frame (density and flame equal to Blender's arrays, the
bundle's temperature twice Blender's heat_grid, which RNA scales by 0.5), and writes OUT.vdb:
the bundle's grids plus `blender_temperature` on the same transform, for
`vdbmarch --temperature-grid blender_temperature --temperature-scale 1000`.
"""

import sys

import bpy
import numpy as np
import pyopenvdb as vdb


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    bundle, out = argv[0], argv[1]
    scene = bpy.context.scene
    scene.frame_set(scene.frame_end)
    domain = next(o for o in scene.objects
                  if any(m.type == "FLUID" and m.fluid_type == "DOMAIN" for m in o.modifiers))
    ev = domain.evaluated_get(bpy.context.evaluated_depsgraph_get())
    ds = next(m for m in ev.modifiers if m.type == "FLUID").domain_settings
    res = tuple(ds.domain_resolution)

    def rna(name):  # Blender's flat arrays run x fastest: reshape to [x][y][z]
        return np.array(getattr(ds, name + "_grid"), np.float32).reshape(res[::-1]).transpose(2, 1, 0)

    grids = []
    for name, want, scale in (("density", "density", 1.0), ("flame", "flame", 1.0),
                              ("temperature", "heat", 2.0)):
        g = vdb.read(bundle, name)
        a = np.zeros(res, np.float32)
        g.copyToArray(a, ijk=(0, 0, 0))
        d = np.abs(a - scale * rna(want)).max()
        print(f"blender_temperature: bundle {name} against Blender's {want}_grid x {scale:g}: "
              f"max |difference| {d:.3g}", flush=True)
        if d > 1e-3 * max(a.max(), 1e-6):
            print("blender_temperature: error: the bundle is not this .blend's frame "
                  f"{scene.frame_current}", file=sys.stderr)
            sys.exit(1)
        grids.append(g)
    t = np.ascontiguousarray(rna("temperature"))  # pyopenvdb ignores numpy strides
    g = vdb.FloatGrid()
    g.copyFromArray(t, ijk=(0, 0, 0), tolerance=0.0)
    g.transform = grids[0].transform
    g.name = "blender_temperature"
    g.gridClass = vdb.GridClass.FOG_VOLUME
    grids.append(g)
    vdb.write(out, grids=grids)
    print(f"blender_temperature: {out}: + blender_temperature ({int((t > 0).sum())} voxels "
          f"non-zero, max {t.max():.4f}; ignition {ds.flame_ignition}, max temp "
          f"{ds.flame_max_temp}; the heat in 'temperature': {int((grids[2].activeVoxelCount()))} "
          f"active voxels)", flush=True)


if __name__ == "__main__":
    main()
