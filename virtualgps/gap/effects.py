"""The candidate effects of a diagnosis: which DESIGN section 6 effects a profile lacks, the
parameter values each is tried with, and how a candidate becomes a profile.

"Adding an effect" is switching on its profile table (the same ``receiver.simulate``), so a
candidate is a small table of profile keys (``{"correlated_error": {"enabled": True, "tau_s":
120.0, ...}}``) merged into the profile under test. Each candidate's grid spans the values its
parameters take in real receivers (sources in :mod:`virtualgps.profiles`); the fit picks the
grid point with the smallest training gap (common random numbers: every grid point runs the
same seeds, so the objective is smooth in the parameters). ``default`` is the grid point kept
when the training data say nothing about the parameters (a flat objective, e.g. a start-up
time when no training unit holds a power-on).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

from virtualgps.profiles import build_profile, merge

# Every effect name of DESIGN section 6 (``sky_mask`` is the learned part of ``foliage``).
EFFECT_NAMES = (
    "noise_level", "correlated_error", "dop_error", "cold_start", "nlos", "multipath",
    "foliage", "sky_mask", "cn0_tracking", "elevation_mask", "latency", "static_hold",
    "nav_filter", "sbas",
)  # fmt: skip


@dataclass(frozen=True)
class Candidate:
    """One effect to try: its name, the profile tables of each grid point, the default point.

    grid : tuple of override tables ({table: {key: value}}), one per parameter set
    params : the fitted parameters' names (profile keys), for the report
    default : index into ``grid`` used when the training data cannot tell the points apart
    """

    name: str
    grid: tuple[dict[str, dict[str, Any]], ...]
    params: tuple[str, ...]
    default: int = 0
    learned: tuple[float, ...] = ()  # sky_mask: its grid is learned per fold, at these levels
    learned_atten: bool = False  # sky_mask: also C/N0 deficits as attenuation (cn0_tracking on)

    def params_of(self, overrides: dict[str, dict[str, Any]]) -> dict[str, Any]:
        """The fitted parameters of an override table as profile keys (flat, for the report)."""
        out: dict[str, Any] = {}
        for table in overrides.values():
            out.update({k: v for k, v in table.items() if k in self.params})
        return out


def _points(table: str, fixed: dict[str, Any], **axes: tuple) -> tuple[dict, ...]:
    keys = list(axes)
    return tuple(
        {table: {**fixed, **dict(zip(keys, vals, strict=True))}}
        for vals in itertools.product(*(axes[k] for k in keys))
    )


def _enabled(profile: dict[str, Any], table: str) -> bool:
    return bool(profile.get(table, {}).get("enabled", False))


def candidates(
    profile: dict[str, Any], has_mesh: bool, names: tuple[str, ...] | None = None,
    has_gsv: bool = False,
) -> tuple[list[Candidate], dict[str, str]]:
    """The effects a profile lacks (or has switched off) that can be tried on it.

    Parameters
    ----------
    profile : the profile table under test (as read from its TOML, with earlier accepted
        effects merged in)
    has_mesh : some run is simulated in a scene with a mesh (``nlos``, ``multipath`` need
        walls)
    has_gsv : the real logs list satellites with SNR (``sky_mask`` is learned from them)
    names : restrict to these effects (``--effects``); None: every one

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
    for name in names or EFFECT_NAMES:
        if name not in EFFECT_NAMES:
            skipped[name] = "not an effect of DESIGN section 6"
            continue
        table = "sky" if name == "elevation_mask" else name
        if name != "noise_level" and name != "elevation_mask" and _enabled(profile, table):
            continue  # already in the profile
        c = _candidate(name, profile, baseline, dop, has_mesh, has_gsv)
        if isinstance(c, str):
            skipped[name] = c
        else:
            out.append(c)
    return out, skipped


def _candidate(name: str, profile: dict, baseline: bool, dop: bool, has_mesh: bool,  # noqa: C901
               has_gsv: bool):
    on = {"enabled": True}
    if name == "noise_level":
        if not baseline:
            return "the profile has no baseline noise to scale (noise.model = \"none\")"
        mx = float(profile.get("noise", {}).get("max_noise_m", 3.0))
        mn = float(profile.get("noise", {}).get("min_noise_m", 1.0))
        grid = tuple({"noise": {"max_noise_m": round(mx * f, 3), "min_noise_m": round(mn * f, 3)}}
                     for f in (1.0, 0.1, 0.25, 0.5, 0.75, 1.5, 2.0, 3.0, 4.0))
        return Candidate(name, grid, ("max_noise_m", "min_noise_m"))
    if name == "correlated_error":
        domain = "range" if dop else "position"
        grid = _points(name, {**on, "domain": domain},
                       tau_s=(30.0, 60.0, 100.0, 150.0, 200.0, 300.0, 600.0),
                       sigma_m=(1.5, 2.5, 3.5, 5.0))
        return Candidate(name, grid, ("tau_s", "sigma_m", "domain"), default=14)
    if name == "dop_error":
        # the UERE budget scaled as a whole (its textbook defaults x f)
        base = {"sis_m": 0.8, "iono_zenith_m": 2.0, "tropo_zenith_m": 0.2, "rx_noise_m": 0.5,
                "multipath_a_m": 0.13, "multipath_b_m": 0.53}
        grid = tuple({"dop_error": {**on, **{k: round(v * f, 3) for k, v in base.items()}},
                      "noise": {"model": "none"}} for f in (1.0, 0.5, 2.0, 3.0))
        return Candidate(name, grid, tuple(base))
    if name == "cold_start":
        grid = ({name: {**on, "power_on": "hot"}},) + tuple(
            {name: {**on, "power_on": "cold", "ttff_cold_s": v}}
            for v in (10.0, 20.0, 30.0, 35.0, 45.0, 60.0, 90.0))
        return Candidate(name, grid, ("power_on", "ttff_cold_s", "ttff_hot_s"), default=4)
    if name == "nlos":
        if not has_mesh:
            return "needs a scene with walls (no run is simulated in a mesh)"
        tracking = _enabled(profile, "cn0_tracking")
        grid = _points(name, on, scattering=(False, True), max_dist_m=(30.0, 50.0),
                       reflection_loss_db=(3.0, 5.0, 7.0, 9.0, 12.0) if tracking else (7.0,))
        return Candidate(name, grid, ("scattering", "max_dist_m", "reflection_loss_db"))
    if name == "multipath":
        if not dop:
            return "needs dop_error (its range errors are solved with the others)"
        # Without walls to measure the distance to, the antenna's surroundings (a vehicle's
        # roof, the ground) reflect everywhere alike: the open-sky proximity is 1 and sigma_m
        # takes the scale.
        fixed = on if has_mesh else {**on, "open_sky_factor": 1.0}
        grid = _points(name, fixed, sigma_m=(2.0, 4.0, 8.0, 16.0), tau_s=(10.0, 30.0, 100.0))
        return Candidate(name, grid, ("sigma_m", "tau_s"), default=4)
    if name == "foliage":
        if not has_mesh:
            return "needs a scene with trees"
        grid = _points(name, on, db_per_m=(0.5, 1.0, 2.0, 4.0))
        return Candidate(name, grid, ("db_per_m",), default=1)
    if name == "sky_mask":
        if not has_gsv:
            return "needs GSV with SNR in the real logs (it is learned from what they track)"
        # Attenuation only means something to a receiver whose tracking follows C/N0; without
        # cn0_tracking a C/N0 deficit is that effect's to explain, not a direction's.
        return Candidate(name, (), ("az_bin_deg", "el_bin_deg", "atten_db"),
                         learned=SKY_MASK_LEVELS,
                         learned_atten=_enabled(profile, "cn0_tracking"))
    if name == "cn0_tracking":
        grid = _points(name, on, cn0_zenith_dbhz=(30.0, 33.0, 36.0, 39.0, 42.0, 45.0),
                       horizon_loss_db=(10.0, 16.0, 22.0))
        return Candidate(name, grid, ("cn0_zenith_dbhz", "horizon_loss_db"), default=13)
    if name == "elevation_mask":
        cur = float(profile.get("sky", {}).get("elevation_mask_deg", 5.0))
        vals = tuple(v for v in (0.0, 5.0, 10.0, 15.0, 20.0) if v != cur)
        grid = tuple({"sky": {"elevation_mask_deg": v}} for v in (cur,) + vals)
        return Candidate(name, grid, ("elevation_mask_deg",))
    if name == "latency":
        # steps of 0.1-0.15 s below 1 s: a first-order filter of tau lags by
        # exp(-dt/tau) / (1 - exp(-dt/tau)) epochs (0.58 s at tau 1 s, 1 Hz), and a latency
        # between grid points lost to the filter's nearer lag (self-check: 0.58 and 0.69 s)
        grid = _points(name, on, latency_s=(0.1, 0.25, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.25,
                                            1.5, 2.0, 3.0))
        return Candidate(name, grid, ("latency_s",), default=0)
    if name == "nav_filter":
        # 0.5 s steps where receivers' filters lie (and fine latencies): with coarser grids a
        # pure delay fits a filter's lag better than the filter itself does, and back
        grid = _points(name, on, tau_s=(0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 6.0, 8.0, 16.0))
        return Candidate(name, grid, ("tau_s",), default=1)
    if name == "static_hold":
        grid = _points(name, on, threshold_mps=(0.2, 0.4, 0.8, 1.5))
        return Candidate(name, grid, ("threshold_mps",), default=1)
    if name == "sbas":
        return Candidate(name, ({name: dict(on)},), ())
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
    """:func:`virtualgps.profiles.build_profile` of a merged table."""
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
