#!/usr/bin/env python3
"""sarracen's interpolate_3d_grid on the particles and grid particles2vdb uses, for the
side-by-side table in scripts/bench_density.sh.

    bench_sarracen.py PARTICLES.ply TRUTH.npy --bounds X0,Y0,Z0,X1,Y1,Z1 --h0 H [--neighbours 32] [--runs 3]
                      [--only uniform|knn]

PARTICLES.ply and TRUTH.npy come from the gen_particles example (binary PLY with double x, y, z
and float mass; the analytic density on the grid as float32, shape (z, y, x)). The grid is
TRUTH's shape over the bounds, values at voxel centres, as particles2vdb's and sarracen's are.

sarracen interpolates per particle with the particle's own smoothing length (a scatter:
rho(x) = sum_j m_j W(|x - x_j|, h_j), M4 cubic spline of radius 2h, as nimbus); with
dens_weight=True, normalize=False and a target of ones, what it grids is that density. Two
choices of h_j:
  uniform  h_j = H (particles2vdb's auto h0): the same estimate as usl;
  knn      h_j = (distance to the N*-th nearest other particle) / 2 (scipy cKDTree), the
           usual adaptive SPH smoothing length, N* as particles2vdb's --neighbours.
Times: median of RUNS, after one warm-up call that pays numba's JIT (reported apart); the knn
row's time includes the tree query. Error: relative L2 against TRUTH over every grid point.
"""

import argparse
import statistics
import sys
import time

import numpy as np


def read_ply(path):
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline().decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        if "format binary_little_endian 1.0" not in header:
            sys.exit(f"{path}: expected a binary little-endian PLY (the gen_particles example writes one)")
        count = next(int(l.split()[2]) for l in header if l.startswith("element vertex"))
        kinds = {"double": "<f8", "float": "<f4"}
        fields = [(l.split()[2], kinds[l.split()[1]]) for l in header if l.startswith("property")]
        data = np.fromfile(f, dtype=np.dtype(fields), count=count)
    return data


def rel_l2(estimate, truth):
    return float(np.sqrt(np.sum((estimate - truth) ** 2) / np.sum(truth.astype(np.float64) ** 2)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("particles")
    ap.add_argument("truth")
    ap.add_argument("--bounds", required=True)
    ap.add_argument("--h0", type=float, required=True)
    ap.add_argument("--neighbours", type=int, default=32)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--only", choices=["uniform", "knn"], help="one choice of h (time the whole script for it: import, JIT, h, grid)")
    args = ap.parse_args()

    import sarracen
    from sarracen.interpolate import interpolate_3d_grid
    from scipy.spatial import cKDTree
    import numba

    data = read_ply(args.particles)
    truth = np.load(args.truth)
    lo = [float(v) for v in args.bounds.split(",")[:3]]
    hi = [float(v) for v in args.bounds.split(",")[3:]]
    nz, ny, nx = truth.shape
    n = len(data)
    mass = data["mass"].astype(np.float64) if "mass" in data.dtype.names else np.ones(n)
    xyz = np.stack([data["x"], data["y"], data["z"]], axis=1)
    print(f"sarracen {sarracen.__version__ if hasattr(sarracen, '__version__') else '?'}, numba threads {numba.get_num_threads()}, "
          f"{n} particles, grid {nx}x{ny}x{nz}")

    # Warm-up: numba compiles the kernels on first use.
    t = time.perf_counter()
    small = slice(0, min(n, 1000))
    sdf = sarracen.SarracenDataFrame({"x": xyz[small, 0], "y": xyz[small, 1], "z": xyz[small, 2], "h": np.full(small.stop, args.h0),
                                      "m": mass[small], "one": np.ones(small.stop)}, params={"hfact": 1.2})
    interpolate_3d_grid(sdf, "one", x_pixels=8, y_pixels=8, z_pixels=8, xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]),
                                 zlim=(lo[2], hi[2]), dens_weight=True, normalize=False, backend="cpu")
    print(f"numba JIT warm-up {time.perf_counter() - t:.2f} s (not in the times below)")

    print(f"{'sarracen h':<28} {'median s':>9} {'rel L2':>8} {'mass':>7}")
    voxel_volume = np.prod([(hi[i] - lo[i]) / s for i, s in enumerate((nx, ny, nz))])
    for label in (args.only,) if args.only else ("uniform", "knn"):
        times = []
        for _ in range(args.runs):
            t = time.perf_counter()
            if label == "uniform":
                h = np.full(n, args.h0)
            else:
                d, _ = cKDTree(xyz).query(xyz, k=args.neighbours + 1, workers=-1)
                h = d[:, -1] / 2.0
            out = interpolate_3d_grid(
                sarracen.SarracenDataFrame({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "h": h, "m": mass, "one": np.ones(n)},
                                           params={"hfact": 1.2}),
                "one", x_pixels=nx, y_pixels=ny, z_pixels=nz, xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]),
                dens_weight=True, normalize=False, backend="cpu")
            times.append(time.perf_counter() - t)
        name = f"uniform h0={args.h0:.3f}" if label == "uniform" else f"knn N*={args.neighbours}"
        print(f"{name:<28} {statistics.median(times):>9.3f} {rel_l2(out, truth):>8.4f} {out.sum() * voxel_volume / mass.sum():>7.4f}")


if __name__ == "__main__":
    main()
