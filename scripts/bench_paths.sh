#!/usr/bin/env bash
# Li_multiple's paths on the Cloud1-class scene (scripts/bench_cloud1.sh's density, medium,
# sun and camera): the noise of the path-traced multiple scattering, without a reference, as
# the relative RMSE between the images of two seeds (nimbus-compare: 2x2 blocks, covered
# pixels; the paths are unbiased, so this is sqrt(2) x each image's noise from the paths), and
# the CPU seconds (user + sys) of each whole vdbcache run beside it, and once without
# Li_multiple (the fixed part: plan, light tables, single scattering, transmittance grids).
#
#   scripts/bench_paths.sh [WORKDIR]      (PATHS=16 by default; BIN=target/ci)
#
# Efficiency is 1 / (RMSE^2 x CPU seconds of the paths): compare it between builds run side
# by side, not across machines or loads.
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-$(mktemp -d)}
mkdir -p "$work"
paths=${PATHS:-16}
bin=${BIN:-target/ci}
target=${CARGO_TARGET_DIR:-target}
gen="$target/ci/examples/gen_particles"
[ -x "$gen" ] || cargo build --profile ci --locked -p nimbus-density --example gen_particles >&2
[ -s "$work/cloud1.ply" ] || "$gen" cloud1 "$work/cloud1.ply" 500000 1 >&2
[ -s "$work/density.vdb" ] || "$bin/particles2vdb" "$work/cloud1.ply" --bounds 0,0,0,339,42,361 --voxel-size 1 -o "$work/density.vdb"

optics=(--extinction 30 --albedo 0.95 --g 0.6 --sun dir=0.5,0.3,-0.8,irradiance=4)
camera=(--eye 170,-300,160 --look-at 170,180,10 --width 1024 --height 576)
cpu() { /usr/bin/time -f "%U %S" -o "$work/time.txt" "$@" >/dev/null 2>"$work/stderr.txt"; awk '{print $1 + $2}' "$work/time.txt"; }

fixed=$(cpu "$bin/vdbcache" "$work/density.vdb" "${optics[@]}" "${camera[@]}" --no-multiple -o "$work/fixed.vdb")
for seed in 1 2; do
    c=$(cpu "$bin/vdbcache" "$work/density.vdb" "${optics[@]}" "${camera[@]}" --paths "$paths" --seed "$seed" -o "$work/cache-$seed.vdb")
    "$bin/vdbmarch" "$work/cache-$seed.vdb" -o "$work/image-$seed.exr" 2>/dev/null
    echo "seed $seed: vdbcache CPU s $c (without Li_multiple $fixed)"
done
"$bin/nimbus-compare" "$work/image-1.exr" "$work/image-2.exr"
