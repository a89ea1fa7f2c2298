#!/work/venv-mitsuba/bin/python
"""Renders a nimbus density VDB with Mitsuba 3 (volpath) under nimbus's conventions, for
side-by-side comparisons with `vdbmarch --reference` (issue #7, peers).

Setup (once):
    /usr/bin/python3 -m venv --system-site-packages /work/venv-mitsuba
    /work/venv-mitsuba/bin/pip install mitsuba OpenEXR
(--system-site-packages gives pyopenvdb, which only loads under /usr/bin/python3.)

Flags mirror vdbmarch's; what is not given comes from the file's nimbus:* metadata.
Prints `render_seconds=...` on stdout.

How nimbus's conventions map onto Mitsuba's (checked numerically by --check-grid and by
comparing images with vdbmarch --reference; see scripts/peers/README.md):
- density: Mitsuba's gridvolume stores samples at cell centres of a grid over [0,1]^3 and
  clamps to the edge outside them; nimbus's value for index i sits at integer index i and the
  density is 0 beyond the active voxels. So the array is padded with one zero voxel per side
  (N+2 samples) and the unit cube is mapped onto index [lo-1.5, hi+1.5]: sample m then lands
  at index lo-1+m exactly, and the clamped outer half cell holds the zero padding.
- medium: heterogeneous, sigma_t = scale * grid with scale = extinction, constant RGB
  albedo, hg phase (same sign convention: g > 0 forward).
- sun: `directional` emitter, `direction` = where light travels, `irradiance` = E.
- camera: perspective, fov_axis x, look_at(eye, look_at, up); Mitsuba's image right is
  cross(forward, up) as in nimbus; box reconstruction filter (radius 0.5 pixel = the pixel).
- background: a `constant` emitter with the background radiance (omitted when 0).
- Russian roulette: volpath rolls it at the top of every loop iteration once depth > rr_depth,
  and a null collision is an iteration. Past rr_depth every null collision kills the path with
  probability >= 5% and scales the survivors by 1/q, so a path crossing n null collisions
  carries weight ~0.95^-n with probability ~0.95^n: unbiased in expectation, but so
  heavy-tailed that at any feasible spp the image comes out dark (the plume, whose global
  majorant makes hundreds of null collisions per path: mean 0.976 of the reference at 64 spp,
  0.979 at 256). rr_depth 512 (default here) keeps roulette out of reach, as vdbmarch
  --reference's max depth 512 does; then the plume agrees (1.004 at 64 spp) and converges
  faster per second.
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import nimbus_scene as ns  # noqa: E402

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

# scalar_rgb: llvm_ad_rgb aborts on this machine (drjit emits llvm.minimum, which the system
# LLVM 15 cannot select on x86: "LLVM ERROR: Cannot select: f32 = fminimum").
VARIANTS = ("scalar_rgb", "llvm_ad_rgb")


def grid_to_world(density):
    """4x4 map from Mitsuba's unit cube (over the zero-padded array) to world."""
    n = np.array(density.values.shape, dtype=np.float64) + 2
    unit_to_index = np.eye(4)
    unit_to_index[:3, :3] = np.diag(n)
    unit_to_index[:3, 3] = density.lo - 1.5
    return density.index_to_world @ unit_to_index


def medium_dict(scene):
    d = scene["density"]
    padded = np.pad(d.values, 1)
    # Mitsuba's VolumeGrid is indexed [z][y][x] (x fastest); pyopenvdb's array is [x][y][z].
    data = np.ascontiguousarray(padded.transpose(2, 1, 0))[..., None]
    to_world = mi.ScalarTransform4f(grid_to_world(d).tolist())
    return {
        "type": "heterogeneous",
        "sigma_t": {"type": "gridvolume", "grid": mi.VolumeGrid(data), "to_world": to_world,
                    "filter_type": "trilinear", "wrap_mode": "clamp"},
        "scale": float(scene["extinction"]),
        "albedo": {"type": "rgb", "value": list(scene["albedo"])},
        "phase": {"type": "hg", "g": float(scene["g"])},
    }


def scene_dict(scene, spp, max_depth, seed, rr_depth=5):
    d = scene["density"]
    to_world = grid_to_world(d)
    # The medium's boundary: a cube ([-1,1]^3 in its own space) over the grid's unit box.
    cube = to_world @ np.array([[0.5, 0, 0, 0.5], [0, 0.5, 0, 0.5], [0, 0, 0.5, 0.5], [0, 0, 0, 1]])
    out = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": max_depth, "rr_depth": rr_depth},
        "sensor": {
            "type": "perspective",
            "fov": float(scene["fov"]), "fov_axis": "x",
            "near_clip": 1e-4, "far_clip": 1e7,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=list(scene["eye"]), target=list(scene["look_at"]), up=list(scene["up"])),
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            "film": {"type": "hdrfilm", "width": scene["width"], "height": scene["height"],
                     "pixel_format": "rgba", "rfilter": {"type": "box"}},
        },
        "volume": {
            "type": "cube",
            "to_world": mi.ScalarTransform4f(cube.tolist()),
            "bsdf": {"type": "null"},
            "interior": medium_dict(scene),
        },
    }
    for i, s in enumerate(scene["suns"]):
        out[f"sun{i}"] = {"type": "directional", "direction": list(s["dir"]),
                          "irradiance": {"type": "rgb", "value": list(s["irradiance"])}}
    if scene.get("sky") is not None:
        # nimbus's sky both lights the medium and is seen behind it, as a constant emitter is.
        out["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": list(scene["sky"])}}
    if scene.get("envmap"):
        out["environment"] = envmap_dict(scene["envmap"])
    if (scene.get("sky") is not None or scene.get("envmap")) and any(b > 0 for b in scene["background"]):
        ns.fail("a background with an environment cannot be matched in Mitsuba (its emitter is what rays see)")
    if any(b > 0 for b in scene["background"]):
        out["background"] = {"type": "constant",
                             "radiance": {"type": "rgb", "value": list(scene["background"])}}
    return out


def envmap_dict(envmap):
    """Mitsuba's `envmap` read with Blender's World mapping. Mitsuba looks a direction v up
    in the emitter's local frame at u = atan2(v.x, -v.z) / 2 pi, v = acos(v.y) / pi (Y up);
    Blender at u = 0.5 - atan2(w.y, w.x) / 2 pi, v = acos(w.z) / pi (Z up). They agree when
    local = (w.y, w.z, w.x), so to_world maps local x, y, z to world y, z, x; nimbus's
    rotation reads the map at R_z(rotation) w, so the frame turns by -rotation."""
    c, s = np.cos(np.radians(envmap["rotation"])), np.sin(np.radians(envmap["rotation"]))
    turn_back = np.array([[c, s, 0, 0], [-s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    permute = np.array([[0, 0, 1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float)
    return {"type": "envmap", "filename": envmap["path"], "scale": float(envmap["strength"]),
            "to_world": mi.ScalarTransform4f((turn_back @ permute).tolist())}


def check_grid(scene, samples=2000, seed=1):
    """Max |Mitsuba gridvolume - nimbus trilinear| over random world points in and around the
    grid's box: the voxel-centre and axis-order conventions, checked rather than assumed."""
    d = scene["density"]
    vol = mi.load_dict(medium_dict(scene)["sigma_t"])
    lo, hi = d.world_bounds()
    rng = np.random.default_rng(seed)
    pts = rng.uniform(lo, hi, size=(samples, 3))
    ours = d.sample(pts)
    err = 0.0
    for p, v in zip(pts, ours):
        it = dr.zeros(mi.Interaction3f)
        it.p = mi.Point3f(*p)
        theirs = vol.eval_1(it)
        err = max(err, abs(float(theirs) - v))
    return err, float(np.abs(ours).max())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ns.add_scene_args(ap)
    ap.add_argument("-o", "--output", required=True, help="EXR (RGBA float32)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=-1, help="volpath max_depth (-1: unbounded)")
    ap.add_argument("--rr-depth", type=int, default=512,
                    help="volpath rr_depth (default 512, vdbmarch --reference's max depth; Mitsuba's own "
                         "default 5 renders heterogeneous media too dark at any feasible spp, see below)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variant", default="scalar_rgb", choices=VARIANTS)
    ap.add_argument("--check-grid", action="store_true",
                    help="also compare the gridvolume with nimbus's trilinear density at random points")
    args = ap.parse_args()

    mi.set_variant(args.variant)
    scene = ns.resolve_scene(args)
    if args.check_grid:
        err, peak = check_grid(scene)
        print(f"grid_check_max_abs_error={err:.3g} peak_density={peak:.3g}")

    t0 = time.perf_counter()
    mscene = mi.load_dict(scene_dict(scene, args.spp, args.max_depth, args.seed, args.rr_depth))
    t1 = time.perf_counter()
    img = mi.render(mscene, spp=args.spp, seed=args.seed)
    dr.eval(img)
    img = np.array(img, dtype=np.float32)
    t2 = time.perf_counter()
    mi.Bitmap(img, mi.Bitmap.PixelFormat.RGBA).write(args.output)
    print(f"variant={args.variant} spp={args.spp} load_seconds={t1 - t0:.3f} render_seconds={t2 - t1:.3f}")


if __name__ == "__main__":
    main()
