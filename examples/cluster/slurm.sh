#!/usr/bin/env bash
# A pcimg conversion on Slurm: plan, a job array of shards, then the finalize
# job once every shard succeeded (--dependency=afterok). Run on the login node:
#   examples/cluster/slurm.sh OUT.pcimg INPUTS...   (paths every node sees)
# SHARDS (default 64) and MEM (per shard, default 8G) may be set.
set -euo pipefail
out=$1; shift
shards=${SHARDS:-64}; mem=${MEM:-8G}
plan="$out.plan.json"
# Reads LAS/LAZ/E57 headers (text, PCD, PLY: a sampling pass); converts nothing.
pcimg convert --plan "$plan" --shards "$shards" --memory "$mem" -o "$out" "$@"
# Array tasks are numbered 0..N-1: pcimg takes SLURM_ARRAY_TASK_ID as the 0-based shard.
array=$(sbatch --parsable --array="0-$((shards - 1))" --cpus-per-task=2 --mem="$mem" \
  --requeue --job-name=pcimg-shard \
  --wrap="pcimg convert -q --plan '$plan' --shard $shards")
# Checks every receipt against the plan, builds the overview, writes the index last.
sbatch --dependency="afterok:$array" --job-name=pcimg-index --wrap="pcimg index '$out'"
