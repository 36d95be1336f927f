"""The held-out design of a diagnosis: which spans of data are units, how they are grouped into
folds, and what is left for the outer test (DESIGN 7.2).

Units. With three runs or more each run is a unit (leave one run out). Otherwise each run is cut
into time blocks separated by guard gaps at least as long as the real log's position error
correlation time, so that a held-out block shares no correlated error with the blocks a fit saw
(the simulations need no guard: held-out units are simulated with seeds of their own); the
guards' epochs are simulated (the receiver runs through them) but belong to no unit. Each block
lasts at least as long as a guard, and at least :data:`MIN_BLOCK_S`.

Nesting. The units are split into at most :data:`MAX_OUTER` outer groups. For each outer group,
the choice of effects and their parameters is made on the other units alone (their own folds:
at most :data:`MAX_INNER` groups), and the profile so chosen is measured on the outer group, which
neither step saw; the reported reduction is the mean over outer groups. The full choice, the one
the calibrated profile is made of, uses every unit. A design needs three units at least (one
outer, two inner); with fewer there is no honest held-out figure, and the diagnosis says so and
claims no effect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

MIN_BLOCK_S = 120.0  # the shortest time block (a few minutes of a receiver's slow behaviour)
MIN_GUARD_S = 30.0  # tracking state (fades, reacquisition) outlives the error's 1/e time
MIN_UNITS = 3
MAX_OUTER = 5
MAX_INNER = 4


@dataclass(frozen=True)
class Unit:
    """A span of data scored as one: run index, its epochs (n,) bool, a description."""

    run: int
    mask: np.ndarray = field(repr=False)
    label: str


@dataclass(frozen=True)
class Design:
    """The units of a diagnosis and how they are held out.

    units : the held-out units (runs, or time blocks)
    whole : one unit per run holding every epoch (what a single run's calibrated profile is
        fitted on: a whole hour pins a slow error's time constant better than its blocks)
    fit_on_whole : the calibrated profile is fitted on ``whole`` (a single run), else on units
    guard_s : the guard between blocks (0 with whole runs as units)
    scheme : "leave one run out" or "leave one time block out (guard N s)"
    outer : groups of unit indices held out in turn by the outer test (empty: no outer test)
    warnings : what the design could not do, for people
    """

    units: list[Unit]
    whole: list[Unit]
    fit_on_whole: bool
    guard_s: float
    scheme: str
    outer: list[list[int]]
    warnings: list[str]

    @property
    def claims(self) -> bool:
        """Enough units for a held-out test of effects."""
        return len(self.units) >= MIN_UNITS

    def all_units(self) -> list[Unit]:
        """Units then whole runs: the order of a run's per-unit results."""
        return self.units + self.whole


def groups(indices: list[int], k: int) -> list[list[int]]:
    """``indices`` in at most ``k`` contiguous groups of near-equal size (order kept)."""
    k = max(1, min(k, len(indices)))
    return [list(map(int, g)) for g in np.array_split(np.asarray(indices, dtype=int), k)
            if len(g)]


def blocks(t_unix_s: np.ndarray, valid: np.ndarray, guard_s: float, max_blocks: int
           ) -> list[np.ndarray]:
    """Time blocks of one run separated by guard gaps.

    Parameters
    ----------
    t_unix_s : (n,) epoch times; valid : (n,) bool, epochs with truth
    guard_s : seconds between blocks; max_blocks : at most this many

    Returns
    -------
    masks : (n,) bool each, in time order; fewer than two when the run is too short
    """
    tv = t_unix_s[valid]
    if tv.size < 2:
        return []
    span = float(tv[-1] - tv[0])
    min_len = max(MIN_BLOCK_S, guard_s)
    n = int(min(max_blocks, math.floor((span + guard_s) / (min_len + guard_s))))
    if n < 1:
        return []
    length = (span - (n - 1) * guard_s) / n
    out = []
    for b in range(n):
        lo = tv[0] + b * (length + guard_s)
        hi = lo + length
        out.append(valid & (t_unix_s >= lo) & ((t_unix_s < hi) if b < n - 1 else
                                                (t_unix_s <= hi)))
    return [m for m in out if m.any()]


def make_design(names: list[str], t_unix_s: list[np.ndarray], valid: list[np.ndarray],
                corr_time_s: list[float], max_blocks: int) -> Design:
    """The held-out design of some runs (see the module docstring).

    Parameters
    ----------
    names : run names; t_unix_s, valid : per run (n_i,) epoch times and truth flags
    corr_time_s : per run, the position error's correlation time (NaN: longer than half the
        run), seconds
    max_blocks : blocks per run at most (``--blocks``)
    """
    warnings: list[str] = []
    whole = [Unit(i, v.copy(), f"run {n}") for i, (n, v) in enumerate(zip(names, valid,
                                                                         strict=True))]
    if len(names) >= MIN_UNITS:
        units = list(whole)
        scheme, guard = "leave one run out", 0.0
        fit_on_whole = False
    else:
        units, guard = [], 0.0
        for i, (n, t, v, tau) in enumerate(zip(names, t_unix_s, valid, corr_time_s,
                                              strict=True)):
            tv = t[v]
            span = float(tv[-1] - tv[0]) if tv.size > 1 else 0.0
            g = tau if math.isfinite(tau) else span / 4.0
            if not math.isfinite(tau):
                warnings.append(f"run {n}: its error stays correlated over half the run or "
                                "longer; blocks are guarded by a quarter of the run and are "
                                "not independent")
            g = max(MIN_GUARD_S, g)
            guard = max(guard, g)
            bl = blocks(t, v, g, max_blocks)
            for b, m in enumerate(bl):
                t0, t1 = t[m][0] - tv[0], t[m][-1] - tv[0]
                units.append(Unit(i, m, f"run {n} block {b + 1}/{len(bl)} "
                                        f"({t0:.0f}-{t1:.0f} s)" if len(names) > 1 else
                                  f"time block {b + 1}/{len(bl)} ({t0:.0f}-{t1:.0f} s)"))
        scheme = f"leave one time block out (blocks guarded by {guard:.0f} s)"
        fit_on_whole = len(names) == 1
    if len(units) < MIN_UNITS:
        span = max((float(t[v][-1] - t[v][0]) if v.sum() > 1 else 0.0)
                   for t, v in zip(t_unix_s, valid, strict=True))
        warnings.append(
            f"too little data for a held-out test: {len(units)} unit(s), {MIN_UNITS} needed "
            f"(runs of {span:.0f} s hold blocks of at least {max(MIN_BLOCK_S, guard):.0f} s "
            f"separated by the error's correlation time, {guard:.0f} s); no effect is claimed, "
            "the located gaps stand alone")
        return Design(units, whole, fit_on_whole, guard, scheme, [], warnings)
    outer = groups(list(range(len(units))), MAX_OUTER)
    return Design(units, whole, fit_on_whole, guard, scheme, outer, warnings)


def folds(units: list[int], k: int = MAX_INNER) -> list[list[int]]:
    """Cross-validation folds (held-out groups) over some units."""
    return groups(units, k)
