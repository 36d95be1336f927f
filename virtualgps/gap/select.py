"""Choosing effects (DESIGN 7.2): fit each candidate's parameters on training units, measure it
on held-out units, and add the best while it clearly helps.

One selection works on a set of units and their folds. Each round, for every candidate and every
fold, each grid point is simulated with the fitting seeds over the runs (common random numbers:
every point runs the same seeds, so the objective is smooth in the parameters); the fold's point
is the one with the smallest mean gap on the fold's training units (its default unless another
point is better by more than :data:`.fit.FLAT_MIN`); that point is then measured on the fold's
held-out units with the held-out seeds, never the fitting ones (with common random numbers a
run's blocks share seeds, and a fit would carry their luck into its held-out blocks).

A candidate is added when its held-out gain is clear (:func:`acceptable`): over the folds it
changes, larger than twice :data:`MIN_GAIN_ABS` and than :data:`MIN_GAIN_REL` of the gap;
positive over every fold, with both seed sets; positive in most folds it changes; and without
any metric's held-out distance rising by more than :data:`WORSEN_MAX` (no effect buys a lower
total by trading one metric for another).
Candidates whose held-out gaps differ by less than :data:`TIE_EPS`, or swap places under the
other seed set, are tied; a tie goes to the candidate with fewer parameters.

The added effect's parameters are then fitted on the selection's fit units with both seed sets
(:mod:`.fit`: identifiability, intervals, grid edges). Later rounds try the candidates that
helped, refitted around the points their folds chose, on top of the effects added so far; one
whose refit runs into an end of that cut is tried again on its whole grid, and the fit of an
added one extends a cut axis into its whole grid first. Where the first round's runner-up, a
competing explanation, is never added, a second search starts from it, kept where it ends
clearly lower (by what adding an effect needs); where neither ends clearly lower, the report
names the other as an equally good explanation (:func:`settle_paths`). At the end an added
effect the others make redundant (the held-out gap no higher without it) is taken out again.

Selections are generators: they yield the (table, seed set, units) they need next, and a driver
(:func:`drive`) runs several side by side, each going on as soon as its own request is
scored.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from virtualgps.gap import effects as fx
from virtualgps.gap.design import folds as make_folds
from virtualgps.gap.fit import FLAT_MIN, Fitted, fit_final, fit_index, grid_options, pulled_past_cut
from virtualgps.gap.simulator import FIT, HELD, Request, Simulator, mean_per_metric
from virtualgps.gap.where import pooled_tracking_disagreement
from virtualgps.sky import systems

MIN_GAIN_ABS = 0.05  # an effect is added when it lowers the held-out gap by more than this
MIN_GAIN_REL = 0.05  # and by more than this share of the gap before it
WORSEN_MAX = 1.0  # ... and no metric's held-out distance rises by more than this
TIE_EPS = 0.02  # held-out gaps this close are a tie
RETRY_BEST = 6  # candidates carried into the next round of the greedy search, at most
COMPETITOR_SHARE = 0.5  # a runner-up explaining this share of the first effect's gain competes
PROGRESS_EVERY_S = 10.0  # a progress line while choosing effects, at most this often

@dataclass
class Tried:
    """One candidate tried on top of each fold's current profile.

    fold_overrides : the override tables fitted per fold
    before, after : (F,) held-out gap per fold without and with it (held-out seeds)
    before_fit, after_fit : the same with the fitting seeds (the ranking's second opinion)
    metrics_before, metrics_after : per-metric held-out distances without and with it
    metrics_moved : those with it for judging what it worsens (:meth:`Simulator.moved_parts`:
        a narrower spread about the same centre is no worsening); None: ``metrics_after``
    past_cut : a grid cut to part of its values (a later round's) was fitted against a cut
        end in some fold (:func:`.fit.pulled_past_cut`)
    """

    cand: fx.Candidate
    fold_overrides: list[dict]
    fold_points: list[dict]
    before: np.ndarray
    after: np.ndarray
    before_fit: np.ndarray
    after_fit: np.ndarray
    metrics_before: dict[str, float]
    metrics_after: dict[str, float]
    metrics_moved: dict[str, float] | None = None
    tied_with: list[str] = field(default_factory=list)
    past_cut: bool = False

    @property
    def gap_after(self) -> float:
        return _mean(self.after)

    @property
    def gap_after_fit(self) -> float:
        return _mean(self.after_fit)


def _mean(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.mean(x[np.isfinite(x)])) if np.isfinite(x).any() else math.nan


def try_candidates(sim: Simulator, cands: list[fx.Candidate], fold_tables: list[dict],
                   folds: list[list[int]], train: list[list[int]]
                   ) -> Generator[Request, None, list[Tried]]:
    """Fit every candidate per fold on the fold's training units and measure it on its
    held-out units (a generator: see the module docstring)."""
    n_f = len(folds)
    if any(c.learned for c in cands):
        yield [(fold_tables[f], FIT, train[f]) for f in range(n_f)]
    options = {}
    # (each table made once: the simulator keys its scores by the table object)
    tables: dict[tuple[int, int], list[dict]] = {}
    req: Request = []
    for ci, c in enumerate(cands):
        for f in range(n_f):
            opts, default = grid_options(sim, fold_tables[f], c, train[f])
            options[ci, f] = (opts, default)
            tables[ci, f] = [fx.apply(fold_tables[f], o) for o in opts]
            req += [(t, FIT, train[f]) for t in tables[ci, f]]
    yield req
    chosen: dict[tuple[int, int], int] = {}
    points: dict[tuple[int, int], dict] = {}
    past_cut: set[int] = set()
    req = []
    for (ci, f), (_, default) in options.items():
        j = np.array([sim.gap(t, FIT, train[f]) for t in tables[ci, f]])
        k = chosen[ci, f] = fit_index(j, default)
        if not cands[ci].learned and pulled_past_cut(cands[ci], j):
            past_cut.add(ci)
        points[ci, f] = cands[ci].points[k] if not cands[ci].learned else {}
        held = folds[f]
        for t in (tables[ci, f][k], fold_tables[f]):
            req += [(t, HELD, held), (t, FIT, held)]
    yield req
    out = []
    for ci, c in enumerate(cands):
        ov = [options[ci, f][0][chosen[ci, f]] for f in range(n_f)]
        with_t = [tables[ci, f][chosen[ci, f]] for f in range(n_f)]

        def per_fold(tables: list[dict], seed_set: int) -> np.ndarray:
            return np.array([sim.gap(tables[f], seed_set, folds[f]) for f in range(n_f)])

        out.append(Tried(
            c, ov, [points[ci, f] for f in range(n_f)], per_fold(fold_tables, HELD),
            per_fold(with_t, HELD),
            per_fold(fold_tables, FIT), per_fold(with_t, FIT),
            mean_per_metric([sim.parts(fold_tables[f], HELD, folds[f]) for f in range(n_f)]),
            mean_per_metric([sim.parts(with_t[f], HELD, folds[f]) for f in range(n_f)]),
            mean_per_metric([sim.moved_parts(with_t[f], fold_tables[f], HELD, folds[f])
                             for f in range(n_f)]),
            past_cut=ci in past_cut))
    return out


def mark_ties(tried: list[Tried]) -> list[list[Tried]]:
    """Sort by held-out gap and group candidates that are tied: held-out gaps within TIE_EPS,
    or in the other order under the fitting seeds. Returns the tie groups, best first."""
    tried.sort(key=lambda t: t.gap_after if math.isfinite(t.gap_after) else math.inf)
    groups: list[list[Tried]] = []
    for t in tried:
        if groups and math.isfinite(t.gap_after):
            prev = groups[-1][-1]
            close = t.gap_after - prev.gap_after < TIE_EPS
            swapped = (math.isfinite(t.gap_after_fit) and math.isfinite(prev.gap_after_fit)
                       and t.gap_after_fit < prev.gap_after_fit)
            if close or swapped:
                groups[-1].append(t)
                continue
        groups.append([t])
    for g in groups:
        for t in g:
            t.tied_with = [o.cand.name for o in g if o is not t]
    return groups


def acceptable(tr: Tried, current: float) -> tuple[bool, str]:
    """Whether a candidate clearly lowers the held-out gap (see the module docstring), and if
    not, why. The gain is judged over the held-out folds it changes (a start-up shows in the
    one block that holds the power-on; averaged over every fold it would be diluted away),
    and must be positive over all of them, with either seed set."""
    per = tr.before - tr.after
    # A group counts by how much the candidate changes it: wholly from FLAT_MIN up, in
    # proportion below. A start-up leaves the later blocks all but unchanged, so they do not
    # dilute its gain; and a group whose change lies near FLAT_MIN no longer drops in or out
    # of the mean whole. (On the GSDC drive with its truth moved, multipath changed four
    # groups by 0.025, 0.213, -0.007 and -0.0197: the last left out, the mean over the two
    # left, 0.119, passed 0.1; counted, it is 0.073 over three. 2026-11-29.)
    w = np.where(np.isfinite(per), np.minimum(np.abs(per) / FLAT_MIN, 1.0), 0.0)
    per = np.nan_to_num(per)
    gain = current - tr.gap_after
    local = float(np.sum(w * per) / np.sum(w)) if w.sum() > 0 else 0.0
    need = max(2 * MIN_GAIN_ABS, MIN_GAIN_REL * current)
    if not (local > need and gain > 0):
        return False, (f"held-out gain {gain:.3f} ({local:.3f} over the {w.sum():.1f} "
                       f"held-out group(s) it changes) below {need:.3f}")
    gain_fit = _mean(tr.before_fit) - tr.gap_after_fit
    if not gain_fit > 0:
        return False, "the gain is not repeated with the other seed set"
    if not np.sum(w * (per > 0)) > 0.5 * w.sum():
        return False, "it helps fewer than half of the held-out units it changes"
    worse = {m: d for m, d in worsened(tr).items() if d > WORSEN_MAX}
    if worse:
        return False, "it worsens " + ", ".join(f"{m} by {d:.2f}" for m, d in worse.items())
    return True, ""


def worsened(tr: Tried) -> dict[str, float]:
    """How much a candidate raises each metric's held-out distance (negative: lowers it),
    judged by its centres' moves (``metrics_moved``) where given."""
    after = tr.metrics_after if tr.metrics_moved is None else tr.metrics_moved
    return {m: d - tr.metrics_before.get(m, 0.0) for m, d in after.items()}


@dataclass
class Selection:
    """What one selection found.

    steps : accepted effects in the order added (report entries)
    ranking : every candidate of the first round, best held-out gap first (report entries)
    skipped : {effect: why it was not tried}
    baseline, final : held-out gap (held-out seeds) of the base and of the final fold profiles
    final_table : the profile with the added effects fitted on the fit units
    fold_tables : each fold's profile; folds : the held-out groups
    rounds : per round, the gap before it and each candidate's held-out gap and verdict
    tracking : per-PRN tracking disagreement on held-out units, before and after
    removed : added effects taken out again, the others making them redundant
    paths : where a second search started from the first round's runner-up: each search's
        first effect, effects and held-out gap after, which was kept, and whether the other
        is a tie (:func:`settle_paths`)
    """

    steps: list[dict]
    ranking: list[dict]
    skipped: dict[str, str]
    baseline: float
    final: float
    final_table: dict
    fold_tables: list[dict]
    folds: list[list[int]]
    rounds: list[dict] = field(default_factory=list)
    tracking: dict = field(default_factory=dict)
    removed: list[dict] = field(default_factory=list)
    paths: list[dict] = field(default_factory=list)


def _rounds(sim: Simulator, base: dict, units: list[int], fit_units: list[int],
            candidates: Callable[[dict], tuple[list[fx.Candidate], dict[str, str]]],
            folds: list[list[int]], train: list[list[int]], current: float,
            cands: list[fx.Candidate], first: tuple[list[Tried], Tried] | None = None,
            full: bool = False) -> Generator[Request, None, tuple]:
    """The greedy rounds from ``base`` (a generator): each adds the best acceptable
    candidate. ``first``: the first round's candidates as already tried, and the one to add
    first (the competing path of :func:`select`); ``full``: the reported selection (its fits'
    intervals hold what refits pick, :func:`.fit.fit_final`).

    Returns (steps, rounds, table, held-out gap after, the first round's (tried, verdicts))
    """
    n_f = len(folds)
    fold_tables = [base] * n_f
    table = base
    steps: list[dict] = []
    rounds: list[dict] = []
    first_round = None
    while cands:
        if first is not None and not rounds:
            tried, forced = first
        else:
            tried = yield from try_candidates(sim, cands, fold_tables, folds, train)
            forced = None
            # a candidate refitted around its earlier points whose fit runs into the cut is
            # tried again on its whole grid
            wide = [t.cand.whole for t in tried if t.past_cut]
            if wide:
                again = yield from try_candidates(sim, wide, fold_tables, folds, train)
                names = {c.name for c in wide}
                tried = [t for t in tried if t.cand.name not in names] + again
        groups = mark_ties(tried)
        verdicts = {id(t): acceptable(t, current) for t in tried}
        rounds.append({"gap_before": current, "tried": [
            {"name": t.cand.name, "gap_after": t.gap_after,
             "gap_after_fit_seeds": t.gap_after_fit, "params": t.cand.params_of(
                 t.fold_overrides[0]), "verdict": verdicts[id(t)][1] or "acceptable"}
            for t in tried]})
        if first_round is None:
            first_round = (tried, verdicts)
        best, fitted = None, None
        for g in ([[forced]] if forced is not None else groups):
            ok = sorted((t for t in g if verdicts[id(t)][0]),
                        key=lambda t: (t.cand.complexity, (t.gap_after + t.gap_after_fit)))
            for t in ok:
                f = yield from fit_final(sim, table, t.cand, fit_units, refits=full)
                if fx.apply(table, f.overrides) != table:
                    best, fitted = t, f
                    break
            if best is not None:
                break
        if best is None:
            break
        table = fx.apply(table, fitted.overrides)
        # Later rounds judge candidates on top of the effects added so far, as fitted on the
        # selection's fit units (the folds share them: their held-out units saw that fit, so
        # a later round's held-out gain is a little optimistic; the outer test is not).
        fold_tables = [table] * n_f
        steps.append(entry(best, sim, folds, fitted) | {"gap_before": current,
                                                        "_fitted": fitted.overrides})
        # Later rounds refit the candidates that lowered the held-out gap in this one, around
        # the points their folds chose (an effect that shows in one held-out unit, a start-up,
        # gains little on average yet may be real), and any the added effect makes applicable.
        cands = [t.cand.near(t.fold_points) for t in tried
                 if t is not best and t.gap_after < current - FLAT_MIN][:RETRY_BEST]
        yield [(table, HELD, units)]
        # the next round's gains are measured from the profile it starts from
        current = _mean(np.array([sim.gap(table, HELD, f) for f in folds]))
        more, _ = candidates(table)
        known = {c.name for c in cands} | {s["name"] for s in steps}
        cands += [c for c in more if c.name not in known]
    return steps, rounds, table, current, first_round


def _runner_up(first_round: tuple[list[Tried], dict], added: list[str], before: float
               ) -> Tried | None:
    """The first round's best acceptable candidate, in the order the greedy search takes
    them, that the search did not add at all (one added on top of the others later leads to
    the same effects), where it explains at least COMPETITOR_SHARE of what the first added
    one does alone: a competing explanation. ``before``: the held-out gap before the round."""
    tried, verdicts = first_round
    first = next(t for t in tried if t.cand.name == added[0])
    need = COMPETITOR_SHARE * (before - first.gap_after)
    for g in mark_ties(list(tried)):
        ok = sorted((t for t in g if verdicts[id(t)][0]),
                    key=lambda t: (t.cand.complexity, (t.gap_after + t.gap_after_fit)))
        for t in ok:
            if t.cand.name not in added:
                return t if before - t.gap_after >= need else None
    return None


def settle_paths(paths: list[dict]) -> int:
    """Which of two searches' ends is kept: the second (from the first round's runner-up)
    where its held-out gap is clearly lower, by what adding an effect needs (see
    :func:`acceptable`), else the first. Where neither is clearly lower and they end with
    different effects, the other is marked ``tie``: the data do not decide between the two
    explanations, and the report says so.

    paths : the two searches, each {"first", "effects", "gap_after"}; marked in place
    (``kept``, ``tie``). Returns the kept one's index.
    """
    a, b = paths[0]["gap_after"], paths[1]["gap_after"]
    margin = max(2 * MIN_GAIN_ABS, MIN_GAIN_REL * a)
    kept = 1 if a - b > margin else 0
    paths[kept]["kept"] = True
    other = paths[1 - kept]
    if (abs(a - b) <= margin
            and set(other["effects"]) != set(paths[kept]["effects"])):
        other["tie"] = True
    return kept


def alternative(paths: list[dict]) -> dict | None:
    """``report.json``'s ``alternative``: the search that ended about as low as the kept one
    with other effects (marked ``tie`` by :func:`settle_paths`), said for people; None
    without one."""
    tie = next((p for p in paths if p.get("tie")), None)
    kept = next((p for p in paths if p.get("kept")), None)
    if tie is None or kept is None:
        return None
    return {"effects": tie["effects"], "gap_after": tie["gap_after"],
            "chosen": kept["effects"], "chosen_gap_after": kept["gap_after"],
            "what": f"{', '.join(tie['effects'])} "
                    f"{'explains' if len(tie['effects']) == 1 else 'explain'} the logs about "
                    f"as well as the effects "
                    f"added ({', '.join(kept['effects'])}): held-out gap "
                    f"{tie['gap_after']:.3f} against {kept['gap_after']:.3f}, closer than "
                    f"adding an effect needs; the data do not decide between {kept['first']} "
                    f"and {tie['first']}"}


def select(sim: Simulator, base: dict, units: list[int], fit_units: list[int],
           candidates: Callable[[dict], tuple[list[fx.Candidate], dict[str, str]]],
           k_folds: int, full: bool = False) -> Generator[Request, None, Selection]:
    """Greedy selection of effects on ``units`` (a generator; see the module docstring).

    Parameters
    ----------
    sim : the simulator; base : the profile table under test
    units : the units cross-validated over; fit_units : what added effects are fitted on
    candidates : profile table -> (candidates, skipped)
    k_folds : folds at most
    full : the reported selection: also measure the per-PRN tracking disagreement, and widen
        the fits' intervals by refits (:func:`.fit.fit_final`)
    """
    folds = make_folds(units, k_folds, sim.design.unit_keys())
    train = [[u for u in units if u not in f] for f in folds]
    n_f = len(folds)
    # (the base's held-out scores of every unit read are the guard of every table's score:
    # Simulator.set_reference)
    yield [(base, HELD, sorted(set(units) | set(fit_units)))]
    baseline = _mean(np.array([sim.gap(base, HELD, f) for f in folds]))
    cands, skipped = candidates(base)
    steps, rounds, table, current, first_round = yield from _rounds(
        sim, base, units, fit_units, candidates, folds, train, baseline, cands, full=full)
    ranking = ([entry(t, sim, folds, None) | {"accepted_test": first_round[1][id(t)][1]}
                for t in first_round[0]] if first_round is not None else [])
    paths = []
    # Greedy order can go wrong where two candidates explain the same thing: the one that
    # explains a little more alone may leave less for the others (a filter explains a delay's
    # lag and, against a noisier profile, the smoothness of a phone's errors; a delay and a
    # filter that smooths only the errors explain both, and better). So the runner-up of the
    # first round that the search never added starts a second search, kept where it ends with
    # a held-out gap clearly lower (the outer test judges the whole procedure).
    alt = _runner_up(first_round, [s["name"] for s in steps], baseline) if steps else None
    if alt is not None:
        steps2, rounds2, table2, current2, _ = yield from _rounds(
            sim, base, units, fit_units, candidates, folds, train, baseline, cands,
            first=(first_round[0], alt), full=full)
        paths = [{"first": steps[0]["name"], "effects": [s["name"] for s in steps],
                  "gap_after": current},
                 {"first": alt.cand.name, "effects": [s["name"] for s in steps2],
                  "gap_after": current2}]
        if settle_paths(paths) == 1:
            steps, rounds, table, current = steps2, rounds2, table2, current2
    fold_tables = [table] * n_f
    sel = Selection(steps, ranking, skipped, baseline, current, table, fold_tables, folds,
                    rounds, paths=paths)
    yield from _contributions(sim, base, sel)
    # An effect the others make redundant (the held-out gap is no higher without it) goes:
    # greedy order can add one that later effects explain better; ties go to the simpler model.
    drop = [s for s in sel.steps if len(sel.steps) > 1 and s["contribution"] <= 0.0]
    if drop:
        for s in drop:
            s["removed"] = (f"the held-out gap is no higher without it (leave-one-out "
                            f"contribution {s['contribution']:.3f})")
        sel.steps = [s for s in sel.steps if s not in drop]
        table = base
        for s in sel.steps:
            table = fx.apply(table, s["_fitted"])
        sel.final_table, sel.fold_tables = table, [table] * n_f
        yield [(table, HELD, units)]
        sel.final = _mean(np.array([sim.gap(table, HELD, f) for f in folds]))
        sel.removed = drop
    if full:
        fold_tables = sel.fold_tables
        yield [(t, HELD, f) for t, f in zip([base] * n_f + fold_tables,
                                                         folds + folds, strict=True)]
        counts_before = [c for f in folds for c in sim.prn_counts(base, HELD, f)]
        counts_after = [c for f, t in zip(folds, fold_tables, strict=True)
                        for c in sim.prn_counts(t, HELD, f)]
        before = pooled_tracking_disagreement(counts_before)
        after = pooled_tracking_disagreement(counts_after)
        sel.tracking = {"baseline": before, "final": after,
                        "shrink": 1.0 - after / before if before > 0 else math.nan}
        # per satellite system (the runs share their satellite columns)
        letters = systems.letters(sim.runs[0].view.prn)
        if len(set(letters.tolist()) - {"?"}) > 1:
            sel.tracking["by_system"] = {
                systems.system_named(x).name: {
                    "baseline": pooled_tracking_disagreement(counts_before, letters == x),
                    "final": pooled_tracking_disagreement(counts_after, letters == x)}
                for x in dict.fromkeys(letters.tolist()) if x != "?"}
    return sel


def entry(tr: Tried, sim: Simulator, folds: list[list[int]], fitted: Fitted | None) -> dict:
    """A report entry for a tried candidate."""
    c = tr.cand
    worse = {m: round(d, 3) for m, d in worsened(tr).items() if d > FLAT_MIN}
    out = {
        "name": c.name,
        "params": c.params_of(fitted.overrides if fitted is not None else tr.fold_overrides[0]),
        "gap_before": _mean(tr.before),
        "gap_after": tr.gap_after,
        "gap_after_fit_seeds": tr.gap_after_fit,
        "gap_after_spread": _spread(tr.after),
        "heldout": "; ".join(", ".join(sim.units[u].label for u in f) for f in folds),
        "fold_params": [c.params_of(o) for o in tr.fold_overrides],
        "metrics_before": tr.metrics_before,
        "metrics_after": tr.metrics_after,
        "metrics_moved": tr.metrics_after if tr.metrics_moved is None else tr.metrics_moved,
        "worsens": worse,
        "tied_with": list(tr.tied_with),
        "parameters": c.complexity,
        "_overrides": list(tr.fold_overrides),
        # the held-out units it changes (by FLAT_MIN or more): where it shows
        "_shows_in": sorted(u for f, fold in enumerate(folds)
                            if np.isfinite(tr.before[f] - tr.after[f])
                            and abs(tr.before[f] - tr.after[f]) >= FLAT_MIN for u in fold),
    }
    if fitted is not None:
        out["fit"] = fitted.public()
    return out


def _spread(x: np.ndarray) -> list[float]:
    v = x[np.isfinite(x)]
    return [float(v.min()), float(v.max())] if v.size else [math.nan, math.nan]


def _contributions(sim: Simulator, base: dict, sel: Selection) -> Generator[Request, None, None]:
    """Each added effect's leave-one-out contribution to the held-out gap: the held-out gap
    with every added effect but it (as fitted) minus the gap with all."""
    steps = sel.steps
    if len(steps) < 2:
        for s in steps:
            s["contribution"] = s["gap_before"] - s["gap_after"]
        return
    without = []
    for s in steps:
        t = base
        for other in steps:
            if other is not s:
                t = fx.apply(t, other["_fitted"])
        without.append([t] * len(sel.folds))
    yield [(t, HELD, sel.folds[f]) for per in without for f, t in enumerate(per)]
    full = _mean(np.array([sim.gap(t, HELD, f) for t, f in zip(sel.fold_tables, sel.folds,
                                                                strict=True)]))
    for s, per in zip(steps, without, strict=True):
        held = _mean(np.array([sim.gap(t, HELD, f) for t, f in zip(per, sel.folds,
                                                                    strict=True)]))
        s["contribution"] = held - full


def drive(sim: Simulator, gens: dict[str, Generator],
          progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run selections side by side. The requests of every selection that is ready are
    submitted together (:meth:`Simulator.submit`). While half the workers or more are busy, a
    selection whose request is scored waits for the others: their requests often name the
    same tables, which then share a job (a selection that goes on alone has its tables
    simulated again for the others later: going on whenever a worker was idle cost 2 workers
    8 % more simulated epochs on the MT3339 hour, 2026-11-27). Once more than half would be
    idle, the ready ones go on, so many workers do not wait for a round's slowest jobs. One or
    two workers thus run round by round. Each selection sees only its own scores, so the results
    do not depend on which jobs finish first.

    Returns {name: the generator's return value}
    """
    results: dict[str, Any] = {}
    waiting: dict[str, Request] = {}
    ready, started = list(gens), set()
    said = time.monotonic()
    while ready or waiting:
        asked: list = []
        for name in ready:
            try:
                req = gens[name].send(None) if name in started else next(gens[name])
            except StopIteration as stop:
                results[name] = stop.value
                continue
            started.add(name)
            waiting[name] = req
            asked += req
        sim.submit(asked)
        ready = []
        while waiting:
            # (while half the workers or more are busy, nobody goes on: nothing is checked)
            if 2 * sim.queue.busy() < sim.workers():
                ready = [name for name, req in waiting.items() if sim.has(req)]
                if ready:
                    break
            sim.collect()
            if progress and time.monotonic() - said > PROGRESS_EVERY_S:
                said = time.monotonic()
                progress(f"choosing effects: {len(waiting)} selection(s) under way, "
                         f"{sim.n_sims:,} epochs simulated")
        for name in ready:
            del waiting[name]
    return results
