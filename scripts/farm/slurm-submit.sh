#!/usr/bin/env bash
# Submits a frame sequence to Slurm as an array job of frame chunks (issue #20):
#
#   scripts/farm/slurm-submit.sh 'smoke.$F4.ply' -o 'frames/smoke.$F4.exr' --frames 1-240 \
#       --chunk 10 [--max-running N] [--partition P] [--log-dir DIR] [--wait] \
#       [--sbatch 'MORE SBATCH FLAGS'] [-- nimbus-render flags...]
#
# Task i of `sbatch --array=0-(chunks-1)%N` runs
#   nimbus-render INPUT -o OUTPUT --frames <chunk i> --skip-existing [nimbus-render flags]
# so a resubmission (or a requeued task) renders only the frames still missing; every frame
# is written atomically, so a cancelled task leaves no partial file. nimbus-render splits the
# frame set into chunks (--print-chunks): the frame syntax is nimbus-render's own.
# Prints the job id (with --wait, waits for the job and exits non-zero if a task failed).
# nimbus-render is $NIMBUS_RENDER, else the one on PATH, else target/release's.
set -euo pipefail
usage() { sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 2; }
input= output= frames= chunk=10 max_running= partition= log_dir= wait= sbatch_extra=
[ $# -ge 1 ] || usage
while [ $# -gt 0 ]; do
  case "$1" in
    -o|--output) output=$2; shift 2 ;;
    --frames) frames=$2; shift 2 ;;
    --frame) frames=$2; shift 2 ;;
    --chunk) chunk=$2; shift 2 ;;
    --max-running) max_running=$2; shift 2 ;;
    --partition) partition=$2; shift 2 ;;
    --log-dir) log_dir=$2; shift 2 ;;
    --sbatch) sbatch_extra=$2; shift 2 ;;
    --wait) wait=1; shift ;;
    -h|--help) usage ;;
    --) shift; break ;;
    -*) echo "error: unknown flag $1 (flags for nimbus-render go after --) (slurm-submit.sh)" >&2; exit 2 ;;
    *) [ -z "$input" ] || { echo "error: two inputs: '$input' and '$1' (slurm-submit.sh)" >&2; exit 2; }; input=$1; shift ;;
  esac
done
render_flags=("$@")
[ -n "$input" ] && [ -n "$output" ] && [ -n "$frames" ] || { echo "error: give INPUT, -o OUTPUT and --frames SET (slurm-submit.sh)" >&2; exit 2; }
here=$(cd "$(dirname "$0")/../.." && pwd)
nr=${NIMBUS_RENDER:-$(command -v nimbus-render || echo "$here/target/release/nimbus-render")}
[ -x "$nr" ] || { echo "error: nimbus-render not found (set NIMBUS_RENDER, or make build) ($nr)" >&2; exit 2; }
nr=$(realpath "$nr")
command -v sbatch >/dev/null || { echo "error: sbatch is not installed (apt install slurm-wlm) (slurm-submit.sh)" >&2; exit 2; }

# The chunks, by nimbus-render itself (it also checks the names and the frame set: exit 2).
listing=$("$nr" "$input" -o "$output" --frames "$frames" --print-chunks "$chunk") || exit $?
mapfile -t chunks <<< "$listing"

# Relative names are the submitting directory's: the tasks start there.
workdir=$(pwd)
log_dir=${log_dir:-$workdir}
mkdir -p "$log_dir" "$(dirname "$output")"
array="0-$((${#chunks[@]} - 1))"
[ -z "$max_running" ] || array="$array%$max_running"

script=$(mktemp "${TMPDIR:-/tmp}/nimbus-slurm.XXXXXX")
trap 'rm -f "$script"' EXIT
{
  echo '#!/usr/bin/env bash'
  echo "# nimbus-render over $frames in ${#chunks[@]} chunks of $chunk frames (scripts/farm/slurm-submit.sh)"
  echo 'set -euo pipefail'
  printf 'cd %q\n' "$workdir"
  printf 'chunks=('; printf ' %q' "${chunks[@]}"; echo ' )'
  printf 'exec %q %q -o %q --frames "${chunks[$SLURM_ARRAY_TASK_ID]}" --skip-existing' "$nr" "$input" "$output"
  [ ${#render_flags[@]} -eq 0 ] || printf ' %q' "${render_flags[@]}"
  echo
} > "$script"

sbatch_flags=(--parsable --job-name=nimbus-render --array="$array" --cpus-per-task=1
  --output="$log_dir/nimbus-render-%A_%a.log")
[ -z "$partition" ] || sbatch_flags+=(--partition="$partition")
[ -z "$wait" ] || sbatch_flags+=(--wait)
read -r -a extra <<< "$sbatch_extra"
sbatch "${sbatch_flags[@]}" "${extra[@]}" "$script"
