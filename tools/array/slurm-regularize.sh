#!/usr/bin/env bash
# Regularize a map on S3 (or on a shared file system) as a Slurm job array, then commit:
#
#   sbatch tools/array/slurm-regularize.sh s3://my-city-bucket/maps/city
#
# submits N array tasks (each: `denser regularize MAP --shard auto/N`, the index from
# SLURM_ARRAY_TASK_ID minus SLURM_ARRAY_TASK_MIN) and a commit job that starts once all of them
# finished (afterok; a failed task is simply resubmitted: `sbatch --array=7 ...`). Set the AWS_*
# variables (AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY, AWS_REGION, and AWS_ENDPOINT_URL /
# AWS_ALLOW_HTTP for an S3-compatible store) in the environment you submit from: Slurm passes it.
#SBATCH --job-name=denser-shards
#SBATCH --array=0-15
#SBATCH --cpus-per-task=4
#SBATCH --mem=8G
#SBATCH --time=04:00:00
#SBATCH --requeue
set -euo pipefail
MAP="${1:?usage: sbatch slurm-regularize.sh MAP [denser regularize flags]}"
shift
FLAGS=("$@")
if [ ${#FLAGS[@]} -eq 0 ]; then
  FLAGS=(--lambda 0.8 --iterations 100 --memory-budget 6GiB)
fi
N=$(( SLURM_ARRAY_TASK_MAX - SLURM_ARRAY_TASK_MIN + 1 ))
if [ "${SLURM_ARRAY_TASK_ID}" = "${SLURM_ARRAY_TASK_MIN}" ] && [ -z "${DENSER_COMMIT_SUBMITTED:-}" ]; then
  # The first task submits the commit step, to run after every task of this array succeeded.
  DENSER_COMMIT_SUBMITTED=1 sbatch --job-name=denser-commit --dependency="afterok:${SLURM_ARRAY_JOB_ID}" \
    --cpus-per-task=4 --mem=8G --time=04:00:00 \
    --wrap="denser regularize '${MAP}' ${FLAGS[*]}"
fi
srun denser regularize "${MAP}" --shard "auto/${N}" "${FLAGS[@]}"
