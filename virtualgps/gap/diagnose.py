"""The sim-to-real diagnosis (DESIGN section 7): where the gap lies, which effect causes it, how
far it shrinks on data that neither the choice nor the fit saw.

1. Every real run is re-simulated along its truth, at its real epochs, from its own power-on,
   as an ensemble of seeds (:mod:`.ensemble`); its statistics per segment against the seeds'
   values, judged together (:mod:`.bands`), locate the gap (:func:`where_table`).
2. The data are cut into held-out units (:mod:`.design`: runs, or time blocks with guard gaps).
   A selection (:mod:`.select`) ranks the candidate effects (:mod:`.effects`) by their held-out
   gap and adds them greedily while they clearly help.
3. The reported reduction is nested: for each outer group of units the whole selection runs on
   the other units, and the profile it makes is measured on the outer group with seeds of its
   own (:func:`choose_effects`). The full selection, on every unit, makes the calibrated
   profile and the ranking.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import special

from virtualgps.gap import effects as fx
from virtualgps.gap.design import MAX_INNER, Design
from virtualgps.gap.motion import LAG_MIN_VEL_RMS_MPS
from virtualgps.gap.observed import Obs, RunView
from virtualgps.gap.runs import Run
from virtualgps.gap.select import Request, Selection, drive, select
from virtualgps.gap.simulator import HELD, OUTER, Simulator
from virtualgps.gap.where import (
    errors_enu,
    finish_rows,
    judged_rows,
    merged_segments,
    segment_stats,
    segments,
    sky_sectors,
)


@dataclass(frozen=True)
class Options:
    """How a diagnosis runs.

    seeds : ensemble size for locating the gap and the final band
    fit_seeds : seeds per seed set while fitting (common random numbers); default
        min(seeds, 8)
    effects : candidate effect names (None: every one the profile lacks)
    jobs : local worker processes (None: all cores); dask : a Dask scheduler address
    blocks : held-out time blocks per run at most (fewer or more runs: see :mod:`.design`)
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


# --- choosing effects ----------------------------------------------------------------------------


@dataclass
class Choice:
    """What :func:`choose_effects` found: the full selection and the outer test."""

    full: Selection
    outer: list[dict] = field(default_factory=list)

    def outer_summary(self) -> dict:
        """The outer test: the mean held-out gap before and after over the outer groups, the
        reduction with a 95 % t interval over them (NaN without an outer test), and whether
        that interval lies above 0 (``confirmed``; None without an interval: one group)."""
        before = np.array([o["gap_before"] for o in self.outer], dtype=float)
        after = np.array([o["gap_after"] for o in self.outer], dtype=float)
        ok = np.isfinite(before) & np.isfinite(after)
        out = {"gap_before": math.nan, "gap_after": math.nan, "reduction": math.nan,
               "interval": [math.nan, math.nan], "confirmed": None, "groups": int(ok.sum()),
               "not_judged": []}
        if not ok.any():
            return out
        d = before[ok] - after[ok]
        out.update(gap_before=float(before[ok].mean()), gap_after=float(after[ok].mean()),
                   reduction=float(d.mean()))
        if d.size > 1:
            half = float(special.stdtrit(d.size - 1, 0.975)) * float(np.std(d, ddof=1)) \
                / math.sqrt(d.size)
            out["interval"] = [float(d.mean() - half), float(d.mean() + half)]
            out["confirmed"] = bool(out["interval"][0] > 0.0)
        out["not_judged"] = not_judged(self.full.steps, self.outer)
        return out


def not_judged(steps: list[dict], outer: list[dict]) -> list[dict]:
    """The added effects the outer test cannot judge: the units where the effect shows (its
    held-out gap changes by FLAT_MIN or more) lie in one outer group, whose choice was made
    without it. Such an effect shows in data seen once (a run's one power-on, the one stop of
    a drive): held out, the choice made on the other units had nothing to add it for, so the
    outer test's reduction leaves it out, however right it is. (An effect that shows in
    several groups and none chose is no such case: they preferred another explanation, which
    ``outer_share`` says.)

    steps : the full selection's added effects (entries with ``_shows_in``: unit indices)
    outer : the outer groups (``units``: unit indices held out; ``effects``: their choice)

    Returns
    -------
    [{"effect", "shows_in": [held-out unit labels of the groups that hold it]}]
    """
    out = []
    for s in steps:
        shows = set(s.get("_shows_in", ()))
        holding = [o for o in outer if shows & set(o["units"])]
        if len(holding) == 1 and s["name"] not in holding[0]["effects"]:
            out.append({"effect": s["name"], "shows_in": [o["heldout"] for o in holding]})
    return out


def _outer(sim: Simulator, base: dict, inner: list[int], held: list[int],
           candidates: Callable) -> Generator[Request, None, dict]:
    """One outer group: the selection on the other units, measured on the group."""
    sel = yield from select(sim, base, inner, inner, candidates, MAX_INNER)
    yield [(sel.final_table, OUTER, held), (base, OUTER, held), (base, HELD, held)]
    return {"heldout": ", ".join(sim.units[u].label for u in held), "units": list(held),
            "effects": [s["name"] for s in sel.steps],
            "params": {s["name"]: s["params"] for s in sel.steps},
            "gap_before": sim.gap(base, OUTER, held),
            "gap_after": sim.gap(sel.final_table, OUTER, held)}


def choose_effects(sim: Simulator, base: dict, opts: Options, has_mesh: bool, has_gsv: bool,
                   progress: Callable[[str], None] | None = None,
                   systems: tuple[str, str] = ("", "G"), starts: bool = True,
                   sky_wrong: str | None = None) -> Choice:
    """The full selection (every unit; the calibrated profile and the ranking) and, where the
    design allows, the outer test, all simulated in shared batches. ``systems``: RINEX letters
    of the systems the logs list and of those the ephemeris holds (``constellations``);
    ``starts``: some log starts at power-on (``cold_start``); ``sky_wrong``: why the simulated
    sky is not the logs' (no effect placed on it is tried), or None."""
    design: Design = sim.design

    def candidates(table: dict):
        return fx.candidates(table, has_mesh, opts.effects, has_gsv, *systems, starts=starts,
                             sky_wrong=sky_wrong)

    units = list(range(len(design.units)))
    fit_units = ([len(design.units) + i for i in range(len(design.whole))]
                 if design.fit_on_whole else units)
    gens: dict[str, Generator] = {"full": select(sim, base, units, fit_units, candidates,
                                                 MAX_INNER, full=True)}
    for o, group in enumerate(design.outer):
        inner = [u for u in units if u not in group]
        gens[f"outer {o}"] = _outer(sim, base, inner, group, candidates)
    res = drive(sim, gens, progress)
    return Choice(res["full"], [res[f"outer {o}"] for o in range(len(design.outer))])


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


def where_table(runs: list[Run], sims: list[Obs], holdout: bool = True
                ) -> tuple[list[dict], float, dict]:
    """The located gaps of every segment (pooled over runs, and per run), judged together.

    sims : each run's ensemble as :func:`virtualgps.gap.runs.sim_obs` of its view
    holdout : check the bands on the seeds themselves (the report's table; the calibrated
        profile's table, which only says what stays unexplained, needs no such check)

    Returns
    -------
    rows : the report's ``where`` entries (segments holding the same epochs merged, the other
        names in ``same_as``)
    alpha_row : the per-row level the rows were judged at (:func:`virtualgps.gap.where.
        finish_rows`)
    holdout : the bands checked on the seeds themselves (:func:`virtualgps.gap.where.
        seed_holdout`; {} without ``holdout``)
    """
    errs = [errors_enu(r.view, s) for r, s in zip(runs, sims, strict=True)]
    view, sim, er, es = pooled(runs, sims, errs)
    rows: list[dict] = []
    for name, (m, same) in merged_segments(segments(view)).items():
        rows += [r | {"same_as": same}
                 for r in judged_rows(segment_stats(view, sim, er, es, m), name)]
    sat_metrics = ("tracked_agreement", "tracked_share", "cn0_median_dbhz")
    allep = np.ones(view.t_unix_s.size, bool)
    for name, m in sky_sectors(view).items():
        rows += judged_rows(segment_stats(view, sim, er, es, allep, m, sat_metrics), name)
    for j, p in enumerate(view.prn):
        m = np.zeros_like(view.sat_ok)
        m[:, j] = view.sat_ok[:, j]
        if m.any():
            rows += judged_rows(segment_stats(view, sim, er, es, allep, m, sat_metrics),
                                f"prn:{int(p)}")
    if len(runs) > 1:
        for r, s, e in zip(runs, sims, errs, strict=True):
            ones = np.ones(r.view.t_unix_s.size, bool)
            rows += judged_rows(segment_stats(r.view, s, r.err_real, e, ones),
                                f"run:{r.view.name}")
    return finish_rows(rows, holdout)


def not_assessed(runs: list[Run]) -> list[dict]:
    """The metrics the real logs cannot support, with the reason."""
    out = []
    # (every satellite the logs list stands elsewhere in the simulated sky: causes.sky)
    sky = ("the logs' satellites stand where the ephemeris does not put them (see causes: sky)"
           if any(r.info.get("sky", {}).get("misplaced_prns") for r in runs)
           and not any(r.view.sat_ok.any() for r in runs) else None)
    if not any(r.view.assess["gsv"] for r in runs):
        for m in ("tracked_agreement", "tracked_share", "cn0_median_dbhz"):
            out.append({"metric": m, "reason": "no GSV sentence (satellites in view) in the "
                        "real logs"})
    elif not any(r.view.assess["cn0"] for r in runs):
        for m in ("tracked_agreement", "tracked_share", "cn0_median_dbhz"):
            out.append({"metric": m, "reason": "the real logs' GSV carry no SNR"})
    elif sky:
        for m in ("tracked_agreement", "tracked_share", "cn0_median_dbhz"):
            out.append({"metric": m, "reason": sky})
    if not any(r.view.assess["gsa"] for r in runs):
        out.append({"metric": "used_el_p05_deg", "reason": "no GSA sentence (satellites used) "
                    "in the real logs"})
    elif sky:
        out.append({"metric": "used_el_p05_deg", "reason": sky})
    if not np.isfinite(np.concatenate([r.view.real.sats_used[0] for r in runs])).any():
        for m in ("sats_used_mean", "used_changes_per_min"):
            out.append({"metric": m, "reason": "the real logs give no count of satellites "
                        "used (GGA field empty, no GSA)"})
    if all(r.view.reference == "median" for r in runs):
        out.append({"metric": "bias_m", "reason": "static truth at an unknown point: errors are "
                    "taken about the run's median fix"})
    if not any(np.any(r.view.speed_mps >= 0.3) for r in runs):
        out.append({"metric": "lag_s", "reason": "the truth never moves"})
    elif not any(_velocity_varies(r) for r in runs):
        out.append({"metric": "lag_s", "reason": "the truth moves at one velocity: a lag "
                    "cannot be told from a constant bias"})
    if not any(r.view.assess.get("gga", True) for r in runs):
        for m in ("up_p68_m", "dgps_fraction"):
            out.append({"metric": m, "reason": "no GGA in the real logs (RMC or GLL alone: "
                        "no altitude, no fix quality)"})
    if not any(np.isfinite(r.view.real.hdop).any() for r in runs):
        out.append({"metric": "hdop_median", "reason": "no HDOP in the real logs"})
    return out


def _velocity_varies(run: Run) -> bool:
    """Whether the run's moving truth varies its velocity enough for
    :func:`~virtualgps.gap.motion.lag_s`."""
    v = run.view
    moving = v.valid & (v.speed_mps >= 0.3)
    vel = v.vel_enu_mps[moving, :2]
    vel = vel[np.isfinite(vel).all(axis=1)]
    return vel.shape[0] >= 30 and float(np.sum((vel - vel.mean(axis=0)) ** 2)) >= (
        vel.shape[0] * LAG_MIN_VEL_RMS_MPS ** 2)


# The name a calibrated profile takes: its base profile's, with this suffix.
CALIBRATED_SUFFIX = "-calibrated"
EPOCH_SEGMENTS = ("all", "startup", "steady", "moving", "stationary", "near_buildings", "open")


def unexplained(where_final: list[dict]) -> list[dict]:
    """What stays outside its band with the calibrated profile (epoch segments and per run),
    with its size: how far the real value lies beyond the band (``beyond``, the metric's
    units) and its signed z."""
    out = []
    for w in where_final:
        if not w["outside"] or not (w["segment"] in EPOCH_SEGMENTS
                                    or w["segment"].startswith("run:")):
            continue
        beyond = w["real"] - w["sim_hi"] if w["real"] > w["sim_hi"] else w["real"] - w["sim_lo"]
        out.append({"metric": w["metric"], "segment": w["segment"],
                    "same_as": w.get("same_as", []), "real": w["real"],
                    "sim_lo": w["sim_lo"], "sim_hi": w["sim_hi"],
                    "sim_median": w["sim_median"], "beyond": beyond, "z": w["z"]})
    return out


def public(entry: dict) -> dict:
    """An effect entry without its private fields."""
    return {k: v for k, v in entry.items() if not k.startswith("_")}


def write_profile(table: dict, base_name: str, added: Sequence[str], path: Path,
                  notes: Sequence[str] = ()) -> None:
    """Write the calibrated profile TOML (``run``/``replay --profile PATH`` accept it): ``table``
    with the effects named in ``added``, made from the profile ``base_name``, with ``notes``
    (sentences: what the outer test cannot vouch for) as comments at its head.

    A profile that ``gap`` calibrated before keeps its name (``NAME-calibrated``, not
    ``NAME-calibrated-calibrated``) and its description grows by the effects added this time.
    """
    t = dict(table)
    done = " (no effect reduced the held-out gap)"
    again = base_name.endswith(CALIBRATED_SUFFIX)
    t["name"] = base_name if again else base_name + CALIBRATED_SUFFIX
    before = str(table.get("description", base_name)) if again else base_name
    if added:
        t["description"] = f"{before.removesuffix(done)} + " + ", ".join(added)
    else:
        t["description"] = before if again else before + done
    head = ("# Made by `virtualgps gap`: the profile under test with the effects that reduced\n"
            "# the held-out gap, their parameters fitted on every run.\n")
    for n in notes:
        head += "".join(f"# {line}\n" for line in textwrap.wrap(
            n[0].upper() + n[1:] + ".", 92))
    path.write_text(head + fx.to_toml(t), encoding="utf-8")
