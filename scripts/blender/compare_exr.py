"""Compares EXRs of the same camera (A: nimbus, B: Cycles, as a rule); optionally a side-by-side PNG.

    blender -b --factory-startup --python-exit-code 1 -P scripts/blender/compare_exr.py -- \
        LABEL=A.exr:B.exr ... [--png OUT.png --view Filmic --diff-scale 4]

Run inside Blender because its Python has numpy and reads EXR (bpy.data.images.load), and its
colour management is the view transform both pictures go through (this machine's python3 has
neither numpy nor OpenEXR). Prints one line a pair:

    LABEL: mean RGB A (r, g, b) B (r, g, b), ratio A/B (r, g, b) mean M,
           relative RMSE R over N covered 2x2 blocks

- mean RGB: over all pixels; the ratio M is of the means of (R + G + B) / 3.
- relative RMSE: as nimbus-bench (crates/bench/src/image.rs) does it against its reference:
  both images averaged over 2x2 pixel blocks (which takes out most pixel-scale noise), then
  sqrt(mean over covered blocks and channels of (A - B)^2) / mean over covered blocks of B's
  (R + G + B) / 3. Covered: A's alpha (nimbus's 1 - transmittance) above 0.01 in the block
  (Cycles' alpha is 1 everywhere on an opaque film, so B's alpha is not used).
- --png: one row a pair, nimbus | Cycles | |nimbus - Cycles| x diff-scale, linear values
  through Blender's view transform (--view Filmic, Blender 3.4's default, or Standard) on an
  sRGB display, panels 2 px apart.
"""

import argparse
import sys

import bpy
import numpy as np


def load(path):
    img = bpy.data.images.load(path)
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)  # rows bottom to top, as Blender stores them


def blocks2(a):
    h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
    a = a[:h, :w]
    return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])


def compare(label, a, b):
    if a.shape != b.shape:
        print(f"compare_exr: error: {label}: {a.shape[1]}x{a.shape[0]} against "
              f"{b.shape[1]}x{b.shape[0]}", file=sys.stderr)
        sys.exit(2)
    ma, mb = a[..., :3].reshape(-1, 3).mean(0), b[..., :3].reshape(-1, 3).mean(0)
    ratio = ma / np.maximum(mb, 1e-30)
    ba, bb = blocks2(a.astype(np.float64)), blocks2(b.astype(np.float64))
    cov = ba[..., 3] > 0.01
    sq = ((ba[..., :3] - bb[..., :3]) ** 2).mean(-1)[cov]
    level = bb[..., :3].mean(-1)[cov]
    rel = np.sqrt(sq.mean()) / level.mean() if cov.any() and level.mean() > 0 else float("nan")
    f3 = lambda v: "(%.5f, %.5f, %.5f)" % tuple(v)
    print(f"{label}: mean RGB A {f3(ma)} B {f3(mb)}, ratio A/B {f3(ratio)} mean "
          f"{ma.mean() / mb.mean():.4f}, relative RMSE {rel:.4f} over {int(cov.sum())} covered "
          f"2x2 blocks", flush=True)


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="compare_exr.py")
    p.add_argument("pairs", nargs="+", metavar="LABEL=A.exr:B.exr")
    p.add_argument("--png", help="one row per pair: nimbus | Cycles | |difference|")
    p.add_argument("--view", default="Filmic")
    p.add_argument("--diff-scale", type=float, default=4.0)
    args = p.parse_args(argv)

    rows = []
    for pair in args.pairs:
        label, files = pair.split("=", 1)
        na, nb = files.split(":", 1)
        a, b = load(na), load(nb)
        compare(label, a, b)
        rows.append((a, b))

    if args.png:
        h, w = rows[0][0].shape[:2]
        gap = 2
        out = np.zeros((len(rows) * (h + gap) - gap, 3 * w + 2 * gap, 4), np.float32)
        out[..., :3] = 0.18  # the gaps
        out[..., 3] = 1.0
        for r, (a, b) in enumerate(reversed(rows)):  # Blender's rows run bottom to top
            y = r * (h + gap)
            out[y:y + h, :w, :3] = a[..., :3]
            out[y:y + h, w + gap:2 * w + gap, :3] = b[..., :3]
            out[y:y + h, 2 * w + 2 * gap:, :3] = np.abs(a[..., :3] - b[..., :3]) * args.diff_scale
        img = bpy.data.images.new("compare", out.shape[1], out.shape[0], alpha=False,
                                  float_buffer=True)
        img.pixels.foreach_set(out.ravel())
        scene = bpy.context.scene
        scene.view_settings.view_transform = args.view
        scene.view_settings.look = "None"
        scene.view_settings.exposure = 0.0
        scene.view_settings.gamma = 1.0
        scene.display_settings.display_device = "sRGB"
        s = scene.render.image_settings
        s.file_format, s.color_mode, s.color_depth, s.compression = "PNG", "RGB", "8", 90
        img.save_render(args.png, scene=scene)
        print(f"compare_exr: {args.png}: rows {', '.join(x.split('=')[0] for x in args.pairs)}; "
              f"nimbus | Cycles | |difference| x {args.diff_scale:g}, view {args.view}", flush=True)


if __name__ == "__main__":
    main()
