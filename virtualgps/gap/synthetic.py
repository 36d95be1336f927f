"""The self-check's synthetic trials (``virtualgps gap --selfcheck``, DESIGN section 7.4).

For every effect the check can inject: pseudo-real logs are made by the simulator with the
effect switched on at known parameters (drawn per trial), on a fresh trajectory (static or
moving, open sky or the bundled campus, a time drawn near the TLE set's epoch) with a fresh
seed, written as NMEA and read back like a real log; the diagnosis then runs on them with the
effect withheld from the profile (:mod:`.selfcheck`). A trial's row says what was ranked and
added first and which parameters were recovered within their intervals.

The profile under test is ``holux-m1000`` with the effect switched off (for its own effects) or
as it is (for the effects it lacks); ``noise_level`` and ``dop_error``, which change the
baseline error, are checked on ``usarsim``; ``multipath`` on ``ideal`` with ``dop_error`` (white
errors of its own, against which metres of error on the low satellites stand out; the
``holux-m1000``'s minutes-long correlated error hides them in a 15-minute log). Each effect is
checked where its signature can show at the drawn parameters: ``nlos`` near the campus's walls;
``multipath`` in open sky, where the low satellites it acts on are received directly (between
the campus's buildings they are blocked, and the ones received, above ~22 deg, get a tenth of
it); ``latency`` and ``nav_filter`` on vehicle paths (at walking speed their lag, 1-4 m, is below
a receiver's error between buildings); a blocked sky sector in open sky (between buildings the
mesh blocks much of it already).
"""

from __future__ import annotations

import io
import json
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps import geodesy
from virtualgps.device import nmea
from virtualgps.gap import effects as fx
from virtualgps.gap.bands import holdout_counts
from virtualgps.poses import pose
from virtualgps.receiver.definition import Georef, Receiver
from virtualgps.receiver.profiles import load_profile_dict
from virtualgps.receiver.skyview import compute_sky
from virtualgps.run.replay import epoch_grid, run_replay

DURATION_S = 900.0  # each pseudo-real run: 15 minutes at 1 Hz


SEED_BASE = 100_000  # pseudo-real seeds lie far from the diagnosis' seeds 0..N


NOTHING = "nothing"  # what a diagnosis that adds no effect ranks first


@dataclass(frozen=True)
class Injection:
    """How one effect is injected.

    base : the profile under test; withhold : tables that switch the effect off in it
    draw : (rng, low_sats) -> the injected tables (known parameters); low_sats: (12,) the
        run's mean number of satellites below 30 deg elevation per 30 deg of azimuth
    scenarios : the trajectories it is checked on (cycled over trials)
    on_axes : (injected tables, the base profile's tables) -> the injection on the candidate's
        own axes where those are not the tables' keys (a scale of the base's values), so that
        its recovery is judged on them too; None: the tables' keys are the axes
    """

    base: str
    withhold: dict
    draw: Callable[[np.random.Generator, np.ndarray], dict]
    scenarios: tuple[str, ...]
    on_axes: Callable[[dict, dict], dict] | None = None


def _u(rng: np.random.Generator, lo: float, hi: float, nd: int = 1) -> float:
    return round(float(rng.uniform(lo, hi)), nd)


def _sector(rng: np.random.Generator, low_sats: np.ndarray) -> list[list[float]]:
    """A blocked sky sector (a wall or a vehicle the scene lacks): 60-120 deg of azimuth from
    the horizon to 30-45 deg of elevation, in 30 x 15 deg bins.

    It is placed where the run's satellites pass below 30 deg both inside it and outside it
    (``low_sats``: (12,) mean number of satellites below 30 deg per 30 deg of azimuth): a
    sector that one satellite crosses for a few minutes leaves next to no trace in a log, and
    one that holds every low satellite is the same, in the log, as a higher elevation mask.
    Without such a place, anywhere.
    """
    width, rows = int(rng.integers(2, 5)), int(rng.integers(2, 4))
    inside = np.array([[(c - s) % 12 < width for c in range(12)] for s in range(12)])
    low = np.asarray(low_sats, dtype=float)
    fits = np.flatnonzero(((inside * low).sum(1) >= MIN_SECTOR_SATS)
                          & ((~inside * low).sum(1) >= MIN_SECTOR_SATS))
    start = int(rng.choice(fits)) if fits.size else int(rng.integers(0, 12))
    row = [math.inf if inside[start, c] else 0.0 for c in range(12)]
    return [list(row) for _ in range(rows)]


MIN_SECTOR_SATS = 1.5  # mean satellites below 30 deg inside (and outside) a blocked sector

# The base of the noise trials: the paper's profile, whose error is its Gaussian noise alone
# (``noise_level`` scales it; ``dop_error`` replaces it)
NOISE_BASE = "usarsim"


INJECTIONS: dict[str, Injection] = {
    "correlated_error": Injection(
        "holux-m1000", {"correlated_error": {"enabled": False}},
        lambda r, _: {"correlated_error": {"enabled": True, "domain": "range",
                                           "tau_s": _u(r, 80, 400, 0), "sigma_m": _u(r, 2.5, 5)}},
        ("static_open", "moving_open", "static_built")),
    "cold_start": Injection(
        "holux-m1000", {"cold_start": {"enabled": False}},
        lambda r, _: {"cold_start": {"enabled": True, "power_on": "cold",
                                     "ttff_cold_s": _u(r, 25, 60, 0)}},
        ("static_open", "moving_open", "static_built")),
    "cn0_tracking": Injection(
        "holux-m1000", {"cn0_tracking": {"enabled": False}},
        lambda r, _: {"cn0_tracking": {"enabled": True, "cn0_zenith_dbhz": _u(r, 35, 41, 0),
                                       "horizon_loss_db": _u(r, 16, 24, 0)}},
        ("static_open", "moving_open", "static_built")),
    "nlos": Injection(
        "holux-m1000", {"nlos": {"enabled": False}},
        lambda r, _: {"nlos": {"enabled": True, "scattering": True, "max_dist_m": 50.0,
                               "reflection_loss_db": _u(r, 4, 8, 0)}},
        ("moving_built",)),
    "multipath": Injection(
        "ideal", {"dop_error": {"enabled": True}},
        lambda r, _: {"multipath": {"enabled": True, "sigma_m": _u(r, 10, 20), "tau_s": 30.0,
                                    "open_sky_factor": 1.0}},
        ("static_open",)),
    "latency": Injection(
        "holux-m1000", {},
        lambda r, _: {"latency": {"enabled": True, "latency_s": _u(r, 0.5, 2.0, 2)}},
        ("moving_open",)),
    "nav_filter": Injection(
        "holux-m1000", {},
        lambda r, _: {"nav_filter": {"enabled": True, "tau_s": _u(r, 1.5, 4.0)}},
        ("moving_open",)),
    "static_hold": Injection(
        "holux-m1000", {},
        lambda r, _: {"static_hold": {"enabled": True, "threshold_mps": _u(r, 0.6, 1.5)}},
        ("moving_open", "moving_built")),
    "sbas": Injection(
        "holux-m1000", {},
        lambda r, _: {"sbas": {"enabled": True}},
        ("static_open", "moving_open", "static_built")),
    "elevation_mask": Injection(
        "holux-m1000", {},
        lambda r, _: {"sky": {"elevation_mask_deg": _u(r, 15, 25, 0)}},
        ("static_open", "moving_open")),
    "sky_mask": Injection(
        "holux-m1000", {},
        lambda r, low: {"sky_mask": {"enabled": True, "az_bin_deg": 30.0, "el_bin_deg": 15.0,
                                  "atten_db": _sector(r, low)}},
        ("static_open", "moving_open")),
    "noise_level": Injection(
        NOISE_BASE, {},
        lambda r, _: _scaled_noise(_u(r, 2.0, 3.75, 2)),
        ("static_open", "moving_open"),
        lambda tables, base: {"scale": round(tables["noise"]["max_noise_m"]
                                             / base["noise"]["max_noise_m"], 3)}),
    "dop_error": Injection(
        NOISE_BASE, {},
        lambda r, _: {"noise": {"model": "none"}, "dop_error": {"enabled": True}},
        ("static_open", "moving_open"),
        lambda tables, base: {"scale": 1.0}),  # the UERE budget as it is (effects.UERE_M)
}


def _scaled_noise(scale: float) -> dict:
    """``noise_level`` as its candidate fits it (:mod:`virtualgps.gap.effects`): the base
    profile's maxNoise and minNoise both times ``scale`` (the candidate has one axis, so an
    injection off it would leave nothing to recover)."""
    noise = load_profile_dict(NOISE_BASE)[0]["noise"]
    return {"noise": {k: round(float(noise[k]) * scale, 3) for k in ("max_noise_m", "min_noise_m")}}


def _moving_enu(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """(n, 3) ENU positions of a vehicle-like path: legs at 2-10 m/s with turns, slow spells
    (0-0.3 m/s) and stops in between (accelerations, turns and crawls: what latency,
    nav_filter and static_hold show up in)."""
    n = t.size
    speed = np.zeros(n)
    heading = np.zeros(n)
    i, h = 0, rng.uniform(0, 2 * np.pi)
    while i < n:
        leg = int(rng.uniform(40, 120))
        v = rng.uniform(2.0, 10.0)
        turn = rng.uniform(-0.05, 0.05)  # rad/s
        k = np.arange(min(leg, n - i))
        speed[i : i + k.size] = v * np.minimum(1.0, (k + 1) / 8.0)  # accelerate over ~8 s
        heading[i : i + k.size] = h + turn * k
        h = heading[i + k.size - 1]
        i += k.size
        slow = int(rng.uniform(10, 30))
        speed[i : i + slow] = rng.uniform(0.0, 0.3)
        heading[i : i + slow] = h
        i += slow
    dt = np.diff(t, prepend=t[0])
    east = np.cumsum(speed * np.sin(heading) * dt)
    north = np.cumsum(speed * np.cos(heading) * dt)
    return np.stack([east, north, np.zeros(n)], axis=1)


def _walk_in_scene(scene, rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """(n, 3) ENU: along the scene's demo waypoints (streets between the buildings), from a
    random start, at 1-4 m/s with stops, 1.5 m above the ground."""
    wp = np.asarray(scene.demo_waypoints_enu_m, dtype=float)
    loop = np.vstack([wp, wp[:1]])
    seg = np.linalg.norm(np.diff(loop[:, :2], axis=0), axis=1)
    s_knots = np.concatenate([[0.0], np.cumsum(seg)])
    speed = np.where((t - t[0]) % 120.0 < 100.0, rng.uniform(1.0, 4.0), 0.0)
    s = (rng.uniform(0, s_knots[-1]) + np.cumsum(speed * np.diff(t, prepend=t[0]))) % s_knots[-1]
    xy = np.stack([np.interp(s, s_knots, loop[:, a]) for a in (0, 1)], axis=1)
    up = scene.ground_height_m(xy[:, 0], xy[:, 1]) + 1.5
    return np.column_stack([xy, up])


def _static_in_scene(scene, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) ENU: a random point near the demo walk 3-10 m from a wall (where buildings block
    and reflect), 1.5 m above the ground."""
    from virtualgps.receiver.walls import Facades
    from virtualgps.sky.scene import CLASS_OCCLUDER

    wp = np.asarray(scene.demo_waypoints_enu_m, dtype=float)
    sel = scene.face_class == CLASS_OCCLUDER
    walls = Facades(scene.vertices_enu_m, scene.faces[sel], scene.face_object[sel])
    a = rng.integers(0, len(wp), 64)
    xy = wp[a, :2] + rng.uniform(0, 1, (64, 1)) * (wp[(a + 1) % len(wp), :2] - wp[a, :2])
    xy = xy + rng.normal(0, 8, (64, 2))
    up = scene.ground_height_m(xy[:, 0], xy[:, 1]) + 1.5
    pts = np.column_stack([xy, up])
    d = walls.wall_dist_m(pts, 30.0)
    good = np.flatnonzero((d >= 3.0) & (d <= 10.0))
    k = int(good[0]) if good.size else int(np.argmin(np.abs(d - 6.0)))
    return np.tile(pts[k], (n, 1))


def _low_sats(rx: Receiver, t: np.ndarray, enu: np.ndarray) -> np.ndarray:
    """(12,) mean number of satellites above the mask and below 30 deg, per 30 deg of
    azimuth."""
    sky = compute_sky(rx, t, enu)
    low = sky.above_mask & (sky.el_deg < 30.0)
    col = (np.nan_to_num(sky.az_deg[low]) % 360.0 // 30.0).astype(int)
    return np.bincount(np.clip(col, 0, 11), minlength=12) / len(t)


@dataclass(frozen=True)
class Spec:
    """What one kind of trial injects: its label, the profile under test, the tables that
    withhold the effects from it, and the effects injected (none for a null trial).

    kind : "single", "pair" or "null"; effects : the injected effects' names
    scenarios : the trajectories it is checked on (cycled over trials)
    """

    label: str
    kind: str
    base: str
    withhold: dict
    effects: tuple[str, ...]
    scenarios: tuple[str, ...]


def spec_of(label: str) -> Spec:
    """The trial spec of an effect name, a pair ``a+b`` of effects or ``nothing@PROFILE``;
    ``EFFECT@PROFILE`` (or ``a+b@PROFILE``) injects into another profile than the effect's
    own base (a name or a TOML path), drawn as in its own trials, withheld from and diagnosed
    against that profile (an effect it already has is switched off where the effect's own
    trial withholds it). ``noise_level`` and ``dop_error`` stay on their base, whose noise
    they are stated in.
    """
    names_part, _, other = label.partition("@")
    if names_part == NOTHING:
        base = other or "holux-m1000"
        return Spec(label, "null", base, {}, (), NULL_SCENARIOS.get(base, ALL_SCENARIOS))
    names = tuple(names_part.split("+"))
    unknown = [n for n in names if n not in INJECTIONS]
    if unknown:
        raise ValueError(f"{label}: no self-check trial injects {', '.join(unknown)} (those "
                         f"that do: {', '.join(INJECTIONS)}, nothing@PROFILE)")
    injs = [INJECTIONS[n] for n in names]
    if len({i.base for i in injs}) != 1:
        raise ValueError(f"{label}: the effects are checked on different profiles")
    if other and any(i.on_axes is not None for i in injs):
        raise ValueError(f"{label}: {names_part} is checked on {injs[0].base} only (its "
                         "injection is stated in that profile's noise)")
    common = tuple(sc for sc in injs[0].scenarios if all(sc in i.scenarios for i in injs))
    withhold: dict = {}
    for i in injs:
        withhold = fx.apply(withhold, i.withhold)
    return Spec(label, "pair" if len(names) > 1 else "single", other or injs[0].base, withhold,
                names, common or injs[0].scenarios)


# Null trials: logs made by the profile under test itself, in each kind of place (any other
# profile, a name or a TOML path: in all four). A self-check runs these profiles' by default:
# the MTK, the paper's, and a multi-system u-blox (its log and diagnosis on GPS and GLONASS).
ALL_SCENARIOS = ("static_open", "moving_open", "static_built", "moving_built")
NULL_SCENARIOS = {"holux-m1000": ALL_SCENARIOS, "usarsim": ("static_open", "moving_open"),
                  "ublox-m8n": ALL_SCENARIOS}


# Two effects at once, on the profile both are withheld from, where both can show.
PAIRS = ("cold_start+latency", "cn0_tracking+static_hold")


def trial_tag(label: str) -> str:
    """A trial label as a file-name stem: ``cold_start+latency`` -> ``cold_start-latency``,
    ``nothing@my/prof.toml`` -> ``nothing-my-prof.toml`` (a profile's path holds separators)."""
    return re.sub(r"[^A-Za-z0-9_.]+", "-", label)


@dataclass(frozen=True)
class Trial:
    """One pseudo-real run, written to files the diagnosis reads."""

    label: str
    index: int
    scenario: str
    injected: dict
    real: Path
    truth: str
    scene: str | None
    tle: str
    profile: Path


def make_trial(label: str, index: int, work: Path, scene, scene_dir: str, scene_tle: str,
               open_tle: str) -> Trial:
    """Write the pseudo-real NMEA log, its truth and the withheld profile of one trial.

    A trial in open sky runs near ``open_tle``'s epoch, one among the scene's buildings near
    ``scene_tle``'s. A base profile that tracks more systems than GPS runs near the scene
    set's epoch in both, where sets of those systems are bundled: its log and its diagnosis
    see every system it tracks, each from the set nearest the trial's start
    (:func:`virtualgps.sky.skytime.choose_tle_set`, as ``replay`` and ``gap`` choose them);
    ``Trial.tle`` then joins the sets' paths with ``os.pathsep``.
    """
    from virtualgps.sky.ephemeris import load_tle, load_tle_sets
    from virtualgps.sky.skytime import choose_system_sets

    spec = spec_of(label)
    rng = np.random.default_rng([SEED_BASE, _label_index(label), index])
    scenario = spec.scenarios[index % len(spec.scenarios)]
    built = scenario.endswith("built")
    base, _ = load_profile_dict(spec.base)
    letters = fx.build(base).constellations.letters()
    tle = scene_tle if built or letters != "G" else open_tle
    eph = load_tle(tle)
    t0 = float(np.floor(eph.epoch_center_unix_s + rng.uniform(-2, 2) * 86400.0))
    if letters != "G":
        others, _ = choose_system_sets(letters.replace("G", ""), t0)  # (none: left out)
        tle = os.pathsep.join([tle, *(str(path) for path, _ in others)])
        eph = load_tle_sets(tle.split(os.pathsep), systems_kept=letters)
    t = t0 + np.arange(DURATION_S + 1.0)
    if built:
        georef = Georef(scene.lat_deg, scene.lon_deg, scene.alt_hae_m)
        enu = (_walk_in_scene(scene, rng, t) if scenario.startswith("moving")
               else _static_in_scene(scene, rng, t.size))
    else:
        georef = Georef(round(float(rng.uniform(-55, 55)), 4),
                        round(float(rng.uniform(-180, 180)), 4), 100.0)
        enu = _moving_enu(rng, t) if scenario.startswith("moving") else np.zeros((t.size, 3))
    withheld = fx.apply(base, spec.withhold)
    injected: dict = {}
    if spec.effects:
        low = _low_sats(Receiver(fx.build(withheld), eph, scene if built else None, georef), t,
                        enu)
        for name in spec.effects:
            injected = fx.apply(injected, INJECTIONS[name].draw(rng, low))
    real_prof = fx.build(fx.apply(withheld, injected), f"selfcheck {label}")
    rx = Receiver(real_prof, eph, scene if built else None, georef)
    track = pose.PoseTrack(t, "enu", enu, np.full(enu.shape, np.nan))
    buf = io.BytesIO()
    fmt = nmea.NmeaFormat.from_dict(real_prof.nmea)
    run_replay(rx, track, epoch_grid(t, real_prof.rate_hz, None), fmt, buf,
               SEED_BASE + 1000 * _label_index(label) + index)
    tag = f"{trial_tag(label)}-{index}"
    work.mkdir(parents=True, exist_ok=True)
    real = work / f"{tag}.nmea"
    real.write_bytes(buf.getvalue())
    ecef = geodesy.enu_to_ecef(enu, georef.lat0_deg, georef.lon0_deg, georef.alt0_hae_m)
    lat, lon, alt = geodesy.ecef_to_geodetic(ecef)
    if scenario.startswith("static"):
        truth = f"static:{lat[0]:.9f},{lon[0]:.9f},{alt[0]:.3f}"
    else:
        truth_path = work / f"{tag}-truth.jsonl"
        truth_path.write_text("".join(
            json.dumps({"t": float(ti), "lat": float(a), "lon": float(b), "alt": float(c)}) + "\n"
            for ti, a, b, c in zip(t, lat, lon, alt, strict=True)))
        truth = str(truth_path)
    prof_path = work / f"{tag}-profile.toml"
    name = base.get("name") or Path(spec.base).stem
    withheld = dict(withheld, name=f"{name}-without-{'+'.join(spec.effects)}" if spec.effects
                    else name)
    prof_path.write_text(fx.to_toml(withheld), encoding="utf-8")
    return Trial(label, index, scenario, injected, real, truth,
                 scene_dir if built else None, tle, prof_path)


def _label_index(label: str) -> int:
    """A stable number per trial label (the trial's random streams)."""
    if label in INJECTIONS:
        return list(INJECTIONS).index(label)
    return 100 + sum((k + 1) * ord(c) for k, c in enumerate(label)) % 10_000


def recovered(names: tuple[str, ...], report: dict) -> tuple[dict, dict, dict]:
    """The fitted parameters of the injected effects as the report gives them (with the axis
    values of the chosen point, ``fit.point``, that the parameters do not name), their
    intervals (``fit.intervals``: the near-optimal grid points and those refits picked) and
    the grids those were fitted over."""
    params, intervals, grids = {}, {}, {}
    for e in report["effects"]:
        if e["name"] in names and e.get("accepted"):
            params.update({**(e.get("fit") or {}).get("point", {}), **e["params"]})
            intervals.update((e.get("fit") or {}).get("intervals", {}))
            grids.update((e.get("fit") or {}).get("grid", {}))
    return params, intervals, grids


def covered(injected: dict, intervals: dict, grids: dict | None = None) -> dict[str, bool]:
    """Per numeric injected parameter with an interval: does the interval hold it? An
    interval is a set of grid points, and a fit resolves a value to the nearest point: a value
    between the interval's end and the next grid point outside it counts as held when it lies
    nearer the end (the span widened half-way to those neighbours; without the grid, the span
    itself)."""
    out = {}
    for k, v in injected.items():
        iv = intervals.get(k)
        if isinstance(v, int | float) and not isinstance(v, bool) and isinstance(iv, list) \
                and len(iv) == 2 and all(isinstance(x, int | float) for x in iv):
            lo, hi = fx.grid_span((grids or {}).get(k) or [], float(iv[0]), float(iv[1]))
            out[k] = bool(lo - 1e-9 <= v <= hi + 1e-9)
    return out


def _flat(tables: dict) -> dict:
    out: dict[str, Any] = {}
    for t in tables.values():
        out.update({k: v for k, v in t.items() if k != "enabled"})
    return out


def _row(trial: Trial, kind: str, effects: tuple[str, ...], report: dict) -> dict:
    """The self-check's record of one trial."""
    accepted = [e["name"] for e in report["effects"] if e.get("accepted")]
    # "nothing" ranks after the added effects and before every candidate not added
    ranked = accepted + [NOTHING] + [e["name"] for e in report["effects"]
                                     if not e.get("accepted")]
    params, intervals, grids = recovered(effects, report)
    injected = _flat(trial.injected)
    on_axes = [INJECTIONS[n].on_axes for n in effects if INJECTIONS[n].on_axes is not None]
    if on_axes:
        base = load_profile_dict(spec_of(trial.label).base)[0]
        for where in on_axes:
            injected.update(where(trial.injected, base))
    if kind == "null":
        success = ranked[0] == NOTHING
    elif kind == "pair":
        success = set(accepted[:len(effects)]) == set(effects)
    else:
        success = ranked[0] == effects[0]
    return {
        "injected": trial.label, "kind": kind, "effects": list(effects),
        "scenario": trial.scenario, "params": injected, "ranked": ranked,
        "accepted": accepted, "ranked_first": ranked[0],
        "added_first": accepted[0] if accepted else NOTHING, "success": success,
        "alternative": (report.get("alternative") or {}).get("effects"),
        "recovered": params, "recovered_interval": intervals,
        "covered": covered(injected, intervals, grids),
        **report_fields(report), "real": str(trial.real), "truth": trial.truth,
    }


def report_fields(report: dict) -> dict:
    """What every self-check trial records of its diagnosis's report: the outer test's gaps,
    reduction, interval and verdict (``outer_confirmed``: its interval above 0, None with one
    group) and the effects it cannot judge, the located-gap rows, the seed holdout and the
    causes applied."""
    outer = report.get("outer") or {}
    where = report["where"]
    return {
        "gap_before": report["gap_baseline"], "gap_after": report["gap_final"],
        "outer_reduction": outer.get("reduction"), "outer_interval": outer.get("interval"),
        "outer_confirmed": outer.get("confirmed"),
        "outer_not_judged": [n["effect"] for n in outer.get("not_judged", [])],
        "where_rows": len(where), "where_outside": sum(w["outside"] for w in where),
        "seed_holdout": holdout_counts(report["band"]),
        "causes": [c["name"] for c in report.get("causes", []) if c.get("applied")],
    }
