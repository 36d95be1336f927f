"""A real run aligned with its simulation, and both as the logs print them.

:class:`Obs` holds receiver output (a real log's, or an ensemble's seeds'), :class:`RunView` a
real run with its truth and sky at its own epochs. A real log prints its fixes, HDOP and
altitude to a few decimals, so the simulated ones are rounded alike before anything is
compared (:func:`quantize`, with the resolution read from the log by
:func:`position_quantum_min` and :func:`printed_step`): else an MTK log's HDOP ``1.00``
against a simulated 1.0028 would be a gap that no effect explains.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from virtualgps.gap.motion import local_en_m


@dataclass(frozen=True)
class Obs:
    """Receiver output over ``n`` epochs and ``k`` satellites, for ``s`` seeds (1: a real log).

    lat_deg, lon_deg, alt_hae_m : (s, n) float, NaN without a fix
    quality : (s, n) int, GGA quality (> 0: a fix)
    hdop : (s, n) float; sats_used : (s, n) float, NaN where unknown
    speed_mps : (s, n) float, reported speed
    tracked : (s, n, k) bool, the satellite has an SNR; cn0_dbhz : (s, n, k) float
        (float32 for an ensemble), dB-Hz, NaN where not tracked
    used : (s, n, k) bool (GSA)
    """

    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_hae_m: np.ndarray
    quality: np.ndarray
    hdop: np.ndarray
    sats_used: np.ndarray
    speed_mps: np.ndarray
    tracked: np.ndarray
    cn0_dbhz: np.ndarray
    used: np.ndarray

    @property
    def fixed(self) -> np.ndarray:
        """(s, n) bool, a fix with a position."""
        return (self.quality > 0) & np.isfinite(self.lat_deg) & np.isfinite(self.lon_deg)


@dataclass(frozen=True)
class RunView:
    """A real run aligned with its simulation: ``n`` real epochs, ``k`` GPS satellites.

    name : the run's name; t_unix_s : (n,) UTC seconds; power_on_unix_s : the log's start
    truth_lat_deg, truth_lon_deg, truth_alt_hae_m : (n,) the truth (NaN where unknown)
    reference : "truth" (errors about the truth) or "median" (static at an unknown point:
        errors about each run's own median fix; bias not assessed)
    vel_enu_mps : (n, 3) truth velocity, m/s (NaN where unknown); near_building : (n,) bool,
        some satellite above the mask has its direct path through a building
    prn : (k,); az_deg, el_deg : (n, k) degrees
    sat_ok : (n, k) bool, comparable: above the mask and in an epoch where the real log lists
        satellites (GSV)
    assess : the real log's support: {"gsv": bool, "cn0": bool, "gsa": bool}
    real : Obs with s = 1
    started : the log starts at power-on (its first epoch has no fix); else the receiver was
        already running and the start-up is not assessed
    quantum_min : the resolution of the log's printed positions, arc-minutes (1e-4 for
        ``ddmm.mmmm``; 0: unknown); simulated fixes are rounded alike before comparing
    hdop_step, alt_step_m : the printed resolution of HDOP and of the altitude (0: unknown)
    """

    name: str
    t_unix_s: np.ndarray
    power_on_unix_s: float
    truth_lat_deg: np.ndarray
    truth_lon_deg: np.ndarray
    truth_alt_hae_m: np.ndarray
    reference: str
    vel_enu_mps: np.ndarray
    near_building: np.ndarray
    prn: np.ndarray
    az_deg: np.ndarray
    el_deg: np.ndarray
    sat_ok: np.ndarray
    assess: dict
    real: Obs
    started: bool = True
    quantum_min: float = 0.0
    hdop_step: float = 0.0
    alt_step_m: float = 0.0

    @property
    def valid(self) -> np.ndarray:
        """(n,) bool, the truth is known at the epoch (only these epochs are compared)."""
        return np.isfinite(self.truth_lat_deg) & np.isfinite(self.truth_lon_deg)

    @property
    def speed_mps(self) -> np.ndarray:
        """(n,) truth speed over ground, m/s (NaN where unknown: neither moving nor
        stationary)."""
        return np.hypot(self.vel_enu_mps[:, 0], self.vel_enu_mps[:, 1])

    @cached_property
    def truth_en_m(self) -> np.ndarray:
        """(n, 2) the truth, metres east and north of its first known point (NaN where
        unknown); worked out once per run, not per segment (a run has hundreds)."""
        return local_en_m(self.truth_lat_deg, self.truth_lon_deg)


# The printed resolutions of a position, arc-minutes: NMEA writes minutes with 2 decimals at the
# coarsest (ddmm.mm, 18 m) and phones with 6 or 7.
QUANTA_MIN = tuple(10.0 ** -k for k in range(2, 8))


def position_quantum_min(lat_deg: np.ndarray, lon_deg: np.ndarray) -> float:
    """The resolution a log prints positions with, in arc-minutes: the coarsest power of ten
    (1e-2 to 1e-7) of which every fix's latitude and longitude minutes are a multiple (MTK's
    ``ddmm.mmmm``: 1e-4; the GSDC phones print 1e-6). 0.0 without a fix, or finer than 1e-7.

    Read from the digits, not from the steps between fixes: a receiver that prints one fix
    throughout (an ideal or held static fix) has no step, and one with few fixes steps by far
    more than its last digit (``mtk-3301.log``: six fixes printed to 1e-6, stepping by 1e-3;
    the GSDC phones' smallest step is 1e-5). The smallest step taken across latitude and
    longitude together, as before, made a log of one repeated fix print to 10,000
    arc-minutes: every simulated fix was then rounded thousands of kilometres away.

    lat_deg, lon_deg : (n,) float, degrees, NaN without a fix
    """
    m = np.concatenate([np.asarray(lat_deg, float), np.asarray(lon_deg, float)]) * 60.0
    m = m[np.isfinite(m)]
    if m.size == 0:
        return 0.0
    for q in QUANTA_MIN:
        r = m / q
        # (minutes made degrees by the reader and minutes again here are off by ~1e-12)
        if np.all(np.abs(r - np.round(r)) < 1e-3):
            return q
    return 0.0


def printed_step(values: np.ndarray, max_decimals: int = 6) -> float:
    """The resolution a log prints a quantity with (10^-k for the fewest decimals k that write
    every finite value exactly, e.g. 0.01 for HDOP ``1.00``, 0.1 for ``0.9``); 0.0 without a
    finite value.

    values : (n,) float as read from the log"""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return 0.0
    for k in range(max_decimals + 1):
        scaled = v * 10.0 ** k
        if np.all(np.abs(scaled - np.round(scaled)) < 1e-6 * np.maximum(1.0, np.abs(scaled))):
            return float(10.0 ** -k)
    return 0.0


def quantize(obs: Obs, quantum_min: float, hdop_step: float = 0.0, alt_step_m: float = 0.0
             ) -> Obs:
    """Simulated fixes printed like the real log's: latitude and longitude rounded to
    ``quantum_min`` arc-minutes (identical fixes in a row then appear as in the log), HDOP and
    altitude to their printed steps (0: left as they are)."""
    def rnd(x: np.ndarray, step: float) -> np.ndarray:
        return np.round(x / step) * step if step > 0 else x
    out = obs
    if quantum_min > 0:
        out = replace(out, lat_deg=rnd(out.lat_deg * 60.0, quantum_min) / 60.0,
                      lon_deg=rnd(out.lon_deg * 60.0, quantum_min) / 60.0)
    if hdop_step > 0 or alt_step_m > 0:
        out = replace(out, hdop=rnd(out.hdop, hdop_step), alt_hae_m=rnd(out.alt_hae_m, alt_step_m))
    return out
