#!/bin/sh
# Submit a terratile pipeline to Slurm as job arrays: plan here, then one array of JOBS
# tasks per phase (count, keep, prepare, finish), each array starting after the whole
# previous one succeeded (afterok), then the merge. `terratile shard` takes its index from
# SLURM_ARRAY_TASK_ID. DIR, the pipeline, its inputs and terratile must be on a file system
# every node sees. Not run in terratile's CI (no Slurm there): see docs/scale.md.
#
#   scale/slurm.sh PIPELINE.toml DIR [SHARDS] [extra sbatch options...]
set -eu
pipeline=$1
dir=$2
shards=${3:-16}
[ $# -ge 3 ] && shift 3 || shift $#
terratile=${TERRATILE:-terratile}

"$terratile" --quiet plan "$pipeline" --out "$dir" --shards "$shards"
jobs=$(sed -n 's/^  "jobs": \([0-9]*\),$/\1/p' "$dir/plan.json")
last=$((jobs - 1))
mkdir -p "$dir/logs"

dep=""
for phase in count keep prepare finish; do
  id=$(sbatch --parsable $dep "$@" --job-name="terratile-$phase" --array="0-$last" \
    --output="$dir/logs/$phase-%a.log" \
    --wrap="\"$terratile\" --quiet shard \"$dir\" --phase $phase")
  dep="--dependency=afterok:$id"
done
id=$(sbatch --parsable $dep "$@" --job-name=terratile-merge --output="$dir/logs/merge.log" \
  --wrap="\"$terratile\" --quiet merge \"$dir\"")
echo "submitted: $jobs jobs per phase, merge job $id (logs in $dir/logs)"
