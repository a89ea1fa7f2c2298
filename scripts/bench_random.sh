#!/usr/bin/env bash
# The chain at its defaults on scenes drawn at random (issue #47; `nimbus-scene --random SEED`,
# crates/bench/src/random.rs): seeds not picked by hand, each through `vdbcache | vdbmarch`
# against the path-traced reference (`vdbmarch --reference`, REF_SPP paths a pixel, and a
# quarter of them with another seed to take the reference's own noise out in quadrature, as
# scripts/bench_unseen.sh does), and single scattering alone (`vdbcache --no-multiple |
# vdbmarch --spp 1`) against the brute-force single-scatter march (nimbus-single; the sky and
# emission left out of that scene, as the brute-force march has neither; SINGLE=0 skips it).
# A markdown row a seed, then the distribution (median, 90th percentile, worst) of the error
# and the time.
#
# Seeds: the regression seeds (REGRESSION, one a line, `SEED # why`) always, then SEEDS if
# given, else N (40) seeds from a counter starting at the date: YYYYMMDD * 1000 + i. Every
# seed that fails (error over 2% less the reference's noise, single scattering over 0.5%, or
# a tool over TIMEOUT seconds) is appended to REGRESSION with its description.
#
#   scripts/bench_random.sh [WORKDIR]    (default out/random; PIXELS 6144 (the image's most
#                                         pixels, 96 x 64's), REF_SPP 1024 (raised while the
#                                         reference's noise exceeds REF_NOISE 0.0067, up to
#                                         REF_SPP_MAX 16384), TIMEOUT 600 a tool, VOXEL_SCALE 1,
#                                         BIN a built tools' directory)
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-out/random}
mkdir -p "$work"
if [ -z "${BIN:-}" ]; then
    cargo build --release --locked -p nimbus --bins -p nimbus-bench >&2
fi
bin=${BIN:-${CARGO_TARGET_DIR:-target}/release}
# shellcheck source=scripts/bench_lib.sh
. scripts/bench_lib.sh
pixels=${PIXELS:-6144}
ref_spp=${REF_SPP:-1024}
ref_spp_max=${REF_SPP_MAX:-16384}
ref_noise=${REF_NOISE:-0.0067}
limit=${TIMEOUT:-600}
voxel_scale=${VOXEL_SCALE:-1}
regression=${REGRESSION:-crates/bench/regression-seeds.txt}
touch "$regression"

old=$(sed -E 's/#.*//' "$regression" | tr -s ' \t' '\n\n' | grep -E '^[0-9]+$' || true)
if [ -n "${SEEDS:-}" ]; then
    new=$SEEDS
else
    start=$(( $(date +%Y%m%d) * 1000 ))
    new=$(seq "$start" $((start + ${N:-40} - 1)))
fi
echo "regression seeds ($regression): $(echo $old)"
echo "new seeds: $(echo $new)"
echo "$pixels pixels at most, reference $ref_spp paths a pixel (and a quarter of them for its noise; more, up to $ref_spp_max, while its noise exceeds $ref_noise), $bin"
echo
echo "| seed | scene | chain CPU s | against the reference | less the reference's noise | reference's noise (paths a pixel) | mean ratio | single scattering (CPU s) |"
echo "|---|---|---|---|---|---|---|---|"

results=$work/results.txt
: > "$results"
# CPU seconds (user + sys) of a command under the time limit; its status 124 on a timeout.
timed() {
    local t=$work/time.txt status=0
    /usr/bin/time -o "$t" -f "%U %S" timeout "$limit" "$@" || status=$?
    cpu=$(awk 'END { print $1 + $2 }' "$t")
    return $status
}
for seed in $old $new; do
    dir=$work/$seed
    mkdir -p "$dir"
    flags=$("$bin/nimbus-scene" --random "$seed" "$dir/scene.vdb" --max-pixels "$pixels" --voxel-scale "$voxel_scale")
    medium=$(echo "$flags" | sed -n 1p)
    camera=$(echo "$flags" | sed -n 2p)
    description=$(echo "$flags" | sed -n 3p | sed -E 's/^seed [0-9]+: //')
    # Every flag is given once, to vdbcache, as a user pipes the chain: the medium, lights,
    # emission and camera reach vdbmarch in the cache's record (tests/flags.rs).
    why=()
    err=- less=- noise=- ratio=- single=- time=- used=
    # shellcheck disable=SC2086
    if timed "$bin/vdbcache" "$dir/scene.vdb" $medium $camera -q -o "$dir/chain.vdb"; then
        c1=$cpu
        # shellcheck disable=SC2086
        if timed "$bin/vdbmarch" "$dir/chain.vdb" -q -o "$dir/chain.exr"; then
            time=$(awk -v a="$c1" -v b="$cpu" 'BEGIN { printf "%.1f", a + b }')
        fi
    fi
    if [ "$time" = - ]; then
        why+=("the chain failed or took over ${limit} s")
    else
        # The reference at REF_SPP paths a pixel, then at more (a power of two, up to
        # REF_SPP_MAX) while its own noise exceeds REF_NOISE: at 1024 paths the references of
        # 19 of 46 seeds carried 1.2-5.2% of noise, and the error less it was then itself a
        # guess (seed 028: 2.11% against 1024 paths, 1.55% against 16384). A larger one that
        # fails or runs over the limit leaves the last.
        spp=$ref_spp reference= quarter=
        while :; do
            candidate=$dir/reference-$spp.exr
            # shellcheck disable=SC2086
            if [ -f "$candidate" ] || { timed "$bin/vdbmarch" "$dir/chain.vdb" --reference --spp "$spp" --seed 101 -q -o "$candidate.tmp.exr" &&
                timed "$bin/vdbmarch" "$dir/chain.vdb" --reference --spp $((spp / 4)) --seed 102 -q -o "${candidate%.exr}-quarter.exr" &&
                mv "$candidate.tmp.exr" "$candidate"; }; then
                reference=$candidate used=$spp
                read -r quarter _ < <(score "$reference" "${reference%.exr}-quarter.exr")
            else
                rm -f "$candidate.tmp.exr"
                break
            fi
            next=$(awk -v q="$quarter" -v n="$ref_noise" -v s="$spp" -v max="$ref_spp_max" 'BEGIN {
                noise = q / sqrt(5); if (!(noise > n) || s >= max) { print 0; exit }
                want = s * (noise / n) ^ 2; t = s * 2; while (t < want && t < max) t *= 2; print (t > max ? max : t) }')
            [ "$next" -gt 0 ] || break
            spp=$next
        done
        if [ -n "$reference" ]; then
            read -r err ratio < <(score "$reference" "$dir/chain.exr")
            read -r less noise < <(less_noise "$err" "$quarter")
            if [ "$less" != - ] && awk -v l="$less" 'BEGIN { exit !(l > 0.02) }'; then
                why+=("$(awk -v l="$less" 'BEGIN { printf "%.2f%%", 100 * l }') off the reference")
            fi
            # A NaN score: nothing the reference sees covered.
            case "$err" in *[nN][aA][nN]*) why+=("no covered pixels");; esac
        else
            why+=("the reference failed or took over ${limit} s")
        fi
    fi
    if [ "${SINGLE:-1}" != 0 ]; then
        # The scene without the sky and emission, which the brute-force march does not have.
        single_medium=$(echo "$medium" | sed -E 's/--sky [^ ]+//; s/--emission-[a-z]+ [^ ]+//g')
        # shellcheck disable=SC2086
        if timed "$bin/vdbcache" "$dir/scene.vdb" $single_medium $camera --no-multiple -q -o "$dir/single.vdb" && s1=$cpu &&
            timed "$bin/vdbmarch" "$dir/single.vdb" --spp 1 -q -o "$dir/single.exr" && s2=$cpu &&
            out=$(timeout "$limit" "$bin/nimbus-single" "$dir/single.vdb" -o "$dir/brute.exr" --compare "$dir/single.exr"); then
            single_err=$(echo "$out" | sed -E 's/.*relative RMSE ([0-9.e+-]+),.*/\1/')
            single=$(awk -v e="$single_err" -v a="$s1" -v b="$s2" 'BEGIN { printf "%.2f%% (%.1f)", 100 * e, a + b }')
            if awk -v e="$single_err" 'BEGIN { exit !(e > 0.005) }'; then
                why+=("single scattering $(awk -v e="$single_err" 'BEGIN { printf "%.2f%%", 100 * e }') off")
            fi
        else
            why+=("single scattering failed or took over ${limit} s")
        fi
    fi
    pct() { [ "$1" = - ] && echo - || awk -v x="$1" 'BEGIN { printf "%.2f%%", 100 * x }'; }
    echo "| $seed | $description | $time | $(pct "$err") | $([ "$less" = - ] && [ "$err" != - ] && echo "below the noise" || pct "$less") | $(pct "$noise")${used:+ ($used)} | $ratio | $single |"
    # Below the noise counts as 0; no score (the chain or reference failed) as none.
    if [ "$err" = - ]; then row_less=-; elif [ "$less" = - ]; then row_less=0; else row_less=$less; fi
    echo "$seed $row_less $time ${single_err:--} ${#why[@]}" >> "$results"
    unset single_err
    if [ ${#why[@]} -gt 0 ] && ! echo "$old" | grep -qx "$seed"; then
        reasons=$(printf '%s; ' "${why[@]}")
        echo "$seed  # ${reasons%; } ($(date +%Y-%m-%d)): $description" >> "$regression"
    fi
done

# The distribution over the seeds that ran: median, 90th percentile, worst.
echo
dist() { # column of results.txt, label, scale
    awk -v c="$1" '$c != "-" { print $c }' "$results" | sort -g | awk -v label="$2" -v scale="$3" -v unit="$4" '
        { v[NR] = $1 } END { if (NR == 0) { print "| " label " | - | - | - | 0 |"; exit }
        m = (NR % 2 ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2); p = v[int(0.9 * NR + 0.999999)]
        printf "| %s | %.2f%s | %.2f%s | %.2f%s | %d |\n", label, scale * m, unit, scale * p, unit, scale * v[NR], unit, NR }'
}
echo "| over the seeds | median | 90th percentile | worst | seeds |"
echo "|---|---|---|---|---|"
dist 2 "error less the reference's noise" 100 "%"
dist 3 "chain CPU s" 1 ""
[ "${SINGLE:-1}" != 0 ] && dist 4 "single-scattering error" 100 "%"
echo
echo "failing: $(awk '$5 > 0 { printf "%s ", $1 }' "$results")(of $(wc -l < "$results"))"
