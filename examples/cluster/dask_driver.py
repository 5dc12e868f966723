#!/usr/bin/env python3
"""Runs a pcimg cluster conversion on Dask distributed: every shard of a plan
as a task (retried when its process dies), then the finalize (`pcimg index`).

    pcimg convert --plan plan.json INPUTS... -o out.pcimg --shards 8
    python3 dask_driver.py plan.json                     # a LocalCluster
    python3 dask_driver.py plan.json --scheduler tcp://host:8786

Shards are idempotent (deterministic part names, atomic writes), so a retry, or
a task run twice, is harmless. Needs: pip install "dask[distributed]".
"""
import argparse, json, shlex, subprocess, sys

from dask.distributed import Client, LocalCluster


def run_shard(pcimg, plan, i, n):
    # A process that dies (killed, out of memory) raises here: Dask retries it.
    subprocess.run(pcimg + ["convert", "--plan", plan, "--shard", f"{i}/{n}", "-q"],
                   check=True)
    return i


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("plan")
    ap.add_argument("--pcimg", default="pcimg", help="the pcimg command")
    ap.add_argument("--scheduler", help="address of a running scheduler")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster workers")
    ap.add_argument("--retries", type=int, default=3)
    a = ap.parse_args()
    pcimg = shlex.split(a.pcimg)
    with open(a.plan) as f:
        plan = json.load(f)["plan"]
    n, out = len(plan["shards"]), plan["output"]
    if a.scheduler:
        client = Client(a.scheduler)
    else:
        # One thread per worker: a shard uses every core it is given.
        client = Client(LocalCluster(n_workers=a.workers, threads_per_worker=1,
                                     processes=True, dashboard_address=None))
    with client:
        futures = [client.submit(run_shard, pcimg, a.plan, i, n, key=f"shard-{i}",
                                 retries=a.retries, pure=False) for i in range(n)]
        done = client.gather(futures)
        print(f"{len(done)} shards done", flush=True)
        # Finalize: check the receipts, build the overview and the index.
        subprocess.run(pcimg + ["index", out], check=True)


if __name__ == "__main__":
    sys.exit(main())
