"""The sim-to-real diagnosis (DESIGN section 7): where the gap lies, which effect causes it, how
far it shrinks on held-out data.

1. Every real run is re-simulated along its truth, at its real epochs, from its own power-on,
   as an ensemble of seeds (:mod:`.ensemble`); its statistics per segment against the
   ensemble's band locate the gap (:mod:`.where`).
2. Units of data are held out in turn: each run (several runs), or each of ``blocks``
   contiguous time blocks (one run). For every candidate effect (:mod:`.effects`) and every
   grid point of its parameters the runs are simulated with the same seeds (common random
   numbers); the gap of each unit is computed once, and for each fold the parameters are the
   grid point with the smallest gap on the other units; the fold's held-out gap is that point's
   gap on the held-out unit. Never the data it was fitted on.
3. Effects are added greedily, best held-out reduction first, while they reduce the held-out gap
   clearly; each added effect keeps its per-fold parameters, so later candidates are judged on
   top of them. Each accepted effect's order-independent contribution is its leave-one-out
   increase of the held-out gap. The calibrated profile takes the parameters fitted on all units.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps import geodesy
from virtualgps.gap import effects as fx
from virtualgps.gap.ensemble import (
    Ensemble,
    EnsembleJob,
    Geometry,
    RunSetup,
    geometry_job,
    setup_digest,
    simulate_job,
    split_seeds,
)
from virtualgps.gap.jobs import map_jobs
from virtualgps.gap.where import (
    SCORE,
    SKY_BIN_AZ_DEG,
    SKY_BIN_EL_DEG,
    Obs,
    RunView,
    bin_tracking,
    errors_enu,
    gap_score,
    pooled_tracking_disagreement,
    position_quantum_min,
    prn_tracking,
    quantize,
    segment_stats,
    segments,
    sky_sectors,
    where_rows,
)
from virtualgps.profiles import Profile
from virtualgps.receiver import Georef

MIN_REDUCTION_ABS = 0.01  # an effect is added when it lowers the held-out gap by more than
MIN_REDUCTION_REL = 0.05  # this, and by more than this share of the gap before it
FLAT_OBJECTIVE = 5e-3  # training gaps this close: the data cannot tell the grid points apart
SCENE_REACH_M = 5000.0
RETRY_BEST = 4  # candidates carried into the next round of the greedy search


@dataclass(frozen=True)
class Options:
    """How a diagnosis runs.

    seeds : ensemble size for locating the gap and the final band
    fit_seeds : seeds per grid point while fitting (common random numbers); default
        min(seeds, 8)
    effects : candidate effect names (None: every one the profile lacks)
    jobs : local worker processes (None: all cores); dask : a Dask scheduler address
    blocks : held-out time blocks for a single run
    """

    seeds: int = 50
    fit_seeds: int | None = None
    effects: tuple[str, ...] | None = None
    jobs: int | None = None
    dask: str | None = None
    blocks: int = 4

    @property
    def n_fit(self) -> int:
        return self.fit_seeds if self.fit_seeds is not None else min(self.seeds, 8)


@dataclass
class Run:
    """A run as the diagnosis holds it: its setup, its aligned real view, ingest facts."""

    setup: RunSetup
    view: RunView
    err_real: np.ndarray  # (1, n, 3)
    info: dict = field(default_factory=dict)


# --- preparing the runs -----------------------------------------------------------------------


def _real_obs(epochs, prn: np.ndarray) -> Obs:
    """The real log's epochs as an :class:`Obs` over the simulator's PRN columns."""
    n, k = len(epochs), prn.size
    col = {int(p): j for j, p in enumerate(epochs.prn)}
    tracked = np.zeros((n, k), bool)
    cn0 = np.full((n, k), np.nan)
    used = np.zeros((n, k), bool)
    for j, p in enumerate(prn):
        c = col.get(int(p))
        if c is not None:
            cn0[:, j] = epochs.cn0_dbhz[:, c]
            tracked[:, j] = np.isfinite(epochs.cn0_dbhz[:, c])
            used[:, j] = epochs.used[:, c]
    sep = np.where(np.isfinite(epochs.geoid_sep_m), epochs.geoid_sep_m,
                   geodesy.geoid_sep_m(np.nan_to_num(epochs.lat_deg),
                                       np.nan_to_num(epochs.lon_deg)))
    sats = np.where(epochs.sats_used >= 0, epochs.sats_used, np.nan).astype(float)
    return Obs(
        lat_deg=epochs.lat_deg[None], lon_deg=epochs.lon_deg[None],
        alt_hae_m=(epochs.alt_msl_m + sep)[None], quality=epochs.quality[None].astype(np.int16),
        hdop=epochs.hdop[None], sats_used=sats[None], speed_mps=epochs.speed_mps[None],
        tracked=tracked[None], cn0_dbhz=cn0[None], used=used[None],
    )


def sim_obs(ens: Ensemble, view: RunView | None = None) -> Obs:
    """An ensemble as an :class:`Obs` (positions rounded like the run's real log)."""
    obs = Obs(
        lat_deg=ens.lat_deg, lon_deg=ens.lon_deg, alt_hae_m=ens.alt_hae_m,
        quality=ens.quality.astype(np.int16), hdop=ens.hdop.astype(float),
        sats_used=ens.used.sum(axis=2).astype(float), speed_mps=ens.speed_mps.astype(float),
        tracked=np.isfinite(ens.cn0_dbhz), cn0_dbhz=ens.cn0_dbhz.astype(float), used=ens.used,
    )
    return obs if view is None else quantize(obs, view.quantum_min)


def prepare_runs(
    runs: Sequence[Any],
    scene: Any,
    scene_path: str | None,
    tle_path: str,
    profile: Profile,
    sky_shift: Callable[[float], float],
    opts: Options,
) -> list[Run]:
    """Align each real run with the simulator: its setup (truth in a scene frame, power-on),
    the sky geometry along it, and the real log over the simulator's satellites.

    Parameters
    ----------
    runs : :class:`virtualgps.gap.ingest.RealRun` values
    scene : the loaded scene (None: open sky); scene_path : its folder
    tle_path : the TLE set; profile : the profile under test (its elevation mask sets which
        satellites are compared)
    sky_shift : run start (UTC s) -> the sky-time shift to use (0: the true sky)
    opts : the options (jobs for the geometry)

    Returns
    -------
    runs : the prepared runs, in input order
    """
    from virtualgps.gap.ingest import truth_positions

    setups, pre = [], []
    for run in runs:
        ep = run.epochs
        t = np.asarray(ep.t_unix_s, dtype=float)
        georef = None
        if scene is not None:
            georef = Georef(scene.lat_deg, scene.lon_deg, scene.alt_hae_m)
        lat, lon, alt, valid = truth_positions(run, t, georef)
        lat, lon, alt = (np.where(valid, x, np.nan) for x in (lat, lon, alt))
        if not valid.any():
            from virtualgps.exceptions import InputFileError

            raise InputFileError(run.path, "no epoch of this log matches its truth in time "
                                 f"(log {t[0]:.0f}-{t[-1]:.0f} UTC s); check the truth file, "
                                 "its time zone and its clock")
        where_scene = scene_path
        if georef is not None:
            enu = geodesy.ecef_to_enu(
                geodesy.geodetic_to_ecef(lat[valid], lon[valid], alt[valid]),
                georef.lat0_deg, georef.lon0_deg, georef.alt0_hae_m)
            if np.nanmax(np.hypot(enu[:, 0], enu[:, 1])) > SCENE_REACH_M:
                georef, where_scene = None, None
        if georef is None:
            k = np.flatnonzero(valid)[0]
            georef = Georef(float(lat[k]), float(lon[k]), float(alt[k]))
        ant = np.zeros((t.size, 3))
        ant[valid] = geodesy.ecef_to_enu(geodesy.geodetic_to_ecef(lat[valid], lon[valid],
                                                                  alt[valid]),
                                         georef.lat0_deg, georef.lon0_deg, georef.alt0_hae_m)
        vel = np.zeros((t.size, 3))
        if valid.sum() > 1:
            k = np.flatnonzero(valid)
            for a in range(3):
                vel[k, a] = np.gradient(ant[k, a], t[k])
            vel[k[1:][np.diff(t[k]) > 5.0]] = 0.0  # (across a gap in the truth: unknown)
        started = not (ep.quality[0] > 0 and np.isfinite(ep.lat_deg[0]))
        t_sim, shift = snap_epochs(t), sky_shift(float(t[0]))
        setups.append(RunSetup(
            key=run.name, t_unix_s=t_sim, antenna_enu_m=ant, vel_enu_mps=vel, valid=valid,
            power_on_unix_s=float(t[0]) if started else math.nan, georef=georef,
            scene_path=where_scene, tle_path=tle_path, sky_shift_s=shift,
            digest=setup_digest(t_sim, ant, valid, georef, where_scene, tle_path, shift)))
        pre.append((run, lat, lon, alt))
    geoms: list[Geometry] = map_jobs(geometry_job, setups, jobs=opts.jobs, dask_address=opts.dask)
    out = []
    mask = profile.sky.elevation_mask_deg
    for setup, geom, (run, lat, lon, alt) in zip(setups, geoms, pre, strict=True):
        ep = run.epochs
        real = _real_obs(ep, geom.prn)
        el = geom.el_deg.astype(float)
        listed = ep.in_view.any(axis=1) | (ep.sats_in_view >= 0)
        with np.errstate(invalid="ignore"):
            above = el >= mask
        sat_ok = above & listed[:, None] & setup.valid[:, None]
        silent = _silent_prns(real.tracked[0], el, sat_ok) if run.has_cn0 else np.zeros(
            geom.prn.size, bool)
        sat_ok &= ~silent[None, :]
        reference = "median" if run.truth.kind == "static" else "truth"
        view = RunView(
            name=run.name, t_unix_s=setup.t_unix_s, power_on_unix_s=float(setup.t_unix_s[0]),
            started=bool(np.isfinite(setup.power_on_unix_s)),
            truth_lat_deg=lat, truth_lon_deg=lon, truth_alt_hae_m=alt, reference=reference,
            vel_enu_mps=setup.vel_enu_mps, near_building=(geom.crosses_building & above).any(1),
            prn=geom.prn, az_deg=geom.az_deg.astype(float), el_deg=el, sat_ok=sat_ok,
            assess={"gsv": bool(run.has_gsv), "cn0": bool(run.has_cn0),
                    "gsa": bool(run.has_gsa)},
            real=real, quantum_min=position_quantum_min(ep.lat_deg, ep.lon_deg),
        )
        out.append(Run(setup, view, errors_enu(view, real), {
            "skipped": dict(run.skipped), "sentences": dict(run.sentences),
            "time_offset_s": run.time_offset_s, "offset": dict(run.offset_info),
            "simulated_in": "scene" if setup.scene_path else "open sky",
            "silent_prns": [int(p) for p in geom.prn[silent]],
        }))
    return out


# A satellite the real receiver never tracks in a whole run, though it rose this high above the
# antenna, is taken as not transmitting (unhealthy, or retired while the TLE set still lists it:
# the MT3339 hour lists PRN 8 at 60-90 deg for an hour with no SNR), not as blocked: it is left
# out of the tracking comparisons, where it would teach a sky mask to block its path.
SILENT_MIN_EL_DEG = 45.0


def _silent_prns(real_tracked: np.ndarray, el_deg: np.ndarray, sat_ok: np.ndarray
                 ) -> np.ndarray:
    """(k,) bool: PRNs compared at an elevation of SILENT_MIN_EL_DEG or more and never tracked
    in the run. real_tracked, el_deg, sat_ok : (n, k)."""
    with np.errstate(invalid="ignore"):
        high = (sat_ok & (el_deg >= SILENT_MIN_EL_DEG)).any(axis=0)
    return high & ~(real_tracked & sat_ok).any(axis=0)


def snap_epochs(t_unix_s: np.ndarray) -> np.ndarray:
    """Epoch times on whole multiples of the log's period where they lie within a quarter
    period of one (real receivers' time tags jitter by milliseconds; on the grid the
    receiver's Gauss-Markov recursions take equal steps), else unchanged.

    t_unix_s : (n,) float, UTC seconds, increasing; returns (n,) float
    """
    t = np.asarray(t_unix_s, dtype=float)
    if t.size < 2:
        return t
    period = float(np.median(np.diff(t)))
    if not period > 0:
        return t
    rate = 1.0 / period
    k = np.rint(t * rate)
    near = np.abs(t - k / rate) <= 0.25 * period
    return np.where(near, k / rate, t)


# --- simulating ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class GapJob:
    """Simulate one run with one profile for the fit seeds, and measure the gap of each of the
    run's held-out units (done where the job runs: only the gaps come back)."""

    job: EnsembleJob
    view: RunView
    err_real: np.ndarray
    units: tuple[np.ndarray, ...]


def gap_job(j: GapJob) -> list[tuple[float, dict[str, float], np.ndarray, np.ndarray]]:
    """The gap of each unit, its distances per metric, and its tracking counts per PRN and per
    sky bin (see :class:`GapJob`)."""
    sims = sim_obs(simulate_job(j.job), j.view)
    err = errors_enu(j.view, sims)
    return [gap_score(segment_stats(j.view, sims, j.err_real, err, m, metrics=SCORE))
            + (prn_tracking(j.view, sims, m), bin_tracking(j.view, sims, m)) for m in j.units]


class Simulator:
    """Runs ensembles of the prepared runs for profile tables, with a cache of unit gaps."""

    def __init__(self, runs: list[Run], opts: Options, base_source: str) -> None:
        self.runs, self.opts, self.source = runs, opts, base_source
        self.n_sims = 0
        self._gaps: dict[tuple[str, int], float] = {}
        self._parts: dict[tuple[str, int], dict[str, float]] = {}
        self._prn: dict[tuple[str, int], np.ndarray] = {}
        self._bins: dict[tuple[str, int], np.ndarray] = {}
        self.units = self._units()
        self.n_folds = len(self.runs) if len(self.runs) > 1 else self.opts.blocks
        # The units the calibrated profile is fitted on: whole runs (a single run's blocks
        # would bias its slow statistics, e.g. the error's correlation time, low).
        self.whole = np.array([len(self.runs) > 1 or u == self.n_folds
                               for u in range(len(self.units))])

    def _units(self) -> list[tuple[int, np.ndarray, str]]:
        """Held-out units, (run index, epoch mask, description): each run; or, for a single
        run, its time blocks followed by the whole run (fitted on, never held out)."""
        if len(self.runs) > 1:
            return [(i, np.ones(r.view.t_unix_s.size, bool), f"run {r.view.name}")
                    for i, r in enumerate(self.runs)]
        t = self.runs[0].view.t_unix_s
        edges = np.linspace(t[0], t[-1], self.opts.blocks + 1)
        out = []
        for b in range(self.opts.blocks):
            m = (t >= edges[b]) & ((t < edges[b + 1]) if b < self.opts.blocks - 1 else True)
            out.append((0, m, f"time block {b + 1}/{self.opts.blocks} "
                        f"({edges[b] - t[0]:.0f}-{edges[b + 1] - t[0]:.0f} s)"))
        return out + [(0, np.ones(t.size, bool), "the whole run")]

    def ensembles(self, table: dict[str, Any], seeds: Sequence[int],
                  runs: Sequence[int] | None = None) -> dict[int, Ensemble]:
        """Simulate runs (all, or the given indices) with a profile table."""
        prof = fx.build(table, self.source)
        idx = list(range(len(self.runs))) if runs is None else list(runs)
        n_jobs = self.opts.jobs or _cores()
        per_run = max(1, n_jobs // max(1, len(idx))) if len(idx) < n_jobs else 1
        jobs, owner = [], []
        for i in idx:
            for part in split_seeds(tuple(seeds), per_run):
                jobs.append(EnsembleJob(self.runs[i].setup, prof, part))
                owner.append(i)
        res = map_jobs(simulate_job, jobs, jobs=self.opts.jobs, dask_address=self.opts.dask)
        self.n_sims += sum(len(j.seeds) * j.setup.t_unix_s.size for j in jobs)
        out: dict[int, list[Ensemble]] = {}
        for i, e in zip(owner, res, strict=True):
            out.setdefault(i, []).append(e)
        return {i: Ensemble.concat(v) for i, v in out.items()}

    def unit_gaps_many(self, tables: Sequence[dict[str, Any]],
                       only_units: Sequence[int] | None = None) -> list[np.ndarray]:
        """(U,) gap of each unit under each profile table (fit seeds; cached; the missing
        (table, run) pairs simulated in one batch of jobs). ``only_units`` defaults to the
        held-out units; units not asked for and not cached are NaN."""
        want = list(range(self.n_folds)) if only_units is None else list(only_units)
        keys = [fx.to_toml(t) for t in tables]
        jobs, todo = [], []
        seeds = tuple(range(self.opts.n_fit))
        for key, table in dict(zip(keys, tables, strict=True)).items():
            missing = [u for u in want if (key, u) not in self._gaps]
            prof = fx.build(table, self.source) if missing else None
            for r in sorted({self.units[u][0] for u in missing}):
                us = [u for u in missing if self.units[u][0] == r]
                run = self.runs[r]
                jobs.append(GapJob(EnsembleJob(run.setup, prof, seeds), run.view,
                                   run.err_real, tuple(self.units[u][1] for u in us)))
                todo.append((key, us))
        if jobs:
            res = map_jobs(gap_job, jobs, jobs=self.opts.jobs, dask_address=self.opts.dask)
            for (key, us), gaps, j in zip(todo, res, jobs, strict=True):
                self.n_sims += len(seeds) * j.job.setup.t_unix_s.size
                for u, (g, parts, prn, bins) in zip(us, gaps, strict=True):
                    self._gaps[(key, u)] = float(g)
                    self._parts[(key, u)] = parts
                    self._prn[(key, u)] = prn
                    self._bins[(key, u)] = bins
        return [np.array([self._gaps.get((k, u), np.nan) for u in range(len(self.units))])
                for k in keys]

    def parts(self, table: dict[str, Any], unit: int) -> dict[str, float]:
        """Distances per metric of a unit under a table (after :meth:`unit_gaps_many`)."""
        return self._parts.get((fx.to_toml(table), unit), {})

    def sky_bins(self, table: dict[str, Any], units: Sequence[int]) -> np.ndarray:
        """(5, n_bins) tracking counts and SNR sums per sky bin summed over units under a table."""
        self.unit_gaps(table, list(units))
        key = fx.to_toml(table)
        return np.sum([self._bins[(key, u)] for u in units], axis=0)

    def heldout_tracking(self, fold_tables: Sequence[dict[str, Any]]) -> float:
        """Per-PRN tracking disagreement over the held-out units, each under its fold's
        profile (pooled; see :func:`virtualgps.gap.where.pooled_tracking_disagreement`)."""
        for f, t in enumerate(fold_tables):
            self.unit_gaps(t, [f])
        return pooled_tracking_disagreement(
            [self._prn[(fx.to_toml(t), f)] for f, t in enumerate(fold_tables)])

    def unit_gaps(self, table: dict[str, Any], only_units: Sequence[int] | None = None
                  ) -> np.ndarray:
        """(U,) gap of each held-out unit under one profile table."""
        return self.unit_gaps_many([table], only_units)[0]


def _cores() -> int:
    import os

    return os.cpu_count() or 1


# --- fitting -------------------------------------------------------------------------------------


@dataclass
class Tried:
    """One candidate tried on top of the current per-fold profiles."""

    cand: fx.Candidate
    fold_overrides: list[dict]  # the tables fitted for each fold
    heldout_before: np.ndarray  # (U,) held-out gaps without it
    heldout_after: np.ndarray  # (U,) with it
    metrics_before: dict[str, float]  # held-out distance per metric without it (mean of folds)
    metrics_after: dict[str, float]  # with it

    @property
    def before(self) -> float:
        return float(np.nanmean(self.heldout_before))

    @property
    def after(self) -> float:
        return float(np.nanmean(self.heldout_after))


def _fit_point(gaps: np.ndarray, train: np.ndarray, default: int) -> int:
    """The grid point with the smallest mean training gap; the default unless the training
    data favour another point by FLAT_OBJECTIVE or more (no evidence keeps the prior).

    gaps : (n_points, U); train : (U,) bool
    """
    with np.errstate(invalid="ignore"):
        j = np.nanmean(np.where(train[None, :], gaps, np.nan), axis=1) if train.any() else None
    if j is None or not np.isfinite(j).any():
        return default
    best = int(np.nanargmin(j))
    if not np.isfinite(j[default]) or j[default] - j[best] >= FLAT_OBJECTIVE:
        return best
    return default


def _options(sim: Simulator, table: dict, cand: fx.Candidate, train: Sequence[int]
             ) -> tuple[list[dict], int]:
    """A candidate's override tables on top of ``table``, and the default's index: its grid,
    or for a learned sky mask the masks learned from the training units at each level."""
    if not cand.learned:
        return list(cand.grid), cand.default
    counts = sim.sky_bins(table, train)
    masks = [fx.learned_sky_mask(counts, lv, SKY_BIN_AZ_DEG, SKY_BIN_EL_DEG, cand.learned_atten)
             for lv in cand.learned]
    masks = [m for m in masks if m is not None]
    return (masks, len(masks) // 2) if masks else ([{}], 0)


def try_candidate(sim: Simulator, fold_tables: list[dict], cand: fx.Candidate) -> Tried:
    """Held-out gap of adding ``cand`` to each fold's profile (see the module docstring)."""
    n_u = sim.n_folds
    all_units = np.arange(len(sim.units))
    options = []
    for f in range(n_u):
        train = all_units[(all_units < n_u) & (all_units != f)]
        options.append(_options(sim, fold_tables[f], cand, train))
    tables = [fx.apply(fold_tables[f], o) for f in range(n_u) for o in options[f][0]]
    flat = iter(sim.unit_gaps_many(tables + fold_tables))
    chosen, after, before = [], np.full(n_u, np.nan), np.full(n_u, np.nan)
    parts_before, parts_after = [], []
    for f in range(n_u):
        gaps = np.stack([next(flat) for _ in options[f][0]])
        train = (all_units < n_u) & (all_units != f)
        p = _fit_point(gaps, train, options[f][1])
        chosen.append(options[f][0][p])
        after[f] = gaps[p, f]
        before[f] = sim.unit_gaps(fold_tables[f])[f]
        parts_before.append(sim.parts(fold_tables[f], f))
        parts_after.append(sim.parts(fx.apply(fold_tables[f], chosen[-1]), f))
    return Tried(cand, chosen, before, after, _mean_parts(parts_before), _mean_parts(parts_after))


def _mean_parts(parts: list[dict[str, float]]) -> dict[str, float]:
    """Mean distance per metric over the folds that assess it."""
    names = sorted({m for p in parts for m in p})
    return {m: float(np.mean([p[m] for p in parts if m in p])) for m in names}


def fit_all(sim: Simulator, table: dict, cand: fx.Candidate) -> dict:
    """The override table fitted on every run (for the calibrated profile)."""
    whole = list(np.flatnonzero(sim.whole))
    opts, default = _options(sim, table, cand, whole)
    gaps = np.stack(sim.unit_gaps_many([fx.apply(table, o) for o in opts], whole))
    return opts[_fit_point(gaps, sim.whole, default)]


@dataclass
class Diagnosis:
    """What :func:`greedy` found."""

    steps: list[dict]  # accepted effects, in the order added
    ranking: list[dict]  # every candidate of the first round, best held-out gap first
    skipped: dict[str, str]
    gap_baseline: float
    gap_final: float
    final_table: dict
    fold_tables: list[dict]
    tracking: dict


def greedy(sim: Simulator, base: dict, opts: Options, has_mesh: bool,
           progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Rank the candidate effects by held-out gap reduction and add them greedily."""
    n_u = sim.n_folds
    fold_tables = [base] * n_u
    all_table = base
    has_gsv = any(r.view.assess["gsv"] and r.view.assess["cn0"] for r in sim.runs)
    cands, skipped = fx.candidates(base, has_mesh, opts.effects, has_gsv)
    baseline = float(np.nanmean([sim.unit_gaps(base)[f] for f in range(n_u)]))
    steps: list[dict] = []
    ranking: list[dict] = []
    current = baseline
    round_no = 0
    while cands:
        round_no += 1
        tried = []
        for c in cands:
            tried.append(try_candidate(sim, fold_tables, c))
            if progress:
                progress(f"round {round_no}: {c.name} held-out gap {tried[-1].after:.3f}")
        tried.sort(key=lambda tr: tr.after if math.isfinite(tr.after) else math.inf)
        if round_no == 1:
            ranking = [_entry(tr, sim, None) for tr in tried]
        # The best clear improvement whose fit on every run changes the profile (one that
        # the whole data fits at the profile's own value would leave the calibrated profile
        # as it is: its held-out gain was the folds' luck).
        best, fitted = None, {}
        for tr in tried:
            if not accept(tr, current):
                continue
            fitted = fit_all(sim, all_table, tr.cand)
            if fx.apply(all_table, fitted) != all_table:
                best = tr
                break
        if best is None:
            break
        all_table = fx.apply(all_table, fitted)
        fold_tables = [fx.apply(t, o)
                       for t, o in zip(fold_tables, best.fold_overrides, strict=True)]
        steps.append(_entry(best, sim, fitted) | {"gap_before": current})
        current = best.after
        # Later rounds try the most promising candidates of this one (each round re-fits
        # them on top of the effects added so far; an effect far behind stays behind).
        cands = [tr.cand for tr in tried if tr is not best][:RETRY_BEST]
        # a newly applicable effect (e.g. multipath once dop_error is in)
        more, _ = fx.candidates(all_table, has_mesh, opts.effects, has_gsv)
        known = {c.name for c in cands} | {s["name"] for s in steps}
        cands += [c for c in more if c.name not in known]
    _contributions(sim, base, steps, fold_tables)
    before = sim.heldout_tracking([base] * n_u)
    after = sim.heldout_tracking(fold_tables)
    tracking = {"baseline": before, "final": after,
                "shrink": 1.0 - after / before if before > 0 else float("nan")}
    return Diagnosis(steps, ranking, skipped, baseline, current, all_table, fold_tables,
                     tracking)


def accept(tr: Tried, current: float) -> bool:
    """Whether a candidate clearly lowers the held-out gap: on average by more than
    MIN_REDUCTION_ABS and MIN_REDUCTION_REL of it, and in most of the held-out units it changes
    at all (a start-up shows in one unit only; an effect that moves every unit must help most
    of them, or its gain is as likely the seeds' luck)."""
    gain = current - tr.after
    per_unit = tr.heldout_before - tr.heldout_after
    changed = np.isfinite(per_unit) & (np.abs(per_unit) > FLAT_OBJECTIVE)
    most = changed.any() and np.sum(per_unit[changed] > 0) > 0.5 * changed.sum()
    return bool(gain > MIN_REDUCTION_ABS and gain > MIN_REDUCTION_REL * current and most)


def _entry(tr: Tried, sim: Simulator, fitted: dict | None) -> dict:
    """A report entry for a tried candidate."""
    c = tr.cand
    folds = [c.params_of(o) for o in tr.fold_overrides]
    return {
        "name": c.name,
        "params": c.params_of(fitted if fitted is not None else tr.fold_overrides[0]),
        "gap_before": tr.before,
        "gap_after": tr.after,
        "gap_after_spread": _spread(tr.heldout_after),
        "heldout": "; ".join(u[2] for u in sim.units[:sim.n_folds]),
        "heldout_scheme": "leave one run out" if len(sim.runs) > 1 else "leave one time block "
                          "out",
        "fold_params": folds,
        "metrics_before": tr.metrics_before,
        "metrics_after": tr.metrics_after,
        "_overrides": list(tr.fold_overrides),
    }


def _spread(x: np.ndarray) -> list[float]:
    v = x[np.isfinite(x)]
    return [float(v.min()), float(v.max())] if v.size else [math.nan, math.nan]


def _contributions(sim: Simulator, base: dict, steps: list[dict], fold_tables: list[dict]
                   ) -> None:
    """Each accepted effect's leave-one-out contribution to the held-out gap: the held-out
    gap with every accepted effect but it (their per-fold parameters) minus the gap with all."""
    if len(steps) < 2:
        for s in steps:
            s["contribution"] = s["gap_before"] - s["gap_after"]
        return
    n_u = sim.n_folds
    held = np.full((len(steps), n_u), np.nan)
    full = np.full(n_u, np.nan)
    for f in range(n_u):
        tables = []
        for s in steps:
            t = base
            for other in steps:
                if other is not s:
                    t = fx.apply(t, other["_overrides"][f])
            tables.append(t)
        gaps = sim.unit_gaps_many(tables + [fold_tables[f]], [f])
        held[:, f] = [g[f] for g in gaps[:-1]]
        full[f] = gaps[-1][f]
    for s, h in zip(steps, held, strict=True):
        s["contribution"] = float(np.nanmean(h) - np.nanmean(full))


# --- where --------------------------------------------------------------------------------------


def pooled(runs: list[Run], sims: list[Obs], errs: list[np.ndarray]
           ) -> tuple[RunView, Obs, np.ndarray, np.ndarray]:
    """All runs as one: epochs concatenated, each run moved in time to follow the previous one
    after a 10 s gap (no change or correlation is counted across runs)."""
    if len(runs) == 1:
        return runs[0].view, sims[0], runs[0].err_real, errs[0]
    views = [r.view for r in runs]
    t_parts, shift = [], 0.0
    for v in views:
        t_parts.append(v.t_unix_s - v.t_unix_s[0] + shift)
        shift = t_parts[-1][-1] + 10.0
    cat = np.concatenate

    def obs(parts: list[Obs]) -> Obs:
        return Obs(**{f: cat([getattr(p, f) for p in parts], axis=1)
                      for f in Obs.__dataclass_fields__})

    v0 = views[0]
    view = replace(
        v0, name="all runs", t_unix_s=cat(t_parts), power_on_unix_s=t_parts[0][0]
        - (v0.t_unix_s[0] - v0.power_on_unix_s),
        truth_lat_deg=cat([v.truth_lat_deg for v in views]),
        truth_lon_deg=cat([v.truth_lon_deg for v in views]),
        truth_alt_hae_m=cat([v.truth_alt_hae_m for v in views]),
        vel_enu_mps=cat([v.vel_enu_mps for v in views]),
        near_building=cat([v.near_building for v in views]),
        az_deg=cat([v.az_deg for v in views]), el_deg=cat([v.el_deg for v in views]),
        sat_ok=cat([v.sat_ok for v in views]),
        assess={k: any(v.assess[k] for v in views) for k in v0.assess},
        real=obs([v.real for v in views]),
    )
    return (view, obs(sims), cat([r.err_real for r in runs], axis=1), cat(errs, axis=1))


def where_table(runs: list[Run], ens: dict[int, Ensemble]) -> tuple[list[dict], dict]:
    """The located gaps of every segment (pooled over runs, and per run).

    Returns
    -------
    rows : the report's ``where`` entries
    pooled_parts : {"view", "sims", "err_real", "err_sim"} of the pooled runs (for figures)
    """
    sims = [sim_obs(ens[i], r.view) for i, r in enumerate(runs)]
    errs = [errors_enu(r.view, s) for r, s in zip(runs, sims, strict=True)]
    view, sim, er, es = pooled(runs, sims, errs)
    rows: list[dict] = []
    for name, m in segments(view).items():
        rows += where_rows(segment_stats(view, sim, er, es, m), name)
    sat_metrics = ("tracked_agreement", "tracked_share", "cn0_median_dbhz")
    allep = np.ones(view.t_unix_s.size, bool)
    for name, m in sky_sectors(view).items():
        rows += where_rows(segment_stats(view, sim, er, es, allep, m, sat_metrics), name)
    for j, p in enumerate(view.prn):
        m = np.zeros_like(view.sat_ok)
        m[:, j] = view.sat_ok[:, j]
        if m.any():
            rows += where_rows(segment_stats(view, sim, er, es, allep, m, sat_metrics),
                               f"prn:{int(p)}")
    if len(runs) > 1:
        for r, s, e in zip(runs, sims, errs, strict=True):
            ones = np.ones(r.view.t_unix_s.size, bool)
            rows += where_rows(segment_stats(r.view, s, r.err_real, e, ones),
                               f"run:{r.view.name}")
    return rows, {"view": view, "sims": sim, "err_real": er, "err_sim": es}


def not_assessed(runs: list[Run]) -> list[dict]:
    """The metrics the real logs cannot support, with the reason."""
    out = []
    if not any(r.view.assess["gsv"] for r in runs):
        for m in ("tracked_agreement", "tracked_share", "cn0_median_dbhz"):
            out.append({"metric": m, "reason": "no GSV sentence (satellites in view) in the "
                        "real logs"})
    elif not any(r.view.assess["cn0"] for r in runs):
        for m in ("tracked_agreement", "tracked_share", "cn0_median_dbhz"):
            out.append({"metric": m, "reason": "the real logs' GSV carry no SNR"})
    if not any(r.view.assess["gsa"] for r in runs):
        out.append({"metric": "used_el_p05_deg", "reason": "no GSA sentence (satellites used) "
                    "in the real logs"})
    if not np.isfinite(np.concatenate([r.view.real.sats_used[0] for r in runs])).any():
        for m in ("sats_used_mean", "used_changes_per_min"):
            out.append({"metric": m, "reason": "the real logs give no count of satellites "
                        "used (GGA field empty, no GSA)"})
    if all(r.view.reference == "median" for r in runs):
        out.append({"metric": "bias_m", "reason": "static truth at an unknown point: errors are "
                    "taken about the run's median fix"})
    if all(np.all(r.view.speed_mps < 0.3) for r in runs):
        out.append({"metric": "lag_s", "reason": "the truth never moves"})
    if not any(np.isfinite(r.view.real.hdop).any() for r in runs):
        out.append({"metric": "hdop_median", "reason": "no HDOP in the real logs"})
    return out


def unexplained(where_final: list[dict]) -> list[dict]:
    """What stays outside the band with the calibrated profile (segment ``all`` and per run)."""
    keep = [w for w in where_final if w["outside"] and (
        w["segment"] in ("all", "steady", "startup", "moving", "stationary", "near_buildings",
                         "open") or w["segment"].startswith("run:"))]
    return [{"metric": w["metric"], "segment": w["segment"], "real": w["real"],
             "sim_lo": w["sim_lo"], "sim_hi": w["sim_hi"]} for w in keep]


def public(entry: dict) -> dict:
    """An effect entry without its private fields."""
    return {k: v for k, v in entry.items() if not k.startswith("_")}


def write_profile(table: dict, base_name: str, steps: list[dict], path: Path) -> None:
    """Write the calibrated profile TOML (``run``/``replay --profile PATH`` accept it)."""
    t = dict(table)
    t["name"] = f"{base_name}-calibrated"
    t["description"] = (f"{base_name} + " + ", ".join(s["name"] for s in steps)
                        if steps else f"{base_name} (no effect reduced the held-out gap)")
    head = ("# Made by `virtualgps gap`: the profile under test with the effects that reduced\n"
            "# the held-out gap, their parameters fitted on every run.\n")
    path.write_text(head + fx.to_toml(t), encoding="utf-8")
