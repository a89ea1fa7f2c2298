#!/usr/bin/env bash
# The chain on a Blender smoke file (issue #18's last measurement): whole commands, release
# build, wall and CPU seconds (user + sys, from /usr/bin/time), median of RUNS runs each,
# with the 1-minute load average beside every row (this machine is shared; CPU s / cores is
# what an idle machine would show):
#   1. the default chain:  vdbcache smoke.vdb -o c.vdb;  vdbmarch c.vdb -o s.exr --preview s.png
#   2. the photon chain:   vdbphoton smoke.vdb | vdbcache --gather-neighbours 64 | vdbmarch
#   3. each tool once more with -v: the per-stage times, and vdbphoton's photons emitted
#      against stored.
# "others s": CPU seconds other processes took during a row's runs (from /proc/stat).
#
# Last quiet run (2026-12-02, 2 cores, tools of 01:11; others 0.1-0.3 s, load 1.45-1.57,
# most of it the runs themselves), wall / CPU s: vdbcache 0.35 / 0.49, vdbmarch 0.37 / 0.55,
# the default chain piped 0.63 / 1.03; vdbphoton 2.04 / 3.56 (7,750,049 photons emitted
# for 200,000 stored, 7,636,364 escaped), the photon chain piped 2.48 / 4.31. Before issue
# #18's work the photon chain took 45 s (12.8M emitted, Simpson sampling).
# The file is Blender 3.4's Mantaflow bake of a Quick Smoke-like plume
# (scripts/blender/make_smoke.py): made into WORKDIR when it is missing and blender is on
# PATH; without blender the script says so and exits 0 (nothing in the tests needs Blender).
#
#   scripts/bench_blender_smoke.sh [WORKDIR]     (default out/blender; RUNS=3;
#                                                  NIMBUS_BIN=dir of built tools, else
#                                                  cargo builds target/release)
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD
work=${1:-out/blender}
mkdir -p "$work"
work=$(cd "$work" && pwd)
runs=${RUNS:-3}

if [ ! -s "$work/smoke.vdb" ]; then
    if ! command -v blender >/dev/null 2>&1; then
        echo "bench_blender_smoke: blender is not installed and $work/smoke.vdb is missing;" \
             "skipping (apt-get install --no-install-recommends blender to run it)" >&2
        exit 0
    fi
    echo "bench_blender_smoke: baking $work/smoke.vdb with $(blender --version 2>/dev/null | head -1)" >&2
    blender -b --factory-startup --python-exit-code 1 \
        --python "$repo/scripts/blender/make_smoke.py" -- "$work" >"$work/make_smoke.log" 2>&1 \
        || { tail -20 "$work/make_smoke.log" >&2; exit 1; }
    grep '^make_smoke:' "$work/make_smoke.log" >&2 || true
fi

if [ -n "${NIMBUS_BIN:-}" ]; then
    bin=$NIMBUS_BIN
else
    cargo build --release --locked -p nimbus --bins >&2
    bin=${CARGO_TARGET_DIR:-target}/release
fi
bin=$(cd "$bin" && pwd)
for t in vdbcache vdbmarch vdbphoton; do
    [ -x "$bin/$t" ] || { echo "bench_blender_smoke: no $bin/$t" >&2; exit 1; }
done
cd "$work"

median() { sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
load() { cut -d' ' -f1 /proc/loadavg; }
# Busy CPU seconds of the whole machine so far (/proc/stat, USER_HZ 100): a row's delta less
# its own CPU seconds is what other work took meanwhile (0 on a quiet machine; the load
# average lags by a minute, this does not).
busy() { awk '/^cpu / {printf "%.2f\n", ($2 + $3 + $4 + $7 + $8 + $9) / 100}' /proc/stat; }
# One row: label, then a shell command line run RUNS times (stdout and stderr to run.log;
# a failing run prints its last lines and stops the script).
row() {
    local label=$1 cmd=$2 walls=() cpus=() loads=() i b0 ours=0
    b0=$(busy)
    for ((i = 0; i < runs; i++)); do
        loads+=("$(load)")
        if ! /usr/bin/time -f "%e %U %S" -o time.txt bash -c "set -o pipefail; $cmd" >run.log 2>&1; then
            printf "%-44s failed: %s\n" "$label" "$(grep -v '^Command exited' run.log | tail -3 | tr '\n' ' ')"
            cat time.txt >&2 || true
            exit 1
        fi
        read -r w u s <time.txt
        walls+=("$w")
        cpus+=("$(awk -v u="$u" -v s="$s" 'BEGIN {print u + s}')")
        ours=$(awk -v a="$ours" -v b="${cpus[-1]}" 'BEGIN {print a + b}')
    done
    printf "%-44s %8s %8s %8s   %s\n" "$label" \
        "$(printf '%s\n' "${walls[@]}" | median)" "$(printf '%s\n' "${cpus[@]}" | median)" \
        "$(awk -v b="$(busy)" -v b0="$b0" -v o="$ours" 'BEGIN {d = b - b0 - o; printf "%.1f", d < 0 ? 0 : d}')" \
        "${loads[*]}"
}

export PATH="$bin:$PATH"
echo "== $work/smoke.vdb: median of $runs, $(nproc) cores; tools $bin ($(date -r "$bin/vdbcache" '+%F %T'))"
printf "%-44s %8s %8s %8s   %s\n" "command" "wall s" "cpu s" "others s" "load (1 min) at each run"
row "vdbcache smoke.vdb -o c.vdb" "vdbcache smoke.vdb -o c.vdb"
row "vdbmarch c.vdb -o s.exr --preview s.png" "vdbmarch c.vdb -o s.exr --preview s.png"
row "default chain, piped" "vdbcache smoke.vdb | vdbmarch -o s.exr --preview s.png"
row "vdbphoton smoke.vdb -o p.vdb" "vdbphoton smoke.vdb -o p.vdb"
row "vdbcache p.vdb --gather-neighbours 64" "vdbcache p.vdb --gather-neighbours 64 -o cp.vdb"
row "vdbmarch cp.vdb -o sp.exr" "vdbmarch cp.vdb -o sp.exr --preview sp.png"
row "photon chain, piped" "vdbphoton smoke.vdb | vdbcache --gather-neighbours 64 | vdbmarch -o sp.exr --preview sp.png"

echo
echo "== -v, one run each (load $(load))"
for cmd in "vdbcache -v smoke.vdb -o c.vdb" "vdbmarch -v c.vdb -o s.exr --preview s.png" \
           "vdbphoton -v smoke.vdb -o p.vdb" "vdbcache -v p.vdb --gather-neighbours 64 -o cp.vdb" \
           "vdbmarch -v cp.vdb -o sp.exr --preview sp.png"; do
    echo "\$ $cmd"
    bash -c "$cmd" 2>&1 | sed 's/^/    /'
done
