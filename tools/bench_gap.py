"""Benchmark of ``virtualgps gap``: a 1 h run, 50 seeds, every candidate effect, at several
worker counts.

    python tools/bench_gap.py [--data ../shared/data] [--seeds 50] [--workers 1,2]
                              [--repeat 1] [--dask tcp://HOST:8786 | --dask-local]
                              [--model 16,2] [--profile-jobs DIR]

The run is the MT3339 static hour (3231 epochs over 3600 s) against ``usarsim``, which lacks
every effect of DESIGN section 6, so every one is a candidate. For each worker count it times
the whole diagnosis (reading the log, the ensembles, the nested choice of effects, the figures
and the reports) and splits it: the time the main process spent waiting for jobs, and the
serial rest (the main process alone: reading, judging the rows, choosing, figures). It prints
the jobs, their time in all, the submissions' sizes, and the speed-up against the first worker
count. With ``--dask-local`` each worker count also runs on a Dask cluster of that many
single-threaded worker processes on 127.0.0.1 (``distributed.LocalCluster``), beside the local
workers.

``--model N`` answers "how would N workers do?" on a machine with fewer cores
(:func:`virtualgps.gap.jobs.model`): the jobs are shaped for N workers, run in this process as
they are submitted, each timing itself, and a clock plays N workers (each job to the first free
one, in submission order, as a process pool or Dask hands them out) beside the main process's
own time. The diagnosis goes on exactly as with N real workers (each selection when its jobs
are back by that clock). Each job and each result is pickled and unpickled, on the main
process's clock or the job's as in a pool. It leaves out what more cores cost each job (memory
bandwidth, a shared cache) and the pool's pipes, so it bounds the speed-up from above. The
located gaps, judged in a thread beside the workers in a real run, are played as such a thread
(off the main process's clock, :class:`virtualgps.gap.jobs.ModelThread`); ``--workers 2
--model 2`` shows how close the model comes on this machine's cores.
Measure on the cores themselves where you have them.

``--profile-jobs DIR`` profiles the modelled runs' jobs alone (they run in this process there):
``DIR/jobs-N.prof`` per modelled worker count N, and the functions that took longest printed;
``--model 16,1`` so compares the jobs shaped for 16 workers with those shaped for one.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from virtualgps.gap import diagnose as dg
from virtualgps.gap import jobs, tool

ROOT = Path(__file__).resolve().parents[1]


def once(inp: tool.GapInputs, opts: dg.Options, model_workers: int | None = None) -> dict:
    """One diagnosis with its reports (on ``model_workers`` modelled workers where given); the
    timings."""
    jobs.shutdown()
    jobs.reset_stats()
    jobs.model(model_workers)
    try:
        t0 = time.perf_counter()
        report, figures, calibrated = tool.diagnose(inp, opts)
        with tempfile.TemporaryDirectory() as out:
            tool.write_outputs(report, figures, calibrated, report["profile"], out, opts.jobs,
                               opts.dask)
        wall = time.perf_counter() - t0
        serial = wall - jobs.STATS["wait_s"]
        if model_workers:
            wall, serial = jobs.model_times_s()
    finally:
        jobs.model(None)
    return {"wall_s": wall, "serial_s": serial, "submits": list(jobs.STATS["submits"]),
            "jobs": jobs.STATS["jobs"], "job_s": jobs.STATS["job_s"],
            "epochs": report["simulated_epochs"], "repeats": report["repeated_simulations"],
            "added": [e["name"] for e in report["effects"] if e.get("accepted")]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--workers", default="1,2",
                    help="worker counts, comma-separated ('': only the modelled ones)")
    ap.add_argument("--dask", help="a running Dask scheduler for every run")
    ap.add_argument("--dask-local", action="store_true",
                    help="also run each worker count on a local Dask cluster of that size")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--model", default="",
                    help="also model these worker counts, comma-separated (see above)")
    ap.add_argument("--profile-jobs", metavar="DIR",
                    help="profile the modelled runs' jobs into DIR/jobs-N.prof (see above)")
    args = ap.parse_args()
    data = Path(args.data)
    inp = tool.GapInputs(
        real=(str(data / "mt3339-static" / "hour_test_1.txt"),), truth=("static",),
        scene="none", tle=str(data / "magdeburg-campus" / "tle" / "gps-ops.2017-03-26.tle.txt"),
        profile="usarsim")
    first = None
    for n in (int(w) for w in args.workers.split(",") if w):
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
                    r = once(inp, dg.Options(seeds=args.seeds, jobs=n, dask=address))
                    first = first or r["wall_s"]
                    say(f"{kind} workers {n} run {k + 1}", r, n, first)
            finally:
                if cluster is not None:
                    jobs.shutdown()
                    cluster.close()
    for n in (int(w) for w in args.model.split(",") if w):
        prof = _profile_jobs() if args.profile_jobs else None
        try:
            r = once(inp, dg.Options(seeds=args.seeds, jobs=1), model_workers=n)
        finally:
            if prof is not None:
                _stop_profiling(prof, Path(args.profile_jobs) / f"jobs-{n}.prof")
        first = first or r["wall_s"]
        say(f"modelled workers {n}", r, n, first)
        print(f"  {(r['serial_s'] + r['job_s']) / r['wall_s']:.2f}x the same jobs one at a time "
              "(serial rest plus job time over the modelled wall)", flush=True)


def _profile_jobs():
    """A profiler switched on inside each job only (the modelled runs call the jobs here)."""
    import cProfile

    prof = cProfile.Profile()
    call = jobs._Timed.__call__

    def profiled(self, item):
        prof.enable()
        try:
            return call(self, item)
        finally:
            prof.disable()

    jobs._Timed.__call__ = profiled
    prof.restore = call
    return prof


def _stop_profiling(prof, path: Path) -> None:
    """Put the jobs back as they were; write the profile and print its top functions."""
    import pstats

    jobs._Timed.__call__ = prof.restore
    path.parent.mkdir(parents=True, exist_ok=True)
    prof.dump_stats(str(path))
    print(f"  jobs' profile: {path}", flush=True)
    pstats.Stats(prof).sort_stats("cumulative").print_stats(15)


def say(what: str, r: dict, n: int, first: float) -> None:
    """Print one run's timings (``first``: the first run's wall time, the speed-ups'
    reference)."""
    b = r["submits"]
    small = sum(x < 3 * n for x in b)
    print(f"{what}: {r['wall_s']:.1f} s (serial {r['serial_s']:.1f} s), speed-up "
          f"{first / r['wall_s']:.2f}x; {r['jobs']:,} jobs, {r['job_s']:.1f} s of job time; "
          f"{r['epochs']:,} simulated epochs ({r['epochs'] / r['wall_s']:,.0f}/s; "
          f"{r['repeats']} tables simulated again for a seed set and run); "
          f"{len(b)} submissions, median {sorted(b)[len(b) // 2] if b else 0} jobs, "
          f"{small} under {3 * n} jobs; added: {', '.join(r['added']) or 'nothing'}",
          flush=True)
    print(f"  submission sizes: {b}", flush=True)


if __name__ == "__main__":
    main()
