#!/usr/bin/env bash
# The main job on bundled data: each sample particle set through the whole chain,
#   particles2vdb | vdbcache | vdbmarch   (multiple scattering by paths: no photons needed)
# with per-stage times (-v). Results land in out/: <scene>.exr, <scene>.png, and the
# intermediate <scene>.vdb (the cache VDB, openable in Blender or Houdini).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/release}
mkdir -p out

render() {
  local scene=$1; shift
  local particles=$1; shift
  local density_flags=$1; shift
  local light_flags=$1; shift
  local camera_flags=$1; shift
  echo "== $scene: $particles" >&2
  local start=$(date +%s%N)
  # shellcheck disable=SC2086
  "$BIN/particles2vdb" "$particles" -v $density_flags \
    | "$BIN/vdbcache" -v $light_flags $camera_flags -o "out/$scene.vdb"
  "$BIN/vdbmarch" -v "out/$scene.vdb" -o "out/$scene.exr" --preview "out/$scene.png" "$@"
  local ms=$(( ($(date +%s%N) - start) / 1000000 ))
  printf '== %s: %d.%03d s in all -> out/%s.exr, out/%s.png\n' "$scene" $((ms / 1000)) $((ms % 1000)) "$scene" "$scene" >&2
}

# A flat cumulus deck (340 x 360 x 40 units) lit by a low sun, seen from above its edge.
render cloud data/cloud.ply "--voxel-size 2" \
  "--extinction 30 --albedo 0.95 --g 0.6 --sun dir=0.5,0.3,-0.8,irradiance=4" \
  "--eye 170,-300,160 --look-at 170,180,10"
# A smoke plume rising 150 units, darker and more absorbing, lit from the side.
render plume data/plume.ply "--voxel-size 1" \
  "--extinction 40 --albedo 0.8 --g 0.3 --sun dir=-0.7,0.5,-0.5,irradiance=5" \
  ""

cp out/cloud.exr out/demo.exr
cp out/cloud.png out/demo.png
echo "demo: out/demo.exr, out/demo.png" >&2
