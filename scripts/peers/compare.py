#!/work/venv-mitsuba/bin/python
"""Peers' time versus error on one scene, as CSV on stdout (issue #7's bench calls this).

    compare.py scene.vdb --reference ref.exr [scene flags as vdbmarch's] \
        [--spp 4,16,64,256] [--vdb-render 1:1,0.5:2,0.25:4] [--vdbmarch PATH]

For each spp it renders the scene with Mitsuba 3 (mitsuba_render.py) and scores the image
against the reference (normally `vdbmarch --reference --aovs` at high spp): relative RMSE
over pixels with reference alpha > 0.01 after 2x2 block averaging, relative to the mean of
those pixels, and the mean-radiance ratio (nimbus_scene.compare). With --vdb-render-steps it
With --vdb-render STEP:SUPERSAMPLE,... it adds vdb_render rows (single scattering only,
isotropic: meaningful for g = 0), scored against the reference's `single` layer. With
--vdbmarch it adds `vdbmarch --reference` rows at the same spp ladder (seed 1000 + spp, so
they are independent of a reference rendered with the default seed), timed in the same run.
Scene flags not given come from the VDB's nimbus:* metadata, as for vdbmarch.

Columns: renderer,setting,render_seconds,wall_seconds,rel_rmse,mean_ratio,against
(render_seconds excludes process start and scene loading; wall_seconds is the whole run).
"""
import argparse
import csv
import os
import re
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
    if args.sky:
        out += ["--sky", args.sky]
    if args.environment:
        out += ["--environment", args.environment, "--environment-strength", str(args.environment_strength),
                "--environment-rotation", str(args.environment_rotation)]
    return out


def run(cmd):
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        ns.fail(f"{os.path.basename(cmd[1])} failed: {p.stderr.strip()[-800:]}", 1)
    kv = dict(tok.split("=", 1) for tok in p.stdout.split() if "=" in tok)
    return float(kv["render_seconds"]), wall


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ns.add_scene_args(ap)
    ap.add_argument("--reference", required=True, help="reference EXR (vdbmarch --reference [--aovs])")
    ap.add_argument("--spp", default="4,16,64,256", help="Mitsuba spp ladder")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rr-depth", type=int, default=512, help="Mitsuba volpath rr_depth (mitsuba_render.py)")
    ap.add_argument("--vdb-render", default="",
                    help="vdb_render ladder STEP:SUPERSAMPLE,... (step in voxels, rays per pixel side)")
    ap.add_argument("--vdbmarch", help="vdbmarch binary: add nimbus reference rows at each spp")
    ap.add_argument("--device", default="cpu", help="vdbmarch --device for those rows")
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
                              "--spp", str(spp), "--seed", str(args.seed),
                              "--rr-depth", str(args.rr_depth)] + flags)
            rmse, ratio = ns.compare(ns.read_exr(exr), reference)
            out.writerow(["mitsuba3-scalar_rgb", f"spp={spp},rr_depth={args.rr_depth}", f"{secs:.3f}", f"{wall:.3f}",
                          f"{rmse:.5f}", f"{ratio:.5f}", "all"])
            sys.stdout.flush()
        if args.vdbmarch:
            march_flags = ns.vdbmarch_flags(ns.resolve_scene(args))
            for spp in [int(s) for s in args.spp.split(",") if s]:
                exr = os.path.join(where, f"vdbmarch_{spp}spp.exr")
                t0 = time.perf_counter()
                p = subprocess.run([args.vdbmarch, "--reference", args.input, "-o", exr, "--spp", str(spp),
                                    "--seed", str(1000 + spp), "--device", args.device, "-v"] + march_flags,
                                   capture_output=True, text=True)
                wall = time.perf_counter() - t0
                if p.returncode != 0:
                    ns.fail(f"vdbmarch failed: {p.stderr.strip()[-800:]}", 1)
                m = re.search(r"path trace\s+([0-9.]+) s", p.stderr)
                secs = float(m.group(1)) if m else float("nan")
                rmse, ratio = ns.compare(ns.read_exr(exr), reference)
                out.writerow([f"vdbmarch-reference-{args.device}", f"spp={spp}", f"{secs:.3f}", f"{wall:.3f}",
                              f"{rmse:.5f}", f"{ratio:.5f}", "all"])
                sys.stdout.flush()
        ladder = [tuple(x.split(":")) for x in args.vdb_render.split(",") if x]
        if ladder:
            single = ns.read_exr(args.reference, layer="single")
        for step, ss in ladder:
            exr = os.path.join(where, f"vdb_render_step{step}_ss{ss}.exr")
            secs, wall = run([py, os.path.join(HERE, "vdb_render.py"), args.input, "-o", exr,
                              "--step", step, "--shadow-step", step, "--supersample", ss] + flags)
            rmse, ratio = ns.compare(ns.read_exr(exr), single)
            out.writerow(["vdb_render", f"step={step},ss={ss}", f"{secs:.3f}",
                          f"{wall:.3f}", f"{rmse:.5f}", f"{ratio:.5f}", "single"])
            sys.stdout.flush()


if __name__ == "__main__":
    main()
