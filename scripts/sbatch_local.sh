#!/bin/bash
# A stand-in for Slurm's sbatch that runs jobs at once on this machine, one
# array task after another: the options scripts/slurm_render.sh uses
# (--parsable, --job-name, --array=1-N, --output with %a, --dependency=
# afterok:ID, --wrap) and no others. Tests use it, and so can anyone without
# a cluster:  SBATCH=scripts/sbatch_local.sh scripts/slurm_render.sh ...
set -uo pipefail
state=${SBATCH_LOCAL_STATE:-${TMPDIR:-/tmp}/sbatch-local.$(id -u)}
mkdir -p "$state"
array="" output="slurm-%j.out" dependency="" wrap=""
for arg in "$@"; do
    case "$arg" in
        --parsable | --job-name=*) ;;
        --array=*) array=${arg#--array=} ;;
        --output=*) output=${arg#--output=} ;;
        --dependency=afterok:*) dependency=${arg#--dependency=afterok:} ;;
        --wrap=*) wrap=${arg#--wrap=} ;;
        --partition=* | --gres=* | --time=* | --cpus-per-task=* | --mem=*) ;;
        *) echo "sbatch_local.sh: unsupported option $arg" >&2; exit 2 ;;
    esac
done
[ -n "$wrap" ] || { echo "sbatch_local.sh: no --wrap command" >&2; exit 2; }
id=$(($(cat "$state/last" 2>/dev/null || echo 1000) + 1))
echo "$id" > "$state/last"
status=0
if [ -n "$dependency" ] && [ "$(cat "$state/$dependency" 2>/dev/null)" != 0 ]; then
    echo "sbatch_local.sh: job $id not run: job $dependency did not succeed" >&2
    status=1
elif [ -n "$array" ]; then
    first=${array%-*} last=${array#*-}
    for ((task = first; task <= last; task++)); do
        log=${output//%a/$task}
        SLURM_ARRAY_TASK_ID=$task SLURM_JOB_ID=$id bash -c "$wrap" > "${log//%j/$id}" 2>&1 || status=1
    done
else
    SLURM_JOB_ID=$id bash -c "$wrap" > "${output//%j/$id}" 2>&1 || status=1
fi
echo "$status" > "$state/$id"
echo "$id"
