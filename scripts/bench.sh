#!/usr/bin/env bash
# Benchmark tables (not tests: these machines are shared, so quote medians and ratios from
# one run). Each prints its own table; run one alone with the command shown in its header.
set -euo pipefail
cd "$(dirname "$0")/.."
run() { echo; echo "== $*"; "$@"; }
run cargo bench --locked -p nimbus-vdb --bench io
run cargo bench --locked -p nimbus-gpu --bench sampling
run cargo run --locked --release -p nimbus-density --example accuracy
run cargo bench --locked -p nimbus-density --bench estimate
run cargo bench --locked -p nimbus-photon --bench trace
run cargo run --locked --release -p nimbus-photon --example figure2
run cargo bench --locked -p nimbus-cache --bench bake
run cargo bench --locked -p nimbus-march --bench render
# vdbmarch on the Cloud1-class and smoke-like caches (made by the release tools).
run scripts/bench-scenes.sh
run cargo bench --locked -p nimbus-march --bench scenes
# The offset noise on the demo's cloud and plume: no noise, baked, exact (issue #30).
run scripts/bench_noise.sh
# The Cloud1-class chain at its defaults, stage by stage, beside the paper's Table 4.
run scripts/bench_cloud1.sh out/bench/cloud1
# A Blender Mantaflow smoke file through the chain (where Blender is installed).
run scripts/bench_blender_smoke.sh out/bench/blender
# Run time against error for the whole chain, against the path-traced reference:
# out/bench/pareto.csv and out/bench/pareto.png.
rel=${CARGO_TARGET_DIR:-target}/release
run "$rel/nimbus-bench" --bin "$rel"
# Single scattering at the defaults against a brute-force single-scatter march.
run scripts/bench_single.sh
# The same on scenes made from formulas that the bundled two are not (issue #30).
run scripts/bench_unseen.sh out/unseen
# The defaults on 40 scenes drawn at random from the date's seeds, and the regression seeds
# (crates/bench/regression-seeds.txt), against the reference (issue #47).
run scripts/bench_random.sh out/random
# A 24-frame sequence of the moving plume through nimbus-render, locally and on a one-node
# Slurm cluster (as root), and frame-to-frame flicker (issue #20).
run scripts/bench_sequence.sh out/bench/sequence
# Peers side by side (issue #7), where Mitsuba 3 is installed (scripts/peers/README.md):
# Mitsuba and `vdbmarch --reference` over an spp ladder, scored against the cached reference,
# to out/bench/SCENE/peers.csv. The plume only by default: Mitsuba's scalar variant (the only
# one that runs here) needs hours for the cloud. PEERS_SCENES="plume cloud" to add it.
py=${MITSUBA_PYTHON:-/work/venv-mitsuba/bin/python}
if [ -x "$py" ] && "$py" -c "import mitsuba" 2>/dev/null; then
    for scene in ${PEERS_SCENES:-plume}; do
        # Any of the scene's caches carries the camera the chain and the reference used.
        cache=$(ls out/bench/"$scene"/cache-*.vdb | head -n 1)
        echo; echo "== peers on $scene (out/bench/$scene/peers.csv)"
        "$py" scripts/peers/compare.py "$cache" --reference out/bench/"$scene"/reference.exr \
            --spp 4,16,64,256 --vdbmarch "$rel/vdbmarch" | tee out/bench/"$scene"/peers.csv
    done
else
    echo; echo "(Mitsuba 3 not installed: peers skipped; see scripts/peers/README.md)"
fi
