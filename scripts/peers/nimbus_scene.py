"""What the peer renderers share about a nimbus scene: the density grid read from a VDB,
the medium / lights / camera (from vdbmarch-style flags or the file's `nimbus:*` metadata),
EXR reading and the error metric of issue #7.

pyopenvdb only imports under /usr/bin/python3 (or a venv made from it with
--system-site-packages), so the import is deferred to the functions that need it.
"""
import argparse
import math
import os
import sys

import numpy as np

DEFAULT_ALBEDO = (0.9, 0.9, 0.9)   # design.md section 3
DEFAULT_FOV = 40.0                 # horizontal, degrees (design.md section 4)
DEFAULT_SIZE = (960, 540)


def fail(message, code=2):
    """design.md section 7: one `error: ...` line on stderr; exit 2 for bad usage or input."""
    print(f"error: {message}", file=sys.stderr)
    sys.exit(code)


class Density:
    """The `density` grid's active bounding box as a dense array plus the index->world map.

    `values[i, j, k]` is the voxel at index (lo + (i, j, k)); its value sits at that integer
    index coordinate (OpenVDB's BoxSampler convention, which nimbus follows)."""

    def __init__(self, values, lo, index_to_world):
        self.values = values              # float32, shape (nx, ny, nz), x slowest
        self.lo = np.asarray(lo, dtype=np.int64)
        self.index_to_world = index_to_world   # 4x4 affine, column vectors

    def world(self, ijk):
        p = np.append(np.asarray(ijk, dtype=np.float64), 1.0)
        return (self.index_to_world @ p)[:3]

    def world_bounds(self):
        """World AABB of the region where trilinear density can be non-zero
        (one voxel beyond the active box on every side)."""
        hi = self.lo + np.array(self.values.shape) - 1
        corners = [self.world([x, y, z]) for x in (self.lo[0] - 1, hi[0] + 1)
                   for y in (self.lo[1] - 1, hi[1] + 1) for z in (self.lo[2] - 1, hi[2] + 1)]
        corners = np.array(corners)
        return corners.min(axis=0), corners.max(axis=0)

    def sample(self, p_world):
        """Trilinear density at world points (N,3), background 0 outside the box: the
        numpy twin of openvdb::tools::BoxSampler, used to check other renderers' grids."""
        inv = np.linalg.inv(self.index_to_world)
        p = np.asarray(p_world, dtype=np.float64)
        idx = (inv[:3, :3] @ p.T).T + inv[:3, 3] - self.lo
        base = np.floor(idx).astype(np.int64)
        f = idx - base
        padded = np.pad(self.values, 1)
        out = np.zeros(len(p))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    c = base + [dx, dy, dz] + 1
                    inside = np.all((c >= 0) & (c < np.array(padded.shape)), axis=1)
                    v = np.zeros(len(p))
                    ci = c[inside]
                    v[inside] = padded[ci[:, 0], ci[:, 1], ci[:, 2]]
                    w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) \
                        * (f[:, 2] if dz else 1 - f[:, 2])
                    out += w * v
        return out


def read_vdb(path, grid_name=None):
    """(Density, file metadata dict). `grid_name` defaults to what the file records under
    `nimbus:density_grid`, else `density` (as the nimbus tools do)."""
    import pyopenvdb as vdb
    try:
        meta = vdb.readMetadata(path)
        name = grid_name or meta.get("nimbus:density_grid") or "density"
        grid = vdb.read(path, name)
    except Exception as e:  # pyopenvdb raises KeyError/IOError/RuntimeError with a message
        fail(f"cannot read {grid_name or 'the density grid'}: {e} ({path})")
    if not isinstance(grid, vdb.FloatGrid):
        fail(f"grid {name} is not a float grid ({path})")
    if not grid.transform.isLinear:
        fail(f"grid {name} has a non-affine transform ({path})")
    if grid.activeVoxelCount() == 0:
        fail(f"grid {name} has no active voxels ({path})")
    (lo, hi) = grid.evalActiveVoxelBoundingBox()
    lo = np.array(lo)
    dims = np.array(hi) - lo + 1
    values = np.zeros(tuple(int(d) for d in dims), dtype=np.float32)
    grid.copyToArray(values, ijk=tuple(int(v) for v in lo))
    # The affine map from the images of the origin and the unit index vectors.
    t = grid.transform
    o = np.array(t.indexToWorld((0.0, 0.0, 0.0)))
    m = np.eye(4)
    for a, e in enumerate(((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0))):
        m[:3, a] = np.array(t.indexToWorld(e)) - o
    m[:3, 3] = o
    return Density(values, lo, m), meta


# ---- parameters -------------------------------------------------------------------------

def _vec(text, n=3, what="value"):
    try:
        parts = [float(x) for x in str(text).split(",")]
    except ValueError:
        fail(f"{what} must be {n} numbers, got {text}")
    if n == 3 and len(parts) == 1:
        parts = parts * 3
    if len(parts) != n or not all(math.isfinite(x) for x in parts):
        fail(f"{what} must be {n} finite numbers, got {text}")
    return tuple(parts)


def _key_values(text):
    """`k=a,b,c,k2=d` -> {k: 'a,b,c', k2: 'd'} (the nimbus text forms)."""
    out, key = {}, None
    for tok in text.split(","):
        tok = tok.strip()
        if "=" in tok:
            key, val = tok.split("=", 1)
            out[key.strip()] = val.strip()
        elif key is not None:
            out[key] += "," + tok
    return out


def parse_sun(text):
    kv = _key_values(text.split(":", 1)[1] if text.startswith("sun:") else text)
    if "pos" in kv or "intensity" in kv:
        return None  # a point light: the peers here only take suns
    d = np.array(_vec(kv.get("dir", "0,0,-1"), what="sun dir"))
    n = np.linalg.norm(d)
    if n == 0:
        fail(f"sun dir must be non-zero ({text})")
    return {"dir": tuple(d / n), "irradiance": _vec(kv.get("irradiance", "1"), what="irradiance")}


def add_scene_args(ap):
    """The flags every peer script takes, spelled like vdbmarch's."""
    ap.add_argument("input", help="density VDB (grid `density`)")
    ap.add_argument("--grid", help="density grid name (default: file's nimbus:density_grid, else density)")
    ap.add_argument("--extinction", type=float)
    ap.add_argument("--albedo")
    ap.add_argument("--g", type=float)
    ap.add_argument("--sun", action="append", help="dir=X,Y,Z,irradiance=R,G,B (repeatable)")
    ap.add_argument("--eye")
    ap.add_argument("--look-at")
    ap.add_argument("--up")
    ap.add_argument("--fov", type=float, help="horizontal field of view, degrees")
    ap.add_argument("--width", type=int)
    ap.add_argument("--height", type=int)
    ap.add_argument("--background", default="0", help="background radiance R,G,B")
    ap.add_argument("--sky", help="uniform sky radiance R,G,B (vdbmarch's --sky)")
    ap.add_argument("--environment", help="equirectangular EXR with Blender's World mapping")
    ap.add_argument("--environment-strength", type=float, default=1.0)
    ap.add_argument("--environment-rotation", type=float, default=0.0, help="degrees about +Z")


def resolve_scene(args):
    """Flags over the file's nimbus:* metadata over design.md defaults, as vdbmarch does."""
    density, meta = read_vdb(args.input, args.grid)
    medium = _key_values(meta.get("nimbus:medium", ""))
    camera = _key_values(meta.get("nimbus:camera", ""))
    if "look_at" in camera:
        camera["look-at"] = camera.pop("look_at")
    if "size" in camera:
        w, h = camera.pop("size").split("x")
        camera["width"], camera["height"] = w, h

    ext = args.extinction if args.extinction is not None else float(medium.get("extinction", 1.0))
    albedo = _vec(args.albedo if args.albedo else medium.get("albedo", "0.9"), what="albedo")
    g = args.g if args.g is not None else float(medium.get("g", 0.0))

    lights_text = args.sun if args.sun else [s for s in meta.get("nimbus:lights", "").split(";") if s.strip()]
    lit_otherwise = bool(args.sky or args.environment or meta.get("nimbus:environment", "none").strip() not in ("", "none"))
    # As vdbmarch: with an environment and no light given, no default sun.
    suns = [parse_sun(s) for s in lights_text] or ([] if lit_otherwise else [parse_sun("dir=0,0,-1,irradiance=1")])
    if any(s is None for s in suns):
        print("warning: point lights are not passed to peers; only suns are used", file=sys.stderr)
        suns = [s for s in suns if s is not None]

    lo, hi = density.world_bounds()
    centre = (lo + hi) / 2
    fov = args.fov if args.fov is not None else float(camera.get("fov", DEFAULT_FOV))
    look_at = _vec(args.look_at or camera.get("look-at") or ",".join(map(str, centre)), what="look-at")
    up = _vec(args.up or camera.get("up", "0,0,1"), what="up")
    if args.eye or "eye" in camera:
        eye = _vec(args.eye or camera["eye"], what="eye")
    else:
        eye = None
    width = args.width or int(camera.get("width", DEFAULT_SIZE[0]))
    height = args.height or int(camera.get("height", DEFAULT_SIZE[1]))
    if eye is None:
        # vdbmarch's default frames the bounds from -Y; peers need it given explicitly to be
        # sure of matching, so refuse rather than guess a different framing.
        fail("no camera: give --eye/--look-at or a file with nimbus:camera metadata")
    sky, envmap = None, None
    recorded = meta.get("nimbus:environment", "none").strip()
    if args.sky:
        sky = _vec(args.sky, what="sky")
    elif args.environment:
        envmap = {"path": os.path.abspath(args.environment), "strength": args.environment_strength,
                  "rotation": args.environment_rotation}
    elif recorded.startswith("sky="):
        sky = _vec(recorded[4:], what="sky")
    elif recorded.startswith("map="):
        path, rest = recorded[4:].rsplit(",strength=", 1)
        strength, rotation = rest.split(",rotation=")
        envmap = {"path": path, "strength": float(strength), "rotation": float(rotation)}
    return {
        "sky": sky, "envmap": envmap,
        "density": density, "extinction": ext, "albedo": albedo, "g": g, "suns": suns,
        "eye": eye, "look_at": look_at, "up": up, "fov": fov, "width": width, "height": height,
        "background": _vec(args.background, what="background"),
    }


def vdbmarch_flags(scene):
    """The same scene as vdbmarch flags (so a driver can render nimbus's side identically)."""
    j = lambda v: ",".join(repr(float(x)) for x in v)
    flags = ["--extinction", repr(scene["extinction"]), "--albedo", j(scene["albedo"]),
             "--g", repr(scene["g"]), "--eye", j(scene["eye"]), "--look-at", j(scene["look_at"]),
             "--up", j(scene["up"]), "--fov", repr(scene["fov"]), "--width", str(scene["width"]),
             "--height", str(scene["height"]), "--background", j(scene["background"])]
    for s in scene["suns"]:
        flags += ["--sun", f"dir={j(s['dir'])},irradiance={j(s['irradiance'])}"]
    if scene.get("sky") is not None:
        flags += ["--sky", j(scene["sky"])]
    if scene.get("envmap"):
        e = scene["envmap"]
        flags += ["--environment", e["path"], "--environment-strength", repr(e["strength"]),
                  "--environment-rotation", repr(e["rotation"])]
    return flags


# ---- images ------------------------------------------------------------------------------

def read_exr(path, layer=None):
    """(H,W,4) float array RGBA of an EXR; `layer` picks `layer.R` etc (nimbus --aovs).
    A layer without its own A takes the image's A (the coverage); no A at all reads as 1."""
    import OpenEXR
    with OpenEXR.File(path, separate_channels=True) as f:
        ch = f.channels()
        pre = f"{layer}." if layer else ""
        names = [pre + c for c in "RGB"]
        missing = [n for n in names if n not in ch]
        if missing:
            fail(f"{path} has no channels {missing} (has {sorted(ch)})")
        rgb = [np.asarray(ch[n].pixels, dtype=np.float64) for n in names]
        a = ch.get(pre + "A", ch.get("A"))
        alpha = np.asarray(a.pixels, dtype=np.float64) if a is not None else np.ones_like(rgb[0])
    return np.stack(rgb + [alpha], axis=-1)


def block2(img):
    """2x2 block average (odd trailing rows/columns dropped)."""
    h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
    i = img[:h, :w]
    return (i[0::2, 0::2] + i[1::2, 0::2] + i[0::2, 1::2] + i[1::2, 1::2]) / 4


def compare(test, ref, alpha_min=0.01):
    """Issue #7's metric: after 2x2 block averaging, over pixels whose reference alpha
    exceeds `alpha_min`: RMSE of RGB relative to the mean reference radiance there, and the
    ratio of mean radiances (test / reference)."""
    t, r = block2(test), block2(ref)
    mask = r[..., 3] > alpha_min
    if not mask.any():
        return float("nan"), float("nan")
    tr, rr = t[mask][:, :3], r[mask][:, :3]
    mean = rr.mean()
    rmse = math.sqrt(((tr - rr) ** 2).mean()) / mean
    return rmse, tr.mean() / mean


def write_exr(path, rgba):
    """RGBA float32 EXR, ZIP compressed (as nimbus writes)."""
    import OpenEXR
    rgba = np.ascontiguousarray(rgba, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {c: np.ascontiguousarray(rgba[..., i]) for i, c in enumerate("RGBA")}
    with OpenEXR.File(header, channels) as f:
        f.write(path)
