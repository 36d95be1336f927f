"""GPS broadcast ephemeris from RINEX 2/3 navigation files: the orbits a receiver itself uses.

A user's own log from last month has no TLE set anywhere public, but the day's broadcast
ephemeris is (IGS/CDDIS daily ``brdc`` files) and is often recorded with the log. The file is
read with georinex (a maintained RINEX reader; ``pip install 'virtualgps[rinex]'``); the orbit
of each record is computed here, vectorised over times and satellites, with the user algorithm
of IS-GPS-200 (Rev. N, section 20.3.3.4.3, Table 20-IV): Kepler's equation solved to machine
precision, the harmonic corrections, and the rotation into ECEF at the given time.

At each time a satellite's position comes from its healthy record with the nearest time of
ephemeris ``toe``, within half the fit interval plus a margin (``MAX_AGE_S``); outside that the
satellite has no position (NaN), as a receiver without a valid ephemeris has none.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from virtualgps.exceptions import InputFileError

F64 = NDArray[np.float64]

MU_M3_S2 = 3.986005e14  # WGS-84 gravitational constant for GPS (IS-GPS-200 Table 20-IV)
OMEGA_E_RAD_S = 7.2921151467e-5  # WGS-84 Earth rotation rate (IS-GPS-200 Table 20-IV)
WEEK_S = 604800.0
GPS_EPOCH_UNIX_S = 315964800.0  # 1980-01-06T00:00:00Z
MAX_AGE_S = 4.0 * 3600.0  # a record serves up to 4 h from its toe (fit interval 4 h, plus 2 h)
KEPLER_ITERATIONS = 10  # Newton steps: |E error| < 1e-15 from E = M for GPS eccentricities

# GPS - UTC in seconds from each date (UTC Unix seconds) on: the leap seconds since 1980
# (IERS Bulletin C; none announced after 2017-01-01).
_LEAPS = ((362793600, 1), (394329600, 2), (425865600, 3), (489024000, 4), (567993600, 5),
          (631152000, 6), (662688000, 7), (709948800, 8), (741484800, 9), (773020800, 10),
          (820454400, 11), (867715200, 12), (915148800, 13), (1136073600, 14),
          (1230768000, 15), (1341100800, 16), (1435708800, 17), (1483228800, 18))

# The record fields, in georinex's names, that the orbit needs.
_FIELDS = ("sqrtA", "Eccentricity", "M0", "DeltaN", "omega", "Omega0", "OmegaDot", "Io",
           "IDOT", "Cuc", "Cus", "Crc", "Crs", "Cic", "Cis", "Toe", "GPSWeek", "health")


def gps_minus_utc_s(t_unix_s: ArrayLike) -> F64:
    """GPS time minus UTC, seconds (the leap seconds since 1980-01-06) at UTC times."""
    t = np.asarray(t_unix_s, dtype=float)
    starts = np.array([s for s, _ in _LEAPS], dtype=float)
    steps = np.array([0] + [n for _, n in _LEAPS], dtype=float)
    return steps[np.searchsorted(starts, t, side="right")]


@dataclass(frozen=True, eq=False)
class BroadcastEphemeris:
    """GPS satellites from a RINEX navigation file (same interface as
    :class:`virtualgps.sky.ephemeris.Constellation`: ``prn``, ``sat_ecef_m``, ``sat_state_ecef``,
    ``epoch_center_unix_s``).

    Attributes
    ----------
    prn : (n_sat,) int, PRNs ascending
    rec_sat : (n_rec,) int, each record's satellite (index into ``prn``)
    toe_gps_s : (n_rec,) float, each record's time of ephemeris, GPS seconds since 1980-01-06
    elements : {name: (n_rec,) float}, the Keplerian elements and corrections (``_FIELDS``)
    source : str, the file
    """

    prn: NDArray[np.int64]
    rec_sat: NDArray[np.int64]
    toe_gps_s: F64
    elements: dict[str, F64]
    source: str

    def __len__(self) -> int:
        return int(self.prn.shape[0])

    @property
    def epoch_center_unix_s(self) -> float:
        """Middle of the records' toe span, UTC Unix seconds (for the sky-time policy)."""
        first, last = self.coverage_unix_s
        return 0.5 * (first + last)

    @property
    def coverage_unix_s(self) -> tuple[float, float]:
        """The first and last UTC Unix seconds at which some record serves (``MAX_AGE_S``
        either side of the toes)."""
        ends = np.array([self.toe_gps_s.min() - MAX_AGE_S, self.toe_gps_s.max() + MAX_AGE_S])
        ends += GPS_EPOCH_UNIX_S
        ends -= gps_minus_utc_s(ends)
        return float(ends[0]), float(ends[1])

    def record_index(self, t_gps_s: F64) -> NDArray[np.int64]:
        """(n_t, n_sat) the record serving each satellite at each GPS time (-1: none)."""
        out = np.full((t_gps_s.size, len(self)), -1, dtype=np.int64)
        for s in range(len(self)):
            recs = np.flatnonzero(self.rec_sat == s)  # sorted by toe (see read_rinex_nav)
            toe = self.toe_gps_s[recs]
            j = np.clip(np.searchsorted(toe, t_gps_s), 1, toe.size) - 1
            j_next = np.minimum(j + 1, toe.size - 1)
            nearest = np.where(np.abs(toe[j_next] - t_gps_s) < np.abs(toe[j] - t_gps_s), j_next, j)
            ok = np.abs(toe[nearest] - t_gps_s) <= MAX_AGE_S
            out[:, s] = np.where(ok, recs[nearest], -1)
        return out

    def sat_ecef_m(self, t_unix_s: ArrayLike) -> F64:
        """Satellite positions in ECEF at UTC times.

        Parameters
        ----------
        t_unix_s : scalar or (...) float, UTC Unix seconds; (n_t,) gives (n_t, n_sat, 3)

        Returns
        -------
        sat_ecef_m : (..., n_sat, 3) float, metres, ECEF (WGS-84); NaN where the satellite has
            no healthy record within ``MAX_AGE_S``
        """
        t = np.asarray(t_unix_s, dtype=float)
        tf = t.reshape(-1)
        t_gps = tf - GPS_EPOCH_UNIX_S + gps_minus_utc_s(tf)
        idx = self.record_index(t_gps)
        safe = np.maximum(idx, 0)
        el = {k: v[safe] for k, v in self.elements.items()}
        tk = t_gps[:, None] - self.toe_gps_s[safe]
        pos = orbit_ecef_m(el, tk)
        pos = np.where((idx < 0)[..., None], np.nan, pos)
        return pos.reshape(t.shape + (len(self), 3))

    def sat_state_ecef(self, t_unix_s: ArrayLike, with_velocity: bool = True
                       ) -> tuple[F64, F64 | None]:
        """Positions and (central-difference, +-0.5 s) velocities in ECEF, m and m/s."""
        t = np.asarray(t_unix_s, dtype=float)
        pos = self.sat_ecef_m(t)
        if not with_velocity:
            return pos, None
        return pos, self.sat_ecef_m(t + 0.5) - self.sat_ecef_m(t - 0.5)


def orbit_ecef_m(el: dict[str, F64], tk_s: F64) -> F64:
    """IS-GPS-200 Table 20-IV: a satellite's ECEF position from its broadcast elements.

    Parameters
    ----------
    el : {name: (...) float}: sqrtA (m^0.5), Eccentricity, M0, DeltaN (rad/s), omega, Omega0,
        OmegaDot (rad/s), Io, IDOT (rad/s), Cuc, Cus, Cic, Cis (rad), Crc, Crs (m), Toe (s of
        the GPS week)
    tk_s : (...) float, seconds from the time of ephemeris (GPS time; any span, no week wrap)

    Returns
    -------
    sat_ecef_m : (..., 3) float, metres, ECEF at the time toe + tk
    """
    a = el["sqrtA"] ** 2
    e = el["Eccentricity"]
    n = np.sqrt(MU_M3_S2 / a**3) + el["DeltaN"]
    m = el["M0"] + n * tk_s
    ecc = m.copy()
    for _ in range(KEPLER_ITERATIONS):  # Newton on E - e sin E = M
        ecc = ecc - (ecc - e * np.sin(ecc) - m) / (1.0 - e * np.cos(ecc))
    nu = np.arctan2(np.sqrt(1.0 - e**2) * np.sin(ecc), np.cos(ecc) - e)
    phi = nu + el["omega"]
    s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
    u = phi + el["Cus"] * s2 + el["Cuc"] * c2
    r = a * (1.0 - e * np.cos(ecc)) + el["Crs"] * s2 + el["Crc"] * c2
    i = el["Io"] + el["Cis"] * s2 + el["Cic"] * c2 + el["IDOT"] * tk_s
    x_orb, y_orb = r * np.cos(u), r * np.sin(u)
    omega = el["Omega0"] + (el["OmegaDot"] - OMEGA_E_RAD_S) * tk_s - OMEGA_E_RAD_S * el["Toe"]
    co, so, ci = np.cos(omega), np.sin(omega), np.cos(i)
    return np.stack([x_orb * co - y_orb * ci * so, x_orb * so + y_orb * ci * co,
                     y_orb * np.sin(i)], axis=-1)


def is_rinex_nav(path: str | Path) -> bool:
    """Whether a file's first line is a RINEX navigation header (``N`` or ``G`` type in
    column 21 of ``RINEX VERSION / TYPE``)."""
    try:
        with open(path, "rb") as f:
            first = f.readline(200).decode("ascii", "replace")
    except OSError:
        return False
    return "RINEX VERSION / TYPE" in first and first[20:21] in ("N", "G")


def read_rinex_nav(path: str | Path) -> BroadcastEphemeris:
    """Read the GPS records of a RINEX 2 or 3 navigation file.

    Raises
    ------
    InputFileError
        naming the file: georinex missing, the file unreadable, or no healthy GPS record
    """
    path = Path(path)
    try:
        import georinex
    except ImportError:
        raise InputFileError(path, "reading RINEX navigation files needs georinex: pip install "
                             "'virtualgps[rinex]'") from None
    try:
        with warnings.catch_warnings():  # xarray's notices about georinex's merges, not ours
            warnings.simplefilter("ignore", FutureWarning)
            nav = georinex.load(path, use="G")
    except Exception as exc:  # georinex raises many kinds on a bad file: name the file
        raise InputFileError(path, f"not a readable RINEX navigation file ({exc})") from None
    if nav is None or "sqrtA" not in getattr(nav, "data_vars", {}):
        raise InputFileError(path, "no GPS records")
    svs = [str(s) for s in nav["sv"].values]
    cols = {k: nav[k].values.astype(float) for k in _FIELDS}  # (n_time, n_sv)
    ok = np.isfinite(cols["sqrtA"]) & np.isfinite(cols["Toe"]) & (cols["health"] == 0)
    ti, si = np.nonzero(ok)
    if ti.size == 0:
        raise InputFileError(path, "no healthy GPS records")
    prn_of_sv = np.array([int(s[1:]) for s in svs])
    prns = np.unique(prn_of_sv[si])
    rec_sat = np.searchsorted(prns, prn_of_sv[si])
    toe = cols["GPSWeek"][ti, si] * WEEK_S + cols["Toe"][ti, si]
    order = np.lexsort((toe, rec_sat))
    elements = {k: cols[k][ti, si][order] for k in _FIELDS if k not in ("GPSWeek", "health")}
    return BroadcastEphemeris(prns.astype(np.int64), rec_sat[order].astype(np.int64),
                              toe[order], elements, str(path))
