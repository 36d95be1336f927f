"""Ensembles of the prepared runs under candidate profiles, scored per held-out unit, with a cache
(DESIGN 7.2).

A request names a profile table, a seed set and units; everything neither scored nor under way
is submitted as jobs (one per table, seed set and run: the run simulated once per seed over all
its epochs, and the units asked measured where the job runs, so only their scores come back; a
job with the fitting seeds measures every held-out unit of its run, which the folds and the
other selections ask of the same table later). The selections of a diagnosis (the full one
and one per outer fold) run side by side (:func:`virtualgps.gap.select.drive`), each going on
when its own units are scored. When the jobs submitted and those still running make fewer
than several per worker, each job's seeds are split into groups, one job each: every seed is
its own generator, and the groups' statistics are joined before scoring
(:func:`virtualgps.gap.where.merge_stats`), so the scores do not depend on the split, nor on
the order in which jobs finish.

Seed sets. Set 0 fits parameters, set 1 measures the held-out gap of what set 0 fitted (with
common random numbers the same seeds would carry the fit's luck from a run's training blocks
into its held-out blocks), set 2 the outer test. Each set is ``fit_seeds`` seeds of its own.
"""

from __future__ import annotations

import json
import math
import uuid
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from virtualgps.gap import effects as fx
from virtualgps.gap.design import Design
from virtualgps.gap.ensemble import Ensemble, EnsembleJob, simulate_job, split_seeds
from virtualgps.gap.jobs import JobQueue, map_jobs, share, shared, worker_count
from virtualgps.gap.runs import Run, sim_obs
from virtualgps.gap.where import (
    SCORE_METRICS,
    Judged,
    SegmentStats,
    bin_tracking,
    errors_enu,
    gap_score,
    judge_scored,
    merge_stats,
    moved_parts,
    pack_vectors,
    prn_tracking,
    segment_stats,
    tracking_means,
    unpack_vectors,
)

FIT, HELD, OUTER = 0, 1, 2  # seed sets
MIN_JOBS_PER_WORKER = 3  # a smaller batch has its jobs' seeds split
# What a selection asks the simulator for: (profile table, seed set, units) to be scored
Request = list[tuple[dict[str, Any], int, Sequence[int]]]


@dataclass(frozen=True)
class UnitScore:
    """One unit under one table and seed set: each score metric's real value and judgment
    (:func:`virtualgps.gap.where.judge_scored`) and (where asked) the per-PRN and per-sky-bin
    tracking counts (see :func:`virtualgps.gap.where.prn_tracking`,
    :func:`virtualgps.gap.where.bin_tracking`). Its gap is read through
    :meth:`Simulator.gap`, beside the reference's judgments of the same unit. ``seeds``:
    {metric: (seeds,)} each judged metric's per-seed values (a fit's interval judges them as
    if real, :func:`virtualgps.gap.fit.refit_points`)."""

    judged: dict[str, tuple[float, Judged]]
    prn: np.ndarray | None = None
    bins: np.ndarray | None = None
    seeds: dict[str, np.ndarray] | None = None

    @property
    def own(self) -> tuple[float, dict[str, float]]:
        """The gap and per-metric distances in the seeds' own spread, with no reference."""
        return gap_score(self.judged)

    def __reduce__(self) -> tuple:
        # (the seeds' values as one array: see where.pack_vectors)
        return (_score_unpacked, (self.judged, self.prn, self.bins,
                                  *pack_vectors(self.seeds or {}), self.seeds is None))


def _score_unpacked(judged: dict, prn: np.ndarray | None, bins: np.ndarray | None,
                    seed_names: Any, seeds: np.ndarray | None, no_seeds: bool) -> UnitScore:
    return UnitScore(judged, prn, bins, None if no_seeds else unpack_vectors(seed_names, seeds))


@dataclass(frozen=True)
class UnitPart:
    """What a job measures of one unit for its seeds: the statistics and, where asked, the
    tracking counts per PRN and per sky bin (:func:`virtualgps.gap.where.prn_tracking`,
    :func:`virtualgps.gap.where.bin_tracking`: fixed parts and per-seed parts)."""

    stats: SegmentStats
    prn: tuple[np.ndarray, np.ndarray] | None = None
    bins: tuple[np.ndarray, np.ndarray] | None = None


def _mean(x: list[float]) -> float:
    """The mean of a short, non-empty list (plain Python: see :meth:`Simulator.gap`)."""
    return sum(x) / len(x)


def mean_per_metric(per: list[dict[str, float]]) -> dict[str, float]:
    """{metric: mean distance} over the units' (or folds') {metric: distance} that assess it."""
    names = sorted({m for p in per for m in p})
    return {m: _mean([p[m] for p in per if m in p]) for m in names}


def unit_score(parts: list[UnitPart]) -> UnitScore:
    """One unit's score from its parts over seed groups (in seed order)."""
    stats = merge_stats([p.stats for p in parts])
    judged = judge_scored(stats)
    seeds = {m: np.asarray(stats.sim[m], dtype=float) for m in judged}

    def means(which: str) -> np.ndarray | None:
        got = [getattr(p, which) for p in parts]
        if got[0] is None:
            return None
        return tracking_means(got[0][0], np.concatenate([g[1] for g in got], axis=-2))

    return UnitScore(judged, means("prn"), means("bins"), seeds)


@dataclass(frozen=True)
class GapJob:
    """Simulate one run with one profile for some seeds and measure some of its units there.

    run : the key under which the run (setup, view, real errors) was shared with the workers
    (:func:`share_runs`); table, source : the profile table to simulate and where it came
    from (built where the job runs: the main process built each table's profile, 90 us, and
    pickled it for each job, 57 us against 3 us for the table, some 0.2 s of its serial rest
    for the MT3339 hour's 1,860 jobs at 16 workers); seeds : the seeds to simulate; units :
    (n,) bool masks of the units to score; prn, bins : also count tracking per PRN, per sky
    bin; whole : the seeds are the whole seed set, so the units are scored where the job runs
    (else their statistics come back, to be joined with the other seed groups' and scored)
    """

    run: str
    table: dict[str, Any]
    source: str
    seeds: tuple[int, ...]
    units: tuple[np.ndarray, ...]
    prn: bool = False
    bins: bool = False
    whole: bool = True


def share_runs(runs: list[Run]) -> list[str]:
    """Give every worker the prepared runs once (:func:`virtualgps.gap.jobs.share`); returns
    the runs' keys."""
    tag = uuid.uuid4().hex[:12]
    keys = [f"gap-run:{tag}:{i}" for i in range(len(runs))]
    share({k: (r.setup, r.view, r.err_real) for k, r in zip(keys, runs, strict=True)})
    return keys


# What the real log shows in each unit, per process (the memo of :func:`segment_stats`, keyed
# by the run's key and the unit's epochs): a worker measures the same units of a run for table
# after table, and a job of one seed spent half its statistics' time on the real log. The
# memos kept hold at most this many bytes (masks and elevations of a unit's epochs: some
# 0.7 MB a unit for an hour at 1 Hz with GSV, about ten times that at 10 Hz), the least recently
# used dropped first.
UNIT_MEMO_BYTES = 256 * 2**20
_UNIT_MEMO: OrderedDict[tuple[str, bytes], dict] = OrderedDict()
_UNIT_MEMO_SIZE: dict[tuple[str, bytes], int] = {}


def _nbytes(x: Any, seen: dict[int, int] | None = None) -> int:
    """The bytes of the arrays in a memo's values (dicts, tuples, dataclasses), each array
    counted once."""
    top = seen is None
    seen = {} if seen is None else seen
    if isinstance(x, np.ndarray):
        seen[id(x)] = x.nbytes
    elif isinstance(x, dict):
        for v in x.values():
            _nbytes(v, seen)
    elif isinstance(x, (tuple, list)):
        for v in x:
            _nbytes(v, seen)
    elif hasattr(x, "__dataclass_fields__"):
        for f in x.__dataclass_fields__:
            if f != "view":  # (the run's, shared)
                _nbytes(getattr(x, f), seen)
    return sum(seen.values()) if top else 0


def _unit_memo(run: str, mask: np.ndarray) -> tuple[tuple[str, bytes], dict]:
    """A unit's memo (empty the first time) and its key."""
    key = (run, np.packbits(mask).tobytes())
    memo = _UNIT_MEMO.get(key)
    if memo is None:
        memo = _UNIT_MEMO[key] = {}
    else:
        _UNIT_MEMO.move_to_end(key)
    return key, memo


def _keep_memos(keys: list[tuple[str, bytes]]) -> None:
    """Count the memos a job used (it may have filled them further), then drop the oldest
    while they hold too much."""
    for k in keys:
        if k in _UNIT_MEMO:
            _UNIT_MEMO_SIZE[k] = _nbytes(_UNIT_MEMO[k])
    total = sum(_UNIT_MEMO_SIZE.values())
    while total > UNIT_MEMO_BYTES and len(_UNIT_MEMO) > 1:
        k, _ = _UNIT_MEMO.popitem(last=False)
        total -= _UNIT_MEMO_SIZE.pop(k, 0)


def gap_job(j: GapJob) -> list[UnitScore] | list[UnitPart]:
    """Each asked unit of a run under the job's seeds (see :class:`GapJob`): its score, or
    (a seed group's job) what it shows."""
    setup, view, err_real = shared(j.run)
    sims = sim_obs(simulate_job(EnsembleJob(setup, fx.build(j.table, j.source), j.seeds)), view)
    err = errors_enu(view, sims)
    parts, used = [], []
    for m in j.units:
        key, memo = _unit_memo(j.run, m)
        used.append(key)
        parts.append(UnitPart(
            segment_stats(view, sims, err_real, err, m, metrics=SCORE_METRICS, memo=memo),
            prn_tracking(view, sims, m, memo) if j.prn else None,
            bin_tracking(view, sims, m, memo) if j.bins else None))
    _keep_memos(used)
    # Scored here where it can be: in the main process the scoring is serial time.
    return [unit_score([p]) for p in parts] if j.whole else parts


def table_key(table: dict[str, Any]) -> str:
    """A profile table's identity: its JSON text, keys sorted (``json`` writes them twenty times
    faster than TOML)."""
    return json.dumps(table, sort_keys=True)


class Simulator:
    """Runs ensembles of the prepared runs for profile tables; caches each unit's score.

    Parameters
    ----------
    runs : the prepared runs; design : their units (:mod:`.design`)
    fit_seeds : seeds per seed set; jobs, dask : where jobs run; base_source : profile source
    keys : the runs' keys where :func:`share_runs` was called already (None: shared here)
    """

    def __init__(self, runs: list[Run], design: Design, fit_seeds: int, jobs: int | None,
                 dask: str | None, base_source: str, keys: list[str] | None = None) -> None:
        self.runs, self.design, self.n_seeds = runs, design, fit_seeds
        self.jobs, self.dask, self.source = jobs, dask, base_source
        self.units = design.all_units()
        # each run's held-out units (blocks or the run itself; not the whole-run fit units)
        self.run_blocks: dict[int, list[int]] = {}
        for u, unit in enumerate(design.units):
            self.run_blocks.setdefault(unit.run, []).append(u)
        self._scores: dict[tuple[str, int, int], UnitScore] = {}
        # table object -> its key: a selection looks the same tables up thousands of times
        # (the objects are held here, so an id is never reused while its key is kept)
        self._keys: dict[int, tuple[dict[str, Any], str]] = {}
        self.keys = keys if keys is not None else share_runs(runs)
        # per-sky-bin counts are only read to learn sky masks, from logs with SNR
        self.bins = any(r.view.assess.get("gsv") and r.view.assess.get("cn0") for r in runs)
        self.n_sims = 0
        self.batches: list[int] = []  # jobs per submission (for the benchmark)
        # times each (table, seed set, run) was simulated: more than once where a later request
        # asked units an earlier job did not measure
        self._simulated: dict[tuple[str, int, int], int] = {}
        self.queue = JobQueue(gap_job, jobs, dask)
        # units under way: one slot per seed group, filled as the jobs come back
        self._parts: dict[tuple[str, int, int], list[UnitPart | UnitScore | None]] = {}
        self.reference: str | None = None  # see set_reference
        self.reference_table: dict[str, Any] | None = None
        self._gaps: dict[tuple[str, int, int, str | None], tuple[float, dict[str, float]]] = {}

    def seeds(self, seed_set: int) -> tuple[int, ...]:
        """The seeds of a seed set (disjoint ranges)."""
        return tuple(range(seed_set * self.n_seeds, (seed_set + 1) * self.n_seeds))

    def request(self, items: Request) -> None:
        """Make sure every (table, seed set, units) item is scored (:meth:`submit`, then
        :meth:`collect` until :meth:`has`)."""
        items = list(items)
        self.submit(items)
        while not self.has(items):
            self.collect()

    def submit(self, items: Request) -> None:
        """Submit the jobs that score what is neither scored nor under way of (table, seed
        set, units) items: one per table, seed set and run, scoring that run's missing units.
        Per-sky-bin counts come with the fitting seeds (learned sky masks are fitted),
        per-PRN counts with the held-out seeds (the tracking disagreement)."""
        def wanted(k: tuple[str, int, int]) -> bool:  # neither scored nor under way
            return k not in self._scores and k not in self._parts

        todo: dict[tuple[str, int, int], tuple[dict[str, Any], set[int]]] = {}
        for table, seed_set, units in items:
            key = self.key(table)
            for u in units:
                if wanted((key, seed_set, u)):
                    todo.setdefault((key, seed_set, self.units[u].run), (table, set()))[1].add(u)
        if not todo:
            return
        # A fitting-seeds job scores every held-out unit of its run (not the whole run's): the
        # fold that asked a table on its training units asks the chosen point on its held-out
        # unit next, and a selection that reaches the same table later (the outer groups
        # often fit the same effect alike) asks the units the first did not hold. Each such
        # request simulated the run again; a unit more to measure costs a share of one job.
        for (key, seed_set, r), (_, us) in todo.items():
            if seed_set == FIT:
                us.update(u for u in self.run_blocks[r] if wanted((key, FIT, u)))
        # Fewer jobs than several per worker, beside what still keeps the workers busy, would
        # leave workers idle while the slowest job runs: the jobs' seeds are then split into
        # groups, a job each (no seed is simulated twice, and the scores are the same).
        workers = self.workers()
        short = MIN_JOBS_PER_WORKER * workers - self.queue.busy()
        groups = -(-short // len(todo)) if workers > 1 and len(todo) < short else 1
        tagged = []
        for (key, seed_set, r), (table, us) in todo.items():
            self._simulated[key, seed_set, r] = self._simulated.get((key, seed_set, r), 0) + 1
            order = sorted(us)
            seed_groups = split_seeds(self.seeds(seed_set), groups)
            for u in order:
                self._parts[(key, seed_set, u)] = [None] * len(seed_groups)
            for g, seeds in enumerate(seed_groups):
                job = GapJob(self.keys[r], table, self.source, seeds,
                             tuple(self.units[u].mask for u in order), prn=seed_set == HELD,
                             bins=seed_set == FIT and self.bins, whole=len(seed_groups) == 1)
                tagged.append(((key, seed_set, tuple(order), g, len(seeds)), job))
        self.batches.append(len(tagged))
        self.queue.submit(tagged)

    def collect(self) -> None:
        """Wait for at least one job and take in every finished one's results (a unit is
        scored once every seed group of it is back)."""
        for (key, seed_set, order, g, n_seeds), got in self.queue.wait():
            self.n_sims += n_seeds * self.runs[self.units[order[0]].run].setup.t_unix_s.size
            for u, one in zip(order, got, strict=True):
                k = (key, seed_set, u)
                parts = self._parts[k]
                parts[g] = one
                if all(p is not None for p in parts):
                    del self._parts[k]
                    # (a whole seed set's job scored its units where it ran; seed groups are
                    # joined in seed order)
                    self._scores[k] = one if len(parts) == 1 else unit_score(parts)

    @property
    def repeats(self) -> int:
        """Simulations of a (table, seed set, run) after its first (see :meth:`submit`)."""
        return sum(self._simulated.values()) - len(self._simulated)

    def has(self, items: Request) -> bool:
        """Whether every (table, seed set, units) item is scored."""
        return all((self.key(table), seed_set, u) in self._scores
                   for table, seed_set, units in items for u in units)

    def workers(self) -> int:
        """The workers jobs go to (local processes, or the Dask cluster's threads)."""
        return worker_count(self.jobs, self.dask)

    def key(self, table: dict[str, Any]) -> str:
        """:func:`table_key` of a table, computed once per table object."""
        hit = self._keys.get(id(table))
        if hit is not None and hit[0] is table:
            return hit[1]
        key = table_key(table)
        self._keys[id(table)] = (table, key)
        return key

    def scores(self, table: dict[str, Any], seed_set: int, units: Sequence[int]
               ) -> list[UnitScore]:
        """Some units' scores (after :meth:`request`)."""
        key = self.key(table)
        return [self._scores[(key, seed_set, u)] for u in units]

    def set_reference(self, table: dict[str, Any] | None) -> None:
        """The profile under test, whose held-out seeds' judgments guard every table's score
        of the same unit (:func:`virtualgps.gap.bands.distance_against`); None: each table
        in its own seeds' spread alone. Its held-out scores must be requested before any
        other table's gap of those units is read."""
        self.reference = None if table is None else self.key(table)
        self.reference_table = table

    def reference_scores(self, seed_set: int, units: Sequence[int]) -> list[UnitScore] | None:
        """The reference's scores of some units with a seed set (after :meth:`request` of
        (:attr:`reference_table`, seed set, units)); None without a reference."""
        return None if self.reference_table is None else self.scores(
            self.reference_table, seed_set, units)

    def _unit_gap(self, key: str, seed_set: int, u: int) -> tuple[float, dict[str, float]]:
        k = (key, seed_set, u, self.reference)
        hit = self._gaps.get(k)
        if hit is None:
            score = self._scores[(key, seed_set, u)]
            if self.reference is None:
                hit = score.own
            else:
                ref = self._scores.get((self.reference, HELD, u))
                if ref is None:
                    raise RuntimeError(f"unit {u}: the reference's held-out scores were not "
                                       "requested before a gap was read")
                hit = gap_score(score.judged, ref.judged)
            self._gaps[k] = hit
        return hit

    def gap(self, table: dict[str, Any], seed_set: int, units: Sequence[int]) -> float:
        """Mean gap over some units (NaN where none is assessed)."""
        key = self.key(table)
        g = [self._unit_gap(key, seed_set, u)[0] for u in units]
        g = [x for x in g if math.isfinite(x)]
        # (plain Python on these short lists: numpy's per-call cost was a tenth of a
        # diagnosis's serial time, some 40,000 means)
        return _mean(g) if g else float("nan")

    def parts(self, table: dict[str, Any], seed_set: int, units: Sequence[int]
              ) -> dict[str, float]:
        """Mean distance per metric over the units that assess it."""
        key = self.key(table)
        return mean_per_metric([self._unit_gap(key, seed_set, u)[1] for u in units])

    def moved_parts(self, table: dict[str, Any], before: dict[str, Any], seed_set: int,
                    units: Sequence[int]) -> dict[str, float]:
        """Mean per-metric distance over the units that assess it, for judging what ``table``
        worsens against ``before`` (the model it adds to): a metric whose seeds scatter less
        than the model before's counts its centre's move, not the narrower spread
        (:func:`virtualgps.gap.where.moved_parts`)."""
        per = []
        for u in units:
            ref = (self._scores.get((self.reference, HELD, u)) if self.reference is not None
                   else None)
            per.append(moved_parts(self.scores(table, seed_set, [u])[0].judged,
                                   self.scores(before, seed_set, [u])[0].judged,
                                   ref.judged if ref is not None else None))
        return mean_per_metric(per)

    def sky_bins(self, table: dict[str, Any], seed_set: int, units: Sequence[int]
                 ) -> np.ndarray:
        """(5, n_bins) tracking counts and SNR sums per sky bin, summed over units."""
        return np.sum([s.bins for s in self.scores(table, seed_set, units)], axis=0)

    def prn_counts(self, table: dict[str, Any], seed_set: int, units: Sequence[int]
                   ) -> list[np.ndarray]:
        """Per-PRN tracking counts of some units."""
        return [s.prn for s in self.scores(table, seed_set, units)]


def ensembles(runs: list[Run], table: dict[str, Any], seeds: Sequence[int], jobs: int | None,
              dask: str | None, source: str) -> tuple[dict[int, Ensemble], int]:
    """Simulate every run with a profile table for some seeds, whole outputs (each run's seeds
    split into jobs so that a batch holds several jobs per worker).

    Returns {run index: Ensemble} and the simulated epochs
    """
    prof = fx.build(table, source)
    n_jobs = worker_count(jobs, dask)
    per_run = max(1, (4 * n_jobs) // max(1, len(runs)))
    items, owner = [], []
    for i, r in enumerate(runs):
        for part in split_seeds(tuple(seeds), per_run):
            items.append(EnsembleJob(r.setup, prof, part))
            owner.append(i)
    res = map_jobs(simulate_job, items, jobs=jobs, dask_address=dask)
    out: dict[int, list[Ensemble]] = {}
    for i, e in zip(owner, res, strict=True):
        out.setdefault(i, []).append(e)
    n = sum(len(j.seeds) * j.setup.t_unix_s.size for j in items)
    return {i: Ensemble.concat(v) for i, v in out.items()}, n
