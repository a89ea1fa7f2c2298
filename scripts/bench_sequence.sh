#!/usr/bin/env bash
# A frame sequence through the whole chain (issue #20): the bundled plume moving 1 unit a
# frame along +X and 0.5 up (scripts/make_moving_particles.py), FRAMES frames (default 24) at
# a small look-development size, rendered by nimbus-render on this machine and by a one-node
# Slurm cluster running two array tasks at a time (as root: scripts/farm/slurm-local.sh);
# seconds a frame and the peak memory of the largest process; and frame-to-frame flicker, the
# relative RMS difference of consecutive frames (nimbus-compare) of a static scene with the
# Perlin offset noise on, beside the moving scene's for scale, and of a slowly moving plume
# against its path-traced reference's (nimbus-compare --flicker).
#
#   scripts/bench_sequence.sh [OUT]        (make bench runs it; NIMBUS_BIN=target/ci for the
#                                           ci profile's binaries)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=$(realpath "${NIMBUS_BIN:-${CARGO_TARGET_DIR:-target}/release}")
out=${1:-out/bench/sequence}
frames=${FRAMES:-24}
mkdir -p "$out"
out=$(realpath "$out")
for tool in nimbus-render particles2vdb vdbcache vdbmarch nimbus-compare; do
  [ -x "$bin/$tool" ] || { echo "error: $bin/$tool missing (make build, or cargo build --release --workspace)" >&2; exit 1; }
done
python3 scripts/make_moving_particles.py data/plume.ply "$out/plume.####.ply" --frames "$frames" --velocity 1,0,0.5
flags=(--extinction 40 --albedo 0.8 --g 0.3 --sun dir=-0.7,0.5,-0.5,irradiance=5 --sky 0.15,0.24,0.42
  --eye 10,-420,100 --look-at 10,0,95 --width 240 --height 180 --quality draft -q
  --particles2vdb "--voxel-size 2")
seconds() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.2f}')" "$@"; }
peak_mb() { awk -F': ' '/Maximum resident set size/ {printf "%.0f", $2 / 1024}' "$1"; }

echo "| run | frames | wall s | s/frame | peak memory (largest process) |"
echo "|---|---|---|---|---|"
rm -rf "$out/local"
t0=$(date +%s.%N)
/usr/bin/time -v -o "$out/local.time" "$bin/nimbus-render" "$out/plume.####.ply" -o "$out/local/plume.####.exr" \
  --frames "1-$frames" "${flags[@]}"
t1=$(date +%s.%N)
wall=$(seconds "$t0" "$t1")
echo "| one machine, frames one after another | $frames | $wall | $(python3 -c "print(f'{$wall / $frames:.2f}')") | $(peak_mb "$out/local.time") MB |"

if [ "$(id -u)" -eq 0 ] && command -v slurmctld >/dev/null; then
  cluster=$out/cluster
  rm -rf "$cluster" "$out/slurm" "$out/slurm-logs"
  scripts/farm/slurm-local.sh start "$cluster" 2
  trap 'scripts/farm/slurm-local.sh stop "$cluster"' EXIT
  export SLURM_CONF=$cluster/slurm.conf
  # Each task's peak memory: nimbus-render under /usr/bin/time (Slurm keeps no accounting here).
  timed=$out/nimbus-render-timed
  printf '#!/bin/sh\nexec /usr/bin/time -v -o "%s/slurm-time.${SLURM_ARRAY_TASK_ID:-submit}" %q "$@"\n' "$out" "$bin/nimbus-render" > "$timed"
  chmod +x "$timed"
  rm -f "$out"/slurm-time.*
  t0=$(date +%s.%N)
  NIMBUS_RENDER=$timed scripts/farm/slurm-submit.sh "$out/plume.####.ply" -o "$out/slurm/plume.####.exr" \
    --frames "1-$frames" --chunk 4 --max-running 2 --log-dir "$out/slurm-logs" \
    -- "${flags[@]}" > "$out/slurm.job"
  # Poll (sbatch --wait polls at growing intervals, which would add seconds to the wall time).
  while [ -n "$(squeue -h -j "$(cat "$out/slurm.job")")" ]; do sleep 0.2; done
  t1=$(date +%s.%N)
  done_frames=$(ls "$out/slurm" | wc -l)
  wall=$(seconds "$t0" "$t1")
  echo "| Slurm, one node, 2 tasks at a time (chunks of 4) | $done_frames | $wall | $(python3 -c "print(f'{$wall / $frames:.2f}')") | $(cat "$out"/slurm-time.[0-9]* | awk -F': ' '/Maximum resident set size/ {if ($2 > m) m = $2} END {printf "%.0f", m / 1024}') MB a task |"
  for f in $(seq 1 "$frames"); do
    n=$(printf '%04d' "$f")
    cmp -s "$out/local/plume.$n.exr" "$out/slurm/plume.$n.exr" || echo "(frame $f differs between the local and the Slurm run)"
  done
else
  echo "| Slurm | (skipped: needs root and slurm-wlm) | | | |"
fi

# Flicker: a static scene (frame 1's particles for every frame), offset noise on.
for f in 1 2 3 4; do cp "$out/plume.0001.ply" "$out/static.$(printf '%04d' "$f").ply"; done
rm -rf "$out/static"
"$bin/nimbus-render" "$out/static.####.ply" -o "$out/static/static.####.exr" --frames 1-4 "${flags[@]}" \
  --vdbmarch "--offset-noise 1 --noise-scale 4"
echo
echo "| consecutive frames | relative RMS difference |"
echo "|---|---|"
for f in 1 2 3; do
  a=$(printf '%04d' "$f"); b=$(printf '%04d' $((f + 1)))
  r=$("$bin/nimbus-compare" "$out/static/static.$a.exr" "$out/static/static.$b.exr" | sed 's/.*relative RMSE \([^,]*\),.*/\1/')
  echo "| static scene, offset noise on, $f -> $((f + 1)) | $r |"
done
for f in 1 12; do
  a=$(printf '%04d' "$f"); b=$(printf '%04d' $((f + 1)))
  r=$("$bin/nimbus-compare" "$out/local/plume.$a.exr" "$out/local/plume.$b.exr" | sed 's/.*relative RMSE \([^,]*\),.*/\1/')
  echo "| moving plume (1 unit a frame), $f -> $((f + 1)) | $r |"
done

# The chain's flicker beyond the motion: a slowly moving plume (0.25 a frame along +X, 0.125
# up) against a path-traced reference of each frame (vdbmarch --reference on the frame's own
# cache.vdb, which records the medium and the lights), the same seed for every frame in both,
# at the draft quality above and at the default. "excess" is the RMS of (image change -
# reference change): what the chain adds to the motion or misses of it; the reference's own
# noise floor is beside it (frame 1 at two seeds).
spp=${FLICKER_SPP:-2048}
python3 scripts/make_moving_particles.py data/plume.ply "$out/slow.####.ply" --frames 4 --velocity 0.25,0,0.125
default_flags=()
for f in "${flags[@]}"; do [ "$f" = --quality ] || [ "$f" = draft ] || default_flags+=("$f"); done
rm -rf "$out/slow" "$out/slow-draft" "$out/slow-kept"
"$bin/nimbus-render" "$out/slow.####.ply" -o "$out/slow-draft/slow.####.exr" --frames 1-4 "${flags[@]}"
"$bin/nimbus-render" "$out/slow.####.ply" -o "$out/slow/slow.####.exr" --frames 1-4 \
  --keep-intermediates "$out/slow-kept" "${default_flags[@]}"
view=(--eye 10,-420,100 --look-at 10,0,95 --width 240 --height 180 --reference --spp "$spp" -q)
for f in 1 2 3 4; do
  n=$(printf '%04d' "$f")
  "$bin/vdbmarch" "$out/slow-kept/slow.$n.cache.vdb" "${view[@]}" -o "$out/slow/reference.$n.exr"
done
"$bin/vdbmarch" "$out/slow-kept/slow.0001.cache.vdb" "${view[@]}" --seed 1 -o "$out/slow/reference-seed1.0001.exr"
floor=$("$bin/nimbus-compare" "$out/slow/reference.0001.exr" "$out/slow/reference-seed1.0001.exr" | sed 's/.*relative RMSE \([^,]*\),.*/\1/')
echo
echo "| slowly moving plume, $spp-spp reference | reference change | chain change | excess | chain's error, frame 1 |"
echo "|---|---|---|---|---|"
for run in slow-draft slow; do
  label=$([ "$run" = slow ] && echo "default quality" || echo "draft")
  error=$("$bin/nimbus-compare" "$out/slow/reference.0001.exr" "$out/$run/slow.0001.exr" | sed 's/.*relative RMSE \([^,]*\),.*/\1/')
  for f in 1 2 3; do
    a=$(printf '%04d' "$f"); b=$(printf '%04d' $((f + 1)))
    "$bin/nimbus-compare" --flicker "$out/slow/reference.$a.exr" "$out/slow/reference.$b.exr" \
      "$out/$run/slow.$a.exr" "$out/$run/slow.$b.exr" |
      sed "s/reference change \([^,]*\), image change \([^,]*\), excess \(.*\)/| $label, $f -> $((f + 1)) | \1 | \2 | \3 | $error |/"
  done
done
echo "(reference noise floor: frame 1 at seeds 0 and 1 differ by $floor relative RMSE)"
