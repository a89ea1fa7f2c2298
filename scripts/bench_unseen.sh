#!/usr/bin/env bash
# Single scattering at the defaults on scenes the bundled two are not (issue #30): each scene
# of `nimbus-scene` (crates/bench/src/scenes.rs: anvil, forward, sheet: non-cubic, rotated
# and offset lattices, a thin dense sheet, g up to 0.9) through `vdbcache --no-multiple |
# vdbmarch --spp 1`, against the independent brute-force single-scatter march
# (nimbus-single: a Simpson shadow ray at every eighth-of-a-voxel camera step, no cache, no
# table). Issue 18's target: 0.5% relative RMSE. The default refines Li_single's lattice per
# axis (`--single-tolerance`, design.md section 5); beside it the uniform lattices of
# `--cache-scale 1` (the density's, unrefined) and 0.5, which say how much of the error is
# Li_single's lattice rather than the light table or the march.
#
#   scripts/bench_unseen.sh [WORKDIR]     (default out/unseen; WIDTH x HEIGHT 160 x 90)
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-out/unseen}
mkdir -p "$work"
bin=${CARGO_TARGET_DIR:-target}/release
w=${WIDTH:-160}
h=${HEIGHT:-90}
cargo build --release --locked -p nimbus --bins -p nimbus-bench >&2
echo "| scene | --cache-scale | vdbcache --no-multiple wall s | vdbmarch against the brute-force march |"
echo "|---|---|---|---|"
for scene in anvil forward sheet; do
    flags=$("$bin/nimbus-scene" "$scene" "$work/$scene.vdb")
    medium=$(echo "$flags" | sed -n 1p)
    camera=$(echo "$flags" | sed -n 2p)
    images=()
    declare -A bake
    for scale in default 1 0.5; do
        lattice=()
        [ "$scale" = default ] || lattice=(--cache-scale "$scale")
        # shellcheck disable=SC2086
        bake[$scale]=$( { /usr/bin/time -f "%e" "$bin/vdbcache" "$work/$scene.vdb" $medium $camera --width "$w" --height "$h" \
            --no-multiple "${lattice[@]}" -q -o "$work/$scene-$scale.vdb"; } 2>&1 | tail -n 1)
        "$bin/vdbmarch" "$work/$scene-$scale.vdb" --spp 1 -q -o "$work/$scene-$scale.exr"
        images+=(--compare "$work/$scene-$scale.exr")
    done
    "$bin/nimbus-single" "$work/$scene-default.vdb" -o "$work/$scene-brute.exr" "${images[@]}" |
        while read -r image score; do
            scale=${image%.exr:}; scale=${scale##*-}
            echo "| $scene | $scale | ${bake[$scale]} | $score |"
        done
done
