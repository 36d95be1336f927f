"""Benchmark of ``virtualgps gap``: a 1 h run, 50 seeds, every candidate effect, at several
worker counts.

    python tools/bench_gap.py [--data ../shared/data] [--seeds 50] [--workers 1,2]
                              [--repeat 1] [--dask tcp://HOST:8786 | --dask-local]
                              [--model 16 [--model-on 2]]

The run is the MT3339 static hour (3231 epochs over 3600 s) against ``usarsim``, which lacks
every effect of DESIGN section 6, so every one is a candidate. For each worker count it times
the whole diagnosis (reading the log, the ensembles, the nested choice of effects, the figures
and the reports) and splits it: the time spent in batches of parallel jobs, and the serial rest
(the main process alone: reading, judging the rows, choosing between batches, figures). It
prints the batches' sizes (a batch smaller than several times the worker count leaves workers
idle while its slowest job runs) and the speed-up against the first worker count. With
``--dask-local`` each worker count also runs on a Dask cluster of that many single-threaded
worker processes on 127.0.0.1 (``distributed.LocalCluster``), beside the local workers.

``--model N`` answers "how would N workers do?" on a machine with fewer cores: the batches are
shaped for N workers (as ``--jobs N`` shapes them) but run on ``--model-on`` local workers, each
job timing itself; then every batch is replayed on N workers, each job going to the first free
worker in submission order (as a process pool or Dask hands them out), and the model's wall time
is the serial rest, plus each batch's makespan, plus the per-batch overhead measured in this
run. The speed-up printed is against one worker's own run (batches shaped for one, timed first
in the same call), and against the same jobs on one worker (the sum of their times).
It leaves out what more cores cost each job (memory bandwidth, a shared cache), so it bounds
the speed-up from above; measure on the cores themselves where you have them.
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
    ap.add_argument("--model", type=int, help="model this many workers (see above)")
    ap.add_argument("--model-on", type=int, default=2, help="local workers running the model")
    args = ap.parse_args()
    data = Path(args.data)
    inp = tool.GapInputs(
        real=(str(data / "mt3339-static" / "hour_test_1.txt"),), truth=("static",),
        scene="none", tle=str(data / "magdeburg-campus" / "tle" / "gps-ops.2017-03-26.tle.txt"),
        profile="usarsim")
    if args.model:
        base = once(inp, dg.Options(seeds=args.seeds, jobs=1))
        print(f"one worker: {base['wall_s']:.1f} s (serial {base['serial_s']:.1f} s)")
        model(inp, args.seeds, args.model, args.model_on, base["wall_s"])
        return
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


def makespan_s(job_s: list[float], workers: int) -> float:
    """The wall time of one batch on ``workers``: each job, in order, to the first free one."""
    free = [0.0] * workers
    for d in job_s:
        i = min(range(workers), key=free.__getitem__)
        free[i] += d
    return max(free, default=0.0)


def model(inp: tool.GapInputs, seeds: int, n: int, on: int, one_worker_s: float) -> None:
    """Shape the batches for ``n`` workers, run them on ``on``, and model ``n`` workers
    (``one_worker_s``: one worker's own run, the speed-up's reference)."""
    jobs.STATS["shape_for"] = n
    try:
        r = once(inp, dg.Options(seeds=seeds, jobs=on))
    finally:
        jobs.STATS["shape_for"] = 0
    per_job = jobs.STATS["job_s"]
    batch_s = jobs.STATS["batch_s"]
    # What a batch costs beyond its jobs on these workers: sending, forking, collecting.
    overhead = sum(max(0.0, b - makespan_s(j, on)) for b, j in zip(batch_s, per_job,
                                                                     strict=True))
    one = r["serial_s"] + sum(sum(j) for j in per_job) + overhead
    many = r["serial_s"] + sum(makespan_s(j, n) for j in per_job) + overhead
    small = sum(len(j) < 3 * n for j in per_job)
    print(f"model: batches shaped for {n} workers, run on {on}: {r['wall_s']:.1f} s "
          f"(serial {r['serial_s']:.1f} s, per-batch overhead {overhead:.1f} s in all); "
          f"{len(per_job)} batches, {small} under {3 * n} jobs; jobs {sum(map(len, per_job))}, "
          f"{sum(sum(j) for j in per_job):.1f} s of job time")
    print(f"  modelled: {n} workers {many:.1f} s: speed-up {one_worker_s / many:.2f}x one "
          f"worker's run, {one / many:.2f}x these jobs on one (an upper bound: more cores "
          "also slow each job)")
    print(f"  batch sizes: {[len(j) for j in per_job]}")
    print(f"  batch makespans on {n} (s): {[round(makespan_s(j, n), 2) for j in per_job]}")


if __name__ == "__main__":
    main()
