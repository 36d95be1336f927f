"""Receiver profiles: TOML files (built-ins in ``virtualgps/receiver/profiles/``) into frozen
dataclasses.

Precedence of settings (documented once, in docs/usage.md): built-in defaults < profile < config
file (``--config``) < command-line flags. A config file may hold run settings at its top level
(``scene``, ``seed``, ...; see :data:`RUN_KEYS`), a ``[georef]`` table, and any profile key or
table, which overrides the profile's (e.g. ``[noise] max_noise_m = 8.0``).
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from virtualgps.exceptions import ConfigError, InputFileError, VirtualGPSError
from virtualgps.receiver.nmea_format import NmeaFormat
from virtualgps.sky import systems as _sys
from virtualgps.sky.skymask import SKY_MASK_MAX_CELL, SkyMaskParams
from virtualgps.tomlfile import read_toml, toml_key_line

BUILTIN_PROFILES = ("holux-m1000", "usarsim", "ideal", "ublox-m8n", "ublox-m9n", "phone")
DEFAULT_PROFILE = "holux-m1000"

# Settings of a run (not of the receiver) that a config file may set at its top level.
RUN_KEYS = frozenset(
    {
        "scene",
        "profile",
        "tle",
        "poses",
        "link",
        "serial",
        "baud_rate",
        "rate",
        "start_time",
        "seed",
        "origin",
        "out",
        "fixes",
        "georef",
    }
)


@dataclass(frozen=True)
class SkyParams:
    """What the antenna can see.

    elevation_mask_deg : satellites below are not used (the paper: 5 deg)
    max_channels : at most this many satellites are used, 4..72 (12: an MTK receiver, whose one
        GSA has 12 fields; multi-system receivers use more, e.g. a u-blox M8's 72 channels,
        listed 12 per system's GSA in NMEA 4.11)
    foliage : "block" (foliage-class objects block like buildings) or "ignore"
    """

    elevation_mask_deg: float = 5.0
    max_channels: int = 12
    foliage: str = "block"


@dataclass(frozen=True)
class NoiseParams:
    """The baseline position error (DESIGN section 6, ``noise_level``).

    model : "usarsim" (the paper's Eq. 1-3 white noise) or "none"
    max_noise_m : the paper's maxNoise, error bound (3 sigma) with 4 satellites, metres
    min_noise_m : the paper's minNoise, error bound (3 sigma) with 12 satellites, metres
    """

    model: str = "usarsim"
    max_noise_m: float = 3.0
    min_noise_m: float = 1.0


@dataclass(frozen=True)
class SignalParams:
    """GSV signal strength of tracked satellites: linear in sin(elevation) between two values."""

    cn0_horizon_dbhz: float = 20.0
    cn0_zenith_dbhz: float = 45.0


@dataclass(frozen=True)
class ColdStartParams:
    """Start-up (DESIGN section 6, ``cold_start``): no fix until the time to first fix.

    TTFF after a start of each kind is drawn from a normal distribution with the given mean and
    ``ttff_sd_frac`` x mean standard deviation (clipped at 0). Typical MediaTek values (MT3339
    module data sheets quote 35 s cold, 33 s warm, 1 s hot); not M-1000 datasheet facts.
    ``power_on`` is the start the receiver makes when the run begins ("none": a fix at once).
    After a cold or warm start the first fix uses 4 satellites; the others become usable one
    by one, uniformly within ``decode_spread_s`` (each needs its ephemeris, 18-30 s of
    navigation message: IS-GPS-200 subframes 1-3), and the fix starts off by a random
    ``converge_sigma_m`` error that decays with ``converge_tau_s``.
    """

    enabled: bool = False
    power_on: str = "none"
    ttff_cold_s: float = 35.0
    ttff_warm_s: float = 33.0
    ttff_hot_s: float = 1.0
    ttff_sd_frac: float = 0.15
    decode_spread_s: float = 30.0
    converge_sigma_m: float = 10.0
    converge_tau_s: float = 20.0


@dataclass(frozen=True)
class DopErrorParams:
    """``dop_error``: per-satellite range errors by elevation, solved by weighted least squares.

    One-sigma UERE (metres) = sqrt(sis^2 + (F_iono iono_zenith)^2 + (F_tropo tropo_zenith)^2
    + rx_noise^2 + (multipath_a + multipath_b exp(-el / 10 deg))^2); see
    :func:`virtualgps.receiver.errors.uere_sigma_m`. Defaults: modern GPS signal-in-space URE (< 1 m
    RMS), a single-frequency receiver's residual ionosphere after the broadcast model (~50 % of a
    few metres of vertical delay) and troposphere after a model, and DO-229's airborne multipath
    form; typical textbook values (Misra & Enge, table 7.3), to be calibrated.
    """

    enabled: bool = False
    sis_m: float = 0.8
    iono_zenith_m: float = 2.0
    tropo_zenith_m: float = 0.2
    rx_noise_m: float = 0.5
    multipath_a_m: float = 0.13
    multipath_b_m: float = 0.53
    # Doppler: each satellite's range-rate error (zenith sigma, m/s, scaled with elevation like
    # the UERE; first-order Gauss-Markov over range_rate_tau_s), solved by the same weighted
    # least squares into the reported velocity: a static receiver prints small speeds and a
    # wandering course, as the MT3339's static hours do (calibrated there, docs/profiles.md).
    range_rate_sigma_mps: float = 0.05
    range_rate_tau_s: float = 1.0


@dataclass(frozen=True)
class CorrelatedErrorParams:
    """``correlated_error``: first-order Gauss-Markov errors with correlation time ``tau_s``.

    domain "range": per-satellite range errors (needs ``dop_error``), stationary sigma
    ``sigma_m`` at the zenith scaled with elevation like the UERE; they replace the white part
    of the UERE except the receiver noise, and a change of the used set moves the fix.
    domain "position": east/north/up position errors, sigma ``sigma_m`` each (up: x ``up_ratio``).
    """

    enabled: bool = False
    domain: str = "range"
    tau_s: float = 150.0
    sigma_m: float = 2.0
    up_ratio: float = 1.5


@dataclass(frozen=True)
class Cn0TrackingParams:
    """``cn0_tracking``: C/N0 from elevation and losses; tracking with hysteresis.

    C/N0 = cn0_zenith_dbhz + antenna gain (0 dB at the zenith, -horizon_loss_db at the horizon)
    + a Gauss-Markov fade per satellite (fade_sigma_db, fade_tau_s); a blocked line of sight
    gives no signal. Acquired after reacq_s at or above acq_dbhz, tracked down to track_dbhz.
    Used = tracked, above the elevation mask and, with ``use_dbhz`` > 0, a signal level without
    the fades (the receiver's C/N0 estimate averaged over them) of at least use_dbhz: MTK
    firmware tracks weak satellites it leaves out of the fix (the MT3339 static hour uses 29 %
    of its tracked satellite-epochs at 13-16 dB-Hz, 97 % at 25-28). GSV SNR = the tracked C/N0.
    Defaults: a small patch antenna; MTK's acquisition/tracking sensitivities (-148/-165 dBm)
    set the thresholds' order (``holux-m1000`` calibrates them on the MT3339 hour).
    """

    enabled: bool = False
    cn0_zenith_dbhz: float = 42.0
    horizon_loss_db: float = 14.0
    fade_sigma_db: float = 2.0
    fade_tau_s: float = 10.0
    acq_dbhz: float = 24.0
    track_dbhz: float = 16.0
    reacq_s: float = 2.0
    use_dbhz: float = 0.0


@dataclass(frozen=True)
class LatencyParams:
    """``latency``: the fix describes where the antenna was ``latency_s`` before its epoch."""

    enabled: bool = False
    latency_s: float = 0.1


@dataclass(frozen=True)
class NavFilterParams:
    """``nav_filter``: the receiver's smoothing of its position, a first-order low-pass with
    time constant ``tau_s`` (lags behind the truth when accelerating), restarted after a gap.

    With ``velocity_aided`` the filter carries its position forward with the receiver's own
    velocity (Doppler) and low-passes only what the ranges add to it: the position's *error*
    is smoothed and the motion followed without lag (a phone's or a car receiver's Kalman
    filter: errors that change little from one epoch to the next, turns kept)."""

    enabled: bool = False
    tau_s: float = 1.0
    velocity_aided: bool = False


@dataclass(frozen=True)
class StaticHoldParams:
    """``static_hold``: MTK static navigation (``$PMTK386``): below ``threshold_mps`` the
    output position stays where it was when the speed fell below it. MTK's default is 0.4 m/s
    (PMTK386 documentation); 0 disables it as on the device."""

    enabled: bool = False
    threshold_mps: float = 0.4


@dataclass(frozen=True)
class SbasParams:
    """``sbas``: SBAS/WAAS corrections: GGA quality 2 (mode letter D), and with ``dop_error``
    the signal-in-space and ionospheric range errors scaled by these factors (SBAS corrects
    orbits, clocks and the ionosphere; residual ionosphere of the WAAS grid ~0.5 m vs a few
    metres for the broadcast model: Misra & Enge, section 5.4)."""

    enabled: bool = False
    sis_factor: float = 0.5
    iono_factor: float = 0.25


@dataclass(frozen=True)
class NlosParams:
    """``nlos``: a satellite whose direct path is blocked is still received off a facade
    (single specular bounce, image method, walls within ``max_dist_m``), ``reflection_loss_db``
    weaker and with a range bias of the excess path. The Magdeburg logs show blocked passes
    6.7 +- 0.7 dB weaker than clear ones (../shared/data/SOURCES.md).

    With ``scattering``, blocked satellites are received off rough walls instead: scattered in
    a lobe around the specular direction (a specular point on the wall is its centre), weaker
    by -10 ``scattering_alpha`` log10((1 + cos psi) / 2) dB more (Degli-Esposti et al. 2007's
    directive model; see :func:`virtualgps.receiver.walls.scattered_paths`, which tries the walls
    nearest the antenna); paths losing more than ``scattering_max_loss_db`` are ignored.
    Specular reflection alone finds a path for ~12 % of the building-crossing satellite-epochs
    at the Magdeburg waypoints, where the phone tracked 57 %; with scattering ~60 % have one."""

    enabled: bool = False
    reflection_loss_db: float = 7.0
    max_dist_m: float = 30.0
    scattering: bool = False
    scattering_alpha: float = 4.0
    scattering_max_loss_db: float = 10.0


@dataclass(frozen=True)
class MultipathParams:
    """``multipath``: line-of-sight multipath, an extra range error on each satellite received
    directly (not blocked), correlated in time, large near walls and at low elevation.

    Each such satellite's range gets a first-order Gauss-Markov error with correlation time
    ``tau_s`` and standard deviation sigma_m x exp(-el / el0_deg) x proximity, proximity =
    max(0, 1 - d / max_dist_m) for d the horizontal distance from the antenna to the nearest
    wall of the scene that rises above it (the ``nlos`` facades); ``open_sky_factor`` is the
    proximity without a scene. It adds to ``dop_error``'s range errors (which it needs) and is
    solved with them; the receiver's weights and reported sigmas (GST) do not know it.

    Grounds and defaults (typical values, to be calibrated): code multipath is worst at low
    elevation, where DO-229 (J.2.4) models it as a + b exp(-el / 10 deg); a wall's reflection
    keeps the satellite's elevation and its delay, 2 d cos(el), falls slowly with it, hence
    el0_deg = 15. Near buildings a C/A receiver's range errors reach metres (van Nee,
    "Multipath effects on GPS code phase measurements", NAVIGATION 39(2), 1992), hence
    sigma_m = 4 m next to a wall at the horizon. For a static antenna the reflection's phase
    turns with the satellite's motion in tens of seconds to minutes (van Nee: slow fading for
    stationary users); integrity studies model raw code multipath as Gauss-Markov with time
    constants of 10-900 s (after Joerger and Pervan, NAVIGATION, 2016): tau_s = 30 s.
    max_dist_m = 30 m is the ``nlos`` search's reach.
    """

    enabled: bool = False
    sigma_m: float = 4.0
    el0_deg: float = 15.0
    max_dist_m: float = 30.0
    tau_s: float = 30.0
    open_sky_factor: float = 0.0


@dataclass(frozen=True)
class FoliageParams:
    """``foliage``: foliage-class objects attenuate instead of block: ``db_per_m`` times the
    path length through the crowns, at most ``max_db`` (a saturating specific attenuation; ITU-R
    P.833's vegetation model has this form). An open (billboard) tree crossing counts
    ``billboard_m`` metres. Takes precedence over ``sky.foliage``."""

    enabled: bool = False
    db_per_m: float = 1.0
    max_db: float = 20.0
    billboard_m: float = 4.0




@dataclass(frozen=True)
class ConstellationsParams:
    """``constellations``: the satellite systems the receiver tracks, by name or RINEX letter
    (GPS, GLONASS, Galileo, BeiDou, QZSS; :mod:`virtualgps.sky.systems`). Disabled: GPS alone,
    as the M-1000's MTK generation. Each system's satellites come from its own TLE set (``--tle``
    once per set, or the sets chosen per system for the run's time); NMEA 4.11 output
    (``[nmea] version``) lists them per system.

    The fix solves one receiver clock per system used (the inter-system time offsets). Each
    system keeps GPS's models but for two settings, tables by system name whose entries
    override the defaults system by system:

    sis_factor : its signal-in-space range error (orbit and clock of the broadcast ephemeris)
        as a multiple of GPS's ``dop_error.sis_m``. Defaults: the global average SISREs of
        Montenbruck, Steigenberger and Hauschild, "Broadcast versus precise ephemerides: a
        multi-GNSS perspective", GPS Solutions 19 (2015) 321-333, over 2013/14: GPS 0.7 m,
        GLONASS 1.9, Galileo 1.6 (its early in-orbit-validation years), BeiDou 1.5, QZSS 0.6,
        hence 2.7, 2.3, 2.1 and 0.86. (SBAS corrections, ``[sbas]``, scale GPS's alone.)
    cn0_offset_db : dB added to its satellites' C/N0 (default 0 for every system: no measured
        difference is assumed; the ICDs' minimum received powers, e.g. GPS L1 C/A -158.5 dBW
        against GLONASS L1OF -161 dBW, bound the signals from below, not what receivers see).
    """

    enabled: bool = False
    systems: tuple[str, ...] = ("GPS",)
    sis_factor: tuple[tuple[str, float], ...] = (("GLONASS", 2.7), ("Galileo", 2.3),
                                                 ("BeiDou", 2.1), ("QZSS", 0.86))
    cn0_offset_db: tuple[tuple[str, float], ...] = ()

    def letters(self) -> str:
        """RINEX letters of the systems tracked, e.g. ``"GR"`` (``"G"`` when disabled)."""
        if not self.enabled:
            return "G"
        return "".join(dict.fromkeys(_sys.system_named(n).letter for n in self.systems))

    def untracked(self, prn: Any) -> Any:
        """Which satellites belong to a system of GPS, GLONASS, Galileo, BeiDou and QZSS that
        this receiver does not track: (n_sat,) bool, or None when it tracks every such system
        among ``prn`` (the usual case: the ephemeris holds the profile's systems; a u-blox
        client's CFG-GNSS switches systems off while the run goes on). SBAS and numbers of no
        known system are never untracked here."""
        import numpy as np

        return _untracked(self.letters(), tuple(np.asarray(prn, dtype=np.int64).tolist()))

    def per_satellite(self, prn: Any, key: str, gps_value: float) -> Any:
        """The setting ``key`` (``"sis_factor"``, ``"cn0_offset_db"``) of each satellite's
        system: ``gps_value`` for GPS, SBAS, numbers of no known system and systems the table
        leaves out.

        prn : (n_sat,) int, satellite numbers (:mod:`virtualgps.sky.systems`)
        Returns (n_sat,) float, or ``gps_value`` itself when off or every satellite is GPS's.
        """
        if not self.enabled or not getattr(self, key):
            return gps_value
        import numpy as np

        # (cached per constellation: the live loop asks every epoch)
        return _per_satellite(self, key, tuple(np.asarray(prn, dtype=np.int64).tolist()),
                              gps_value)


@functools.lru_cache(maxsize=32)
def _untracked(letters: str, prn: tuple[int, ...]) -> Any:
    letters_of = _sys.letters(prn)
    import numpy as np

    off = np.isin(letters_of, [x for x in "GRECJ" if x not in letters])
    if not off.any():
        return None
    off.flags.writeable = False  # (shared by every call)
    return off


@functools.lru_cache(maxsize=32)
def _per_satellite(cs: ConstellationsParams, key: str, prn: tuple[int, ...],
                   gps_value: float) -> Any:
    import numpy as np

    table = {_sys.system_named(n).letter: float(v) for n, v in getattr(cs, key)}
    letters = _sys.letters(prn)
    if not np.isin(letters, list(table)).any():
        return gps_value
    out = np.array([table.get(x, gps_value) for x in letters.tolist()], dtype=float)
    out.flags.writeable = False  # (shared by every call)
    return out


@dataclass(frozen=True)
class UbxParams:
    """``ubx``: the u-blox module a ``command_link = "ubx"`` profile answers as (DESIGN 5b):
    ``generation`` "M8" (NEO-M8N: protocol 18, UBX-CFG messages) or "M9" (NEO-M9N: protocol
    32, also the CFG-VALSET/VALGET/VALDEL configuration keys), which fixes its MON-VER, its
    power-on configuration and the commands it takes (:mod:`virtualgps.device.ubx`)."""

    generation: str = "M8"


@dataclass(frozen=True)
class Profile:
    """A receiver profile: output format, rates and the error model's parameters.

    rate_hz : epochs per second; baud : serial speed the output is paced to (8N1);
    pose_timeout_s : a pose older than this gives no-fix epochs;
    georef : "wgs84" (exact) or "flat_earth" (the paper's conversion);
    nmea : the ``[nmea]`` table, read by :class:`virtualgps.receiver.nmea_format.NmeaFormat`;
    command_link : "mtk" (answer $PMTK commands written to the device), "ubx" (answer UBX
        and ``$PUBX`` as a u-blox module, ``[ubx]``, and write its UBX output) or "none"
        (ignore them);
    firmware : the body of the ``$PMTK705`` answer (release, build id, model) with ``mtk``.
    """

    name: str
    description: str = ""
    rate_hz: float = 1.0
    baud: int = 38400
    pose_timeout_s: float = 2.0
    georef: str = "wgs84"
    sky: SkyParams = field(default_factory=SkyParams)
    noise: NoiseParams = field(default_factory=NoiseParams)
    signal: SignalParams = field(default_factory=SignalParams)
    cold_start: ColdStartParams = field(default_factory=ColdStartParams)
    dop_error: DopErrorParams = field(default_factory=DopErrorParams)
    correlated_error: CorrelatedErrorParams = field(default_factory=CorrelatedErrorParams)
    cn0_tracking: Cn0TrackingParams = field(default_factory=Cn0TrackingParams)
    latency: LatencyParams = field(default_factory=LatencyParams)
    nav_filter: NavFilterParams = field(default_factory=NavFilterParams)
    static_hold: StaticHoldParams = field(default_factory=StaticHoldParams)
    sbas: SbasParams = field(default_factory=SbasParams)
    nlos: NlosParams = field(default_factory=NlosParams)
    multipath: MultipathParams = field(default_factory=MultipathParams)
    foliage: FoliageParams = field(default_factory=FoliageParams)
    sky_mask: SkyMaskParams = field(default_factory=SkyMaskParams)
    constellations: ConstellationsParams = field(default_factory=ConstellationsParams)
    ubx: UbxParams = field(default_factory=UbxParams)
    nmea: dict[str, Any] = field(default_factory=dict)
    command_link: str = "none"
    firmware: str = "AXN_1.30,0000,HOLUX M-1000 (virtualgps),"
    source: str = ""


class SettingError(ConfigError):
    """A bad setting; ``section`` and ``key`` locate it in its TOML file ("" = top level)."""

    def __init__(self, section: str, key: str | None, message: str) -> None:
        super().__init__(message)
        self.section, self.key = section, key


_CHOICES = {
    ("", "georef"): ("wgs84", "flat_earth"),
    ("sky", "foliage"): ("block", "ignore"),
    ("noise", "model"): ("usarsim", "none"),
    ("cold_start", "power_on"): ("none", "hot", "warm", "cold"),
    ("correlated_error", "domain"): ("range", "position"),
    ("", "command_link"): ("mtk", "ubx", "none"),
    ("ubx", "generation"): ("M8", "M9"),
}
_NMEA_TEXT = frozenset(chr(c) for c in range(32, 127)) - set("$*!\\")
_TABLES = {
    "sky": SkyParams,
    "noise": NoiseParams,
    "signal": SignalParams,
    "cold_start": ColdStartParams,
    "dop_error": DopErrorParams,
    "correlated_error": CorrelatedErrorParams,
    "cn0_tracking": Cn0TrackingParams,
    "latency": LatencyParams,
    "nav_filter": NavFilterParams,
    "static_hold": StaticHoldParams,
    "sbas": SbasParams,
    "nlos": NlosParams,
    "multipath": MultipathParams,
    "foliage": FoliageParams,
    "constellations": ConstellationsParams,
    "ubx": UbxParams,
}


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Deep-merge two tables, ``over`` winning; neither input is modified.

    Parameters
    ----------
    base, over : nested dicts (TOML tables)

    Returns
    -------
    merged : a new nested dict
    """
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def profile_path(name_or_path: str) -> Path | None:
    """Where a built-in profile lives, or None if ``name_or_path`` is not a built-in name."""
    if name_or_path in BUILTIN_PROFILES:
        builtins = resources.files("virtualgps.receiver") / "profiles"
        return Path(str(builtins.joinpath(f"{name_or_path}.toml")))
    return None


def load_profile_dict(name_or_path: str) -> tuple[dict[str, Any], str]:
    """Read a built-in profile by name, or a profile TOML file by path.

    Returns
    -------
    data : the profile table
    source : the file it came from
    """
    path = profile_path(name_or_path)
    if path is None:
        path = Path(name_or_path)
        if not path.exists():
            raise ConfigError(
                f"unknown profile {name_or_path!r}: give one of {', '.join(BUILTIN_PROFILES)} "
                "or the path of a profile TOML file"
            )
    return read_toml(path), str(path)


def _float(value: Any, section: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        name = f"{section}.{key}" if section else key
        raise SettingError(section, key, f"{name} must be a number, got {value!r}")
    return float(value)


def _build_table(cls: type, table: dict[str, Any], prefix: str) -> Any:
    fields = cls.__dataclass_fields__
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        full = f"{prefix}.{key}"
        if key not in fields:
            raise SettingError(
                prefix, key, f"unknown setting {full!r}; known in [{prefix}]: {', '.join(fields)}"
            )
        default = fields[key].default
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise SettingError(prefix, key, f"{full} must be true or false, got {value!r}")
        elif isinstance(default, float):
            value = _float(value, prefix, key)
        elif isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise SettingError(prefix, key, f"{full} must be an integer, got {value!r}")
        elif str(fields[key].type).startswith("tuple[tuple[str, float]"):
            # (a table by name: name = number)
            if not isinstance(value, dict) or not all(
                    isinstance(v, int | float) and not isinstance(v, bool)
                    for v in value.values()):
                raise SettingError(prefix, key, f"{full} must be a table of numbers by name, "
                                   f"e.g. {{GLONASS = 1.0}}, got {value!r}")
            # (entries override the defaults system by system)
            value = tuple(sorted({**dict(default),
                                  **{str(k): float(v) for k, v in value.items()}}.items()))
        elif isinstance(default, tuple):  # (a list of names)
            if not isinstance(value, list) or not value or not all(
                    isinstance(v, str) for v in value):
                raise SettingError(prefix, key, f"{full} must be a non-empty list of names, "
                                   f"got {value!r}")
            value = tuple(value)
        choices = _CHOICES.get((prefix, key))
        if choices and value not in choices:
            raise SettingError(prefix, key, f"{full} must be one of {choices}, got {value!r}")
        kwargs[key] = value
    return cls(**kwargs)


def _bins(value: float, whole_deg: float, section: str, key: str) -> int:
    """How many bins of ``value`` degrees make ``whole_deg``; SettingError unless a whole number."""
    n = round(whole_deg / value) if value > 0 else 0
    if n < 1 or abs(n * value - whole_deg) > 1e-9:
        raise SettingError(section, key, f"{section}.{key} must divide {whole_deg:g} deg into "
                           f"whole bins (e.g. 5, 10, 15), got {value!r}")
    return n


def _mask_grid(
    value: Any, section: str, key: str, n_el: int, n_az: int
) -> tuple[tuple[float, ...], ...]:
    """Validate one sky-mask grid (a list of rows of dB values) and freeze it."""
    name = f"{section}.{key}" if section == "sky_mask" else f'{section}."{key}"'
    layout = (f"a list of at most {n_el} rows (elevation bins from the horizon up), each a list "
              f"of {n_az} attenuations in dB (azimuth bins from north)")
    if not isinstance(value, list) or not all(isinstance(r, list) for r in value):
        raise SettingError(section, key, f"{name} must be {layout}; got {value!r:.60}")
    if len(value) > n_el:
        raise SettingError(section, key, f"{name} has {len(value)} rows, more than the {n_el} "
                           "elevation bins (90 / el_bin_deg)")
    for r, row in enumerate(value, start=1):
        if len(row) != n_az:
            raise SettingError(section, key, f"{name} row {r} has {len(row)} values; expected "
                               f"{n_az} (360 / az_bin_deg)")
        for c, x in enumerate(row, start=1):
            if isinstance(x, bool) or not isinstance(x, int | float) or not x >= 0.0:
                raise SettingError(section, key, f"{name} row {r} column {c} must be an "
                                   f"attenuation >= 0 dB (inf blocks), got {x!r}")
    return tuple(tuple(float(x) for x in row) for row in value)


def _build_sky_mask(table: dict[str, Any]) -> SkyMaskParams:
    """Validate ``[sky_mask]`` (and ``[sky_mask.cells]``) into :class:`SkyMaskParams`."""
    grids = ("atten_db", "cells")
    mask = _build_table(SkyMaskParams, {k: v for k, v in table.items() if k not in grids},
                        "sky_mask")
    n_az = _bins(mask.az_bin_deg, 360.0, "sky_mask", "az_bin_deg")
    n_el = _bins(mask.el_bin_deg, 90.0, "sky_mask", "el_bin_deg")
    if not mask.block_db > 0.0:
        raise SettingError("sky_mask", "block_db", f"sky_mask.block_db must be > 0 dB, got "
                           f"{mask.block_db!r}")
    if not 0.0 <= mask.cell_m < float("inf"):
        raise SettingError("sky_mask", "cell_m", "sky_mask.cell_m must be >= 0 metres (0: no "
                           f"cells), got {mask.cell_m!r}")
    atten = _mask_grid(table.get("atten_db", []), "sky_mask", "atten_db", n_el, n_az)
    cells_in = table.get("cells", {})
    if not isinstance(cells_in, dict):
        raise SettingError("sky_mask", "cells", '[sky_mask.cells] must be a table of grids '
                           'keyed "i,j" (east, north cell indices)')
    if cells_in and mask.cell_m == 0.0:
        raise SettingError("sky_mask.cells", None, "sky_mask.cells needs sky_mask.cell_m > 0, "
                           "the side of the cells in metres")
    cells = {}
    for key, grid in cells_in.items():
        m = re.fullmatch(r"\s*(-?\d+)\s*,\s*(-?\d+)\s*", key)
        ij = (int(m.group(1)), int(m.group(2))) if m else None
        if ij is None or max(abs(ij[0]), abs(ij[1])) > SKY_MASK_MAX_CELL:
            raise SettingError("sky_mask.cells", key, f'sky_mask.cells."{key}": a cell is '
                               f'written "i,j" (integers within +-{SKY_MASK_MAX_CELL}: east, '
                               "north indices of floor(position / cell_m))")
        if ij in cells:
            raise SettingError("sky_mask.cells", key, f'sky_mask.cells."{key}" repeats cell {ij}')
        cells[ij] = _mask_grid(grid, "sky_mask.cells", key, n_el, n_az)
    return replace(mask, atten_db=atten, cells=tuple(sorted(cells.items())))


def build_profile(data: dict[str, Any], source: str = "<profile>") -> Profile:  # noqa: C901
    """Validate a profile table and build the :class:`Profile`.

    Parameters
    ----------
    data : the merged profile table (profile file, then config-file overrides)
    source : named in error messages

    Returns
    -------
    profile : Profile

    Raises
    ------
    ConfigError : an unknown key, a wrong type or an out-of-range value, naming the key.
    """
    kwargs: dict[str, Any] = {"source": source}
    top = Profile.__dataclass_fields__
    for key, value in data.items():
        if key in _TABLES:
            if not isinstance(value, dict):
                raise SettingError("", key, f"[{key}] must be a table")
            kwargs[key] = _build_table(_TABLES[key], value, key)
        elif key == "sky_mask":
            if not isinstance(value, dict):
                raise SettingError("", key, "[sky_mask] must be a table")
            kwargs[key] = _build_sky_mask(value)
        elif key == "nmea":
            if not isinstance(value, dict):
                raise SettingError("", key, "[nmea] must be a table")
            try:
                NmeaFormat.from_dict(value)
            except ConfigError as exc:
                nmea_key = str(exc).split(":", 1)[0].removeprefix("nmea.")
                raise SettingError(
                    "nmea", nmea_key if nmea_key in value else None, str(exc)
                ) from None
            kwargs[key] = dict(value)
        elif key in top and key != "source":
            if key in ("rate_hz", "pose_timeout_s"):
                value = _float(value, "", key)
            elif key == "baud" and (isinstance(value, bool) or not isinstance(value, int)):
                raise SettingError("", key, f"baud must be an integer, got {value!r}")
            elif key in ("name", "description", "firmware") and not isinstance(value, str):
                raise SettingError("", key, f"{key} must be a string, got {value!r}")
            elif key == "firmware" and not set(value) <= _NMEA_TEXT:
                raise SettingError("", key, "firmware must be printable ASCII without $ * ! \\")
            choices = _CHOICES.get(("", key))
            if choices and value not in choices:
                raise SettingError("", key, f"{key} must be one of {choices}, got {value!r}")
            kwargs[key] = value
        else:
            raise SettingError(
                "",
                key,
                f"unknown profile setting {key!r}; known: "
                f"{', '.join(k for k in top if k != 'source')}",
            )
    if "name" not in kwargs:
        raise SettingError("", None, "a profile needs a name")
    prof = Profile(**kwargs)
    if not 0.0 < prof.rate_hz <= 20.0:
        raise SettingError("", "rate_hz", f"rate_hz must be in (0, 20], got {prof.rate_hz}")
    if prof.baud < 300:
        raise SettingError("", "baud", f"baud must be at least 300, got {prof.baud}")
    if prof.pose_timeout_s <= 0:
        raise SettingError("", "pose_timeout_s", "pose_timeout_s must be positive")
    if not -10.0 <= prof.sky.elevation_mask_deg < 90.0:
        raise SettingError(
            "sky", "elevation_mask_deg", "sky.elevation_mask_deg must be in [-10, 90)"
        )
    if not 4 <= prof.sky.max_channels <= 72:
        raise SettingError("sky", "max_channels", "sky.max_channels must be in [4, 72]")
    if prof.dop_error.enabled and prof.noise.model != "none":
        raise SettingError("noise", "model", 'dop_error replaces the baseline noise: set '
                           'noise.model = "none" (or disable dop_error)')
    cs = prof.constellations
    for key, names in (("systems", cs.systems), ("sis_factor", [n for n, _ in cs.sis_factor]),
                       ("cn0_offset_db", [n for n, _ in cs.cn0_offset_db])):
        try:
            if any(_sys.system_named(n) is _sys.SBAS for n in names):
                raise ValueError("SBAS is not a system tracked for the fix (see [sbas])")
        except ValueError as exc:
            raise SettingError("constellations", key, f"constellations.{key}: {exc}") from None
    if any(not 0.0 < v <= 100.0 for _, v in cs.sis_factor):
        raise SettingError("constellations", "sis_factor",
                           "constellations.sis_factor: each factor must be in (0, 100]")
    ce = prof.correlated_error
    if ce.enabled and ce.domain == "range" and not prof.dop_error.enabled:
        raise SettingError("correlated_error", "domain", 'correlated_error.domain = "range" '
                           'needs dop_error.enabled (or use domain = "position")')
    ct = prof.cn0_tracking
    if ct.acq_dbhz < ct.track_dbhz or ct.fade_tau_s <= 0 or ct.reacq_s < 0:
        raise SettingError("cn0_tracking", "acq_dbhz", "need acq_dbhz >= track_dbhz, "
                           "fade_tau_s > 0 and reacq_s >= 0")
    if prof.nav_filter.tau_s <= 0 or prof.latency.latency_s < 0 or (
        prof.static_hold.threshold_mps < 0
    ):
        raise SettingError("nav_filter", "tau_s", "need nav_filter.tau_s > 0, "
                           "latency.latency_s >= 0 and static_hold.threshold_mps >= 0")
    if ce.tau_s <= 0 or ce.sigma_m < 0:
        raise SettingError("correlated_error", "tau_s", "need tau_s > 0 and sigma_m >= 0")
    mp = prof.multipath
    if mp.enabled and not prof.dop_error.enabled:
        raise SettingError("multipath", "enabled", "multipath needs dop_error.enabled (its "
                           "range errors are solved by least squares with the others)")
    for key, rule, good in (
        ("tau_s", "> 0 s", mp.tau_s > 0), ("sigma_m", ">= 0 m", mp.sigma_m >= 0),
        ("el0_deg", "> 0 deg", mp.el0_deg > 0), ("max_dist_m", "> 0 m", mp.max_dist_m > 0),
        ("open_sky_factor", "in [0, 1]", 0 <= mp.open_sky_factor <= 1),
    ):
        if not good:
            raise SettingError("multipath", key, f"multipath.{key} must be {rule}, got "
                               f"{getattr(mp, key)!r}")
    if prof.noise.min_noise_m < 0 or prof.noise.max_noise_m < prof.noise.min_noise_m:
        raise SettingError(
            "noise",
            "min_noise_m",
            "need 0 <= noise.min_noise_m <= noise.max_noise_m, got "
            f"{prof.noise.min_noise_m} and {prof.noise.max_noise_m}",
        )
    return prof


def _in_file(exc: SettingError, path: str | Path | None) -> VirtualGPSError:
    """Point a setting error at its file and line (or keep it as is without a file)."""
    if path is None:
        return exc
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError:
        text = ""
    line = toml_key_line(text, exc.section, exc.key) or toml_key_line(text, exc.section, None)
    return InputFileError(path, str(exc), line)


def _has(table: dict[str, Any], section: str, key: str | None) -> bool:
    where: Any = table
    for part in section.split(".") if section else ():  # "sky_mask.cells": a nested table
        where = where.get(part) if isinstance(where, dict) else None
    if not isinstance(where, dict):
        return False
    return key is None or key in where


def load_profile(
    name_or_path: str,
    overrides: dict[str, Any] | None = None,
    overrides_path: str | Path | None = None,
    flag_overrides: dict[str, Any] | None = None,
) -> Profile:
    """Load a profile and apply config-file overrides (built-in defaults < profile < config).

    Parameters
    ----------
    name_or_path : a built-in name (``holux-m1000``, ``usarsim``, ``ideal``) or a TOML path
    overrides : profile keys/tables from a config file, applied on top
    overrides_path : the config file they came from (named, with the line, in errors)
    flag_overrides : profile keys set by command-line flags, applied last

    Returns
    -------
    profile : Profile

    Raises
    ------
    InputFileError : a bad setting, naming the file (profile or config) and its line
    """
    data, source = load_profile_dict(name_or_path)
    try:
        prof = build_profile(data, source)
    except SettingError as exc:
        raise _in_file(exc, source) from None
    if overrides:
        data = merge(data, overrides)
        source = f"{source} + {overrides_path or 'config'}"
        try:
            prof = build_profile(data, source)
        except SettingError as exc:
            # The profile alone was valid: the setting at fault comes from the overrides.
            blame = overrides_path if _has(overrides, exc.section, exc.key) else source
            raise _in_file(exc, blame) from None
    if flag_overrides:
        try:
            prof = build_profile(merge(data, flag_overrides), f"{source} + flags")
        except SettingError as exc:
            raise ConfigError(f"command line: {exc}") from None
    return prof
