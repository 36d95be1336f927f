"""How well this machine runs N copies of the same work at once: the ceiling for the gap tool's
workers (``tools/bench_gap.py``) and a fleet's (``tools/bench_fleet.py``).

    python tools/bench_cores.py [--data ../shared/data] [--copies 4,8,16]

Four kinds of work, each timed alone (the best of three) and then as N forked copies started
together (after one warm round): a pure-Python loop, numpy on cache-sized arrays (50,000
values), numpy on memory-sized ones (16 million), and the gap tool's own simulation (20 seeds
of the MT3339 static hour under ``holux-m1000``, four per :func:`simulate_job`, as a worker
runs them). One line per kind: each copy's time against the time alone (median and worst),
and the rate of N copies in units of one alone. Where the simulation's rate at N copies is
near N, what ``bench_gap.py --workers N`` loses against one worker is the tool's own (job
shapes, the main process), not the machine's.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # (one thread per copy, as the gap workers pin it)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RUN: tuple = ()  # (setup, profile) of the hour, set before the copies fork


def py_loop() -> float:
    t = time.perf_counter()
    s = 0
    for i in range(15_000_000):
        s += i * i
    return time.perf_counter() - t


def np_loop(size: int, reps: int) -> float:
    """numpy's elementwise work over ``size`` values, ``reps`` times."""
    x = np.random.default_rng(0).random(size)
    t = time.perf_counter()
    for _ in range(reps):
        np.sin(x) * x + 1.0
    return time.perf_counter() - t


def np_small() -> float:
    return np_loop(50_000, 2000)  # (400 kB: within a core's own cache)


def np_big() -> float:
    return np_loop(16_000_000, 8)  # (128 MB: from memory)


def gap_sim() -> float:
    from virtualgps.gap import ensemble as en

    setup, prof = RUN
    t = time.perf_counter()
    for k in range(5):
        en.simulate_job(en.EnsembleJob(setup, prof, tuple(range(4 * k, 4 * k + 4))))
    return time.perf_counter() - t


def prepare(data: Path) -> None:
    """Read and align the hour once, before the copies fork (as the gap tool shares it)."""
    global RUN
    from virtualgps.gap import tool
    from virtualgps.gap.runs import prepare_runs
    from virtualgps.receiver.profiles import build_profile

    inp = tool.GapInputs(real=(str(data / "mt3339-static" / "hour_test_1.txt"),),
                         truth=("static",), scene="none",
                         tle=str(data / "magdeburg-campus" / "tle" /
                                 "gps-ops.2017-03-26.tle.txt"),
                         profile="holux-m1000")
    runs_in, scene, scene_dir, tle, table, source = tool.load_inputs(inp)
    prof = build_profile(table, source)
    shift = tool.sky_shift(tool.ephemeris_of(tle, prof.constellations.letters()))
    runs = prepare_runs(runs_in, scene, scene_dir, tle, prof, shift, 1, None)
    RUN = (runs[0].setup, prof)


def call(name: str) -> float:
    return globals()[name]()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--copies", default="4,8,16", help="copy counts, comma-separated")
    args = ap.parse_args()
    prepare(Path(args.data))
    ctx = mp.get_context("fork")
    for name in ("py_loop", "np_small", "np_big", "gap_sim"):
        one = min(call(name) for _ in range(3))
        row = [f"{name}: alone {one:.3f} s"]
        for n in (int(x) for x in args.copies.split(",")):
            with ctx.Pool(n) as pool:
                pool.map(call, [name] * n)  # (warm)
                ts = pool.map(call, [name] * n)
            med = float(np.median(ts))
            row.append(f"{n} at once {med / one:.2f}x as long (worst {max(ts) / one:.2f}x): "
                       f"{n * one / med:.1f}x one's rate")
        print("; ".join(row), flush=True)


if __name__ == "__main__":
    main()
