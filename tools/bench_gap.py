"""Benchmark of ``virtualgps gap`` (issue #8): a 1 h run, 50 seeds, every candidate effect.

    python tools/bench_gap.py [--data ../shared/data] [--seeds 50] [--jobs N] [--repeat 1]
                              [--dask tcp://HOST:8786]

The run is the MT3339 static hour (3231 epochs over 3600 s) against ``usarsim``, which lacks
every effect of DESIGN section 6, so every one is a candidate. Times the whole diagnosis
(reading the log, the ensembles, the fits, the figures and writing the reports) and prints it
with the simulated epochs per second. Target: at most 120 s on this project's 2-core machine.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from virtualgps.gap import diagnose as dg
from virtualgps.gap import tool

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--jobs", type=int)
    ap.add_argument("--dask")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    data = Path(args.data)
    inp = tool.GapInputs(
        real=(str(data / "mt3339-static" / "hour_test_1.txt"),), truth=("static",),
        scene="none", tle=str(data / "magdeburg-campus" / "tle" / "gps-ops.2017-03-26.tle.txt"),
        profile="usarsim")
    opts = dg.Options(seeds=args.seeds, jobs=args.jobs, dask=args.dask)
    for k in range(args.repeat):
        t0 = time.perf_counter()
        report, figures, calibrated = tool.diagnose(inp, opts)
        t1 = time.perf_counter()
        with tempfile.TemporaryDirectory() as out:
            tool.write_outputs(report, figures, calibrated, report["profile"], out)
        t2 = time.perf_counter()
        n = report["simulated_epochs"]
        print(f"run {k + 1}: {t2 - t0:.1f} s in all (diagnosis {t1 - t0:.1f} s, report "
              f"{t2 - t1:.1f} s); {n:,} simulated epochs ({n / (t1 - t0):,.0f} epochs/s); "
              f"{len(report['effects'])} candidates, added: "
              f"{', '.join(e['name'] for e in report['effects'] if e.get('accepted'))}")


if __name__ == "__main__":
    main()
