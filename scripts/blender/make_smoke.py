"""Bakes a Blender (Mantaflow) smoke plume, or a fire, to an OpenVDB file nimbus can read.

    blender -b --python-exit-code 1 --python scripts/blender/make_smoke.py -- OUTDIR \
        [--fire] [--resolution N] [--frames F] [--bundle PATH]

Builds what Blender's Object > Quick Effects > Quick Smoke builds from one small emitter, by
hand (the operator's geometry and material, without its fake-context operator calls): an
icosphere of radius 0.25 at the origin as the smoke flow (inflow, from its surface), a gas
domain around it as Quick Smoke places one (centre 1 unit above the emitter, half extents
its own plus (1, 1, 2): a 2.5 x 2.5 x 4.5 box from z = -1.25 to 3.25), and the domain's
Principled Volume material (density 5; blackbody intensity 1 for fire). The plume rises
from the emitter as a narrow stem under a wider cap (at frame 40 it covers 23% of the
domain's columns seen from above), so a sun's disc over the domain's box mostly misses it:
the case issue #18 measured vdbphoton on.

Then it bakes the simulation (cache type All, OpenVDB format, noise off, frames 1..F) into
OUTDIR/cache_smoke (or cache_fire), copies the last frame's `data/fluid_data_####.vdb` to
OUTDIR/smoke.vdb (fire.vdb with --fire) and saves OUTDIR/smoke.blend (fire.blend), which
keeps the cache as a path relative to itself, a sun from above (nimbus's default sun,
direction 0,0,-1) and a camera framing the domain from -Y (fov 40, 960 x 540, as nimbus's
default camera), with Cycles as the render engine, for a later Cycles comparison.

--fire: the flow emits fuel (Quick Smoke's "Fire" style; flow type FIRE), which burns into
`flame` and heat (`temperature`) and makes smoke from the flame (the domain's flame smoke
1.0), so `density`, `flame` and `temperature` are all non-zero (Blender keeps fuel and react
out of the OpenVDB data file: fire.vdb has the same five grids as smoke.vdb).

Defaults: resolution 64 (the domain's longest side: voxel 4.5/64 = 0.0703125, grid 36 x 36
x 64), 40 frames; the bake took 8 s (smoke, 8.0 CPU s) and 8 s (fire) on two cores.

What Blender 3.4.1 (Debian 12) writes, `vdb_print -l -m` of smoke.vdb at the defaults
(frame 40; the cache's OpenVDB defaults: blosc, half floats):

    grid         type                 class       active voxels  active bbox (index)      min .. max
    density      Tree_float_5_4_3     fog volume   8,707         [5,5,13]->[30,30,45]     1.0e-6 .. 0.993
    flame        Tree_float_5_4_3     fog volume   0 (empty tree; present even without fire)
    shadow       Tree_float_5_4_3     fog volume   82,944 + 36 tiles  [0,0,0]->[35,35,63]  0.038 .. 1
    temperature  Tree_float_5_4_3     fog volume   8,559         [5,5,13]->[30,30,45]     1.0e-6 .. 1
    velocity     Tree_vec3s_5_4_3     staggered    8,707         [5,5,13]->[30,30,45]

    fire.vdb (--fire): density 11,542 voxels [5,4,13]->[31,30,53], max 0.138; flame 1,521
    [13,12,13]->[23,23,46], max 0.959; temperature 11,493, max 2.94; shadow and velocity as
    above.

- Every grid is written with is_saved_as_half_float: true, file_compression: blosc, and
  file_base_resolution [36, 36, 64] (the domain's resolution); no file-level metadata.
- Transform: a plain scale, voxel size 0.0703125 (= 4.5 / 64), no translation: index
  (i,j,k) sits at world (i,j,k) * 0.0703125. The domain's own placement (its min corner at
  Blender's (-1.25, -1.25, -1.25), the object's matrix) is not in the file, so in the VDB's
  world space the plume sits 1.25 units off on each axis from where Blender shows it:
  Blender places the cache by the domain object, mapping the grid onto the domain's box
  (texel centres at (i + 0.5) / res), so in Blender's world voxels are 2.5/36 = 0.0694 wide
  in x and y and 4.5/64 in z, half a voxel further in. `--bundle PATH` writes the frame with
  that transform (write_bundle below; checked against Cycles by scripts/compare_cycles.sh,
  whose sunlit smoke agrees to 0.9% RMSE). In the cache's own transform voxels are cubic.
- `shadow` is Mantaflow's light transmittance over the whole domain (dense), not medium;
  nimbus's default `--grid density` is the one to render.
- Optical depth at nimbus's default extinction 1 (density x voxel size summed along an
  axis): at most 2.0 along z, 1.0 along x or y, 0.24 on average over the covered columns
  from above: a faint plume. The .blend's material (Quick Smoke's) renders it at density 5
  in Cycles, which is nimbus's `--extinction 5` (not compared here).
- The plume covers 300 of the domain's 36 x 36 columns seen from above (23%; the active
  bbox 26 x 26), so a sun's disc over the domain's box would mostly miss it.
"""

import argparse
import glob
import os
import shutil
import sys
import time

import bpy
from mathutils import Vector


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="make_smoke.py", description=__doc__.split("\n")[0])
    p.add_argument("outdir")
    p.add_argument("--fire", action="store_true", help="fuel + flame instead of smoke only")
    p.add_argument("--resolution", type=int, default=64, help="domain resolution (longest side)")
    p.add_argument("--frames", type=int, default=40, help="frames to bake (the last is kept)")
    p.add_argument("--bundle", metavar="PATH",
                   help="also write the last frame's density, flame and temperature grids here, "
                        "in Blender's world space (the file nimbus bundles as data/fire.vdb)")
    return p.parse_args(argv)


def principled_volume_material(fire):
    """Quick Smoke's domain material (Blender 3.4 bl_operators/object_quick_effects.py)."""
    mat = bpy.data.materials.new("Smoke Domain Material")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new(type="ShaderNodeOutputMaterial")
    out.location = (600, 0)
    vol = nodes.new(type="ShaderNodeVolumePrincipled")
    vol.location = (300, 0)
    links.new(vol.outputs["Volume"], out.inputs["Volume"])
    vol.inputs["Density"].default_value = 5.0
    if fire:
        vol.inputs["Blackbody Intensity"].default_value = 1.0
    return mat


def main():
    args = parse_args()
    name = "fire" if args.fire else "smoke"
    outdir = os.path.abspath(args.outdir)
    os.makedirs(outdir, exist_ok=True)
    blend_path = os.path.join(outdir, name + ".blend")
    cache_name = "cache_" + name
    cache_dir = os.path.join(outdir, cache_name)
    if os.path.isdir(cache_dir):
        shutil.rmtree(cache_dir)  # a stale bake would be resumed, not redone

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0  # no smoke.blend1 beside the .blend
    scene = bpy.context.scene
    scene.frame_start = 1
    scene.frame_end = args.frames
    scene.render.engine = "CYCLES"
    scene.render.resolution_x, scene.render.resolution_y = 960, 540
    scene.render.resolution_percentage = 100

    # The flow: a small icosphere, as a user would add for Quick Smoke.
    bpy.ops.mesh.primitive_ico_sphere_add(radius=0.25, subdivisions=2, location=(0, 0, 0))
    flow = bpy.context.active_object
    flow.name = "Smoke Emitter"
    fmod = flow.modifiers.new("Fluid", "FLUID")
    fmod.fluid_type = "FLOW"
    fs = fmod.flow_settings
    fs.flow_type = "FIRE" if args.fire else "SMOKE"
    fs.flow_behavior = "INFLOW"
    fs.flow_source = "MESH"
    flow.display_type = "WIRE"  # Quick Smoke hides the flows' surfaces (show_flows off)
    flow.hide_render = True

    # The domain, where Quick Smoke puts it: bounding box centre + (0,0,1), half extents + (1,1,2).
    lo, hi = Vector((-0.25,) * 3), Vector((0.25,) * 3)
    bpy.ops.mesh.primitive_cube_add(size=2)
    domain = bpy.context.active_object
    domain.name = "Smoke Domain"
    domain.location = 0.5 * (hi + lo) + Vector((0.0, 0.0, 1.0))
    domain.scale = 0.5 * (hi - lo) + Vector((1.0, 1.0, 2.0))
    dmod = domain.modifiers.new("Fluid", "FLUID")
    dmod.fluid_type = "DOMAIN"
    ds = dmod.domain_settings
    ds.domain_type = "GAS"
    ds.resolution_max = args.resolution
    ds.use_noise = False  # Quick Fire turns noise on; its upres lives in other files, and costs time
    ds.use_adaptive_domain = False
    ds.cache_type = "ALL"
    ds.cache_data_format = "OPENVDB"
    ds.cache_frame_start = 1
    ds.cache_frame_end = args.frames
    domain.data.materials.append(principled_volume_material(args.fire))

    # A sun from above and a camera from -Y, as nimbus's defaults (design.md section 4).
    sun_data = bpy.data.lights.new("Sun", type="SUN")
    sun_data.energy = 4.0
    sun = bpy.data.objects.new("Sun", sun_data)
    sun.location = (0, 0, 6)  # a sun's direction is its -Z: straight down at rotation 0
    scene.collection.objects.link(sun)
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = 40.0 * 3.141592653589793 / 180.0
    cam = bpy.data.objects.new("Camera", cam_data)
    centre = domain.location.copy()
    half = domain.scale.copy()
    # Distance at which the box's width (x) and height (z) both fit the 40-degree, 16:9 frame.
    import math
    tx = math.tan(math.radians(20.0))
    tz = tx * 540.0 / 960.0
    dist = half.y + max(half.x / tx, half.z / tz) * 1.05
    cam.location = centre + Vector((0.0, -dist, 0.0))
    cam.rotation_euler = (math.radians(90.0), 0.0, 0.0)  # looking along +Y, up +Z
    scene.collection.objects.link(cam)
    scene.camera = cam

    # Save first, so the cache path can be relative to the .blend (the pair moves together).
    bpy.ops.wm.save_as_mainfile(filepath=blend_path)
    ds.cache_directory = "//" + cache_name
    print(f"make_smoke: {name}, resolution {args.resolution}, frames 1..{args.frames}, "
          f"cache {cache_dir}; compression {ds.openvdb_cache_compress_type}, "
          f"precision {ds.openvdb_data_depth}", flush=True)

    bpy.context.view_layer.objects.active = domain
    domain.select_set(True)
    t0 = time.time()
    with bpy.context.temp_override(object=domain, active_object=domain):
        result = bpy.ops.fluid.bake_all()
    print(f"make_smoke: bake_all {result} in {time.time() - t0:.1f} s", flush=True)
    bpy.ops.wm.save_as_mainfile(filepath=blend_path)

    files = sorted(glob.glob(os.path.join(cache_dir, "data", "fluid_data_*.vdb")))
    if not files:
        print(f"make_smoke: error: no fluid_data_*.vdb under {cache_dir}/data", file=sys.stderr)
        sys.exit(1)
    last = files[-1]
    want = os.path.join(cache_dir, "data", "fluid_data_%04d.vdb" % args.frames)
    if last != want:
        print(f"make_smoke: warning: last frame is {last}, expected {want}", file=sys.stderr)
    target = os.path.join(outdir, name + ".vdb")
    shutil.copyfile(last, target)
    print(f"make_smoke: {last} -> {target}; {blend_path}", flush=True)
    if args.bundle:
        write_bundle(last, domain, os.path.abspath(args.bundle))


def write_bundle(cache_file, domain, path):
    """The cache frame with the domain's placement baked into the VDB transform.

    Mantaflow writes its grids with a plain scale (voxel size dx = the domain's longest side
    / resolution) and no translation, in the domain's own grid space. Blender draws and renders
    them by the domain object instead: Cycles maps the grid onto the domain mesh's texture
    space (its bounding box, texel i's centre at (i + 0.5) / res), so world = matrix_world @
    (p0 + (i + 0.5) * cell_size), p0 the mesh's local minimum corner and cell_size the local
    box / res per axis (BKE fluid_set_domain_from_mesh). Here that is x = -1.25 + (i + 0.5) *
    2.5/36 (z: -1.25 + (k + 0.5) * 4.5/64): the file's own transform puts voxel i at i * 4.5/64,
    1.25 units off on each axis (plus half a voxel), and 1.25% too wide in x and y, whose
    cells are 2.5/36 = 0.0694 against dx = 0.0703. The shadow (Mantaflow's own light
    transmittance) and velocity grids are left out; half floats as Blender writes them.
    """
    import pyopenvdb as vdb
    from mathutils import Matrix

    # cell_size and the resolution live on the evaluated modifier (the original's stay 0).
    bpy.context.scene.frame_set(bpy.context.scene.frame_end)
    evaluated = domain.evaluated_get(bpy.context.evaluated_depsgraph_get())
    eds = evaluated.modifiers["Fluid"].domain_settings
    lo = Vector([min(v[a] for v in domain.bound_box) for a in range(3)])
    cell = Vector(eds.cell_size)  # local units per voxel, per axis
    if min(cell) <= 0.0:
        print(f"make_smoke: error: the domain's cell size is {tuple(cell)}", file=sys.stderr)
        sys.exit(1)
    local = Matrix.Identity(4)
    for a in range(3):
        local[a][a] = cell[a]
        local[a][3] = lo[a] + 0.5 * cell[a]
    m = domain.matrix_world @ local  # column vectors: world = m @ (i, j, k, 1)
    # OpenVDB's Mat4 takes row vectors (translation in the last row): the transpose.
    xform = vdb.createLinearTransform([[m[c][r] for c in range(4)] for r in range(4)])
    grids = []
    for name in ("density", "flame", "temperature"):
        g = vdb.read(cache_file, name)
        g.transform = xform
        g.saveFloatAsHalf = True
        grids.append(g)
    meta = {"creator": "Blender %s Mantaflow, scripts/blender/make_smoke.py --fire --bundle "
                       "(frame %d)" % (bpy.app.version_string, bpy.context.scene.frame_end)}
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    vdb.write(path, grids=grids, metadata=meta)
    w0 = m @ Vector((0, 0, 0, 1))
    print(f"make_smoke: bundle {path}: {', '.join(g.name for g in grids)}; voxel (0,0,0) at "
          f"({w0.x:.5f}, {w0.y:.5f}, {w0.z:.5f}), voxel size "
          f"{', '.join('%.6f' % (m[a][a]) for a in range(3))}", flush=True)


if __name__ == "__main__":
    main()
