"""Run settings and their precedence, and assembling a
:class:`~virtualgps.receiver.definition.Receiver`.

Precedence, lowest first: built-in defaults < profile < config file (``--config``) < flags.
A config file's top level may hold the run settings of :data:`virtualgps.receiver.profiles.RUN_KEYS`
(``scene``, ``tle``, ``seed``, ...), a ``[georef]`` table (the paper's second georeference
route), and any profile key or table, which overrides the profile's.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps.bundled import bundled_dir
from virtualgps.exceptions import ConfigError, VirtualGPSError
from virtualgps.geodesy import geoid_sep_m
from virtualgps.receiver.definition import Georef, Receiver
from virtualgps.receiver.params import Profile
from virtualgps.receiver.profiles import DEFAULT_PROFILE, RUN_KEYS, load_profile
from virtualgps.sky import ephemeris as eph
from virtualgps.sky.skytime import choose_system_sets, choose_tle_set
from virtualgps.tomlfile import read_toml

log = logging.getLogger(__name__)

BUNDLED_SCENES_DIR = bundled_dir("scenes")
DEFAULT_SCENE = "magdeburg-campus"
SKY_SHIFT_MAX_OFFSET_DAYS = 3.0


@dataclass(frozen=True)
class RunConfig:
    """The effective settings of one run (after precedence).

    scene : scene folder / scene.toml path, "none" for open sky, or None for the default scene
    profile : the receiver profile (with config-file overrides applied)
    tle : TLE, RINEX or lookup-table file (several: TLE sets, one per group), or None for the
        set chosen by time (:func:`virtualgps.sky.skytime.choose_tle_set`)
    origin : (lat_deg, lon_deg, alt_hae_m) overriding the scene's georeference, or None
    seed : random seed
    start_time_unix_s : simulated UTC start, or None (wall clock)
    """

    profile: Profile
    scene: str | None = None
    tle: tuple[str, ...] | None = None
    origin: tuple[float, float, float] | None = None
    seed: int = 0
    start_time_unix_s: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def _tle_files(value: Any) -> tuple[str, ...] | None:
    """``--tle`` (a list: repeatable) or the config file's ``tle`` (a path or a list)."""
    if value is None:
        return None
    files = [value] if isinstance(value, str | Path) else list(value)
    return tuple(str(f) for f in files) or None


def parse_origin(text: str, what: str = "origin") -> tuple[float, float, float]:
    """Parse ``LAT,LON,ALT_HAE`` (degrees, degrees, metres) as given to ``--origin`` or
    ``--lla`` (``what`` names it in the error)."""
    try:
        lat, lon, alt = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(
            f"{what} must be LAT,LON,ALT_HAE in degrees, degrees, metres, got {text!r}"
        ) from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0 and np.isfinite(alt)):
        raise ConfigError(f"{what} {text!r} is out of range (lat in [-90, 90], lon in [-180, 360))")
    return lat, lon, alt


def parse_time(text: str) -> float:
    """Parse an ISO 8601 UTC time (``2017-03-28T14:52:48Z``; no zone means UTC) to Unix seconds."""
    from datetime import UTC, datetime

    try:
        dt = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise ConfigError(
            f"time must be ISO 8601 like 2017-03-28T14:52:48Z, got {text!r}"
        ) from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


def _georef_from_table(table: dict[str, Any], source: str) -> tuple[float, float, float]:
    try:
        lat, lon = float(table["lat_deg"]), float(table["lon_deg"])
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f"{source}: [georef] needs numbers lat_deg and lon_deg") from None
    if "alt_hae_m" in table:
        alt = float(table["alt_hae_m"])
    elif "alt_msl_m" in table:
        alt = float(table["alt_msl_m"]) + float(geoid_sep_m(lat, lon))
    else:
        alt = 0.0
    return lat, lon, alt


def resolve(flags: dict[str, Any]) -> RunConfig:
    """Apply the precedence rules to the command-line flags (None = not given).

    Parameters
    ----------
    flags : the parsed flags: profile, config, scene, tle, origin, seed, start_time, rate, baud

    Returns
    -------
    config : RunConfig
    """
    file_cfg: dict[str, Any] = {}
    if flags.get("config"):
        file_cfg = read_toml(Path(flags["config"]))
    run = {k: v for k, v in file_cfg.items() if k in RUN_KEYS}
    profile_over = {k: v for k, v in file_cfg.items() if k not in RUN_KEYS}
    if "rate" in run:
        profile_over.setdefault("rate_hz", run["rate"])
    flag_over = {}
    for key in ("rate", "baud"):  # flags of the run that are profile settings
        if flags.get(key) is not None:
            flag_over["rate_hz" if key == "rate" else key] = flags[key]
    profile = load_profile(
        flags.get("profile") or run.get("profile") or DEFAULT_PROFILE,
        profile_over,
        flags.get("config"),
        flag_over,
    )

    def pick(key: str) -> Any:
        return flags[key] if flags.get(key) is not None else run.get(key)

    origin = None
    if flags.get("origin"):
        origin = parse_origin(flags["origin"])
    elif isinstance(run.get("origin"), str):
        origin = parse_origin(run["origin"])
    elif isinstance(run.get("georef"), dict):
        origin = _georef_from_table(run["georef"], str(flags.get("config")))
    start = pick("start_time")
    seed = pick("seed")
    if seed is not None and (type(seed) is not int or seed < 0):
        # (numpy's generators take no negative seed; a float or a string is a typo)
        where = "--seed" if flags.get("seed") is not None else f"{flags.get('config')}: seed"
        raise ConfigError(f"{where} must be a non-negative integer, not {seed!r}")
    return RunConfig(
        profile=profile,
        scene=str(pick("scene")) if pick("scene") is not None else None,
        tle=_tle_files(pick("tle")),
        origin=origin,
        seed=seed if seed is not None else 0,
        start_time_unix_s=parse_time(start) if isinstance(start, str) else start,
        extra={k: run[k] for k in run if k not in ("scene", "tle", "seed", "start_time", "origin")},
    )


def scene_path(spec: str | None) -> Path | None:
    """Resolve ``--scene``: None -> the bundled default, a bundled scene's name, a folder or file.

    Returns None for ``none`` (open sky).
    """
    if spec is None:
        return BUNDLED_SCENES_DIR / DEFAULT_SCENE
    if spec.lower() == "none":
        return None
    p = Path(spec)
    if not p.exists() and (BUNDLED_SCENES_DIR / spec).is_dir():
        return BUNDLED_SCENES_DIR / spec
    if not p.exists():
        bundled = ", ".join(sorted(d.name for d in BUNDLED_SCENES_DIR.iterdir() if d.is_dir()))
        raise ConfigError(
            f"scene {spec!r} not found: give a folder with scene.toml, "
            f"a scene.toml file, 'none', or a bundled scene ({bundled})"
        )
    return p


def load_scene_for(cfg: RunConfig):  # -> (Scene | None, Georef | None, default TLE path | None)
    """Load the configured scene and work out the georeference (flag > config > scene).

    Returns
    -------
    scene : the Scene, or None for open sky
    georef : Georef, or None when open sky has no --origin (the caller then places the origin
        at the first geodetic pose)
    scene_tle : the scene's default TLE file, or None
    """
    from virtualgps.sky.scene import load_scene

    path = scene_path(cfg.scene)
    scene = load_scene(path) if path is not None else None
    if cfg.origin is not None:
        georef = Georef(*cfg.origin)
    elif scene is not None:
        georef = Georef(scene.lat_deg, scene.lon_deg, scene.alt_hae_m)
    else:
        georef = None
    scene_tle = getattr(scene, "tle_path", None) if scene is not None else None
    return scene, georef, scene_tle


PROFILE_SYSTEMS = "profile"  # load_ephemeris: the systems the profile's receiver tracks


def load_ephemeris(cfg: RunConfig, scene_tle: Path | None, t_start_unix_s: float | None = None,
                   systems_kept: str | None = PROFILE_SYSTEMS):
    """Load the ephemeris :func:`virtualgps.sky.skytime.choose_tle_set` picks for a run starting at
    ``t_start_unix_s`` (``--tle``, else the set whose epoch lies nearest among the scene's, the
    bundled and the fetched sets), and log the one line that says which and why.

    Parameters
    ----------
    scene_tle : the scene's set, or None
    t_start_unix_s : the run's start, UTC seconds (None: now, a live run on the wall clock)
    systems_kept : RINEX letters of the systems kept (default: those the profile's receiver
        tracks, ``[constellations]``, GPS alone without it; None: every system, as ``sky``
        lists them)

    Returns
    -------
    ephemeris : Constellation, BroadcastEphemeris or LookupTable
    path : the file it came from
    """
    if systems_kept == PROFILE_SYSTEMS:
        systems_kept = cfg.profile.constellations.letters()
    if cfg.tle is not None and len(cfg.tle) > 1:  # one TLE set per group
        paths = [Path(p) for p in cfg.tle]
        for p in paths:
            if not p.exists():
                raise ConfigError(f"TLE file {p} not found (give --tle PATH to a TLE file)")
        log.info("ephemeris: --tle %s", ", ".join(cfg.tle))
        return eph.load_tle_sets(paths, systems_kept=systems_kept), paths[0]
    others = [x for x in (systems_kept or "") if x != "G"]
    if not cfg.tle and others:  # e.g. sky --systems GPS,GLONASS: a set per system's group
        # A system whose set is nowhere at hand is left out with one warning (a built-in
        # profile must run as installed: no BeiDou set is bundled); none at all is an error.
        found, missing = choose_system_sets("G" * ("G" in systems_kept) + "".join(others),
                                            t_start_unix_s, scene_tle)
        if not found:
            raise missing[0][1]
        for _, line in found:
            log.info("%s", line)
        paths = [path for path, _ in found]
        for name, exc in missing:
            log.warning("ephemeris: %s satellites left out (%s, or fetch the sets with "
                        "'virtualgps ephemeris fetch')", name, exc)
        return eph.load_tle_sets(paths, systems_kept=systems_kept), paths[0]
    path, line = choose_tle_set(cfg.tle[0] if cfg.tle else None, scene_tle, t_start_unix_s)
    if not path.exists():
        raise ConfigError(f"TLE file {path} not found (give --tle PATH to a TLE file)")
    log.info("%s", line)
    return eph.load_ephemeris_file(path, systems_kept), path


def make_receiver(
    cfg: RunConfig,
    scene,
    georef: Georef,
    ephemeris,
    t_start_unix_s: float,
    apply_sky_policy: bool = True,
) -> Receiver:
    """Assemble the receiver, applying the sky-time policy for a run starting at ``t_start``.

    The sky-time policy: when the simulated time lies more than
    ``SKY_SHIFT_MAX_OFFSET_DAYS`` from the TLE epoch, the sky is computed a whole number of GPS
    sky-repeat periods earlier or later, near the epoch, so the sky stays realistic (logged once).
    NMEA times always follow the simulated clock.
    """
    shift = 0.0
    if apply_sky_policy:
        shift = eph.sidereal_shift_s(
            t_start_unix_s, ephemeris.epoch_center_unix_s, SKY_SHIFT_MAX_OFFSET_DAYS
        )
        if shift:
            log.warning(
                "simulated time is %.1f days from the TLE epoch: computing the sky at the same "
                "sidereal time %.1f days earlier (a current TLE file via --tle gives the true sky)",
                (t_start_unix_s - ephemeris.epoch_center_unix_s) / 86400.0,
                shift / 86400.0,
            )
    note = coverage_note(ephemeris, t_start_unix_s - shift)
    if note:
        log.warning("%s: no satellite, no fix (give --start-time within it)", note)
    return Receiver(
        profile=cfg.profile, ephemeris=ephemeris, scene=scene, georef=georef, sky_shift_s=shift
    )


def coverage_note(ephemeris, t_unix_s: float) -> str | None:
    """Say when ``ephemeris`` gives no satellite position at ``t_unix_s``.

    Broadcast orbits (RINEX navigation files) serve a few hours either side of their records
    and lookup tables only their own span; outside, every satellite is NaN and a run has an
    empty sky, which without a word looks like a broken receiver. TLE sets propagate to any
    time (see the sky-time policy for how far they are trusted).

    Parameters
    ----------
    ephemeris : Constellation, BroadcastEphemeris or LookupTable
    t_unix_s : UTC seconds at which the sky is computed (after any sky-time shift)

    Returns
    -------
    note : None where covered (or always covered), else a sentence naming the source and the
        span it covers
    """
    span = getattr(ephemeris, "coverage_unix_s", None)
    if span is None or span[0] <= t_unix_s <= span[1]:
        return None
    first, last, at = (time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))
                       for t in (*span, t_unix_s))
    return f"{ephemeris.source} gives satellite positions from {first} to {last}, not at {at}"


def require_georef(georef: Georef | None, what: str) -> Georef:
    """Raise a clear error when an open-sky run has nothing to place the antenna."""
    if georef is None:
        raise VirtualGPSError(
            f"--scene none needs a place for the antenna: give --origin LAT,LON,ALT_HAE or {what}"
        )
    return georef
