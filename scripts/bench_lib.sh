# Shell helpers the chain-against-reference benchmarks share (sourced by
# scripts/bench_unseen.sh and scripts/bench_random.sh; needs $bin, the tools' directory).

# "IMAGE: relative RMSE 0.0123, mean ratio 0.9990" -> "0.0123 0.9990"
score() { "$bin/nimbus-compare" "$1" "$2" | sed -E 's/.*relative RMSE ([0-9.e+-]+), mean ratio ([0-9.e+-]+).*/\1 \2/'; }

# The chain's error less the reference's own noise, in quadrature: ERROR and the error of a
# second reference of a quarter of the paths and another seed against the first (their
# difference is sqrt(5) times the first's noise) -> "LESS NOISE" as fractions, LESS "-" where
# the error is below the noise.
less_noise() {
    awk -v e="$1" -v q="$2" 'BEGIN { noise = q / sqrt(5); less = e * e - noise * noise;
        printf "%s %.6f\n", (less > 0 ? sprintf("%.6f", sqrt(less)) : "-"), noise }'
}
