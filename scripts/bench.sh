#!/usr/bin/env bash
# Benchmark tables (not tests: these machines are shared, so quote medians and ratios from
# one run). Each prints its own table; run one alone with the command shown in its header.
set -euo pipefail
cd "$(dirname "$0")/.."
run() { echo; echo "== $*"; "$@"; }
run cargo bench --locked -p nimbus-vdb --bench io
run cargo bench --locked -p nimbus-gpu --bench sampling
run cargo run --locked --release -p nimbus-density --example accuracy
run cargo bench --locked -p nimbus-photon --bench trace
run cargo run --locked --release -p nimbus-photon --example figure2
run cargo bench --locked -p nimbus-march --bench render
