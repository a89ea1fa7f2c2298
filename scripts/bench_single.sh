#!/usr/bin/env bash
# Single scattering at the defaults against an independent brute-force single-scatter march
# (nimbus-single: a Simpson shadow ray at every eighth-of-a-voxel camera step, no cache, no
# table), on the bundled scenes as nimbus-bench left them (out/bench/SCENE/cache-paths-.vdb,
# the default chain's cache, which records the scene and camera). Issue 18's target: 0.5%.
#
#   scripts/bench_single.sh            (after nimbus-bench; make bench runs it in order)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${CARGO_TARGET_DIR:-target}/release
echo "| scene | shadows | vdbcache --no-multiple wall s | vdbmarch against the brute-force march |"
echo "|---|---|---|---|"
for scene in cloud plume; do
    dir=out/bench/$scene
    cache=$dir/cache-paths-.vdb
    [ -s "$cache" ] || { echo "$cache missing: run nimbus-bench first" >&2; exit 1; }
    declare -A bake
    for shadows in table rays; do
        bake[$shadows]=$( { /usr/bin/time -f "%e" "$bin/vdbcache" "$cache" --no-multiple --shadows "$shadows" -q -o "$dir/single-$shadows.vdb"; } 2>&1 | tail -n 1)
        "$bin/vdbmarch" "$dir/single-$shadows.vdb" --spp 1 -q -o "$dir/single-$shadows.exr"
    done
    "$bin/nimbus-single" "$cache" -o "$dir/single-brute.exr" --compare "$dir/single-table.exr" --compare "$dir/single-rays.exr" |
        while read -r image score; do
            shadows=${image%.exr:}; shadows=${shadows##*-}
            echo "| $scene | $shadows | ${bake[$shadows]} | $score |"
        done
done
