"""``virtualgps gap`` as a function: real runs in, ``report.json``, ``report.html`` and the
calibrated profile out (DESIGN sections 3 and 7). The command line (:mod:`virtualgps.cli`) only
parses arguments and prints.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps.exceptions import ConfigError
from virtualgps.gap import causes as cz
from virtualgps.gap import diagnose as dg
from virtualgps.gap import effects as fx
from virtualgps.gap import select as sel
from virtualgps.gap.bands import band_description, holdout_warning
from virtualgps.gap.design import make_design
from virtualgps.gap.ensemble import ephemeris_of
from virtualgps.gap.ingest import ingest_notes
from virtualgps.gap.jobs import ModelThread, modelling, start_workers, unshare
from virtualgps.gap.metrics import autocorrelation, to_regular_grid
from virtualgps.gap.observed import Obs, RunView
from virtualgps.gap.report import added_effects, outer_notes
from virtualgps.gap.runs import prepare_runs, sim_obs
from virtualgps.gap.simulator import HELD, Simulator, ensembles, share_runs
from virtualgps.gap.where import autocorr_time_s, errors_enu, tracked_fractions
from virtualgps.receiver.profiles import build_profile, load_profile_dict
from virtualgps.run.config import coverage_note
from virtualgps.sky import ephemeris as eph
from virtualgps.sky import systems
from virtualgps.sky.skytime import choose_system_sets, choose_tle_set

log = logging.getLogger(__name__)

# The gap tool propagates the TLE set straight to the log's time up to this far from its epoch
# (SGP4 beats a sidereal shift for weeks: ephemeris.sidereal_shift_s); beyond, the same
# sidereal time near the epoch (a log years older than every TLE set at hand).
SKY_SHIFT_MAX_DAYS = 60.0
ACF_MAX_LAG_S = 600.0


@dataclass(frozen=True)
class GapInputs:
    """What a diagnosis is given.

    real : the real NMEA logs, one per run; truth : their truth specs, same order
    scene : scene folder/``scene.toml`` or None (open sky); tle : the ephemeris file, or a
    tuple of TLE sets (one per system's group); None: for GPS and each other system the
    profile tracks or the logs list, the set nearest the first run's start (the scene's, the
    bundled and the fetched ones); profile : the profile under test (name or path)
    names : run names (default: the file stems, made unique)
    """

    real: tuple[str, ...]
    truth: tuple[str, ...]
    scene: str | None
    tle: str | tuple[str, ...] | None
    profile: str
    names: tuple[str, ...] | None = None


def _names(paths: Sequence[str]) -> list[str]:
    from virtualgps.poses.rosbag import split_topic

    out, seen = [], {}
    for p in paths:
        stem = Path(split_topic(p)[0]).stem
        seen[stem] = seen.get(stem, 0) + 1
        out.append(stem if seen[stem] == 1 else f"{stem}-{seen[stem]}")
    return out


def sky_note(epoch_center_unix_s: float, t_unix_s: float) -> str | None:
    """A warning when a run lies further than SKY_SHIFT_MAX_DAYS from the TLE set's epoch (its
    satellites then stand where that set puts them at the same sidereal time, not where they
    were), else None."""
    days = abs(t_unix_s - epoch_center_unix_s) / 86400.0
    if days <= SKY_SHIFT_MAX_DAYS:
        return None
    from datetime import UTC, datetime

    day = datetime.fromtimestamp(t_unix_s, UTC).date().isoformat()
    return (f"the TLE set's epoch is {days:.0f} days from the log ({day}): its sky is shifted "
            "to the same sidereal time, not the log's own; per-satellite results need that "
            "day's set (--tle: a TLE set or the day's RINEX navigation file)")


def sky_shift(ephem: eph.Constellation) -> Callable[[float], float]:
    """The sky-time shift a diagnosis uses for a run starting at ``t0`` (UTC s): none within
    SKY_SHIFT_MAX_DAYS of the TLE set ``ephem``'s epoch, else whole sky-repeat periods
    (:func:`virtualgps.sky.ephemeris.sidereal_shift_s`)."""
    return lambda t0: eph.sidereal_shift_s(t0, ephem.epoch_center_unix_s, SKY_SHIFT_MAX_DAYS)


def load_inputs(inp: GapInputs):
    """Read the runs, the scene, the TLE set and the profile (every input error raised here).

    Returns
    -------
    runs, scene, scene_path, tle_path, profile_table, profile_source
    """
    from virtualgps.gap.ingest import load_run
    from virtualgps.run.config import scene_path as resolve_scene

    if not inp.real:
        raise ConfigError("give at least one --real LOG with its --truth")
    if len(inp.real) != len(inp.truth):
        raise ConfigError(f"{len(inp.real)} --real logs but {len(inp.truth)} --truth: give one "
                          "--truth per --real, in the same order")
    names = list(inp.names) if inp.names else _names(inp.real)
    runs = [load_run(r, t, name=n) for r, t, n in zip(inp.real, inp.truth, names, strict=True)]
    spath = resolve_scene(inp.scene)
    scene = None
    if spath is not None:
        from virtualgps.sky.scene import load_scene

        scene = load_scene(spath)
    given = (inp.tle,) if isinstance(inp.tle, str) else tuple(inp.tle or ())
    for p in given:
        if not Path(p).exists():
            raise ConfigError(f"TLE file {p} not found (give --tle PATH)")
    table, source = load_profile_dict(inp.profile)
    profile = build_profile(table, source)  # validates
    scene_tle = getattr(scene, "tle_path", None) if scene is not None else None
    t0 = float(runs[0].epochs.t_unix_s[0])
    if given:
        tles = list(given)
        log.info("ephemeris: --tle %s", ", ".join(tles))
    else:
        # the same rule as run and replay: per system, the set nearest the first run's start
        tle, line = choose_tle_set(None, Path(scene_tle) if scene_tle else None, t0)
        log.info("%s", line)
        wanted = set(profile.constellations.letters()) | set(logged_systems(runs))
        found, missing = choose_system_sets("".join(sorted(wanted - {"G"})), t0)
        for _, line in found:
            log.info("%s", line)
        for name, exc in missing:
            log.info("ephemeris: %s satellites left out (%s)", name, exc)
        tles = [str(tle), *(str(path) for path, _ in found)]
    scene_dir = str(spath.parent if spath.is_file() else spath) if spath is not None else None
    return runs, scene, scene_dir, os.pathsep.join(tles), table, source


def logged_systems(runs: Sequence[Any]) -> str:
    """RINEX letters of the satellite systems the real logs list (GSV or GSA), GPS first; SBAS
    left out (a receiver's corrections, not a system ranged on)."""
    seen: set[str] = set()
    for r in runs:
        ep = r.epochs
        listed = (ep.in_view | ep.used).any(axis=0)
        seen |= set(systems.letters(ep.prn[listed]).tolist())
    return "".join(x for x in "GRECJ" if x in seen)


def diagnose(
    inp: GapInputs,
    opts: dg.Options,
    progress: Callable[[str], None] | None = None,
) -> tuple[dict[str, Any], Any, dict]:
    """Run the whole diagnosis.

    Returns
    -------
    report : the ``report.json`` content (``calibrated_profile`` left to the writer)
    figures : :class:`virtualgps.gap.report.GapFigureData`
    calibrated : the calibrated profile table
    """
    from threadpoolctl import threadpool_limits

    # One BLAS thread in this process: its located gaps are judged in a thread (matrix
    # products in smoothing_s) while this thread forks the workers, and OpenBLAS's fork
    # handler waits for its thread pool, which a product in flight holds: both hung (seen in
    # the test suite). Its own thread pool unused, a fork has nothing to wait for.
    with threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(inp, opts, progress)


def _diagnose(inp: GapInputs, opts: dg.Options, progress: Callable[[str], None] | None
              ) -> tuple[dict[str, Any], Any, dict]:
    t_start = time.perf_counter()
    say = progress or (lambda s: None)
    runs_in, scene, scene_dir, tle, table, source = load_inputs(inp)
    profile = build_profile(table, source)
    ephem = ephemeris_of(tle, profile.constellations.letters())

    shift = sky_shift(ephem)
    for r in runs_in:  # (an orbit file that misses a run would leave its sky empty)
        t = r.epochs.t_unix_s
        for t_at in (float(t[0]), float(t[-1])):
            if note := coverage_note(ephem, t_at - shift(float(t[0]))):
                raise ConfigError(f"{r.name}: {note} (give --tle the navigation file of the "
                                  "log's day)")
    names = ", ".join(Path(p).name for p in tle.split(os.pathsep))
    say(f"{len(runs_in)} run(s) read; ephemeris {names}; simulating along their truth")
    notes = {r.name: n for r in runs_in
             if (n := sky_note(ephem.epoch_center_unix_s, float(r.epochs.t_unix_s[0])))}
    # the systems compared: the profile's, and those the logs list that the ephemeris holds
    # (a constellations candidate may add them)
    held = set(systems.letters(ephemeris_of(tle, None).prn).tolist())
    logged = logged_systems(runs_in)
    own = profile.constellations.letters()
    compared = "".join(x for x in "GRECJ" if x in own or (x in logged and x in held))
    runs = prepare_runs(runs_in, scene, scene_dir, tle, profile, shift, opts.jobs, opts.dask,
                        compared)
    has_mesh = any(r.setup.scene_path is not None for r in runs) and bool(
        getattr(scene, "has_mesh", False))
    has_gsv = any(r.view.assess["gsv"] and r.view.assess["cn0"] for r in runs)

    say(f"baseline: {opts.seeds} seeds")
    base_ens, n_base = ensembles(runs, table, range(opts.seeds), opts.jobs, opts.dask, source)
    # Causes that are not receiver effects come first: a truth offset is removed before
    # anything is judged against the truth.
    tau_real = [_corr_time_s(r.view, r.err_real[0]) for r in runs]
    # (each ensemble as the logs print it, once: the causes, the located gaps and the figures
    # read it; a moved truth changes the errors, not this)
    base_sims = [sim_obs(base_ens[i], r.view) for i, r in enumerate(runs)]
    causes: list[dict] = []
    for i, r in enumerate(runs):
        sim_err = errors_enu(r.view, base_sims[i])
        off = cz.truth_offset_of(r, tau_real[i], sim_err, profile.georef)
        if off is not None:
            causes.append(off)
            if off["applied"]:
                runs[i] = cz.shift_truth(r, off["east_m"], off["north_m"])
        lag = cz.time_offset(runs[i], tau_real[i])
        if lag is not None:
            causes.append(lag)
    simulated = "".join(sorted(set(systems.letters(ephem.prn).tolist()) - {"?"})) or "G"
    for ri in runs_in:
        ep = ri.epochs
        extra = cz.constellations(ri.name, ep.prn, ep.in_view, ep.used, simulated)
        if extra is not None:
            causes.append(extra)
    causes += [c for r in runs if (c := cz.sky(r)) is not None]
    georef = cz.georeference(runs, profile.georef)
    keys = share_runs(runs)
    # (forked before the located gaps' thread starts: see start_workers)
    start_workers(opts.jobs, opts.dask)
    # The located gaps are judged, and the baseline's figures' arrays made, in a thread while
    # the workers simulate the candidates (where the benchmark models workers in this process,
    # a thread would share their time: the model plays it, jobs.ModelThread).
    judging = ThreadPoolExecutor(1) if not modelling() else ModelThread()
    where_job = judging.submit(dg.where_table, runs, base_sims)
    figures_job = judging.submit(figure_data, runs, base_sims)
    # Guards as long as the real error's correlation time: held-out real data then share no
    # correlated error with the data a fit saw (the simulations use seeds of their own).
    design = make_design([r.view.name for r in runs], [r.view.t_unix_s for r in runs],
                         [r.view.valid for r in runs], tau_real, opts.blocks)
    sim = Simulator(runs, design, opts.n_fit, opts.jobs, opts.dask, source, keys)
    base = table
    whole = list(range(len(design.units), len(design.all_units())))  # each run, every epoch
    if georef is not None:
        exact = fx.apply(table, {"georef": "wgs84"})
        sim.request([(t, HELD, whole) for t in (table, exact)])
        georef["gap_flat_earth"] = sim.gap(table, HELD, whole)
        georef["gap_exact"] = sim.gap(exact, HELD, whole)
        georef["applied"] = bool(georef["gap_flat_earth"] - georef["gap_exact"]
                                 > sel.MIN_GAIN_ABS)
        if georef["applied"]:
            base = exact
        causes.insert(0, georef)
    # every table's score is guarded by the profile under test's (a candidate that moves a
    # metric away from the real log gains nothing by widening its seeds' spread)
    sim.set_reference(base)
    choice = None
    if design.claims:
        choice = dg.choose_effects(sim, base, opts, has_mesh, has_gsv, progress=say,
                                   systems=(logged, "".join(sorted(held))),
                                   starts=any(r.view.started for r in runs),
                                   sky_wrong=cz.sky_wrong(causes))
    final_table = choice.full.final_table if choice is not None else base
    changed = final_table != table
    final_sims = None
    if changed:
        final_ens = ensembles(runs, final_table, range(opts.seeds), opts.jobs, opts.dask,
                              source)[0]
        final_sims = [sim_obs(final_ens[i], r.view) for i, r in enumerate(runs)]
    final_job = (judging.submit(dg.where_table, runs, final_sims, holdout=False) if changed
                 else None)
    # (the final figures' arrays are computed meanwhile)
    figures = with_final(figures_job.result(), runs, final_sims, choice)
    where, alpha, holdout = where_job.result()
    say(f"baseline: {sum(w['outside'] for w in where)} located gaps in {len(where)} statistics")
    where_final = final_job.result()[0] if changed else where
    judging.shutdown()
    report = _report(runs, runs_in, notes, tle, profile, source, opts, where, alpha, holdout,
                     design, choice, causes, where_final, sim, n_base, table, base, final_table)
    unshare(keys)
    report["elapsed_s"] = time.perf_counter() - t_start
    return report, figures, final_table


def _corr_time_s(view: RunView, err: np.ndarray) -> float:
    """The 1/e time of a run's horizontal error over its valid fixed epochs (NaN: longer than
    half the run, or too short to tell)."""
    ok = view.valid & np.isfinite(err[:, :2]).all(axis=1)
    return autocorr_time_s(view.t_unix_s[ok], err[ok, :2])


def _outer_share(choice: dg.Choice | None) -> dict[str, float]:
    if choice is None or not choice.outer:
        return {}
    names = {n for o in choice.outer for n in o["effects"]}
    return {n: sum(n in o["effects"] for o in choice.outer) / len(choice.outer) for n in names}


def _report(runs, runs_in, notes, tle, profile, source, opts, where, alpha, holdout, design,
            choice, causes, where_final, sim, n_base, table, base, final_table
            ) -> dict[str, Any]:
    """The ``report.json`` content."""
    share = _outer_share(choice)
    effects: list[dict] = []
    alt = None
    if choice is not None:
        full = choice.full
        names = {s["name"] for s in full.steps}
        removed = {s["name"] for s in full.removed}
        effects = ([dg.public(s) | {"accepted": True} for s in full.steps]
                   + [dg.public(s) | {"accepted": False} for s in full.removed]
                   + [dg.public(r) | {"accepted": False} for r in full.ranking
                      if r["name"] not in names | removed])
        for e in effects:
            e["outer_share"] = share.get(e["name"], 0.0)
            e["heldout_scheme"] = design.scheme
            if e["name"] == "latency" and any(c["name"] == "time_offset" for c in causes):
                e["alias"] = ("a log-vs-truth clock offset of the same size moves the fixes "
                              "alike (see causes: time_offset)")
        alt = sel.alternative(full.paths)
        for c in causes:
            if c["name"] == "time_offset":
                c["read_as"] = [s["name"] for s in full.steps if cz.lags_motion(s)]
                other = [n for n in alt["effects"] if n in cz.LAG_EFFECTS] if alt else []
                if alt and other != c["read_as"]:
                    c["or_read_as"] = other
    outer = choice.outer_summary() if choice is not None else None
    whole = list(range(len(design.units), len(design.all_units())))
    if choice is not None and outer["groups"]:
        gap_baseline, gap_final = outer["gap_before"], outer["gap_after"]
    elif choice is not None:
        gap_baseline, gap_final = choice.full.baseline, choice.full.final
    else:
        sim.request([(base, HELD, whole)])
        gap_baseline = gap_final = sim.gap(base, HELD, whole)
    return {
        "runs": [{"name": r.view.name, "real": str(ri.path), "truth": ri.truth.kind,
                  "epochs": int(r.view.t_unix_s.size), **r.info,
                  **({"sky_warning": notes[ri.name]} if ri.name in notes else {})}
                 for r, ri in zip(runs, runs_in, strict=True)],
        "ephemeris": str(tle) if os.pathsep not in tle else tle.split(os.pathsep),
        "profile": profile.name,
        "profile_source": source,
        "seeds": opts.seeds,
        "fit_seeds": opts.n_fit,
        "band": band_description(len(where), opts.seeds, alpha, holdout),
        "where": where,
        "located": located_groups(where),
        "headline": headline(where, where_final if final_table != table else None),
        "causes": causes,
        "design": {"scheme": design.scheme, "units": [u.label for u in design.units],
                   "guard_s": design.guard_s,
                   "outer_groups": [[design.units[u].label for u in g] for g in design.outer],
                   "claims": design.claims, "warnings": design.warnings},
        "effects": effects,
        "candidates_skipped": choice.full.skipped if choice is not None else {},
        "gap_baseline": gap_baseline,
        "gap_final": gap_final,
        "gap_selection": ({"baseline": choice.full.baseline, "final": choice.full.final,
                           "what": "cross-validated inside the choice: each fold's held-out "
                                   "units were held out from its fit, not from the choice of "
                                   "effects (optimistic); gap_baseline and gap_final are the "
                                   "outer test's"} if choice is not None else None),
        "outer": ({**outer, "folds": choice.outer} if choice is not None else None),
        "selection_rounds": choice.full.rounds if choice is not None else [],
        "search_paths": choice.full.paths if choice is not None else [],
        "alternative": alt,
        "tracking_disagreement": (choice.full.tracking if choice is not None else {}) | {
            "definition": "sum over PRNs of |real - simulated tracked satellite-epochs| / "
                          "compared satellite-epochs, pooled over the held-out units, each "
                          "simulated with its fold's profile"},
        "gap_definition": "mean over the assessed score metrics of each metric's distance: "
                          "max(0, |z| - 1), z the normal quantile of the real value's two-sided "
                          "predictive p-value against the seeds (0 within the metric's floor), "
                          "at most 5; about 0.1 under the null (docs/gap.md: The gap score)",
        "where_final": where_final,
        "unexplained": dg.unexplained(where_final),
        "not_assessed": dg.not_assessed(runs),
        "heldout": [u.label for u in design.units],
        "simulated_epochs": sim.n_sims + n_base,
        "batches": list(sim.batches),
        "repeated_simulations": sim.repeats,
    }


HEADLINE = (("cep50_m", "CEP50", "m"), ("r95_m", "R95", "m"), ("lag_s", "lag", "s"),
            ("smoothing_s", "smoothing", "s"), ("sats_used_mean", "satellites used", ""),
            ("hdop_median", "HDOP", ""),
            ("fix_fraction", "fix fraction", ""), ("ttff_s", "first fix", "s"))


def headline(where: list[dict], where_final: list[dict] | None) -> list[dict]:
    """The figures a roboticist reads first, over all epochs: real, simulated (the profile
    under test: the seeds' median and the 95 % prediction band of one row; ``outside`` is the
    report's judgement over all rows) and, where effects were added, calibrated."""
    def by(rows: list[dict] | None) -> dict[str, dict]:
        if rows is None:
            return {}
        # every epoch, but the first fix where it is measured: after power-on
        want = {m: ("startup" if m == "ttff_s" else "all") for m, _, _ in HEADLINE}
        return {w["metric"]: w for w in rows if w["metric"] in want and (
            want[w["metric"]] == w["segment"] or want[w["metric"]] in w.get("same_as", []))}
    base, fin = by(where), by(where_final)
    out = []
    for metric, label, unit in HEADLINE:
        if metric not in base:
            continue
        w = base[metric]
        out.append({"metric": metric, "label": label, "unit": unit, "real": w["real"],
                    "simulated": w["sim_median"], "sim_lo": w["band95"][0],
                    "sim_hi": w["band95"][1], "outside": w["outside"],
                    "calibrated": fin[metric]["sim_median"] if metric in fin else None})
    return out


def located_groups(where: list[dict]) -> list[dict]:
    """The located gaps grouped by metric: the segments where each lies (most extreme first)."""
    groups: dict[str, list[dict]] = {}
    for w in where:
        if w["outside"]:
            groups.setdefault(w["metric"], []).append(w)
    out = []
    for metric, rows in groups.items():
        rows.sort(key=lambda w: -abs(w["z"]) if math.isfinite(w["z"]) else 0.0)
        out.append({"metric": metric, "rows": len(rows),
                    "segments": [w["segment"] for w in rows],
                    "worst": {k: rows[0][k] for k in ("segment", "real", "sim_lo", "sim_hi",
                                                      "sim_median", "z")}})
    out.sort(key=lambda g: -abs(g["worst"]["z"]) if math.isfinite(g["worst"]["z"]) else 0.0)
    return out


def write_outputs(report: dict, figures: Any, calibrated: dict, profile_name: str,
                  out_dir: str | Path, jobs: int | None = None, dask: str | None = None
                  ) -> dict:
    """Write ``report.json``, ``report.html`` and ``calibrated.toml`` into ``out_dir`` (the
    figures drawn on ``jobs`` worker processes, default all cores, or a Dask cluster)."""
    from virtualgps.gap import report as rp

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    added = added_effects(report)
    dg.write_profile(calibrated, profile_name, added, out / "calibrated.toml",
                     outer_notes(report.get("outer") or {}, added))
    report["calibrated_profile"] = "calibrated.toml"
    rp.write_json(report, out / "report.json")
    rp.write_html(report, figures, out / "report.html", jobs, dask)
    return report


# --- figures ------------------------------------------------------------------------------------


def _err_h(view: RunView, obs: Obs) -> np.ndarray:
    e = errors_enu(view, obs)
    return np.hypot(e[..., 0], e[..., 1])


def _acf(view: RunView, err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lags (s) and autocorrelation of a (n, 2) error series of a run."""
    t = view.t_unix_s
    ok = np.isfinite(err).all(axis=1)
    if ok.sum() < 3:
        lags = np.arange(0, 61, 1.0)
        return lags, np.full(lags.size, np.nan)
    dt = float(np.median(np.diff(t[ok])))
    _, grid = to_regular_grid(t[ok], err[ok], dt)
    max_lag = max(1, min(int(ACF_MAX_LAG_S / dt), grid.shape[0] // 2))
    return dt * np.arange(max_lag + 1), autocorrelation(grid, max_lag)


def figure_data(runs, base_sims) -> Any:
    """Arrays for the report's figures from the baseline alone (``base_sims``: each run's
    ensemble as :func:`virtualgps.gap.runs.sim_obs`); :func:`with_final` adds the rest. (Made
    while the effects are chosen; a diagnosis's end, bounded by the final located gaps' table,
    then makes only the final part.)"""
    from virtualgps.gap.report import GapFigureData, RunFigureData

    figs = []
    for i, r in enumerate(runs):
        v = r.view
        sims = base_sims[i]
        real_eh = np.hypot(r.err_real[0, :, 0], r.err_real[0, :, 1])
        eq4 = np.hypot(v.real.lat_deg - sims.lat_deg, v.real.lon_deg - sims.lon_deg)
        figs.append(RunFigureData(
            name=v.name, t_unix_s=v.t_unix_s, truth_lat_deg=v.truth_lat_deg,
            truth_lon_deg=v.truth_lon_deg, real_lat_deg=v.real.lat_deg[0],
            real_lon_deg=v.real.lon_deg[0], sim_lat_deg=sims.lat_deg, sim_lon_deg=sims.lon_deg,
            real_err_h_m=real_eh, sim_err_h_m=_err_h(v, sims),
            real_sats_used=v.real.sats_used[0], sim_sats_used=sims.sats_used, eq4_deg=eq4))
    az, el, dis = _sky_points(runs, base_sims)
    k = _acf_run(runs)
    v = runs[k].view
    lags, real_acf = _acf(v, runs[k].err_real[0, :, :2])
    return GapFigureData(
        runs=tuple(figs), sky_az_deg=az, sky_el_deg=el, sky_disagreement=dis,
        acf_lags_s=lags, real_acf=_pad(real_acf, lags.size),
        sim_acf=_acf_seeds(v, base_sims[k], lags.size), waterfall_labels=("baseline",),
        waterfall_gaps=(math.nan,))


def with_final(data: Any, runs, final_sims, choice) -> Any:
    """:func:`figure_data`'s arrays with the final profile's ensemble (``final_sims``, None
    where nothing changed) and the choice's waterfall (``choice`` None: none made)."""
    figs = data.runs
    if final_sims is not None:
        figs = tuple(replace(f, final_lat_deg=fin.lat_deg, final_lon_deg=fin.lon_deg,
                             final_err_h_m=_err_h(r.view, fin), final_sats_used=fin.sats_used)
                     for f, r, fin in zip(figs, runs, final_sims, strict=True))
    k = _acf_run(runs)
    steps = choice.full.steps if choice is not None else []
    return replace(
        data, runs=figs, waterfall_labels=("baseline", *(f"+{s['name']}" for s in steps)),
        waterfall_gaps=(float(choice.full.baseline) if choice is not None else math.nan,
                        *(float(s["gap_after"]) for s in steps)),
        final_acf=None if final_sims is None else _acf_seeds(runs[k].view, final_sims[k],
                                                               data.acf_lags_s.size))


def _acf_run(runs) -> int:
    """The run whose autocorrelation is drawn: the longest."""
    return int(np.argmax([r.view.t_unix_s.size for r in runs]))


def _acf_seeds(view: RunView, sims: Obs, n_lags: int) -> np.ndarray:
    """(s, n_lags) each seed's error autocorrelation (:func:`_acf`), padded with NaN."""
    return np.stack([_pad(_acf(view, e[:, :2])[1], n_lags) for e in errors_enu(view, sims)])


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    out = np.full(n, np.nan)
    out[: min(n, x.size)] = x[:n]
    return out


def _sky_points(runs, sims_of_runs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One point per satellite pass (a PRN's contiguous comparable epochs in a run): its
    median direction and real minus simulated tracked share (``sims_of_runs``: each run's
    ensemble as :func:`virtualgps.gap.runs.sim_obs`)."""
    az, el, dis = [], [], []
    for i, r in enumerate(runs):
        v = r.view
        if not (v.assess["gsv"] and v.assess["cn0"]):
            continue
        sims = sims_of_runs[i]
        for j in range(v.prn.size):
            ok = v.sat_ok[:, j]
            if not ok.any():
                continue
            edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                m = np.zeros_like(v.sat_ok)
                m[a:b, j] = True
                fr, _ = tracked_fractions(v, v.real.tracked, m)
                fs, _ = tracked_fractions(v, sims.tracked, m)
                az.append(float(np.median(v.az_deg[a:b, j])))
                el.append(float(np.median(v.el_deg[a:b, j])))
                dis.append(float(fr[0, j] - np.nanmedian(fs[:, j])))
    return np.array(az), np.array(el), np.array(dis)


def _num(v: Any, fmt: str = ".3g") -> str:
    return format(v, fmt) if isinstance(v, int | float) and math.isfinite(v) else "-"


def _param(name: str, value: Any, fit: dict) -> str:
    """``name=value``, with the values that round into its interval's grid points (or "not
    identifiable", or the bound of a fit left at its grid's end) where the fit says."""
    text = f"{name}={fx.value_text(value)}"
    if fit.get("identifiable", {}).get(name) is False:
        return text + " (not identifiable)"
    if name in fit.get("bounds", {}):
        return text + f" ({fit['bounds'][name]}: at the grid's end, a bound)"
    sp = fit.get("spans", {}).get(name)
    return text + (f" ({_num(sp[0])}..{_num(sp[1])})" if sp else "")


def summary_lines(report: dict, top: int = 5) -> list[str]:
    """A few lines for the terminal: the headline, the causes, the located gaps, the effects."""
    lines = []
    for h in report["headline"]:
        cal = (f", calibrated {_num(h['calibrated'])}" if h.get("calibrated") is not None
               else "")
        unit = f" {h['unit']}" if h["unit"] else ""
        lines.append(f"{h['label']}: real {_num(h['real'])}{unit}, simulated "
                     f"{_num(h['simulated'])}{unit} ({_num(h['sim_lo'])}..{_num(h['sim_hi'])})"
                     f"{cal}"
                     + ("  <- gap" if h["outside"] else ""))
    outer = report.get("outer") or {}
    scheme = report["design"]["scheme"]
    if report["effects"] and outer.get("groups"):
        lo, hi = outer.get("interval") or (math.nan, math.nan)
        lines.append(f"profile {report['profile']}: held-out gap {report['gap_baseline']:.3f} "
                     f"-> {report['gap_final']:.3f}"
                     + (f" (reduction {outer['reduction']:.3f}, 95 %: {lo:.3f} to {hi:.3f})"
                        if lo is not None and math.isfinite(lo) else "")
                     + f" on data neither the choice nor the fit saw ({outer['groups']} outer "
                       f"groups; {scheme})")
    else:
        lines.append(f"profile {report['profile']}: gap {_num(report['gap_baseline'])}")
    lines += [f"  note: {n}" for n in outer_notes(outer, added_effects(report))]
    lines += [f"  warning: {w}" for w in report["design"]["warnings"]]
    if note := holdout_warning(report.get("band", {})):
        lines.append(f"  warning: {note}")
    lines += [f"  warning: {r['name']}: {r['sky_warning']}" for r in report["runs"]
              if r.get("sky_warning")]
    lines += [f"  note: {r['name']}: {n}" for r in report["runs"] for n in ingest_notes(r)]
    for c in report.get("causes", []):
        if c["name"] == "truth_offset" and c["applied"]:
            lines.append(f"  cause: the truth of {c['run']} sits {c['size_m']:.1f} m off "
                         f"(E {c['east_m']:+.1f} m, N {c['north_m']:+.1f} m; p "
                         f"{c['p_value']:.2g}): moved before judging"
                         + (f"; {c['reference_note']}" if c.get("reference_note") else ""))
        elif c["name"] == "time_offset":
            if cz.clock_note(c):
                lines.append(f"  cause: {cz.clock_note(c)}")
            if abs(c["lag_s"]) >= 0.2:
                lines.append(f"  cause?: the fixes lag the truth of {c['run']} by "
                             f"{c['lag_s']:.2f} s: {cz.lag_reading(c)}")
        elif c["name"] == "georeference_model" and c.get("applied", True):
            lines.append(f"  cause: {c['what']}")
        elif c["name"] == "georeference_model":
            lines.append(f"  note: {c['what']}; the log fits it no worse than the exact "
                         f"conversion (held-out gap {c['gap_flat_earth']:.3f} with it, "
                         f"{c['gap_exact']:.3f} exact): not a cause here")
        elif c["name"] in ("constellations", "sky"):
            lines.append(f"  cause: {c['run']}: {c['what']}")
    why = cz.sky_wrong(report.get("causes", []))
    if off_sky := [n for n, w in report.get("candidates_skipped", {}).items() if w == why]:
        lines.append(f"  note: not tried on a sky that is not the log's: {', '.join(off_sky)}")
    for g in report["located"][:top]:
        w = g["worst"]
        lines.append(f"  gap: {g['metric']} [{w['segment']}"
                     + (f" +{g['rows'] - 1} more" if g["rows"] > 1 else "")
                     + f"] real {_num(w['real'])}, simulated {_num(w['sim_lo'])}.."
                     f"{_num(w['sim_hi'])}")
    for e in report["effects"][:top]:
        mark = "added" if e.get("accepted") else "not added"
        params = ", ".join(_param(k, v, e.get("fit") or {}) for k, v in e["params"].items())
        tie = f" (tied with {', '.join(e['tied_with'])})" if e.get("tied_with") else ""
        lines.append(f"  effect {e['name']} ({mark}){tie}: held-out gap "
                     f"{e['gap_before']:.3f} -> {e['gap_after']:.3f}"
                     + (f"; {params}" if params else ""))
    if report.get("alternative"):
        lines.append(f"  alternative: {report['alternative']['what']}")
    left = list(dict.fromkeys(u["metric"] for u in report.get("unexplained", [])))
    if left:
        lines.append("  unexplained (outside the final ensemble): " + ", ".join(left))
    if report.get("not_assessed"):
        lines.append("  not assessed: " + ", ".join(sorted({n["metric"]
                                                             for n in report["not_assessed"]})))
    return lines
