#!/usr/bin/env bash
# A dataset as a Slurm job array: each task renders its shard; Slurm sets
# SLURM_ARRAY_TASK_ID, SLURM_ARRAY_TASK_COUNT and SLURM_ARRAY_TASK_MIN and
# `optistim dataset` reads them (docs/DATASETS.md). Re-submitting resumes:
# items already written and verified are kept.
#
#   jid=$(sbatch --parsable tools/dataset_sbatch.sh SPEC OUT)
#   sbatch --dependency=afterok:$jid --wrap "optistim dataset SPEC --out OUT --merge"
#
# Arguments: SPEC OUT [OPTISTIM binary, default `optistim` on PATH].
#SBATCH --job-name=optistim-dataset
#SBATCH --array=0-3
#SBATCH --cpus-per-task=1
#SBATCH --output=optistim-dataset_%A_%a.out
set -euo pipefail
spec=$1
out=$2
bin=${3:-optistim}
exec "$bin" dataset "$spec" --out "$out" --jobs "${SLURM_CPUS_PER_TASK:-1}"
