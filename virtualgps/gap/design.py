"""The held-out design of a diagnosis: which spans of data are units, how they are grouped into
folds, and what is left for the outer test (DESIGN 7.2).

Units. With three runs or more each run is a unit (leave one run out). Otherwise each run is cut
into time blocks separated by guard gaps at least as long as the real log's position error
correlation time, so that a held-out block shares no correlated error with the blocks a fit saw
(the simulations need no guard: held-out units are simulated with seeds of their own); the
guards' epochs are simulated (the receiver runs through them) but belong to no unit. Each block
lasts at least as long as a guard, and at least :data:`MIN_BLOCK_S`.

Simultaneous runs. Receivers logged at the same time (two phones in one car) share their
errors' slow part and their surroundings: a unit of one is not held out from a fit that saw the
other at the same time. Runs whose spans overlap are cut into time blocks on one clock, and the
blocks of one time (one *key*) are always held out together; leave-one-run-out is used only
where no runs overlap.

Nesting. The units are split into at most :data:`MAX_OUTER` outer groups (whole keys). For
each outer group, the choice of effects and their parameters is made on the other units alone
(their own folds: at most :data:`MAX_INNER` groups), and the profile so chosen is measured on
the outer group, which neither step saw; the reported reduction is the mean over outer groups.
The full choice, the one the calibrated profile is made of, uses every unit. A design needs
three independent units (keys) at least (one outer, two inner); with fewer there is no honest
held-out figure, and the diagnosis says so and claims no effect.
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
    keys : per unit, its key: units of one key are held out together (the same time block of
        simultaneous runs); distinct keys are the independent units
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
    keys: list[int] = field(default_factory=list)

    @property
    def claims(self) -> bool:
        """Enough independent units for a held-out test of effects."""
        return len(set(self.unit_keys())) >= MIN_UNITS

    def unit_keys(self) -> list[int]:
        """Each unit's key (its own index where none was given)."""
        return self.keys or list(range(len(self.units)))

    def all_units(self) -> list[Unit]:
        """Units then whole runs: the order of a run's per-unit results."""
        return self.units + self.whole


def groups(indices: list[int], k: int, keys: list[int] | None = None) -> list[list[int]]:
    """``indices`` in at most ``k`` contiguous groups of near-equal size (order kept); with
    ``keys`` (one per index of the design's units), the indices of one key in one group."""
    key_of = (lambda i: i) if keys is None else keys.__getitem__
    distinct = list(dict.fromkeys(key_of(i) for i in indices))
    k = max(1, min(k, len(distinct)))
    parts = [set(map(int, g)) for g in np.array_split(np.asarray(distinct, dtype=int), k)
             if len(g)]
    return [[i for i in indices if key_of(i) in part] for part in parts]


def block_bounds(tv_unix_s: np.ndarray, guard_s: float, max_blocks: int
                 ) -> list[tuple[float, float]]:
    """(start, end) times of the time blocks over sorted epoch times (of one run, or of
    simultaneous runs on one clock), separated by guard gaps: as
    many as fit (each at least a guard and :data:`MIN_BLOCK_S` long), ``max_blocks`` at most;
    none when the times span too little."""
    if tv_unix_s.size < 2:
        return []
    span = float(tv_unix_s[-1] - tv_unix_s[0])
    min_len = max(MIN_BLOCK_S, guard_s)
    n = int(min(max_blocks, math.floor((span + guard_s) / (min_len + guard_s))))
    if n < 1:
        return []
    length = (span - (n - 1) * guard_s) / n
    return [(float(tv_unix_s[0]) + b * (length + guard_s),
             float(tv_unix_s[0]) + b * (length + guard_s) + length) for b in range(n)]


def _in_block(t_unix_s: np.ndarray, valid: np.ndarray, lo: float, hi: float, last: bool
              ) -> np.ndarray:
    return valid & (t_unix_s >= lo) & ((t_unix_s <= hi) if last else (t_unix_s < hi))


def simultaneous(t_unix_s: list[np.ndarray], valid: list[np.ndarray]) -> list[int]:
    """Per run, its cluster: runs whose spans of valid epochs overlap (directly or through
    another run) share one, numbered in the order of their first run."""
    spans = [(float(t[v][0]), float(t[v][-1])) if v.any() else (math.inf, -math.inf)
             for t, v in zip(t_unix_s, valid, strict=True)]
    cluster = list(range(len(spans)))

    def root(i: int) -> int:
        while cluster[i] != i:
            i = cluster[i]
        return i

    for a in range(len(spans)):
        for b in range(a):
            if spans[a][0] <= spans[b][1] and spans[b][0] <= spans[a][1]:
                cluster[root(a)] = root(b)
    return _numbered([root(i) for i in range(len(spans))])


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
    cluster = simultaneous(t_unix_s, valid)
    together = len(set(cluster)) < len(names)
    keys: list = []
    if len(names) >= MIN_UNITS and not together:
        units = list(whole)
        scheme, guard = "leave one run out", 0.0
        fit_on_whole = False
    else:
        gs = []
        for n, t, v, tau in zip(names, t_unix_s, valid, corr_time_s, strict=True):
            tv = t[v]
            span = float(tv[-1] - tv[0]) if tv.size > 1 else 0.0
            if not math.isfinite(tau):
                warnings.append(f"run {n}: its error stays correlated over half the run or "
                                "longer; blocks are guarded by a quarter of the run and are "
                                "not independent")
            gs.append(max(MIN_GUARD_S, tau if math.isfinite(tau) else span / 4.0))
        guard = max(gs)
        units = []
        for c in dict.fromkeys(cluster):
            # simultaneous runs: one clock, guarded by the largest of their guards
            members = [i for i in range(len(names)) if cluster[i] == c]
            tv = np.sort(np.concatenate([t_unix_s[i][valid[i]] for i in members]))
            bounds = block_bounds(tv, max(gs[i] for i in members), max_blocks)
            for b, (lo, hi) in enumerate(bounds):
                for i in members:
                    m = _in_block(t_unix_s[i], valid[i], lo, hi, b == len(bounds) - 1)
                    if not m.any():
                        continue
                    t0, t1 = t_unix_s[i][m][0] - tv[0], t_unix_s[i][m][-1] - tv[0]
                    units.append(Unit(i, m, f"run {names[i]} block {b + 1}/{len(bounds)} "
                                            f"({t0:.0f}-{t1:.0f} s)" if len(names) > 1 else
                                      f"time block {b + 1}/{len(bounds)} ({t0:.0f}-{t1:.0f} s)"))
                    keys.append((c, b))
        scheme = f"leave one time block out (blocks guarded by {guard:.0f} s)" + (
            "; runs at the same time held out together" if together else "")
        fit_on_whole = len(names) == 1
    keys = _numbered(keys) if keys else []
    n_keys = len(set(keys)) if keys else len(units)
    outer = []
    if n_keys < MIN_UNITS:
        span = max((float(t[v][-1] - t[v][0]) if v.sum() > 1 else 0.0)
                   for t, v in zip(t_unix_s, valid, strict=True))
        warnings.append(
            f"too little data for a held-out test: {n_keys} unit(s), {MIN_UNITS} needed "
            f"(runs of {span:.0f} s hold blocks of at least {max(MIN_BLOCK_S, guard):.0f} s "
            f"separated by the error's correlation time, {guard:.0f} s); no effect is claimed, "
            "the located gaps stand alone")
    else:
        outer = groups(list(range(len(units))), MAX_OUTER, keys or None)
    return Design(units, whole, fit_on_whole, guard, scheme, outer, warnings, keys)


def _numbered(keys: list) -> list[int]:
    """Keys as 0, 1, ... in order of first appearance."""
    number = {k: n for n, k in enumerate(dict.fromkeys(keys))}
    return [number[k] for k in keys]


def folds(units: list[int], k: int = MAX_INNER, keys: list[int] | None = None
          ) -> list[list[int]]:
    """Cross-validation folds (held-out groups) over some units, the units of one key (the
    design's :meth:`Design.unit_keys`) in one fold."""
    return groups(units, k, keys)
