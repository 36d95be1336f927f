"""Fitting one candidate effect's parameters (DESIGN 7.2) on some units of data.

Each grid point of the candidate is simulated with a seed set over the units (common random
numbers: every point runs the same seeds, so the objective, the mean gap, is smooth in the
parameters). A fold's point is the one with the smallest objective, unless the default is
within :data:`FLAT_MIN` of it (:func:`fit_index`: no evidence keeps the prior).

An added effect is fitted with both seed sets (:func:`fit_final`, :func:`identify`): a
parameter whose grid points all lie within the seeds' own noise of the best is not
identifiable (the default is kept), and a best point at the edge of its grid extends the grid
by one step, or is reported as a bound. Its interval holds those near-optimal points and, in
the reported selection, the points that fits to logs drawn from the chosen point pick
(:func:`refit_points`): the seeds' noise of the objective alone leaves out the real log's own
luck (the near-optimal points alone held the injected value in 49 of 54 self-check
parameters; 3 of the 5 misses were a single grid point). A grid cut to part of its values (a
later round's refit) that the objective pulls past its end is told by :func:`pulled_past_cut`.
"""

from __future__ import annotations

from collections.abc import Generator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from virtualgps.gap import effects as fx
from virtualgps.gap.bands import distances_many
from virtualgps.gap.simulator import FIT, HELD, Request, Simulator
from virtualgps.gap.where import SKY_BIN_AZ_DEG, SKY_BIN_EL_DEG

FLAT_MIN = 0.02  # gap differences below this: the data cannot tell two points apart


def fit_index(objective: np.ndarray, default: int, flat: float = FLAT_MIN) -> int:
    """The point with the smallest objective, unless the default is within ``flat`` of it (no
    evidence keeps the prior). objective : (points,), NaN left out."""
    if not np.isfinite(objective).any():
        return default
    best = int(np.nanargmin(objective))
    if np.isfinite(objective[default]) and objective[default] - objective[best] <= flat:
        return default
    return best


def pulled_past_cut(cand: fx.Candidate, objective: np.ndarray) -> bool:
    """Whether a candidate cut to part of its grid (:meth:`Candidate.near`) is fitted against an
    end of the cut that is not an end of its whole grid: the objective's best point lies there,
    lower by more than FLAT_MIN than its neighbour inward along that axis, so the fit would go
    on past the cut. (A later round refits around an earlier round's points; once other
    effects are added, a parameter's best value may lie far from them: a noise scale first
    fitted at 4 to cover a filter's lag belongs near 0.2 once the filter is added.)

    objective : (points,) the mean gap of each of ``cand``'s points, NaN left out"""
    if cand.whole is None or not np.isfinite(objective).any():
        return False
    points = cand.points
    best = int(np.nanargmin(objective))
    p = points[best]
    for a, w in zip(cand.axes, cand.whole.axes, strict=True):
        if len(a.values) < 2:
            continue
        for end, inward, whole_end in ((a.values[0], a.values[1], w.values[0]),
                                       (a.values[-1], a.values[-2], w.values[-1])):
            if p[a.name] == end and end != whole_end:
                k = points.index(p | {a.name: inward})
                if np.isfinite(objective[k]) and objective[k] - objective[best] > FLAT_MIN:
                    return True
    return False


@dataclass(frozen=True)
class Fitted:
    """A candidate fitted on a selection's fit units.

    overrides : the chosen point's tables; point : its axis values
    intervals : per axis, the values of the grid points within the noise of the best and,
        where ``refits``, of those the refits picked ([lo, hi] for numbers, the values for
        choices)
    identifiable : per axis, whether the points within the noise of the best leave some grid
        values out (the objective is not flat along it)
    grid_edge : per axis fitted at an end of its grid: "upper" or "lower"
    bounds : per axis still at an end after extending: ">= v" or "<= v"
    flat : no point is better than another beyond the noise
    noise : the seeds' noise of the objective used
    grid : per numeric axis, the grid values fitted over (after any extension): an interval
        resolves a value to the nearest of them
    refits : the fits to logs drawn from the chosen point that widened the intervals
        (:func:`refit_points`; 0: not done)
    """

    overrides: dict
    point: dict
    intervals: dict = field(default_factory=dict)
    identifiable: dict = field(default_factory=dict)
    grid_edge: dict = field(default_factory=dict)
    bounds: dict = field(default_factory=dict)
    flat: bool = False
    noise: float = 0.0
    grid: dict = field(default_factory=dict)
    refits: int = 0

    def public(self) -> dict:
        """The report's ``fit`` entry: ``point``, the chosen axis values (a ``scale`` that
        ``params`` shows only as the values it multiplies); ``spans``: per numeric axis with an
        interval, the values that round into its grid points
        (:func:`virtualgps.gap.effects.grid_span`)."""
        spans = {k: fx.grid_span(self.grid[k], *iv) for k, iv in self.intervals.items()
                 if k in self.grid and isinstance(iv, list) and len(iv) == 2}
        return {"point": self.point, "intervals": self.intervals, "spans": spans,
                "identifiable": self.identifiable, "grid_edge": self.grid_edge,
                "bounds": self.bounds, "flat": self.flat, "noise": self.noise,
                "grid": self.grid, "refits": self.refits}


def identify(cand: fx.Candidate, j_fit: np.ndarray, j_held: np.ndarray
             ) -> tuple[int, dict[str, Any]]:
    """Which grid point to keep and what the data say of each parameter.

    The objective is the mean of the two seed sets' gaps; its noise is twice the spread over
    the grid of half their difference (the seeds' luck, which differs between the sets). The
    points within that noise (at least FLAT_MIN) of the best are near-optimal: a parameter is
    identifiable when they leave some of its grid values out. Each parameter is kept at the
    middle of its near-optimal values, or at its default when not identifiable, where that
    point is near-optimal too (else the best point); a flat objective keeps the default.

    j_fit, j_held : (points,) mean gap on the fit units with each seed set
    Returns the point's index and {"intervals", "identifiable", "grid_edge", "flat", "noise",
    "near" (the indices of the points within the noise of the best)}
    """
    j = np.nanmean(np.stack([j_fit, j_held]), axis=0)
    d = (j_fit - j_held) / 2.0
    d = d[np.isfinite(d)]
    noise = float(2.0 * np.std(d)) if d.size >= 3 else 0.0
    flat = max(FLAT_MIN, noise)
    points = cand.points
    default = cand.default_index
    if not np.isfinite(j).any():
        return default, {"intervals": {}, "identifiable": {}, "grid_edge": {}, "flat": True,
                         "noise": noise, "near": []}
    best = int(np.nanargmin(j))
    near = np.isfinite(j) & (j <= j[best] + flat)
    info: dict[str, Any] = {"intervals": {}, "identifiable": {}, "grid_edge": {},
                            "flat": bool(near.all()), "noise": noise}
    for axis in cand.axes:
        vals = {p[axis.name] for p, n in zip(points, near, strict=True) if n}
        info["identifiable"][axis.name] = vals != set(axis.values)
    # Each parameter at the middle of its near-optimal values (the best single point chases
    # the seeds' noise along a flat valley), and each the data cannot pin down at its default
    # (no evidence keeps the prior; with none at all, the default point itself); the best
    # point where that combination is not near-optimal.
    keep = dict(points[best])
    for a in cand.axes:
        if not info["identifiable"].get(a.name, True):
            keep[a.name] = points[default][a.name]
        else:
            vals = [v for v in a.values
                    if any(n and p[a.name] == v for p, n in zip(points, near, strict=True))]
            keep[a.name] = vals[(len(vals) - 1) // 2]
    idx = default if info["flat"] else next(
        (k for k, p in enumerate(points) if p == keep and near[k]), best)
    info["near"] = [int(k) for k in np.flatnonzero(near)]
    info["intervals"] = intervals(cand, info["near"])
    for axis in cand.axes:
        if len(axis.values) < 2:
            continue
        vals = [p[axis.name] for p, n in zip(points, near, strict=True) if n]
        numeric = _numeric(axis)
        ident = info["identifiable"][axis.name]
        v = points[idx][axis.name]
        if ident and numeric and v == max(axis.values) and min(vals) > min(axis.values):
            info["grid_edge"][axis.name] = "upper"
        elif ident and numeric and v == min(axis.values) and max(vals) < max(axis.values):
            info["grid_edge"][axis.name] = "lower"
    return idx, info


def _numeric(axis: fx.Axis) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in axis.values)


def intervals(cand: fx.Candidate, points: Sequence[int]) -> dict[str, Any]:
    """Per axis of more than one value, the span of some grid points' values ([lo, hi] for
    numbers, the values for choices). points : indices into ``cand.points``"""
    out: dict[str, Any] = {}
    for axis in cand.axes:
        if len(axis.values) < 2:
            continue
        vals = [cand.points[k][axis.name] for k in points]
        out[axis.name] = ([min(vals), max(vals)] if _numeric(axis)
                          else sorted(set(vals), key=str))
    return out


def refit_points(sim: Simulator, tables: Sequence[dict], idx: int, units: Sequence[int],
                 default: int) -> list[int]:
    """The grid points that fits to logs drawn from the chosen point pick: a parametric
    bootstrap of the fit. Each of the chosen point's seeds, of either seed set, is taken as
    the real log of every unit and judged against every grid point's seeds of the other set
    (the sets are disjoint: a pseudo-log is independent of the ensembles it meets); its point
    is the one :func:`fit_index` picks from its mean gap over the units, in the seeds' own
    spread and guarded by the reference's as the real log's gap is
    (:func:`virtualgps.gap.bands.distance_against`). The spread of these points is what the
    real log's own luck does to the fit, which the seeds' noise of the objective alone leaves
    out.

    tables : (T,) the grid's profile tables, each scored on ``units`` with both seed sets, as
        is the simulator's reference (where it has one); idx, default : the chosen and the
        default point's indices
    Returns the picked indices, one per pseudo-log with a gap (2 x seeds per set at most)
    """
    picks: list[int] = []
    n_t = len(tables)
    for own, other in ((HELD, FIT), (FIT, HELD)):
        hat = sim.scores(tables[idx], own, units)
        grid = [sim.scores(t, other, units) for t in tables]
        # (the guard of the real log's objective, from the reference's seeds of the other
        # set: like the real log, a pseudo-log shares no seed with the ensembles it meets)
        ref = sim.reference_scores(other, units)
        total: np.ndarray | None = None
        for k in range(len(units)):
            sc = hat[k]
            if not sc.seeds:
                continue
            n_b = next(iter(sc.seeds.values())).size
            d_sum, d_n = np.zeros((n_t, n_b)), np.zeros((n_t, n_b))
            for m, values in sc.seeds.items():
                have = [t for t in range(n_t) if m in grid[t][k].judged]
                if not have:
                    continue
                guard = ref[k].judged.get(m) if ref is not None else None
                d = distances_many(m, values, [grid[t][k].judged[m][1] for t in have],
                                   [grid[t][k].seeds[m] for t in have],
                                   guard[1] if guard is not None else None)
                ok = np.isfinite(d)
                d_sum[have] += np.where(ok, d, 0.0)
                d_n[have] += ok
            with np.errstate(invalid="ignore"):
                unit_gap = d_sum / d_n  # (T, B): NaN where no metric judged
            if total is None:
                total, count = np.zeros((n_t, n_b)), np.zeros((n_t, n_b))
            ok = np.isfinite(unit_gap)
            total += np.where(ok, unit_gap, 0.0)
            count += ok
        if total is None:
            continue
        with np.errstate(invalid="ignore"):
            j = total / count
        picks += [fit_index(j[:, b], default) for b in range(j.shape[1])
                  if np.isfinite(j[:, b]).any()]
    return picks


def grid_options(sim: Simulator, table: dict, cand: fx.Candidate, train: Sequence[int]
                 ) -> tuple[list[dict], int]:
    """A candidate's override tables on top of ``table`` and the default's index: its grid,
    or for a learned sky mask the masks learned from the training units at each level (the
    table's sky bins must have been requested with the fitting seeds)."""
    if not cand.learned:
        return cand.grid, cand.default_index
    counts = sim.sky_bins(table, FIT, train)
    masks = [fx.learned_sky_mask(counts, lv, SKY_BIN_AZ_DEG, SKY_BIN_EL_DEG, cand.learned_atten)
             for lv in cand.learned]
    masks = [m for m in masks if m is not None]
    return (masks, len(masks) // 2) if masks else ([{}], 0)


def fit_final(sim: Simulator, table: dict, cand: fx.Candidate, units: Sequence[int],
              refits: bool = False) -> Generator[Request, None, Fitted]:
    """Fit a candidate on top of ``table`` over ``units`` with both seed sets, extending an
    axis once where the best point lies at its edge (a generator). ``refits``: the
    intervals also hold the points fits to logs drawn from the chosen point pick
    (:func:`refit_points`; the reported selection's)."""
    if cand.learned:
        yield [(table, FIT, units)]
        opts, default = grid_options(sim, table, cand, units)
        tables = [fx.apply(table, o) for o in opts]
        yield [(t, FIT, units) for t in tables]
        j = np.array([sim.gap(t, FIT, units) for t in tables])
        k = fit_index(j, default)
        return Fitted(opts[k], {"level": cand.learned[min(k, len(cand.learned) - 1)]})
    extended: set[str] = set()
    while True:
        tables = [fx.apply(table, o) for o in cand.grid]
        yield [(t, s, units) for t in tables for s in (FIT, HELD)]
        jf = np.array([sim.gap(t, FIT, units) for t in tables])
        jh = np.array([sim.gap(t, HELD, units) for t in tables])
        idx, info = identify(cand, jf, jh)
        grow = next(((a, side) for a, side in info["grid_edge"].items() if a not in extended),
                    None)
        if grow is None:
            break
        axis, upper = grow[0], grow[1] == "upper"
        if cand.whole_beyond(axis, upper) is None:
            extended.add(axis)  # (past the whole grid: one step, once)
        bigger = cand.extended(axis, upper)
        if bigger is None:
            continue
        cand = bigger
    point = cand.points[idx]
    bounds = {a: (">= " if side == "upper" else "<= ") + f"{point[a]:g}"
              for a, side in info["grid_edge"].items()}
    grid = {a.name: sorted(a.values) for a in cand.axes if _numeric(a)}
    picks: list[int] = []
    if refits and len(tables) > 1:
        if sim.reference_table is not None:
            yield [(sim.reference_table, s, units) for s in (FIT, HELD)]
        picks = refit_points(sim, tables, idx, units, cand.default_index)
        info["intervals"] = intervals(cand, [*info["near"], *picks])
    return Fitted(cand.grid[idx], point, info["intervals"], info["identifiable"],
                  info["grid_edge"], bounds, info["flat"], info["noise"], grid, len(picks))
