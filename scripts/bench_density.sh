#!/usr/bin/env bash
# particles2vdb as a user runs it (release build, whole command: read the PLY, estimate, write
# the VDB), in one session:
#   1. the Cloud1-class scene (500k particles, grid 339 x 42 x 361) and the smoke-like one
#      (330k particles, 280 x 255 x 233) per method, CPU and GPU: median wall time of RUNS runs;
#   2. growth from 100k to 5M particles (cloud1 generator, same grid), usl and asl3 on the
#      CPU: wall time and peak memory (max RSS from /usr/bin/time -v);
#   3. sarracen's interpolate_3d_grid on the same particles and grid (scripts/bench_sarracen.py),
#      when a Python with sarracen is found ($SARRACEN_PYTHON, default /work/venv-sarracen;
#      python3 -m venv /work/venv-sarracen && /work/venv-sarracen/bin/pip install sarracen
#      scipy scikit-learn: sarracen 1.4 imports sklearn without depending on it).
# The in-process table (every method, both backends, error against the analytic density) is
# `cargo bench -p nimbus-density --bench estimate`.
#
#   scripts/bench_density.sh [WORKDIR]      (RUNS=5 by default; SIZES to override step 2)
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-$(mktemp -d)}
mkdir -p "$work"
runs=${RUNS:-5}
sizes=${SIZES:-"100000 300000 1000000 2000000 5000000"}
target=${CARGO_TARGET_DIR:-target}
cargo build --release --locked -p nimbus --bin particles2vdb >&2
# The generator's speed does not matter: the ci profile (no LTO) builds it with the tests' deps.
cargo build --profile ci --locked -p nimbus-density --example gen_particles >&2
p2v="$target/release/particles2vdb"
gen="$target/ci/examples/gen_particles"
# cloud1's grid: explicit bounds (0,0,0)-(339,42,361), unit voxels.
grid=(--bounds 0,0,0,339,42,361 --voxel-size 1)

median() { sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
# "wall_s cpu_s max_rss_kib" of one command (its output discarded). CPU seconds (user + sys)
# are quoted beside wall time because these machines are shared: wall time under load says
# little, CPU time / cores is what an idle machine would show.
measure() { /usr/bin/time -f "%e %U %S %M" -o "$work/time.txt" "$@" >/dev/null 2>&1; awk '{print $1, $2 + $3, $4}' "$work/time.txt"; }

[ -s "$work/cloud1_truth.npy" ] || "$gen" cloud1 "$work/cloud1.ply" 500000 1 "$work/cloud1_truth.npy" >&2
# The smoke-like scene: 330k particles in its 280 x 255 x 233 box of 0.8 voxels (Scene::smoke).
smoke_grid=(--bounds=-30,-30,-8,194,174,178.4 --voxel-size 0.8)
[ -s "$work/smoke.ply" ] || "$gen" smoke "$work/smoke.ply" >&2
for scene in cloud1 smoke; do
    if [ "$scene" = cloud1 ]; then args=("${grid[@]}"); what="Cloud1-class (500k particles, 339x42x361)"; else args=("${smoke_grid[@]}"); what="smoke-like (330k particles, 280x255x233)"; fi
    echo "== 1. whole command, $what, median of $runs ($(nproc) cores, load $(cut -d' ' -f1 /proc/loadavg))"
    printf "%-6s %-4s %10s %10s\n" method dev "wall s" "cpu s"
    for method in usl asl2 asl3 knn ici; do
        for dev in cpu gpu; do
            if ! "$p2v" "$work/$scene.ply" "${args[@]}" --method "$method" --device "$dev" -o "$work/out.vdb" 2>"$work/err.txt"; then
                # Say why (on lavapipe: its loop cap, which the larger supports exceed).
                printf "%-6s %-4s %10s  %s\n" "$method" "$dev" "failed" "$(head -c 110 "$work/err.txt")"
                continue
            fi
            # The GPU (a software adapter here) runs once: tens of seconds per run.
            n=$runs; [ "$dev" = gpu ] && n=1
            for _ in $(seq "$n"); do measure "$p2v" "$work/$scene.ply" "${args[@]}" --method "$method" --device "$dev" -o "$work/out.vdb"; done >"$work/runs.txt"
            printf "%-6s %-4s %10.3f %10.3f\n" "$method" "$dev" "$(cut -d' ' -f1 "$work/runs.txt" | median)" "$(cut -d' ' -f2 "$work/runs.txt" | median)"
        done
    done
    echo
done
echo
echo "== 2. growth, cloud1 generator on the same grid, CPU, one run each"
printf "%10s %-6s %10s %10s %12s\n" particles method "wall s" "cpu s" "max RSS MiB"
for n in $sizes; do
    [ -s "$work/cloud1_$n.ply" ] || "$gen" cloud1 "$work/cloud1_$n.ply" "$n" 1 2>/dev/null
    for method in usl asl3 ici; do
        read -r wall cpu rss < <(measure "$p2v" "$work/cloud1_$n.ply" "${grid[@]}" --method "$method" --device cpu -o "$work/out.vdb")
        printf "%10d %-6s %10.2f %10.2f %12.0f\n" "$n" "$method" "$wall" "$cpu" "$((rss / 1024))"
    done
done

python=${SARRACEN_PYTHON:-/work/venv-sarracen/bin/python}
echo
if [ -x "$python" ] && "$python" -c "import sarracen" 2>/dev/null; then
    echo "== 3. sarracen interpolate_3d_grid, same particles and grid"
    # particles2vdb's auto h0 on this scene, from its -v line "method usl, h0 H (auto), ...".
    h0=$("$p2v" "$work/cloud1.ply" "${grid[@]}" --method usl -v -o "$work/out.vdb" 2>&1 | sed -n 's/.*, h0 \([0-9.e-]*\) (auto).*/\1/p')
    "$python" scripts/bench_sarracen.py "$work/cloud1.ply" "$work/cloud1_truth.npy" --bounds 0,0,0,339,42,361 --h0 "$h0" --runs "$runs"
else
    echo "== 3. sarracen: no Python with sarracen at $python (SARRACEN_PYTHON); skipped"
fi
