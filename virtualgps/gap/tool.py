"""``virtualgps gap`` as a function: real runs in, ``report.json``, ``report.html`` and the
calibrated profile out (DESIGN sections 3 and 7). The command line (:mod:`virtualgps.cli`) only
parses arguments and prints.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps import ephemeris as eph
from virtualgps.config import coverage_note
from virtualgps.exceptions import ConfigError
from virtualgps.gap import diagnose as dg
from virtualgps.gap.metrics import autocorrelation, to_regular_grid
from virtualgps.gap.where import Obs, RunView, tracked_fractions
from virtualgps.profiles import build_profile, load_profile_dict

# The gap tool propagates the TLE set straight to the log's time up to this far from its epoch
# (SGP4 beats a sidereal shift for weeks: ephemeris.sidereal_shift_s); beyond, the same
# sidereal time near the epoch (a log years older than every TLE set at hand).
SKY_SHIFT_MAX_DAYS = 60.0
ACF_MAX_LAG_S = 600.0


@dataclass(frozen=True)
class GapInputs:
    """What a diagnosis is given.

    real : the real NMEA logs, one per run; truth : their truth specs, same order
    scene : scene folder/``scene.toml`` or None (open sky); tle : TLE file (None: the scene's
    set, else the newest bundled); profile : the profile under test (name or path)
    names : run names (default: the file stems, made unique)
    """

    real: tuple[str, ...]
    truth: tuple[str, ...]
    scene: str | None
    tle: str | None
    profile: str
    names: tuple[str, ...] | None = None


def _names(paths: Sequence[str]) -> list[str]:
    out, seen = [], {}
    for p in paths:
        stem = Path(p).stem
        seen[stem] = seen.get(stem, 0) + 1
        out.append(stem if seen[stem] == 1 else f"{stem}-{seen[stem]}")
    return out


def nearest_tle_set(extra: Sequence[Path], t_unix_s: float) -> Path:
    """The TLE set whose epoch lies nearest ``t_unix_s`` among ``extra`` (the scene's), the
    bundled sets and those ``virtualgps ephemeris fetch`` cached: a real log must be compared
    with its own day's sky, which a set months away gives only shifted (per-PRN comparisons
    then mean nothing; :func:`sky_note` says so)."""
    from virtualgps import tlecache

    sets = [(p, None) for p in extra]
    sets += [(p, None) for p in sorted(eph.BUNDLED_EPHEMERIS_DIR.glob("*.tle"))]
    sets += [(c.path, c.epoch_center_unix_s) for c in tlecache.cached_sets()]
    best, best_dt = eph.default_tle_path(), math.inf
    for path, epoch in sets:
        try:
            epoch = eph.load_tle(path).epoch_center_unix_s if epoch is None else epoch
        except (OSError, ValueError):
            continue
        if abs(epoch - t_unix_s) < best_dt:
            best, best_dt = path, abs(epoch - t_unix_s)
    return best


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


def load_inputs(inp: GapInputs):
    """Read the runs, the scene, the TLE set and the profile (every input error raised here).

    Returns
    -------
    runs, scene, scene_path, tle_path, profile_table, profile_source
    """
    from virtualgps.config import scene_path as resolve_scene
    from virtualgps.gap.ingest import load_run

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
        from virtualgps.scene import load_scene

        scene = load_scene(spath)
    if inp.tle is not None:
        tle = Path(inp.tle)
    else:
        scene_tle = getattr(scene, "tle_path", None) if scene is not None else None
        tle = nearest_tle_set([Path(scene_tle)] if scene_tle else [],
                              float(runs[0].epochs.t_unix_s[0]))
    if not tle.exists():
        raise ConfigError(f"TLE file {tle} not found (give --tle PATH)")
    table, source = load_profile_dict(inp.profile)
    build_profile(table, source)  # validates
    scene_dir = str(spath.parent if spath.is_file() else spath) if spath is not None else None
    return runs, scene, scene_dir, str(tle), table, source


def diagnose(
    inp: GapInputs,
    opts: dg.Options,
    progress: Callable[[str], None] | None = None,
) -> tuple[dict[str, Any], Any, dict]:
    """Run the whole diagnosis.

    Returns
    -------
    report : the ``report.json`` content (``calibrated_profile`` left to the writer)
    figures : :class:`virtualgps.report.GapFigureData`
    calibrated : the calibrated profile table
    """
    t_start = time.perf_counter()
    say = progress or (lambda s: None)
    runs_in, scene, scene_dir, tle, table, source = load_inputs(inp)
    profile = build_profile(table, source)
    ephem = _ephemeris(tle)

    def shift(t0: float) -> float:
        return eph.sidereal_shift_s(t0, ephem.epoch_center_unix_s, SKY_SHIFT_MAX_DAYS)

    for r in runs_in:  # (an orbit file that misses a run would leave its sky empty)
        t = r.epochs.t_unix_s
        for t_at in (float(t[0]), float(t[-1])):
            if note := coverage_note(ephem, t_at - shift(float(t[0]))):
                raise ConfigError(f"{r.name}: {note} (give --tle the navigation file of the "
                                  "log's day)")
    say(f"{len(runs_in)} run(s) read; ephemeris {Path(tle).name}; simulating along their truth")
    notes = {r.name: n for r in runs_in
             if (n := sky_note(ephem.epoch_center_unix_s, float(r.epochs.t_unix_s[0])))}
    runs = dg.prepare_runs(runs_in, scene, scene_dir, tle, profile, shift, opts)
    has_mesh = any(r.setup.scene_path is not None for r in runs) and bool(
        getattr(scene, "has_mesh", False))
    sim = dg.Simulator(runs, opts, source)
    seeds = range(opts.seeds)
    base_ens = sim.ensembles(table, seeds)
    where, parts = dg.where_table(runs, base_ens)
    say(f"baseline: {sum(w['outside'] for w in where)} located gaps in {len(where)} statistics")
    diag = dg.greedy(sim, table, opts, has_mesh, progress=say)
    final_table = diag.final_table
    final_ens = base_ens if not diag.steps else sim.ensembles(final_table, seeds)
    where_final, parts_final = (where, parts) if not diag.steps else dg.where_table(
        runs, final_ens)
    elapsed = time.perf_counter() - t_start
    report = {
        "runs": [{"name": r.view.name, "real": str(ri.path), "truth": ri.truth.kind,
                  "epochs": int(r.view.t_unix_s.size), **r.info,
                  **({"sky_warning": notes[ri.name]} if ri.name in notes else {})}
                 for r, ri in zip(runs, runs_in, strict=True)],
        "ephemeris": str(tle),
        "profile": profile.name,
        "profile_source": source,
        "seeds": opts.seeds,
        "fit_seeds": opts.n_fit,
        "where": where,
        "effects": [dg.public(s) | {"accepted": True} for s in diag.steps]
        + [dg.public(r) | {"accepted": False} for r in diag.ranking
           if r["name"] not in {s["name"] for s in diag.steps}],
        "candidates_skipped": diag.skipped,
        "gap_baseline": diag.gap_baseline,
        "gap_final": diag.gap_final,
        "tracking_disagreement": diag.tracking | {
            "definition": "sum over PRNs of |real - simulated tracked satellite-epochs| / "
                          "compared satellite-epochs, pooled over the held-out units, each "
                          "simulated with its fold's profile"},
        "gap_definition": "mean over the assessed score metrics of |ln((real+c)/(sim+c))| "
                          "(scales) or |real-sim|/scale (shares, levels), capped at 3; "
                          "held-out units averaged (README: The gap score)",
        "where_final": where_final,
        "unexplained": dg.unexplained(where_final),
        "not_assessed": dg.not_assessed(runs),
        "heldout": [u[2] for u in sim.units[:sim.n_folds]],
        "elapsed_s": elapsed,
        "simulated_epochs": sim.n_sims,
    }
    figures = figure_data(runs, base_ens, final_ens if diag.steps else None, parts,
                          parts_final if diag.steps else None, diag)
    return report, figures, final_table


def _ephemeris(path: str):
    """The ephemeris at ``path`` (TLE set, RINEX navigation file or lookup table)."""
    return eph.load_ephemeris_file(Path(path))


def write_outputs(report: dict, figures: Any, calibrated: dict, profile_name: str,
                  out_dir: str | Path) -> dict:
    """Write ``report.json``, ``report.html`` and ``calibrated.toml`` into ``out_dir``."""
    from virtualgps import report as rp

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    steps = [e for e in report["effects"] if e.get("accepted")]
    dg.write_profile(calibrated, profile_name, steps, out / "calibrated.toml")
    report["calibrated_profile"] = "calibrated.toml"
    rp.write_json(report, out / "report.json")
    rp.write_html(report, figures, out / "report.html")
    return report


# --- figures ------------------------------------------------------------------------------------


def _err_h(view: RunView, obs: Obs) -> np.ndarray:
    e = dg.errors_enu(view, obs)
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


def figure_data(runs, base_ens, final_ens, parts, parts_final, diag) -> Any:
    """Arrays for the report's figures."""
    from virtualgps.report import GapFigureData, RunFigureData

    figs = []
    for i, r in enumerate(runs):
        v = r.view
        sims = dg.sim_obs(base_ens[i], v)
        fin = dg.sim_obs(final_ens[i], v) if final_ens is not None else None
        real_eh = np.hypot(r.err_real[0, :, 0], r.err_real[0, :, 1])
        eq4 = np.hypot(v.real.lat_deg - sims.lat_deg, v.real.lon_deg - sims.lon_deg)
        figs.append(RunFigureData(
            name=v.name, t_unix_s=v.t_unix_s, truth_lat_deg=v.truth_lat_deg,
            truth_lon_deg=v.truth_lon_deg, real_lat_deg=v.real.lat_deg[0],
            real_lon_deg=v.real.lon_deg[0], sim_lat_deg=sims.lat_deg, sim_lon_deg=sims.lon_deg,
            real_err_h_m=real_eh, sim_err_h_m=_err_h(v, sims),
            real_sats_used=v.real.sats_used[0], sim_sats_used=sims.sats_used, eq4_deg=eq4,
            final_lat_deg=None if fin is None else fin.lat_deg,
            final_lon_deg=None if fin is None else fin.lon_deg,
            final_err_h_m=None if fin is None else _err_h(v, fin),
            final_sats_used=None if fin is None else fin.sats_used,
        ))
    az, el, dis = _sky_points(runs, base_ens)
    # autocorrelation: the longest run
    k = int(np.argmax([r.view.t_unix_s.size for r in runs]))
    v = runs[k].view
    lags, real_acf = _acf(v, runs[k].err_real[0, :, :2])
    sim_err = dg.errors_enu(v, dg.sim_obs(base_ens[k], v))
    sim_acf = np.stack([_pad(_acf(v, e[:, :2])[1], lags.size) for e in sim_err])
    final_acf = None
    if final_ens is not None:
        fe = dg.errors_enu(v, dg.sim_obs(final_ens[k], v))
        final_acf = np.stack([_pad(_acf(v, e[:, :2])[1], lags.size) for e in fe])
    labels = ["baseline"] + [f"+{s['name']}" for s in diag.steps]
    gaps = [diag.gap_baseline] + [s["gap_after"] for s in diag.steps]
    return GapFigureData(
        runs=tuple(figs), sky_az_deg=az, sky_el_deg=el, sky_disagreement=dis,
        acf_lags_s=lags, real_acf=_pad(real_acf, lags.size), sim_acf=sim_acf,
        waterfall_labels=tuple(labels), waterfall_gaps=tuple(float(g) for g in gaps),
        final_acf=final_acf,
    )


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    out = np.full(n, np.nan)
    out[: min(n, x.size)] = x[:n]
    return out


def _sky_points(runs, ens) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One point per satellite pass (a PRN's contiguous comparable epochs in a run): its
    median direction and real minus simulated tracked share."""
    az, el, dis = [], [], []
    for i, r in enumerate(runs):
        v = r.view
        if not (v.assess["gsv"] and v.assess["cn0"]):
            continue
        sims = dg.sim_obs(ens[i], v)
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


def summary_lines(report: dict, top: int = 5) -> list[str]:
    """A few lines for the terminal: the top located gaps and the ranked effects."""
    lines = [f"profile {report['profile']}: gap {report['gap_baseline']:.3f} -> "
             f"{report['gap_final']:.3f} (held out: {report['effects'][0]['heldout_scheme']})"
             if report["effects"] else f"profile {report['profile']}: gap "
             f"{report['gap_baseline']:.3f}, no candidate effect"]
    lines += [f"  warning: {r['name']}: {r['sky_warning']}" for r in report["runs"]
              if r.get("sky_warning")]
    located = [w for w in report["where"] if w["outside"] and w["segment"] in (
        "all", "startup", "steady", "moving", "stationary", "near_buildings", "open")]
    located.sort(key=lambda w: -w.get("distance", 0.0))
    for w in located[:top]:
        lines.append(f"  gap: {w['metric']} [{w['segment']}] real {w['real']:.3g}, "
                     f"simulated {w['sim_lo']:.3g}..{w['sim_hi']:.3g}")
    for e in report["effects"][:top]:
        mark = "added" if e.get("accepted") else "not added"
        params = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in e["params"].items())
        lines.append(f"  effect {e['name']} ({mark}): held-out gap {e['gap_before']:.3f} -> "
                     f"{e['gap_after']:.3f}" + (f"; {params}" if params else ""))
    if report.get("not_assessed"):
        lines.append("  not assessed: " + ", ".join(sorted({n["metric"]
                                                             for n in report["not_assessed"]})))
    return lines


