#!/work/venv-mitsuba/bin/python
"""Renders a nimbus density VDB with OpenVDB's `vdb_render` (libopenvdb-tools) under nimbus's
scene parameters, for comparison with the `single` layer of `vdbmarch --reference --aovs`.

vdb_render's dense-volume shader is single scattering only, with its own conventions
(openvdb/tools/RayTracer.h, VolumeRender::render), translated here:
- coefficients are per VOXEL length (it integrates in index space): -scatter =
  extinction * albedo * voxel size, -absorb = extinction * (1 - albedo) * voxel size;
  so the voxel size must be the same on every axis.
- no phase function: in-scattered light is albedo * light colour * T_light, so a light
  colour of E / (4 pi) equals nimbus's single scattering for an isotropic phase (g = 0);
  for g != 0 the images cannot agree (the script warns and uses E p(cos) at the image
  centre's scattering angle, which is only a rough stand-in).
- `-light X,Y,Z` points TOWARD the light: the negated sun direction; one light only.
- `-gain 0`: its default 0.2 fakes in-scattering along shadow rays; `-cutoff` small so
  neither thin density nor transmittance is cut off early.
- one ray through each pixel's centre, no filter: `--supersample K` renders K x K rays per
  pixel (a K-times larger image, box-averaged here) to approach nimbus's pixel box filter.
- no background; alpha = 1 - mean transmittance, as nimbus.
Prints `render_seconds=...` (vdb_render's own ray-tracing time, summed, and wall time).
"""
import argparse
import math
import os
import re
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import nimbus_scene as ns  # noqa: E402


def hg(cos_t, g):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * cos_t) ** 1.5)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ns.add_scene_args(ap)
    ap.add_argument("-o", "--output", required=True, help="EXR (RGBA float32)")
    ap.add_argument("--step", type=float, default=0.25, help="primary step in voxels")
    ap.add_argument("--shadow-step", type=float, default=0.25, help="shadow step in voxels")
    ap.add_argument("--supersample", type=int, default=4, help="K x K rays per pixel")
    ap.add_argument("--cutoff", type=float, default=1e-6)
    ap.add_argument("--cpus", type=int, default=0)
    ap.add_argument("--vdb-render", default="vdb_render")
    args = ap.parse_args()

    scene = ns.resolve_scene(args)
    d = scene["density"]
    voxel = np.linalg.norm(d.index_to_world[:3, :3], axis=0)
    if not np.allclose(voxel, voxel[0], rtol=1e-6):
        ns.fail(f"vdb_render needs cubic voxels, got sizes {voxel} ({args.input})")
    voxel = voxel[0]
    if len(scene["suns"]) != 1:
        ns.fail("vdb_render takes exactly one light")
    sun = scene["suns"][0]
    if any(b > 0 for b in scene["background"]):
        print("warning: vdb_render has no background; ignoring --background", file=sys.stderr)

    ext, alb = scene["extinction"], np.array(scene["albedo"])
    scatter = ext * alb * voxel
    absorb = ext * (1 - alb) * voxel
    phase = 1 / (4 * math.pi)
    if scene["g"] != 0:
        fwd = np.array(scene["look_at"]) - np.array(scene["eye"])
        fwd /= np.linalg.norm(fwd)
        # w_in = sun dir, w_out = toward the camera = -fwd
        phase = hg(float(np.dot(sun["dir"], -fwd)), scene["g"])
        print(f"warning: vdb_render has no phase function; g={scene['g']} approximated by the "
              f"constant p={phase:.4g} of the image centre's scattering angle", file=sys.stderr)
    colour = np.array(sun["irradiance"]) * phase
    k = args.supersample
    j = lambda v: ",".join(repr(float(x)) for x in v)
    with tempfile.TemporaryDirectory() as tmp:
        raw = os.path.join(tmp, "vdb_render.exr")
        cmd = [args.vdb_render, args.input, raw, "-name", d_name(args),
               "-camera", "persp", "-translate", j(scene["eye"]), "-lookat", j(scene["look_at"]),
               "-up", j(scene["up"]), "-fov", repr(scene["fov"]),
               "-res", f"{scene['width'] * k}x{scene['height'] * k}",
               "-scatter", j(scatter), "-absorb", j(absorb),
               "-light", j(-np.array(sun["dir"])) + "," + j(colour),
               "-gain", "0", "-cutoff", repr(args.cutoff), "-step", repr(args.step),
               "-shadowstep", repr(args.shadow_step), "-cpus", str(args.cpus),
               "-compression", "none", "-v"]
        t0 = time.perf_counter()
        run = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if run.returncode != 0:
            ns.fail(f"vdb_render failed ({run.returncode}): {run.stderr.strip()[-500:]}", 1)
        # -v prints "ray-tracing <name>..." then "...completed in T sec"
        m = re.search(r"ray-tracing.*?\n.*?completed in ([0-9.eE+-]+) sec", run.stdout + run.stderr)
        trace = float(m.group(1)) if m else float("nan")
        img = ns.read_exr(raw)
    h, w = scene["height"], scene["width"]
    img = img.reshape(h, k, w, k, 4).mean(axis=(1, 3))
    ns.write_exr(args.output, img)
    print("vdb_render " + " ".join(cmd[1:]), file=sys.stderr)
    print(f"supersample={k} step={args.step} render_seconds={trace:.3f} wall_seconds={wall:.3f}")


def d_name(args):
    if args.grid:
        return args.grid
    import pyopenvdb as vdb
    return vdb.readMetadata(args.input).get("nimbus:density_grid") or "density"


if __name__ == "__main__":
    main()
