"""Benchmark of ``virtualgps gap``: a 1 h run, 50 seeds, every candidate effect, at several
worker counts.

    python tools/bench_gap.py [--data ../shared/data] [--seeds 50] [--workers 1,2]
                              [--repeat 1] [--dask tcp://HOST:8786 | --dask-local]

The run is the MT3339 static hour (3231 epochs over 3600 s) against ``usarsim``, which lacks
every effect of DESIGN section 6, so every one is a candidate. For each worker count it times
the whole diagnosis (reading the log, the ensembles, the nested choice of effects, the figures
and the reports) and splits it: the time spent in batches of parallel jobs, and the serial rest
(the main process alone: reading, judging the rows, choosing between batches, figures). It
prints the batches' sizes (a batch smaller than several times the worker count leaves workers
idle while its slowest job runs) and the speed-up against the first worker count. With
``--dask-local`` each worker count also runs on a Dask cluster of that many single-threaded
worker processes on 127.0.0.1 (``distributed.LocalCluster``), beside the local workers.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from virtualgps.gap import diagnose as dg
from virtualgps.gap import jobs, tool

ROOT = Path(__file__).resolve().parents[1]


def once(inp: tool.GapInputs, opts: dg.Options) -> dict:
    """One diagnosis with its reports; the timings."""
    jobs.shutdown()
    jobs.reset_stats()
    t0 = time.perf_counter()
    report, figures, calibrated = tool.diagnose(inp, opts)
    with tempfile.TemporaryDirectory() as out:
        tool.write_outputs(report, figures, calibrated, report["profile"], out, opts.jobs,
                           opts.dask)
    wall = time.perf_counter() - t0
    par = jobs.STATS["wall_s"]
    return {"wall_s": wall, "parallel_s": par, "serial_s": wall - par,
            "batches": list(jobs.STATS["batches"]), "epochs": report["simulated_epochs"],
            "added": [e["name"] for e in report["effects"] if e.get("accepted")]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--workers", default="1,2", help="worker counts, comma-separated")
    ap.add_argument("--dask", help="a running Dask scheduler for every run")
    ap.add_argument("--dask-local", action="store_true",
                    help="also run each worker count on a local Dask cluster of that size")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    data = Path(args.data)
    inp = tool.GapInputs(
        real=(str(data / "mt3339-static" / "hour_test_1.txt"),), truth=("static",),
        scene="none", tle=str(data / "magdeburg-campus" / "tle" / "gps-ops.2017-03-26.tle.txt"),
        profile="usarsim")
    first = None
    for n in (int(w) for w in args.workers.split(",")):
        kinds = [("local", args.dask)] + ([("dask", None)] if args.dask_local else [])
        for kind, address in kinds:
            cluster = None
            if kind == "dask":
                from distributed import LocalCluster

                cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                       host="127.0.0.1", dashboard_address=None)
                address = cluster.scheduler_address
            try:
                for k in range(args.repeat):
                    first = report(inp, args.seeds, n, address, kind, k, first)
            finally:
                if cluster is not None:
                    jobs.shutdown()
                    cluster.close()


def report(inp: tool.GapInputs, seeds: int, n: int, address: str | None, kind: str, k: int,
           first: float | None) -> float:
    """Run once and print the timings; returns the first run's wall time (the speed-ups'
    reference)."""
    r = once(inp, dg.Options(seeds=seeds, jobs=n, dask=address))
    first = first or r["wall_s"]
    b = r["batches"]
    small = sum(x < 3 * n for x in b)
    print(f"{kind} workers {n} run {k + 1}: {r['wall_s']:.1f} s (parallel batches "
          f"{r['parallel_s']:.1f} s, serial {r['serial_s']:.1f} s), speed-up "
          f"{first / r['wall_s']:.2f}x; {r['epochs']:,} simulated epochs "
          f"({r['epochs'] / r['wall_s']:,.0f}/s); {len(b)} batches, median "
          f"{sorted(b)[len(b) // 2]} jobs, {small} under {3 * n} jobs; added: "
          f"{', '.join(r['added']) or 'nothing'}")
    print(f"  batch sizes: {b}")
    return first


if __name__ == "__main__":
    main()
