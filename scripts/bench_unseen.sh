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
# Then the whole chain at its defaults (`vdbcache | vdbmarch`, multiple scattering included)
# against the path-traced reference (`vdbmarch --reference`, REF_SPP paths a pixel, cached in
# WORKDIR), issue #30's 2% target. The reference's own noise comes from a second reference of
# a quarter of the paths and another seed (their difference is sqrt(5) times the first's
# noise) and is taken out of the chain's error in quadrature. MULTIPLE_SCALES (e.g. "4 2 1")
# runs the chain again at each Li_multiple lattice (`vdbcache --multiple-scale`: fixed, not
# refined by its estimated bias as the default's may be), the paths
# topped up to the same noise: what the lattice costs in accuracy (docs/benchmarks.md,
# "Li_multiple's lattice and the paths' second pass"). SINGLE=0 skips the single-scattering
# table (its brute-force march takes minutes a scene).
#
#   scripts/bench_unseen.sh [WORKDIR]     (default out/unseen; WIDTH x HEIGHT 160 x 90,
#                                          REF_SPP 4096)
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-out/unseen}
mkdir -p "$work"
w=${WIDTH:-160}
h=${HEIGHT:-90}
# BIN: tools already built elsewhere (e.g. target/ci); else the release build.
if [ -z "${BIN:-}" ]; then
    cargo build --release --locked -p nimbus --bins -p nimbus-bench >&2
fi
bin=${BIN:-${CARGO_TARGET_DIR:-target}/release}
# Writes $work/$scene.vdb and sets $medium and $camera, the flags that complete it.
make_scene() {
    local flags
    flags=$("$bin/nimbus-scene" "$scene" "$work/$scene.vdb")
    medium=$(echo "$flags" | sed -n 1p)
    camera=$(echo "$flags" | sed -n 2p)
}
if [ "${SINGLE:-1}" != 0 ]; then
    echo "| scene | --cache-scale | vdbcache --no-multiple wall s | vdbmarch against the brute-force march |"
    echo "|---|---|---|---|"
    for scene in anvil forward sheet; do
        make_scene
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
fi

ref_spp=${REF_SPP:-4096}
# score: "relative RMSE, mean ratio" of an image against a reference.
# shellcheck source=scripts/bench_lib.sh
. scripts/bench_lib.sh
echo
echo "| scene | Li_multiple lattice | chain CPU s | against the reference | less the reference's noise | reference's noise | mean ratio |"
echo "|---|---|---|---|---|---|---|"
for scene in anvil forward sheet; do
    make_scene
    reference=$work/$scene-reference-$ref_spp-${w}x$h.exr
    for lattice in default ${MULTIPLE_SCALES:-}; do
        flags=()
        [ "$lattice" = default ] || flags=(--multiple-scale "$lattice")
        chain=$work/$scene-chain-$lattice
        # shellcheck disable=SC2086
        cpu=$( { /usr/bin/time -f "%U %S" "$bin/vdbcache" "$work/$scene.vdb" $medium $camera --width "$w" --height "$h" \
            "${flags[@]}" -q -o "$chain.vdb"; } 2>&1 | tail -n 1)
        cpu2=$( { /usr/bin/time -f "%U %S" "$bin/vdbmarch" "$chain.vdb" -q -o "$chain.exr"; } 2>&1 | tail -n 1)
        if [ ! -f "$reference" ]; then
            "$bin/vdbmarch" "$chain.vdb" --reference --spp "$ref_spp" --seed 101 -q -o "$reference"
            "$bin/vdbmarch" "$chain.vdb" --reference --spp $((ref_spp / 4)) --seed 102 -q -o "${reference%.exr}-quarter.exr"
        fi
        read -r err ratio < <(score "$reference" "$chain.exr")
        read -r quarter _ < <(score "$reference" "${reference%.exr}-quarter.exr")
        awk -v e="$err" -v q="$quarter" -v r="$ratio" -v a="$cpu" -v b="$cpu2" -v s="$scene" -v l="$lattice" 'BEGIN {
            split(a, x, " "); split(b, y, " "); noise = q / sqrt(5); less = e * e - noise * noise;
            printf "| %s | %s | %.1f | %.2f%% | %s | %.2f%% | %.4f |\n", s, l, x[1] + x[2] + y[1] + y[2], 100 * e,
                (less > 0 ? sprintf("%.2f%%", 100 * sqrt(less)) : "below the noise"), 100 * noise, r }'
    done
done
