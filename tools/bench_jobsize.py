"""What smaller ensemble jobs cost: the gap tool's jobs for a few tables, their fitting seeds in
one job each, then cut into one job per seed, timed directly in this process (no profiler: it
charges every call, and smaller jobs make more of them).

    python tools/bench_jobsize.py [--data ../shared/data] [--case hour|gsdc] [--repeat 5]

``hour``: the MT3339 static hour against ``usarsim`` (the gap benchmark's case); ``gsdc``: the
GSDC drive against ``phone`` (a moving run: lag and smoothing are measured). Each table is
simulated for 8 seeds and every unit of the run's design scored (per-PRN and per-sky-bin counts
included), as :func:`virtualgps.gap.simulator.gap_job` does in a worker; the rounds alternate
between the two cuts and the medians are printed. To pair with other code, run the same file
from a checkout of it: ``git worktree add /tmp/old REV`` and ``PYTHONPATH=/tmp/old python
/tmp/old/tools/bench_jobsize.py`` (from a folder other than this checkout's root).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from threadpoolctl import threadpool_limits

from virtualgps.gap import effects as fx
from virtualgps.gap import simulator as sm
from virtualgps.gap import tool
from virtualgps.gap.design import make_design
from virtualgps.gap.ensemble import split_seeds
from virtualgps.gap.runs import prepare_runs

ROOT = Path(__file__).resolve().parents[1]
SEEDS = tuple(range(8))


def _inputs(data: Path, case: str) -> tuple[tool.GapInputs, list[dict]]:
    """The run and the candidate overrides whose tables are timed."""
    if case == "hour":
        inp = tool.GapInputs(
            real=(str(data / "mt3339-static" / "hour_test_1.txt"),), truth=("static",),
            scene="none", tle=str(data / "magdeburg-campus" / "tle" / "gps-ops.2017-03-26.tle.txt"),
            profile="usarsim")
        return inp, [{}, {"correlated_error": {"enabled": True, "domain": "position"}},
                     {"nav_filter": {"enabled": True, "tau_s": 2.0}}]
    gsdc = data / "gsdc-2020-05-14-mtv"
    inp = tool.GapInputs(real=(str(gsdc / "Pixel4_chipset.nmea"),),
                         truth=(str(gsdc / "SPAN_Pixel4_1Hz.nmea"),), scene="none", tle=None,
                         profile="phone")
    return inp, [{}, {"latency": {"enabled": True, "latency_s": 1.0}}]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--case", choices=("hour", "gsdc"), default="hour")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    threadpool_limits(1)  # (as a worker)
    inp, overrides = _inputs(Path(args.data), args.case)
    runs_in, scene, scene_dir, tle, table, source = tool.load_inputs(inp)
    profile = tool.build_profile(table, source)
    ephem = tool.ephemeris_of(tle, profile.constellations.letters())
    runs = prepare_runs(runs_in, scene, scene_dir, tle, profile, tool.sky_shift(ephem), 1, None,
                        profile.constellations.letters())
    key = sm.share_runs(runs)[0]
    view = runs[0].view
    design = make_design([view.name], [view.t_unix_s], [view.valid], [300.0], 4)
    masks = tuple(u.mask for u in design.all_units())
    gsv = bool(view.assess.get("gsv"))
    tables = [fx.apply(table, o) for o in overrides]

    def once(groups: int) -> float:
        t0 = time.perf_counter()
        for t in tables:
            for seeds in split_seeds(SEEDS, groups):
                sm.gap_job(sm.GapJob(key, t, source, seeds, masks, prn=gsv, bins=gsv,
                                     whole=groups == 1))
        return time.perf_counter() - t0

    once(1)
    once(len(SEEDS))  # (caches warm: the workers' skies, the real log's memo)
    took: dict[int, list[float]] = {1: [], len(SEEDS): []}
    for _ in range(args.repeat):
        for groups in took:
            took[groups].append(once(groups))
    whole, cut = (statistics.median(took[g]) for g in took)
    print(f"{args.case}: {len(tables)} tables x {len(SEEDS)} seeds x {len(masks)} units: one "
          f"job per table {whole * 1e3:.0f} ms, one job per seed {cut * 1e3:.0f} ms "
          f"({cut / whole:.2f}x; medians of {args.repeat})")


if __name__ == "__main__":
    main()
