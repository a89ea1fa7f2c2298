#!/usr/bin/env bash
# The benchmark scenes, made once by the release tools into out/bench/ (re-made when the
# particles or this script are newer than the file; delete out/bench to remake after changing the tools):
#   cloud1.vdb  Cloud1-class: data/cloud.ply at voxel 1 -> about 340 x 40 x 360 voxels
#   smoke.vdb   smoke-like:   data/plume.ply at 280 voxels on its longest axis
# Each holds density + Li_single + Li_multiple (the full chain up to vdbcache) and records
# its camera, medium and lights.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/release}
mkdir -p out/bench

scene() {
  local out=$1 particles=$2 density_flags=$3 light_flags=$4 camera_flags=$5
  if [[ -f $out && $out -nt $particles && $out -nt $0 ]]; then
    return
  fi
  echo "== making $out" >&2
  # shellcheck disable=SC2086
  "$BIN/particles2vdb" "$particles" -q $density_flags \
    | "$BIN/vdbphoton" -q $light_flags \
    | "$BIN/vdbcache" -q $camera_flags -o "$out"
}

scene out/bench/cloud1.vdb data/cloud.ply "--voxel-size 1" \
  "--extinction 30 --albedo 0.95 --g 0.6 --sun dir=0.5,0.3,-0.8,irradiance=4 --photons 200000 --distance delta" \
  "--eye 170,-300,160 --look-at 170,180,10 --width 1024 --height 576"
scene out/bench/smoke.vdb data/plume.ply "--resolution 280" \
  "--extinction 40 --albedo 0.8 --g 0.3 --sun dir=-0.7,0.5,-0.5,irradiance=5 --photons 200000 --distance delta" \
  "--width 1024 --height 576"
