#!/bin/bash
# Renders one image on a Slurm cluster: a job array of TASKS renders, each
# with its own --seed (the array index) and SPP samples per pixel, then one
# merge job that runs once they all succeed.
#
#   scripts/slurm_render.sh SCENE TASKS SPP OUT.exr [qtrace render options...]
#
# The parts go to OUT.parts/ (part-N.exr and task-N.log); the merged image
# to OUT.exr and its stats to OUT.json. Environment: QTRACE (the binary,
# default: qtrace on PATH), SBATCH (default: sbatch), SBATCH_OPTIONS (more
# sbatch options for every job, e.g. "--partition=gpu --gres=gpu:1").
set -euo pipefail
if [ $# -lt 4 ]; then
    echo "usage: $0 SCENE TASKS SPP OUT.exr [qtrace render options...]" >&2
    exit 2
fi
scene=$1 tasks=$2 spp=$3 out=$4
shift 4
case "$tasks" in '' | *[!0-9]* | 0) echo "$0: TASKS must be a positive integer" >&2; exit 2 ;; esac
case "$out" in *.exr) ;; *) echo "$0: OUT must end in .exr" >&2; exit 2 ;; esac
qtrace=${QTRACE:-qtrace}
sbatch=${SBATCH:-sbatch}
parts=${out%.exr}.parts
mkdir -p "$parts"
# Quote each argument once for the job's shell.
quoted=$(printf ' %q' "$@")
render="$(printf '%q' "$qtrace") render $(printf '%q' "$scene") --spp $spp --seed \$SLURM_ARRAY_TASK_ID -o $(printf '%q' "$parts")/part-\$SLURM_ARRAY_TASK_ID.exr$quoted"
# shellcheck disable=SC2086
array=$($sbatch --parsable ${SBATCH_OPTIONS:-} --job-name=qtrace-render --array=1-"$tasks" \
    --output="$parts/task-%a.log" --wrap="$render")
array=${array%%;*}
merge="$(printf '%q' "$qtrace") merge $(printf '%q' "$parts")/part-*.exr -o $(printf '%q' "$out") --stats $(printf '%q' "${out%.exr}.json")"
# shellcheck disable=SC2086
job=$($sbatch --parsable ${SBATCH_OPTIONS:-} --job-name=qtrace-merge --dependency=afterok:"$array" \
    --output="$parts/merge.log" --wrap="$merge")
echo "submitted render array $array ($tasks tasks) and merge job ${job%%;*}"
