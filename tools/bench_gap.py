"""Benchmark of ``virtualgps gap``: a 1 h run, 50 seeds, every candidate effect, at several
worker counts.

    python tools/bench_gap.py [--data ../shared/data] [--seeds 50] [--workers 1,2]
                              [--repeat 1] [--dask tcp://HOST:8786]

The run is the MT3339 static hour (3231 epochs over 3600 s) against ``usarsim``, which lacks
every effect of DESIGN section 6, so every one is a candidate. For each worker count it times
the whole diagnosis (reading the log, the ensembles, the nested choice of effects, the figures
and the reports) and splits it: the time spent in batches of parallel jobs, and the serial rest
(the main process alone: reading, judging the rows, choosing between batches, figures). It
prints the batches' sizes (a batch smaller than several times the worker count leaves workers
idle while its slowest job runs) and the speed-up against the first worker count.
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
        tool.write_outputs(report, figures, calibrated, report["profile"], out)
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
    ap.add_argument("--dask")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    data = Path(args.data)
    inp = tool.GapInputs(
        real=(str(data / "mt3339-static" / "hour_test_1.txt"),), truth=("static",),
        scene="none", tle=str(data / "magdeburg-campus" / "tle" / "gps-ops.2017-03-26.tle.txt"),
        profile="usarsim")
    first = None
    for n in (int(w) for w in args.workers.split(",")):
        for k in range(args.repeat):
            r = once(inp, dg.Options(seeds=args.seeds, jobs=n, dask=args.dask))
            first = first or r["wall_s"]
            b = r["batches"]
            small = sum(x < 3 * n for x in b)
            print(f"workers {n} run {k + 1}: {r['wall_s']:.1f} s (parallel batches "
                  f"{r['parallel_s']:.1f} s, serial {r['serial_s']:.1f} s), speed-up "
                  f"{first / r['wall_s']:.2f}x; {r['epochs']:,} simulated epochs "
                  f"({r['epochs'] / r['wall_s']:,.0f}/s); {len(b)} batches, median "
                  f"{sorted(b)[len(b) // 2]} jobs, {small} under {3 * n} jobs; added: "
                  f"{', '.join(r['added']) or 'nothing'}")
            print(f"  batch sizes: {b}")


if __name__ == "__main__":
    main()
