#!/work/venv-mitsuba/bin/python
"""Peers' time versus error on one scene, as CSV on stdout (issue #7's bench calls this).

    compare.py scene.vdb --reference ref.exr [scene flags as vdbmarch's] \
        [--spp 4,16,64,256] [--vdb-render-steps 1,0.5,0.25]

For each spp it renders the scene with Mitsuba 3 (mitsuba_render.py) and scores the image
against the reference (normally `vdbmarch --reference --aovs` at high spp): relative RMSE
over pixels with reference alpha > 0.01 after 2x2 block averaging, relative to the mean of
those pixels, and the mean-radiance ratio (nimbus_scene.compare). With --vdb-render-steps it
adds vdb_render rows (single scattering only), scored against the reference's `single`
layer. Scene flags not given come from the VDB's nimbus:* metadata, as for vdbmarch.

Columns: renderer,setting,render_seconds,wall_seconds,rel_rmse,mean_ratio,against
(render_seconds excludes process start and scene loading; wall_seconds is the whole run).
"""
import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import nimbus_scene as ns  # noqa: E402

SCENE_FLAGS = ("grid", "extinction", "albedo", "g", "eye", "look_at", "up", "fov", "width",
               "height", "background")


def forward_flags(args):
    out = []
    for name in SCENE_FLAGS:
        v = getattr(args, name)
        if v is not None:
            out += ["--" + name.replace("_", "-"), str(v)]
    for s in args.sun or []:
        out += ["--sun", s]
    return out


def run(cmd):
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        sys.exit(f"error: {os.path.basename(cmd[1])} failed: {p.stderr.strip()[-800:]}")
    kv = dict(tok.split("=", 1) for tok in p.stdout.split() if "=" in tok)
    return float(kv["render_seconds"]), wall


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ns.add_scene_args(ap)
    ap.add_argument("--reference", required=True, help="reference EXR (vdbmarch --reference [--aovs])")
    ap.add_argument("--spp", default="4,16,64,256", help="Mitsuba spp ladder")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--vdb-render-steps", default="", help="vdb_render step ladder in voxels (empty: skip)")
    ap.add_argument("--supersample", type=int, default=4, help="vdb_render rays per pixel side")
    ap.add_argument("--keep", help="directory to keep the rendered EXRs in")
    args = ap.parse_args()

    reference = ns.read_exr(args.reference)
    flags = forward_flags(args)
    py = sys.executable
    out = csv.writer(sys.stdout, lineterminator="\n")
    out.writerow(["renderer", "setting", "render_seconds", "wall_seconds", "rel_rmse", "mean_ratio", "against"])
    with tempfile.TemporaryDirectory() as tmp:
        where = args.keep or tmp
        os.makedirs(where, exist_ok=True)
        for spp in [int(s) for s in args.spp.split(",") if s]:
            exr = os.path.join(where, f"mitsuba_{spp}spp.exr")
            secs, wall = run([py, os.path.join(HERE, "mitsuba_render.py"), args.input, "-o", exr,
                              "--spp", str(spp), "--seed", str(args.seed)] + flags)
            rmse, ratio = ns.compare(ns.read_exr(exr), reference)
            out.writerow(["mitsuba3-scalar_rgb", f"spp={spp}", f"{secs:.3f}", f"{wall:.3f}",
                          f"{rmse:.5f}", f"{ratio:.5f}", "all"])
            sys.stdout.flush()
        steps = [float(s) for s in args.vdb_render_steps.split(",") if s]
        if steps:
            single = ns.read_exr(args.reference, layer="single")
            single[..., 3] = reference[..., 3]
        for step in steps:
            exr = os.path.join(where, f"vdb_render_step{step:g}.exr")
            secs, wall = run([py, os.path.join(HERE, "vdb_render.py"), args.input, "-o", exr,
                              "--step", str(step), "--shadow-step", str(step),
                              "--supersample", str(args.supersample)] + flags)
            rmse, ratio = ns.compare(ns.read_exr(exr), single)
            out.writerow(["vdb_render", f"step={step:g},ss={args.supersample}", f"{secs:.3f}",
                          f"{wall:.3f}", f"{rmse:.5f}", f"{ratio:.5f}", "single"])
            sys.stdout.flush()


if __name__ == "__main__":
    main()
