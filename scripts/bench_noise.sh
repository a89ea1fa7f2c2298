#!/usr/bin/env bash
# The offset noise's cost and error (issue #30): the demo's cloud and plume caches made
# with scripts/demo.sh's flags (scripts/demo_scenes.sh) into out/bench/noise/, then the
# march bench over them (crates/march/benches/noise.rs: no noise, the displaced medium
# baked (the default), the offsets baked and read per sample, exact).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/release}
source scripts/demo_scenes.sh
out=out/bench/noise
mkdir -p "$out"
cache() {
  local scene=$1 input=$2 density=$3 light=$4 camera=$5
  if [[ ! -f $out/$scene.vdb ]]; then
    # shellcheck disable=SC2086
    "$BIN/particles2vdb" "$input" -q $density | "$BIN/vdbcache" -q $light $camera -o "$out/$scene.vdb"
  fi
}
cache cloud data/cloud.ply "$CLOUD_DENSITY" "$CLOUD_LIGHT" "$CLOUD_CAMERA"
cache plume data/plume.ply "$PLUME_DENSITY" "$PLUME_LIGHT" "$PLUME_CAMERA"
cargo bench --locked -p nimbus-march --bench noise -- "$@"
