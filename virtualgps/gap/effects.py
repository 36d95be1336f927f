"""The candidate effects of a diagnosis: which DESIGN section 6 effects a profile lacks, the
parameter values each is tried with, and how a candidate becomes a profile.

"Adding an effect" is switching on its profile table (the same ``receiver.simulate``), so a
candidate's grid point is a small table of profile keys (``{"correlated_error": {"enabled":
True, "tau_s": 120.0, ...}}``) merged into the profile under test. A candidate's parameters are
axes; its grid is their product, spanning the values they take in real receivers (sources in
:mod:`virtualgps.receiver.profiles`), evenly on the scale each is judged on (geometric for times and
scales). Its default, the point kept when the data cannot tell the points apart, is the
profile's own value where the profile's table names the key, else the grid's centre: never a
value fitted on anyone's log. An axis whose best point lies at the grid's edge can be extended
by one step (:meth:`Candidate.extended`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from virtualgps.receiver.params import CorrelatedErrorParams
from virtualgps.receiver.profiles import build_profile, merge

# Every effect name of DESIGN section 6 (``sky_mask`` is the learned part of ``foliage``).
EFFECT_NAMES = (
    "noise_level", "correlated_error", "dop_error", "cold_start", "nlos", "multipath",
    "foliage", "sky_mask", "cn0_tracking", "elevation_mask", "latency", "static_hold",
    "nav_filter", "sbas", "constellations",
)  # fmt: skip

# The effects that act on which satellites stand where (blocked, masked, weakened or reflected by
# direction and elevation): fitted to a sky that is not the log's (causes.sky), they would explain
# that sky's differences, not the receiver's. (dop_error acts through DOP alone, which a plausible
# sky of another date gives alike, and stays.)
SKY_PLACED = ("nlos", "multipath", "foliage", "sky_mask", "cn0_tracking", "elevation_mask",
              "constellations")


@dataclass(frozen=True)
class Axis:
    """One fitted parameter: its name (the report's key), its grid values, and how far it may
    be extended (``lo``, ``hi``; None: not extended, e.g. on/off or a choice)."""

    name: str
    values: tuple
    lo: float | None = None
    hi: float | None = None

    def step_beyond(self, upper: bool) -> float | None:
        """The next value past the grid's upper (or lower) end, on the grid's own spacing
        (geometric when its values are, else linear), within ``lo``/``hi``; None if none."""
        if self.lo is None or len(self.values) < 2:
            return None
        v = sorted(float(x) for x in self.values)
        a, b = (v[-2], v[-1]) if upper else (v[1], v[0])
        geometric = all(x > 0 for x in v) and len(v) >= 3 and (
            abs(math.log(v[-1] / v[-2]) - math.log(v[1] / v[0])) < 0.2)
        nxt = b * (b / a) if geometric and a > 0 else b + (b - a)
        nxt = round(nxt, 3)
        if not (self.lo < nxt < (self.hi if self.hi is not None else math.inf)):
            return None
        return nxt


def value_text(value: Any) -> str:
    """A parameter's value for people: a number as ``%g``; a table of numbers (a learned sky
    mask's attenuation per azimuth-elevation bin) as how many of its cells are not zero and the
    largest, not its every cell."""
    if isinstance(value, list | tuple) and value and isinstance(value[0], list | tuple):
        flat = [float(x) for row in value for x in row]
        nz = [x for x in flat if x]
        return f"{len(nz)} of {len(flat)} cells not zero" + (f", up to {max(nz):g}" if nz else "")
    return f"{value:g}" if isinstance(value, float) else str(value)


def grid_span(grid: Sequence[float], lo: float, hi: float) -> list[float]:
    """The values a fit resolves into the grid points from ``lo`` to ``hi``: the span widened
    half-way to the nearest grid values outside it (a value between the interval's end and the
    next point outside lies nearer the end); an end of the grid stays where it is.

    grid : the axis's grid values (after any extension); lo, hi : the interval's grid values
    Returns [lo, hi] in the axis's units"""
    below = [g for g in grid if g < lo]
    above = [g for g in grid if g > hi]
    return [float(lo) - ((lo - max(below)) / 2.0 if below else 0.0),
            float(hi) + ((min(above) - hi) / 2.0 if above else 0.0)]


@dataclass(frozen=True)
class Candidate:
    """One effect to try: its axes, how a point becomes profile tables, its default point.

    axes : the fitted parameters (none: on/off)
    make : point {axis: value} -> override tables ({table: {key: value}})
    params : the report's parameter names (profile keys) read back from a point's tables
    default : the default point {axis: value}
    learned : sky_mask: its grid is learned per fold, at these levels
    learned_atten : sky_mask: also C/N0 deficits as attenuation (cn0_tracking on)
    whole : the candidate this one was cut from (:meth:`near`); None: it is whole
    """

    name: str
    axes: tuple[Axis, ...]
    make: Callable[[dict[str, Any]], dict[str, dict[str, Any]]] = field(repr=False)
    params: tuple[str, ...]
    default: dict[str, Any] = field(default_factory=dict)
    learned: tuple[float, ...] = ()
    learned_atten: bool = False
    whole: Candidate | None = field(default=None, repr=False, compare=False)

    @property
    def points(self) -> list[dict[str, Any]]:
        """Every grid point, the first axis slowest."""
        names = [a.name for a in self.axes]
        return [dict(zip(names, vals, strict=True))
                for vals in itertools.product(*(a.values for a in self.axes))]

    @property
    def grid(self) -> list[dict[str, dict[str, Any]]]:
        """The override tables of every grid point."""
        return [self.make(p) for p in self.points]

    @property
    def default_index(self) -> int:
        return self.points.index(self.default) if self.default in self.points else 0

    @property
    def complexity(self) -> int:
        """Parameters it adds (a tie between candidates goes to the smaller)."""
        return max(1, len(self.axes))

    def extended(self, axis: str, upper: bool) -> Candidate | None:
        """The candidate with one more value past an end of ``axis`` (None: cannot): the next
        value of the whole grid where this one is cut from it (:meth:`near`), else one step
        on the axis's own spacing."""
        out = []
        new = None
        for a in self.axes:
            if a.name == axis:
                new = self.whole_beyond(a.name, upper)
                new = a.step_beyond(upper) if new is None else new
                if new is None:
                    return None
                vals = tuple(sorted(set(a.values) | {new}))
                a = Axis(a.name, vals, a.lo, a.hi)
            out.append(a)
        return Candidate(self.name, tuple(out), self.make, self.params, self.default,
                         self.learned, self.learned_atten, self.whole) if new is not None else None

    def whole_beyond(self, axis: str, upper: bool) -> Any:
        """The whole grid's value next past an end of ``axis`` where this candidate is cut
        from it (:meth:`near`); None: none."""
        if self.whole is None:
            return None
        cut = next(a for a in self.axes if a.name == axis)
        whole = next(a for a in self.whole.axes if a.name == axis)
        if not all(isinstance(v, int | float) for v in whole.values):
            return None
        past = [v for v in whole.values
                if (v > max(cut.values) if upper else v < min(cut.values))]
        return (min(past) if upper else max(past)) if past else None

    def near(self, chosen: list[dict[str, Any]]) -> Candidate:
        """The candidate with each axis cut to the values within one grid step of those
        ``chosen`` (points of an earlier round: a later round refits around them); the default
        moves to the nearest kept value."""
        if not chosen or not self.axes:
            return self
        out = []
        for a in self.axes:
            idx = {a.values.index(p[a.name]) for p in chosen if p.get(a.name) in a.values}
            keep = sorted({k + d for k in idx for d in (-1, 0, 1)
                           if 0 <= k + d < len(a.values)}) or range(len(a.values))
            out.append(Axis(a.name, tuple(a.values[k] for k in keep), a.lo, a.hi))
        default = {}
        for a in out:
            v = self.default.get(a.name)
            default[a.name] = v if v in a.values else min(
                a.values, key=lambda x, v=v: 0 if x == v else (
                    abs(x - v) if isinstance(x, int | float) and isinstance(v, int | float)
                    else 1))
        return Candidate(self.name, tuple(out), self.make, self.params, default, self.learned,
                         self.learned_atten, self.whole or self)

    def params_of(self, overrides: dict[str, dict[str, Any]]) -> dict[str, Any]:
        """The fitted parameters of an override table as profile keys (flat, for the report)."""
        out: dict[str, Any] = {}
        for table in overrides.values():
            out.update({k: v for k, v in table.items() if k in self.params})
        return out


def _enabled(profile: dict[str, Any], table: str) -> bool:
    return bool(profile.get(table, {}).get("enabled", False))


def _hot_start(profile: dict[str, Any]) -> bool:
    """The profile powers on with a hot start or none (a fix within a second or two)."""
    return _enabled(profile, "cold_start") and profile["cold_start"].get(
        "power_on", "none") in ("hot", "none")


def _default(axes: tuple[Axis, ...], own: dict[str, Any]) -> dict[str, Any]:
    """Per axis the grid value nearest the profile's own value where it names one, else the
    grid's centre (the lower middle of an even count)."""
    out = {}
    for a in axes:
        v = own.get(a.name)
        if v is not None and all(isinstance(x, int | float) and not isinstance(x, bool)
                                 for x in (*a.values, v)):
            out[a.name] = min(a.values, key=lambda x: abs(math.log(x + 1e-9) - math.log(
                v + 1e-9)) if x > 0 and v > 0 else abs(x - v))
        elif v is not None and v in a.values:
            out[a.name] = v
        else:
            out[a.name] = a.values[(len(a.values) - 1) // 2]
    return out


def _table_candidate(name: str, table: str, fixed: dict[str, Any], axes: tuple[Axis, ...],
                     profile: dict[str, Any], params: tuple[str, ...] | None = None
                     ) -> Candidate:
    """A candidate that sets its axes as keys of one profile table (plus ``fixed`` keys)."""
    def make(p: dict[str, Any]) -> dict[str, dict[str, Any]]:
        return {table: {**fixed, **p}}

    own = profile.get(table, {})
    return Candidate(name, axes, make, params or tuple(a.name for a in axes),
                     _default(axes, own))


def candidates(
    profile: dict[str, Any], has_mesh: bool, names: tuple[str, ...] | None = None,
    has_gsv: bool = False,
    systems_seen: str = "",
    systems_held: str = "G",
    starts: bool = True,
    sky_wrong: str | None = None,
) -> tuple[list[Candidate], dict[str, str]]:
    """The effects a profile lacks (or has switched off) that can be tried on it. A profile
    that powers on with a hot start (or none) lacks a slow start: ``cold_start`` is tried on
    it too.

    Parameters
    ----------
    profile : the profile table under test (as read from its TOML, with earlier accepted
        effects merged in)
    has_mesh : some run is simulated in a scene with a mesh (``nlos``, ``multipath`` need
        walls)
    has_gsv : the real logs list satellites with SNR (``sky_mask`` is learned from them)
    systems_seen : RINEX letters of the systems the real logs list (``constellations``)
    systems_held : RINEX letters of the systems the ephemeris holds satellites of
    starts : some run's log starts at power-on (without it ``cold_start`` changes nothing)
    sky_wrong : why the simulated sky is not the logs' (``causes.sky``), or None: the effects
        that act on where satellites stand (:data:`SKY_PLACED`) are then not tried
    names : restrict to these effects (``--effects``; empty: none); None: every one

    Returns
    -------
    candidates : the applicable ones
    skipped : {name: why it cannot be tried on this profile}
    """
    out: list[Candidate] = []
    skipped: dict[str, str] = {}
    noise = profile.get("noise", {})
    baseline = noise.get("model", "usarsim") == "usarsim"
    dop = _enabled(profile, "dop_error")
    for name in EFFECT_NAMES if names is None else names:
        if name not in EFFECT_NAMES:
            skipped[name] = "not an effect of DESIGN section 6"
            continue
        table = "sky" if name == "elevation_mask" else name
        if name not in ("noise_level", "elevation_mask", "constellations") and _enabled(
                profile, table) and not (name == "cold_start" and _hot_start(profile)):
            continue  # already in the profile
        if sky_wrong and name in SKY_PLACED:
            skipped[name] = sky_wrong
            continue
        if name == "cold_start" and not starts:
            skipped[name] = ("no run starts at power-on (each log's first epoch has a fix): "
                             "a start-up cannot show")
            continue
        if name == "constellations":
            c = _constellations(profile, systems_seen, systems_held)
            if c is None:
                continue  # (the profile tracks every system the logs list)
        else:
            c = _candidate(name, profile, baseline, dop, has_mesh, has_gsv)
        if isinstance(c, str):
            skipped[name] = c
        else:
            out.append(c)
    return out, skipped


def _constellations(profile: dict, seen: str, held: str) -> Candidate | str | None:
    """``constellations``: track the systems the logs list that the profile does not (each a
    system the ephemeris holds), on top of those it tracks; None when it tracks them all."""
    from virtualgps.sky import systems as sy

    own = profile.get("constellations", {})
    tracked = ("".join(sy.system_named(n).letter for n in own.get("systems", ["GPS"]))
               if own.get("enabled") else "G")
    extra = [x for x in seen if x not in tracked]
    if not extra:
        return None
    names = {x: sy.system_named(x).name for x in "GRECJ"}
    usable = [x for x in extra if x in held]
    if not usable:
        return (f"the logs list {', '.join(names[x] for x in extra)} satellites but the "
                f"ephemeris holds none: give --tle with a set of them")
    on = {"enabled": True, "systems": [names[x] for x in "GRECJ" if x in tracked + "".join(
        usable)]}
    return Candidate("constellations", (), lambda p: {"constellations": dict(on)}, ("systems",))


# The UERE budget's textbook values (params.DopErrorParams), scaled as a whole by dop_error.
UERE_M = {"sis_m": 0.8, "iono_zenith_m": 2.0, "tropo_zenith_m": 0.2, "rx_noise_m": 0.5,
          "multipath_a_m": 0.13, "multipath_b_m": 0.53}
GEOMETRIC = (0.25, 0.35, 0.5, 0.71, 1.0, 1.41, 2.0, 2.83, 4.0)  # sqrt(2) steps about 1


def _dop_noise_level(profile: dict) -> Candidate:
    """``noise_level`` of a profile whose error is DOP-driven (``dop_error``, with or without a
    ``correlated_error``): one scale on its whole error budget, the UERE terms and the
    correlated error's sigma (range or position domain), from 1 (the profile as it is). A
    receiver whose errors are a third of the profile's, or three times, differs by that scale
    first."""
    dop = {k: float(profile.get("dop_error", {}).get(k, v)) for k, v in UERE_M.items()}
    ce = profile.get("correlated_error", {})
    sigma = (float(ce.get("sigma_m", CorrelatedErrorParams.sigma_m)) if ce.get("enabled")
             else None)

    def make(p: dict) -> dict:
        f = p["scale"]
        out = {"dop_error": {k: round(v * f, 3) for k, v in dop.items()}}
        if sigma is not None:
            out["correlated_error"] = {"sigma_m": round(sigma * f, 3)}
        return out
    axes = (Axis("scale", GEOMETRIC, 0.0, 100.0),)
    return Candidate("noise_level", axes, make,
                     tuple(UERE_M) if sigma is None else ("sigma_m", "rx_noise_m"), {"scale": 1.0})


def _candidate(name: str, profile: dict, baseline: bool, dop: bool, has_mesh: bool,  # noqa: C901
               has_gsv: bool):
    on = {"enabled": True}
    if name == "noise_level":
        if not baseline and dop:
            return _dop_noise_level(profile)
        if not baseline:
            return "the profile has no baseline noise to scale (noise.model = \"none\")"
        mx = float(profile.get("noise", {}).get("max_noise_m", 3.0))
        mn = float(profile.get("noise", {}).get("min_noise_m", 1.0))

        def make_noise(p: dict) -> dict:
            f = p["scale"]
            return {"noise": {"max_noise_m": round(mx * f, 3), "min_noise_m": round(mn * f, 3)}}
        axes = (Axis("scale", GEOMETRIC, 0.0, 100.0),)
        return Candidate(name, axes, make_noise, ("max_noise_m", "min_noise_m"), {"scale": 1.0})
    if name == "correlated_error":
        domain = "range" if dop else "position"
        axes = (Axis("tau_s", (15.0, 30.0, 60.0, 120.0, 240.0, 480.0, 960.0), 1.0, 7200.0),
                Axis("sigma_m", (1.0, 1.6, 2.5, 4.0, 6.3), 0.1, 100.0))
        return _table_candidate(name, name, {**on, "domain": domain}, axes, profile,
                                ("tau_s", "sigma_m", "domain"))
    if name == "dop_error":
        def make_dop(p: dict) -> dict:
            f = p["scale"]
            return {"dop_error": {**on, **{k: round(v * f, 3) for k, v in UERE_M.items()}},
                    "noise": {"model": "none"}}
        axes = (Axis("scale", (0.5, 0.71, 1.0, 1.41, 2.0), 0.0, 20.0),)
        return Candidate(name, axes, make_dop, tuple(UERE_M), {"scale": 1.0})
    if name == "cold_start":
        def make_start(p: dict) -> dict:
            v = p["ttff_cold_s"]
            return ({name: {**on, "power_on": "hot"}} if v == 0 else
                    {name: {**on, "power_on": "cold", "ttff_cold_s": v}})
        axes = (Axis("ttff_cold_s", (0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 90.0), 0.0, 1800.0),)
        # (a hot-starting profile names no cold TTFF: the grid's centre, as for one without a
        # start-up; where the training units hold no power-on every point ties and the fold
        # that holds it out is judged with that default)
        return Candidate(name, axes, make_start, ("power_on", "ttff_cold_s"),
                         _default(axes, profile.get(name, {})))
    if name == "nlos":
        if not has_mesh:
            return "needs a scene with walls (no run is simulated in a mesh)"
        tracking = _enabled(profile, "cn0_tracking")
        axes = (Axis("scattering", (False, True)), Axis("max_dist_m", (30.0, 50.0)),
                Axis("reflection_loss_db", (3.0, 5.0, 7.0, 9.0, 12.0) if tracking else (7.0,)))
        return _table_candidate(name, name, on, axes, profile)
    if name == "multipath":
        if not dop:
            return "needs dop_error (its range errors are solved with the others)"
        # Without walls to measure the distance to, the antenna's surroundings (a vehicle's
        # roof, the ground) reflect everywhere alike: the open-sky proximity is 1 and sigma_m
        # takes the scale.
        fixed = on if has_mesh else {**on, "open_sky_factor": 1.0}
        axes = (Axis("sigma_m", (1.0, 2.0, 4.0, 8.0, 16.0), 0.1, 200.0),
                Axis("tau_s", (10.0, 30.0, 100.0), 1.0, 3600.0))
        return _table_candidate(name, name, fixed, axes, profile)
    if name == "foliage":
        if not has_mesh:
            return "needs a scene with trees"
        axes = (Axis("db_per_m", (0.25, 0.5, 1.0, 2.0, 4.0), 0.01, 50.0),)
        return _table_candidate(name, name, on, axes, profile)
    if name == "sky_mask":
        if not has_gsv:
            return "needs GSV with SNR in the real logs (it is learned from what they track)"
        # Attenuation only means something to a receiver whose tracking follows C/N0; without
        # cn0_tracking a C/N0 deficit is that effect's to explain, not a direction's.
        return Candidate(name, (), lambda p: {}, ("az_bin_deg", "el_bin_deg", "atten_db"),
                         learned=SKY_MASK_LEVELS,
                         learned_atten=_enabled(profile, "cn0_tracking"))
    if name == "cn0_tracking":
        axes = (Axis("cn0_zenith_dbhz", (30.0, 33.0, 36.0, 39.0, 42.0, 45.0, 48.0), 20.0, 55.0),
                Axis("horizon_loss_db", (10.0, 16.0, 22.0), 0.0, 40.0))
        return _table_candidate(name, name, on, axes, profile)
    if name == "elevation_mask":
        cur = float(profile.get("sky", {}).get("elevation_mask_deg", 5.0))
        vals = tuple(sorted({0.0, 5.0, 10.0, 15.0, 20.0, 25.0, cur}))
        axes = (Axis("elevation_mask_deg", vals, -0.1, 45.0),)
        return Candidate(name, axes, lambda p: {"sky": {"elevation_mask_deg":
                                                       p["elevation_mask_deg"]}},
                         ("elevation_mask_deg",), {"elevation_mask_deg": cur})
    if name == "latency":
        # steps of 0.1-0.15 s below 1 s and 0.25 s to 2.5 s: a first-order filter of tau
        # lags by exp(-dt/tau) / (1 - exp(-dt/tau)) epochs (0.58 s at tau 1 s, 1 Hz), and a
        # latency between grid points lost to the filter's nearer lag (the lag is measured to
        # a few hundredths of a second: motion.fix_lag_s)
        axes = (Axis("latency_s", (0.1, 0.25, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.25, 1.5,
                                   1.75, 2.0, 2.25, 2.5, 3.0), 0.0, 30.0),)
        return _table_candidate(name, name, on, axes, profile)
    if name == "nav_filter":
        # 0.25 s steps where receivers' filters lie: with coarser grids a pure delay fits a
        # filter's lag better than the filter itself does, and back (steps of 0.5 s move a
        # filter's lag by 0.5 s at 1 Hz, and the lag is measured to a few hundredths: a
        # filter of 1.73 s, lag 1.28 s, was taken for a latency of 1.25 s)
        # and whether it follows the motion with the receiver's own velocity (smoothing only
        # the error, without lag: a phone's filter) or low-passes the position itself
        axes = (Axis("tau_s", (0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0, 3.5,
                               4.0, 6.0, 8.0, 16.0), 0.0, 120.0),
                Axis("velocity_aided", (False, True)))
        return _table_candidate(name, name, on, axes, profile)
    if name == "static_hold":
        axes = (Axis("threshold_mps", (0.2, 0.4, 0.8, 1.6, 3.2), 0.0, 20.0),)
        return _table_candidate(name, name, on, axes, profile)
    if name == "sbas":
        return Candidate(name, (), lambda p: {name: dict(on)}, ())
    raise AssertionError(name)


# A sky bin is masked when the real receiver tracks at most this fraction of what the simulation
# tracks there (shares of the bin's satellite-epochs; each level a grid point), where the
# simulation tracks at least SKY_MASK_SIM_SHARE of them (low bins, where a receiver tracks
# satellites part of the time, count as well as high ones).
SKY_MASK_LEVELS = (0.1, 0.25, 0.4)
SKY_MASK_SIM_SHARE = 0.2
SKY_MASK_MIN_EPOCHS = 30  # satellite-epochs a bin needs before it can be judged
# A bin's mean SNR deficit (dB) below which it is not attenuated: a 15-minute log's fades
# (sigma 2-3.5 dB over 10-20 s) move a bin's mean by about 1 dB.
SKY_MASK_MIN_DEFICIT_DB = 2.0


def learned_sky_mask(counts: Any, level: float, az_bin_deg: float, el_bin_deg: float,
                     atten: bool = False) -> dict[str, dict[str, Any]] | None:
    """A ``sky_mask`` table blocking the sky bins where the real receiver loses what the
    simulation tracks (obstacles the scene lacks: a vehicle roof, a wall, a tree), and with
    ``atten`` attenuating those where it tracks them weaker (a roof or a window over an
    antenna indoors, a crown in leaf: DESIGN 7.5's "C/N0 deficit in fixed sky directions").

    Parameters
    ----------
    counts : (5, n_el * n_az) per bin: compared, real tracked, simulated tracked
        satellite-epochs, real and simulated SNR sums over the tracked ones (rows of bins from
        the horizon up; :func:`virtualgps.gap.where.bin_tracking` summed over units)
    level : real tracked share, as a fraction of the simulated one, at or below which a bin is
        masked
    az_bin_deg, el_bin_deg : the bins' size
    atten : also attenuate the bins tracked by both whose mean SNR is lower in the real log by
        at least SKY_MASK_MIN_DEFICIT_DB (by that deficit, to the nearest dB)

    Returns
    -------
    overrides : {"sky_mask": {...}} with ``inf`` in the masked bins, or None if none is masked
    """
    import numpy as np

    c = np.asarray(counts, dtype=float)
    n_az = int(round(360.0 / az_bin_deg))
    with np.errstate(invalid="ignore", divide="ignore"):
        real, simu = c[1] / c[0], c[2] / c[0]
        deficit = c[4] / c[2] - c[3] / c[1]
    masked = ((c[0] >= SKY_MASK_MIN_EPOCHS) & (simu >= SKY_MASK_SIM_SHARE)
              & (real <= level * simu))
    db = np.where(masked, np.inf, 0.0)
    if atten:
        weaker = ((c[1] >= SKY_MASK_MIN_EPOCHS) & (c[2] >= SKY_MASK_MIN_EPOCHS) & ~masked
                  & (deficit >= SKY_MASK_MIN_DEFICIT_DB))
        db = np.where(weaker, np.round(np.where(weaker, deficit, 0.0)), db)
    if not (db > 0).any():
        return None
    rows = db.reshape(-1, n_az)
    last = int(np.flatnonzero((rows > 0).any(axis=1)).max()) + 1
    return {"sky_mask": {"enabled": True, "az_bin_deg": az_bin_deg, "el_bin_deg": el_bin_deg,
                         "atten_db": [list(map(float, r)) for r in rows[:last]]}}


def apply(profile: dict[str, Any], overrides: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The profile table with a candidate's tables merged in."""
    return merge(profile, overrides)


def build(profile: dict[str, Any], source: str = "<gap>"):
    """:func:`virtualgps.receiver.profiles.build_profile` of a merged table."""
    return build_profile(profile, source)


def to_toml(table: dict[str, Any]) -> str:
    """Write a profile table as TOML (scalars, strings, lists and nested tables)."""
    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int | float):
            return repr(float(v)) if isinstance(v, float) else str(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        raise TypeError(f"cannot write {v!r} as TOML")

    def section(prefix: str, t: dict[str, Any]) -> list[str]:
        lines = [f"{k} = {value(v)}" for k, v in t.items() if not isinstance(v, dict)]
        for k, v in t.items():
            if isinstance(v, dict):
                name = f"{prefix}.{k}" if prefix else k
                key = name if all(c.isalnum() or c in "_-." for c in k) else f'{prefix}."{k}"'
                lines += ["", f"[{key}]"] + section(name, v)
        return lines

    return "\n".join(section("", table)) + "\n"
