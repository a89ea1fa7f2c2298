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
# Run time against error for the whole chain, against the path-traced reference:
# out/bench/pareto.csv and out/bench/pareto.png.
run target/release/nimbus-bench --bin target/release
