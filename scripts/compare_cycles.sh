#!/usr/bin/env bash
# The bundled Blender fire (data/fire.vdb) through nimbus beside Blender Cycles' render of the
# same bake (its .blend, with Quick Smoke's fire material), same camera, same sun, black world
# (issue #19; the findings are in docs/benchmarks.md, "Blender fire against Cycles").
#
#   scripts/compare_cycles.sh [WORKDIR]   (default out/fire-cycles; BIN=dir of the built tools,
#                                          default target/release; SPP=Cycles samples, 1024;
#                                          REF_SPP=nimbus --reference samples, 2048;
#                                          PNG=the side-by-side picture, docs/fire-cycles.png)
#
# About 10 minutes on one core at the defaults (each Cycles render 70-100 s at 1024 spp).
#
# 1. Bakes WORKDIR/fire.blend with scripts/blender/make_smoke.py --fire when it is missing
#    (Mantaflow is deterministic here: the bake's last frame must equal data/fire.vdb, which
#    step 2 checks), about 12 s.
# 2. Writes WORKDIR/fire-bt.vdb: data/fire.vdb plus the temperature Cycles actually reads for
#    the domain (`blender_temperature`, flame-derived; scripts/blender/blender_temperature.py).
# 3. Renders with nimbus (the default chain, Blender's material as medium flags: Principled
#    Volume Density 5 is --extinction 5, Color 0.5 with a black Absorption Color is albedo 0.5,
#    Anisotropy 0 is --g 0; and vdbmarch --reference, which has the fire's light scattered by
#    the smoke) and with Cycles (scripts/blender/render_cycles.py, CPU, one thread): the
#    whole image, the fire alone (no sun), the sunlit smoke alone (no emission), the fire in
#    a pure absorber (albedo 0: emission and attenuation only), and Cycles at its own
#    default of 0 volume bounces.
# 4. Prints, per pair, mean RGB, their ratio and the relative RMSE after 2x2 blocks
#    (scripts/blender/compare_exr.py), and writes PNG: nimbus | Cycles | |difference| x 4
#    through Blender 3.4's Filmic view, for the file as nimbus reads it (row 1) and with
#    Blender's temperature (row 2).
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/release}
BIN=$(cd "$BIN" && pwd)
work=${1:-out/fire-cycles}
mkdir -p "$work"
work=$(cd "$work" && pwd)
spp=${SPP:-1024}
png=${PNG:-docs/fire-cycles.png}
case $png in /*) ;; *) png=$repo/$png ;; esac
for t in vdbcache vdbmarch; do
    [ -x "$BIN/$t" ] || { echo "compare_cycles: no $BIN/$t (make build, or BIN=...)" >&2; exit 2; }
done
command -v blender >/dev/null || { echo "compare_cycles: blender is not installed" >&2; exit 2; }
# Blender on one thread: this is a shared 2-core machine, and the timings stay comparable.
# Only the scripts' own lines are shown; a failing run shows its last lines and stops here.
blend() {
    local log
    log=$(mktemp)
    if ! blender -b --factory-startup -t 1 --python-exit-code 1 "$@" >"$log" 2>&1; then
        tail -20 "$log" >&2
        rm -f "$log"
        echo "compare_cycles: blender $* failed" >&2
        return 1
    fi
    grep -E '^(make_smoke|render_cycles|blender_temperature|compare_exr)|mean RGB' "$log" || true
    rm -f "$log"
}

# The demo's fire scene (scripts/demo.sh), at a third of its size: camera, sun, and
# Blender's material as the medium.
cam="--eye 2.6,-7.8,1.8 --look-at 0,0,1.05 --up 0,0,1 --fov 40 --width 320 --height 180"
sun="dir=0.6,0.5,-0.62,irradiance=12"
medium="--extinction 5 --albedo 0.5 --g 0"
dark="dir=0,0,-1,irradiance=0"  # no sun (nimbus puts a default sun where none is given)

if [ ! -s "$work/fire.blend" ]; then
    blend --python scripts/blender/make_smoke.py -- "$work" --fire
fi
blend "$work/fire.blend" -P scripts/blender/blender_temperature.py -- data/fire.vdb "$work/fire-bt.vdb"
[ -s "$work/fire-bt.vdb" ] || { echo "compare_cycles: no $work/fire-bt.vdb" >&2; exit 1; }

# nimbus: NAME, input, flags for vdbcache, flags for vdbmarch, and the medium (default $medium).
nimbus() {
    local name=$1 in=$2 cache=$3 march=$4 med=${5:-$medium} start
    start=$(date +%s%N)
    # shellcheck disable=SC2086
    "$BIN/vdbcache" -q "$in" $med $cam $cache | "$BIN/vdbmarch" -q -o "$work/$name.exr" $march
    echo "nimbus $name: $(( ($(date +%s%N) - start) / 1000000 )) ms" >&2
}
# The reference path tracer (all orders, fire light scattered by the smoke included): NAME,
# input, the medium, flags.
reference() {
    local name=$1 in=$2 med=$3 start
    shift 3
    start=$(date +%s%N)
    # shellcheck disable=SC2086
    "$BIN/vdbmarch" -q --reference "$in" $med $cam --spp "$ref_spp" "$@" -o "$work/$name.exr"
    echo "nimbus --reference $name: $(( ($(date +%s%N) - start) / 1000000 )) ms" >&2
}
ref_spp=${REF_SPP:-2048}
bt="--temperature-grid blender_temperature --temperature-scale 1000 --blackbody-intensity 1"
# The file as nimbus reads it: its `temperature` grid (Mantaflow's heat) recognised.
nimbus n-full data/fire.vdb "--sun $sun" ""
nimbus n-fire data/fire.vdb "--sun $dark" ""
nimbus n-sun data/fire.vdb "--sun $sun" "--no-emission"
# With the temperature Cycles reads (flame-derived).
nimbus n-bt-full "$work/fire-bt.vdb" "--sun $sun" "$bt"
nimbus n-bt-fire "$work/fire-bt.vdb" "--sun $dark" "$bt"
# A pure absorber (albedo 0): nothing scatters, so emission and its attenuation alone.
absorber="--extinction 5 --albedo 0 --g 0"
nimbus n-bt-fire-a0 "$work/fire-bt.vdb" "--sun $dark" "$bt" "$absorber"
# shellcheck disable=SC2086
reference r-bt-fire "$work/fire-bt.vdb" "$medium" --sun "$dark" $bt
# shellcheck disable=SC2086
reference r-bt-fire-a0 "$work/fire-bt.vdb" "$absorber" --sun "$dark" $bt
# shellcheck disable=SC2086
reference r-bt-full "$work/fire-bt.vdb" "$medium" --sun "$sun" $bt

cycles() {
    local name=$1; shift
    # shellcheck disable=SC2086
    blend "$work/fire.blend" -P scripts/blender/render_cycles.py -- $cam --samples "$spp" "$@" \
        -o "$work/$name.exr"
}
cycles c-full --sun "$sun"
cycles c-fire --no-sun
cycles c-sun --sun "$sun" --no-emission
# Colour 0 with Quick Smoke's black Absorption Color: Principled Volume's extinction stays
# density x 5, all of it absorption.
cycles c-fire-a0 --no-sun --color 0
cycles c-full-b0 --sun "$sun" --volume-bounces 0

echo "== A / B: nimbus (data/fire.vdb, vdbcache | vdbmarch at the defaults, $medium) and Cycles ($spp spp, 8 volume bounces unless said); nimbus --reference at $ref_spp spp"
blend -P scripts/blender/compare_exr.py -- \
    "nimbus as read (heat as temperature) / Cycles, whole image=$work/n-full.exr:$work/c-full.exr" \
    "nimbus as read / Cycles, fire alone=$work/n-fire.exr:$work/c-fire.exr" \
    "nimbus / Cycles, sunlit smoke alone=$work/n-sun.exr:$work/c-sun.exr" \
    "nimbus with Blender's temperature / Cycles, whole image=$work/n-bt-full.exr:$work/c-full.exr" \
    "nimbus with Blender's temperature / Cycles at 0 volume bounces, whole image=$work/n-bt-full.exr:$work/c-full-b0.exr" \
    "nimbus with Blender's temperature / Cycles, fire alone=$work/n-bt-fire.exr:$work/c-fire.exr" \
    "nimbus / Cycles, fire alone, pure absorber=$work/n-bt-fire-a0.exr:$work/c-fire-a0.exr" \
    "nimbus reference / Cycles, fire alone=$work/r-bt-fire.exr:$work/c-fire.exr" \
    "nimbus reference / Cycles, whole image=$work/r-bt-full.exr:$work/c-full.exr" \
    "nimbus march / nimbus reference, fire alone, pure absorber=$work/n-bt-fire-a0.exr:$work/r-bt-fire-a0.exr" \
    "fire light scattered by the smoke: nimbus reference albedo 0.5 / 0=$work/r-bt-fire.exr:$work/r-bt-fire-a0.exr" \
    "fire light scattered by the smoke: Cycles colour 0.5 / 0=$work/c-fire.exr:$work/c-fire-a0.exr"
blend -P scripts/blender/compare_exr.py -- --png "$png" \
    "row 1, as read=$work/n-full.exr:$work/c-full.exr" \
    "row 2, Blender's temperature=$work/n-bt-full.exr:$work/c-full.exr" | grep -v '^row'
