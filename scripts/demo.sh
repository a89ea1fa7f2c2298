#!/usr/bin/env bash
# The main job on bundled data: each sample particle set (the cumulus first) through the whole chain,
#   particles2vdb | vdbcache | vdbmarch   (multiple scattering by paths: no photons needed)
# and the bundled Blender fire (already a fog volume) through vdbcache | vdbmarch,
# with per-stage times (-v). Results land in out/: <scene>.exr, <scene>.png, and the
# intermediate <scene>.vdb (the cache VDB, openable in Blender or Houdini).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/release}
mkdir -p out

# render SCENE INPUT DENSITY_FLAGS LIGHT_FLAGS CAMERA_FLAGS [vdbmarch flags...]: particles
# through particles2vdb | vdbcache, or a VDB (already a fog volume; DENSITY_FLAGS unused)
# straight into vdbcache; then vdbmarch.
render() {
  local scene=$1; shift
  local input=$1; shift
  local density_flags=$1; shift
  local light_flags=$1; shift
  local camera_flags=$1; shift
  echo "== $scene: $input" >&2
  local start=$(date +%s%N)
  # shellcheck disable=SC2086
  if [[ $input == *.vdb ]]; then
    "$BIN/vdbcache" -v "$input" $light_flags $camera_flags -o "out/$scene.vdb"
  else
    "$BIN/particles2vdb" "$input" -v $density_flags \
      | "$BIN/vdbcache" -v $light_flags $camera_flags -o "out/$scene.vdb"
  fi
  "$BIN/vdbmarch" -v "out/$scene.vdb" -o "out/$scene.exr" --preview "out/$scene.png" "$@"
  local ms=$(( ($(date +%s%N) - start) / 1000000 ))
  printf '== %s: %d.%03d s in all -> out/%s.exr, out/%s.png\n' "$scene" $((ms / 1000)) $((ms % 1000)) "$scene" "$scene" >&2
}

# Each scene is lit by a sun and a blue sky (--sky: uniform radiance from every direction,
# about a sixth of the light on a horizontal surface, as on a clear day), which camera rays
# also see behind the volume, as Blender shows its World.

source scripts/demo_scenes.sh
# A cumulus of overlapping puffs on a flat base (data/README.md says how it was made), with
# the offset noise as for the deck: the README's first picture.
render cumulus data/cumulus.ply "$CUMULUS_DENSITY" "$CUMULUS_LIGHT" "$CUMULUS_CAMERA" --offset-noise 2
# A flat cumulus deck (340 x 360 x 40 units) under a low sun, seen from above its edge,
# with the paper's Perlin offset noise (one voxel) for detail finer than the particles.
render cloud data/cloud.ply "$CLOUD_DENSITY" "$CLOUD_LIGHT" "$CLOUD_CAMERA" --offset-noise 2
# A smoke plume rising 150 units, darker and more absorbing, lit from the side.
render plume data/plume.ply "$PLUME_DENSITY" "$PLUME_LIGHT" "$PLUME_CAMERA"
# A Blender 3.4 Mantaflow fire (data/fire.vdb, data/README.md): recognised as a Mantaflow
# fire by its `flame` grid beside a normalised `temperature` grid, it renders by default as
# Blender renders it, a blackbody from the flame (1500 to 3000 K; the file's `temperature`,
# Mantaflow's heat, is not used: crates/cli/src/emission.rs). The medium is the .blend's own
# Quick Smoke material (Principled Volume density 5, colour 0.5, no anisotropy); a sun from
# the camera's left, above, strong enough that the smoke beside the flame reads. The camera
# frames the plume from slightly right of -Y (scripts/compare_cycles.sh renders the same
# view in Cycles).
render fire data/fire.vdb "" \
  "--extinction 5 --albedo 0.5 --g 0 --sun dir=0.6,0.5,-0.62,irradiance=12 --sky 0.03,0.04,0.07" \
  "--eye 2.6,-7.8,1.8 --look-at 0,0,1.05"

cp out/cumulus.exr out/demo.exr
cp out/cumulus.png out/demo.png
echo "demo: out/demo.exr, out/demo.png" >&2
