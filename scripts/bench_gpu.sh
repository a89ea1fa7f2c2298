#!/usr/bin/env bash
# The release's chain on the GPU beside the CPU (issue #49), for a machine that has only the
# release (`make dist`), a GPU driver and a shell:
#
#   scripts/bench_gpu.sh [--small] DIST.tar.xz [WORKDIR]
#
# It unpacks the release into WORKDIR (default: a new temporary folder, kept for its images and
# logs) and runs, each with --device gpu and then --device cpu, every tool as a user runs it
# (whole command, files between them):
#
#   cloud1  the Cloud1-class chain of scripts/bench_cloud1.sh: 500k particles made by the
#           release's gen_particles, the 339 x 42 x 361 grid of unit voxels, 1024 x 576
#   cloud   the bundled cumulus deck as scripts/demo.sh renders it (960 x 540)
#   plume   the bundled smoke plume as scripts/demo.sh renders it (960 x 540)
#
# and prints the wall seconds of each tool on each device, and the relative RMSE and mean ratio
# of each GPU image against its CPU twin (nimbus-compare: 2x2 blocks over the covered pixels).
# --small shrinks every scene (50k particles for cloud1, coarser voxels, 160 x 90, --quality
# draft) to run on a software GPU (lavapipe) in a few minutes, and has particles2vdb use the
# paper's --method asl3 on both devices: llvmpipe's loop cap refuses the default ici's gathers
# on all three scenes (its ladder passes over the particles in reach several times; the plume's
# would take 218,016 loop iterations, with --h0 3 still 185,616). The whole run keeps to BUDGET_S
# seconds (default 450, within an 8-minute call) and no command runs longer than STAGE_S
# (default 150): one that does is stopped and shown as such. Where a GPU stage left nothing,
# the GPU's next stage reads the CPU's output (and the table says so). Exit status 1 when any
# stage failed or was stopped, after the tables.
set -uo pipefail

made=
die() { echo "bench_gpu.sh: error: $*" >&2; [ -z "$made" ] || rm -rf "$made"; exit 2; }
small=0
if [ "${1:-}" = --small ]; then small=1; shift; fi
[ $# -ge 1 ] && [ $# -le 2 ] || die "usage: scripts/bench_gpu.sh [--small] DIST.tar.xz [WORKDIR]"
dist=$1
[ -f "$dist" ] || die "no such release: $dist"
budget=${BUDGET_S:-450}
stage_cap=${STAGE_S:-150}
[[ $budget =~ ^[0-9]+$ && $stage_cap =~ ^[0-9]+$ ]] || die "BUDGET_S and STAGE_S must be whole seconds"
for tool in tar xz timeout date awk sort; do
    command -v "$tool" >/dev/null || die "$tool is missing"
done
start_s=$(date +%s)
deadline=$((start_s + budget))

if [ $# = 2 ]; then
    work=$2
    mkdir -p "$work" || die "cannot make $work"
else
    work=$(mktemp -d)
    made=$work
fi
[ -z "$(ls -A "$work")" ] || die "$work is not empty"
mkdir "$work/release"
tar -C "$work/release" -xJf "$dist" || die "$dist does not unpack"
rel=$(find "$work/release" -mindepth 1 -maxdepth 1 -type d | head -n 1)
bin=$rel/bin
for tool in gen_particles particles2vdb vdbcache vdbmarch nimbus-compare; do
    [ -x "$bin/$tool" ] || die "the release has no bin/$tool"
done
# shellcheck source=demo_scenes.sh
source "$rel/scripts/demo_scenes.sh" || die "the release has no scripts/demo_scenes.sh"
made=
export NIMBUS_NO_PROGRESS=1

# Per scene: its particles, particles2vdb's, vdbcache's and vdbmarch's flags.
if [ $small = 1 ]; then
    cloud1_count=50000; cloud1_density="--voxel-size 3 --method asl3"; size_1024="--width 160 --height 90"
    cloud_density="--voxel-size 4 --method asl3"; plume_density="--voxel-size 2 --method asl3"; size_960="--width 160 --height 90"
    quality="--quality draft"
else
    cloud1_count=500000; cloud1_density="--voxel-size 1"; size_1024="--width 1024 --height 576"
    cloud_density=$CLOUD_DENSITY; plume_density=$PLUME_DENSITY; size_960=""
    quality=""
fi
SCENES=(cloud1 cloud plume)
declare -A PARTICLES=([cloud1]="$work/cloud1.ply" [cloud]="$rel/data/cloud.ply" [plume]="$rel/data/plume.ply")
declare -A DENSITY=(
    [cloud1]="--bounds 0,0,0,339,42,361 $cloud1_density"
    [cloud]="$cloud_density"
    [plume]="$plume_density")
declare -A CACHE=(
    [cloud1]="--extinction 30 --albedo 0.95 --g 0.6 --sun dir=0.5,0.3,-0.8,irradiance=4 --eye 170,-300,160 --look-at 170,180,10 $size_1024"
    [cloud]="$CLOUD_LIGHT $CLOUD_CAMERA $size_960"
    [plume]="$PLUME_LIGHT $PLUME_CAMERA $size_960")
declare -A MARCH=([cloud1]="" [cloud]="--offset-noise 2" [plume]="")

results=$work/results.txt
: >"$results"
: >"$work/notes.txt"
# stage SCENE STAGE DEVICE COMMAND...: runs it within the budget, logs to WORK/SCENE-STAGE-DEVICE.log,
# appends "SCENE STAGE DEVICE SECONDS|-" and "STATUS" to the results; fails as the command did.
stage() {
    local scene=$1 name=$2 device=$3; shift 3
    local log=$work/$scene-$name-$device.log
    local left=$((deadline - $(date +%s) - 10))
    [ $left -le $stage_cap ] || left=$stage_cap
    if [ $left -le 0 ]; then
        echo "$scene $name $device - out-of-budget" >>"$results"
        return 1
    fi
    local t0 t1 rc
    t0=$(date +%s%N)
    timeout -k 5 "$left" "$@" >"$log" 2>&1
    rc=$?
    t1=$(date +%s%N)
    local seconds
    seconds=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.2f", (b - a) / 1e9 }')
    case $rc in
        0) echo "$scene $name $device $seconds ok" >>"$results" ;;
        124 | 137) echo "$scene $name $device - stopped-after-${left}s" >>"$results" ;;
        *) echo "$scene $name $device $seconds failed:-exit-$rc" >>"$results"; sed 's/^/    /' "$log" | tail -n 5 >&2 ;;
    esac
    [ $rc = 0 ]
}

echo "bench_gpu.sh: $(basename "$dist") in $rel; $(nproc) cores; $([ $small = 1 ] && echo small || echo full) sizes; budget ${budget} s" >&2
stage cloud1 gen_particles cpu "$bin/gen_particles" cloud1 "$work/cloud1.ply" "$cloud1_count" 1 || true

# Stage by stage, the GPU's then the CPU's; where the GPU's previous stage left nothing (it
# failed: llvmpipe's loop cap refuses particles2vdb's gathers on these scenes, say), the GPU's
# next stage reads the CPU's output, so the later stages are still measured.
input_for() {
    local gpu_file=$1 cpu_file=$2
    if [ "$3" = gpu ] && [ ! -s "$gpu_file" ] && [ -s "$cpu_file" ]; then
        echo "$cpu_file"
    elif [ "$3" = gpu ]; then echo "$gpu_file"; else echo "$cpu_file"; fi
}
for scene in "${SCENES[@]}"; do
    echo "== $scene" >&2
    for device in gpu cpu; do
        # shellcheck disable=SC2086
        stage "$scene" particles2vdb "$device" "$bin/particles2vdb" "${PARTICLES[$scene]}" -v ${DENSITY[$scene]} --device "$device" -o "$work/$scene-density-$device.vdb"
    done
    for device in gpu cpu; do
        input=$(input_for "$work/$scene-density-gpu.vdb" "$work/$scene-density-cpu.vdb" "$device")
        [ -s "$input" ] || { echo "$scene vdbcache $device - no-density" >>"$results"; continue; }
        [ "$device" = cpu ] || [ "$input" = "$work/$scene-density-gpu.vdb" ] || echo "$scene vdbcache $device on-the-CPU's-density" >>"$work/notes.txt"
        # shellcheck disable=SC2086
        stage "$scene" vdbcache "$device" "$bin/vdbcache" "$input" -v ${CACHE[$scene]} $quality --device "$device" -o "$work/$scene-cache-$device.vdb"
    done
    for device in gpu cpu; do
        input=$(input_for "$work/$scene-cache-gpu.vdb" "$work/$scene-cache-cpu.vdb" "$device")
        [ -s "$input" ] || { echo "$scene vdbmarch $device - no-cache" >>"$results"; continue; }
        [ "$device" = cpu ] || [ "$input" = "$work/$scene-cache-gpu.vdb" ] || echo "$scene vdbmarch $device on-the-CPU's-cache" >>"$work/notes.txt"
        # shellcheck disable=SC2086
        stage "$scene" vdbmarch "$device" "$bin/vdbmarch" "$input" -v ${MARCH[$scene]} $quality --device "$device" -o "$work/$scene-$device.exr"
    done
done

adapter=$(grep -h -m 1 -o 'device: gpu: .*' "$work"/*-gpu.log 2>/dev/null | head -n 1 | sed 's/^device: gpu: //')
cpu_model=$(awk -F': ' '/^model name/ {print $2; exit}' /proc/cpuinfo 2>/dev/null)
seconds_of() {
    awk -v s="$1" -v n="$2" -v d="$3" '$1 == s && $2 == n && $3 == d { gsub("-", " ", $5); print ($4 == "-" ? $5 : ($5 == "ok" ? $4 : $4 " (" $5 ")")) }' "$results"
}
note_of() { awk -v s="$1" -v n="$2" -v d="$3" '$1 == s && $2 == n && $3 == d { gsub("-", " ", $4); print " (" $4 ")" }' "$work/notes.txt"; }
echo
echo "== nimbus GPU benchmark: $(basename "$dist"), $([ $small = 1 ] && echo "--small sizes (particles2vdb --method asl3)" || echo "full sizes")"
echo "GPU: ${adapter:-no GPU adapter answered (see $work/*-gpu.log)}"
echo "CPU: $(nproc) cores, ${cpu_model:-unknown}, load $(cut -d' ' -f1 /proc/loadavg 2>/dev/null)"
echo
echo "| scene | stage | GPU wall s | CPU wall s | CPU / GPU |"
echo "|---|---|---|---|---|"
echo "| cloud1 | gen_particles ($cloud1_count particles, CPU only) | | $(seconds_of cloud1 gen_particles cpu) | |"
for scene in "${SCENES[@]}"; do
    gpu_sum=0; cpu_sum=0; whole=1
    for name in particles2vdb vdbcache vdbmarch; do
        g=$(seconds_of "$scene" "$name" gpu); c=$(seconds_of "$scene" "$name" cpu)
        ratio=""
        if [[ $g =~ ^[0-9.]+$ && $c =~ ^[0-9.]+$ ]]; then
            ratio=$(awk -v g="$g" -v c="$c" 'BEGIN { printf "%.2fx", c / g }')
        fi
        [[ $g =~ ^[0-9.]+$ && $c =~ ^[0-9.]+$ ]] || whole=0
        [[ $g =~ ^[0-9.]+$ ]] && gpu_sum=$(awk -v a="$gpu_sum" -v b="$g" 'BEGIN { print a + b }')
        [[ $c =~ ^[0-9.]+$ ]] && cpu_sum=$(awk -v a="$cpu_sum" -v b="$c" 'BEGIN { print a + b }')
        echo "| $scene | $name | ${g:-skipped}$(note_of "$scene" "$name" gpu) | ${c:-skipped} | $ratio |"
    done
    if [ $whole = 1 ]; then
        echo "| $scene | **chain** | **$(printf '%.2f' "$gpu_sum")** | **$(printf '%.2f' "$cpu_sum")** | $(awk -v g="$gpu_sum" -v c="$cpu_sum" 'BEGIN { printf "%.2fx", c / g }') |"
    fi
done
while read -r scene name device what; do
    echo "$scene: the GPU's $name ran ${what//-/ } (the GPU's stage before it left nothing)"
done <"$work/notes.txt"
echo
echo "| scene | GPU image against the CPU's: relative RMSE | mean ratio |"
echo "|---|---|---|"
for scene in "${SCENES[@]}"; do
    if [ -s "$work/$scene-gpu.exr" ] && [ -s "$work/$scene-cpu.exr" ]; then
        line=$("$bin/nimbus-compare" "$work/$scene-cpu.exr" "$work/$scene-gpu.exr" 2>&1)
        rmse=$(sed -nE 's/.*relative RMSE ([0-9.e+-]+), mean ratio ([0-9.e+-]+).*/\1/p' <<<"$line")
        ratio=$(sed -nE 's/.*relative RMSE ([0-9.e+-]+), mean ratio ([0-9.e+-]+).*/\2/p' <<<"$line")
        if [ -n "$rmse" ]; then
            # nimbus-compare prints 4 decimals: 0.0000 is under 0.005%.
            echo "| $scene | $(awk -v e="$rmse" 'BEGIN { if (e == 0) print "< 0.005%"; else printf "%.2f%%", 100 * e }') | $ratio |"
        else
            echo "| $scene | nimbus-compare failed: $line | |"
        fi
    else
        missing=$( { [ -s "$work/$scene-gpu.exr" ] || echo GPU; [ -s "$work/$scene-cpu.exr" ] || echo CPU; } | paste -sd/)
        echo "| $scene | no image from the $missing | |"
    fi
done
echo
echo "$(( $(date +%s) - start_s )) s in all; images, logs and results.txt in $work"
# A stage that failed or was stopped makes the run fail, after the table.
! grep -qv ' ok$' "$results"
