"""What a receiver profile is: one frozen dataclass per TOML table, and :class:`Profile` that
holds them (reading and checking the files: :mod:`virtualgps.receiver.profiles`)."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

from virtualgps.sky import systems as _sys
from virtualgps.sky.skymask import SkyMaskParams


@dataclass(frozen=True)
class SkyParams:
    """What the antenna can see.

    elevation_mask_deg : satellites below are not used (the paper: 5 deg)
    max_channels : at most this many satellites are used, 4..72 (12: an MTK receiver, whose one
        GSA has 12 fields; multi-system receivers use more, e.g. a u-blox M8's 72 channels,
        listed 12 per system's GSA in NMEA 4.11)
    foliage : "block" (foliage-class objects block like buildings) or "ignore"
    pdop_mask : no fix where the used satellites' PDOP is above it (inf: none, the paper's
        model and MTK's: the shared MT3339 hour prints 3D fixes at PDOP 36.02, the shared
        BT-Q1000XT log a 3-satellite fix at PDOP 99.99, its cap). A u-blox
        receiver's default is 25.0 (CFG-NAV5 pDop, CFG-NAVSPG-OUTFIL_PDOP); without one, a
        least-squares fix over four nearly coplanar satellites lands kilometres away
    """

    elevation_mask_deg: float = 5.0
    max_channels: int = 12
    foliage: str = "block"
    pdop_mask: float = float("inf")


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
