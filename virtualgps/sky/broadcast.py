"""Broadcast ephemeris from RINEX 2/3 navigation files: the orbits a receiver itself uses.

A user's own log from last month has no TLE set anywhere public, but the day's broadcast
ephemeris is (IGS/CDDIS daily ``brdc`` files, mixed ``BRDC00...MN.rnx`` files of every system)
and is often recorded with the log. The file is read with georinex (a maintained RINEX reader;
``pip install 'virtualgps[rinex]'``); each record's orbit is computed here, vectorised over
times and satellites:

- GPS, Galileo and BeiDou: Keplerian elements, the user algorithm of IS-GPS-200 (Rev. N,
  section 20.3.3.4.3, Table 20-IV) with each system's constants and time scale: Galileo OS
  SIS ICD (issue 2.0, section 5.1.1: GST aligned to GPS time, its week continuous with GPS's in
  RINEX 3), BeiDou BDS-SIS-ICD-B1I (3.0, section 5.2.4: BDT = GPS time - 14 s, its week 0 GPS
  week 1356; the geostationary satellites' orbit computed in a plane turned by -5 degrees about
  x, section 5.2.4.12);
- GLONASS: the state vector (position, velocity, lunisolar acceleration) at the record's time
  integrated with 4th-order Runge-Kutta under the PZ-90 equations of motion (central term, J2,
  Earth rotation; GLONASS ICD edition 5.1, 2008, appendix A.3.1.2), steps of at most 60 s;
  PZ-90.11 is taken as WGS-84 (they agree to centimetres).

Kepler's equation is solved to machine precision. At each time a satellite's position comes
from its healthy record nearest in time, within ``MAX_AGE_S`` (GLONASS: ``GLONASS_MAX_AGE_S``,
its records being half-hourly); outside that the satellite has no position (NaN), as a receiver
without a valid ephemeris has none.
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
GLONASS_MAX_AGE_S = 1800.0  # a GLONASS record (every 30 min) serves +-30 min
KEPLER_ITERATIONS = 10  # Newton steps: |E error| < 1e-15 from E = M for GPS eccentricities

# Keplerian systems: (our number's offset, mu m^3/s^2, Earth rotation rad/s, week field,
# health field, the system week's offset from GPS weeks, GPS time minus system time s)
_KEPLER = {
    "G": (0, MU_M3_S2, OMEGA_E_RAD_S, "GPSWeek", "health", 0, 0.0),
    "E": (300, 3.986004418e14, 7.2921151467e-5, "GALWeek", "health", 0, 0.0),
    "C": (400, 3.986004418e14, 7.292115e-5, "BDTWeek", "SatH1", 1356, 14.0),
}
BEIDOU_GEO = frozenset((1, 2, 3, 4, 5, 59, 60, 61, 62, 63))  # BeiDou geostationary PRNs
BEIDOU_GEO_TILT_RAD = np.radians(-5.0)  # BDS-SIS-ICD-B1I 3.0 section 5.2.4.12
# PZ-90 (GLONASS ICD edition 5.1, 2008, section 3.1.3 and appendix A.3.1.2)
GLONASS_MU_M3_S2 = 3.986004418e14
GLONASS_AE_M = 6378136.0
GLONASS_J2 = 1082625.75e-9
GLONASS_OMEGA_E_RAD_S = 7.292115e-5
GLONASS_STEP_S = 60.0  # Runge-Kutta steps at most this long
GLONASS_OFFSET = 64  # our number: 64 + orbital slot (virtualgps.sky.systems)

# GPS - UTC in seconds from each date (UTC Unix seconds) on: the leap seconds since 1980
# (IERS Bulletin C; none announced after 2017-01-01).
_LEAPS = ((362793600, 1), (394329600, 2), (425865600, 3), (489024000, 4), (567993600, 5),
          (631152000, 6), (662688000, 7), (709948800, 8), (741484800, 9), (773020800, 10),
          (820454400, 11), (867715200, 12), (915148800, 13), (1136073600, 14),
          (1230768000, 15), (1341100800, 16), (1435708800, 17), (1483228800, 18))

# The record fields, in georinex's names, that a Keplerian orbit needs.
_FIELDS = ("sqrtA", "Eccentricity", "M0", "DeltaN", "omega", "Omega0", "OmegaDot", "Io",
           "IDOT", "Cuc", "Cus", "Crc", "Crs", "Cic", "Cis", "Toe")
_GLONASS_FIELDS = ("X", "Y", "Z", "dX", "dY", "dZ", "dX2", "dY2", "dZ2")  # m, m/s, m/s^2


def gps_minus_utc_s(t_unix_s: ArrayLike) -> F64:
    """GPS time minus UTC, seconds (the leap seconds since 1980-01-06) at UTC times."""
    t = np.asarray(t_unix_s, dtype=float)
    starts = np.array([s for s, _ in _LEAPS], dtype=float)
    steps = np.array([0] + [n for _, n in _LEAPS], dtype=float)
    return steps[np.searchsorted(starts, t, side="right")]


@dataclass(frozen=True, eq=False)
class BroadcastEphemeris:
    """Satellites from a RINEX navigation file (same interface as
    :class:`virtualgps.sky.ephemeris.Constellation`: ``prn``, ``sat_ecef_m``, ``sat_state_ecef``,
    ``epoch_center_unix_s``).

    Attributes
    ----------
    prn : (n_sat,) int, our satellite numbers ascending (:mod:`virtualgps.sky.systems`: GPS
        PRN, 64 + GLONASS slot, 300 + Galileo PRN, 400 + BeiDou PRN)
    rec_sat : (n_rec,) int, each record's satellite (index into ``prn``)
    toe_gps_s : (n_rec,) float, each record's reference time (Keplerian: time of ephemeris;
        GLONASS: the state vector's time), GPS seconds since 1980-01-06
    elements : {name: (n_rec,) float}, the Keplerian elements and corrections (``_FIELDS``;
        ``Toe`` in the system's own seconds of week), ``mu`` and ``omega_e`` (the system's
        constants) and ``geo`` (1: a BeiDou geostationary satellite); NaN for GLONASS records
    glonass : (n_rec, 9) float, GLONASS records' position (m), velocity (m/s) and lunisolar
        acceleration (m/s^2) in PZ-90; NaN for Keplerian records
    max_age_s : (n_rec,) float, how far from its reference time a record serves
    source : str, the file
    """

    prn: NDArray[np.int64]
    rec_sat: NDArray[np.int64]
    toe_gps_s: F64
    elements: dict[str, F64]
    glonass: F64
    max_age_s: F64
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
        """The first and last UTC Unix seconds at which some record serves (its
        ``max_age_s`` either side of its reference time)."""
        ends = np.array([(self.toe_gps_s - self.max_age_s).min(),
                         (self.toe_gps_s + self.max_age_s).max()])
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
            ok = np.abs(toe[nearest] - t_gps_s) <= self.max_age_s[recs[nearest]]
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
            no healthy record near enough
        """
        t = np.asarray(t_unix_s, dtype=float)
        tf = t.reshape(-1)
        t_gps = tf - GPS_EPOCH_UNIX_S + gps_minus_utc_s(tf)
        idx = self.record_index(t_gps)
        safe = np.maximum(idx, 0)
        tk = t_gps[:, None] - self.toe_gps_s[safe]
        glo = np.isfinite(self.glonass[safe, 0]) & (idx >= 0)
        kep = ~glo & (idx >= 0)
        pos = np.full(idx.shape + (3,), np.nan)
        if kep.any():
            el = {k: v[safe[kep]] for k, v in self.elements.items()}
            pos[kep] = orbit_ecef_m(el, tk[kep], el["mu"], el["omega_e"], el["geo"] > 0)
        if glo.any():
            pos[glo] = glonass_ecef_m(self.glonass[safe[glo]], tk[glo])
        return pos.reshape(t.shape + (len(self), 3))

    def sat_state_ecef(self, t_unix_s: ArrayLike, with_velocity: bool = True
                       ) -> tuple[F64, F64 | None]:
        """Positions and (central-difference, +-0.5 s) velocities in ECEF, m and m/s."""
        t = np.asarray(t_unix_s, dtype=float)
        pos = self.sat_ecef_m(t)
        if not with_velocity:
            return pos, None
        return pos, self.sat_ecef_m(t + 0.5) - self.sat_ecef_m(t - 0.5)


def orbit_ecef_m(el: dict[str, F64], tk_s: F64, mu_m3_s2: ArrayLike = MU_M3_S2,
                 omega_e_rad_s: ArrayLike = OMEGA_E_RAD_S, geo: ArrayLike = False) -> F64:
    """IS-GPS-200 Table 20-IV: a satellite's ECEF position from its broadcast elements (with
    another system's constants, and BeiDou's geostationary variant, where given).

    Parameters
    ----------
    el : {name: (...) float}: sqrtA (m^0.5), Eccentricity, M0, DeltaN (rad/s), omega, Omega0,
        OmegaDot (rad/s), Io, IDOT (rad/s), Cuc, Cus, Cic, Cis (rad), Crc, Crs (m), Toe (s of
        the system's week)
    tk_s : (...) float, seconds from the time of ephemeris (any span, no week wrap)
    mu_m3_s2, omega_e_rad_s : (...) the system's gravitational constant and Earth rotation rate
    geo : (...) bool, a BeiDou geostationary satellite (BDS-SIS-ICD-B1I 3.0, 5.2.4.12: the
        orbit in inertial axes, turned by -5 degrees about x, then by the Earth's rotation)

    Returns
    -------
    sat_ecef_m : (..., 3) float, metres, ECEF at the time toe + tk
    """
    a = el["sqrtA"] ** 2
    e = el["Eccentricity"]
    n = np.sqrt(mu_m3_s2 / a**3) + el["DeltaN"]
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
    geo = np.asarray(geo, dtype=bool)
    # (a geostationary satellite's node stays inertial: the Earth's turn comes after the tilt)
    omega = (el["Omega0"] + (el["OmegaDot"] - np.where(geo, 0.0, omega_e_rad_s)) * tk_s
             - omega_e_rad_s * el["Toe"])
    co, so, ci = np.cos(omega), np.sin(omega), np.cos(i)
    xyz = np.stack([x_orb * co - y_orb * ci * so, x_orb * so + y_orb * ci * co,
                    y_orb * np.sin(i)], axis=-1)
    if not geo.any():
        return xyz
    # R_Z(omega_e tk) R_X(-5 deg), R_X(p) = [[1, 0, 0], [0, cos p, sin p], [0, -sin p, cos p]],
    # R_Z(p) = [[cos p, sin p, 0], [-sin p, cos p, 0], [0, 0, 1]] (the ICD's definitions)
    cp, sp = np.cos(BEIDOU_GEO_TILT_RAD), np.sin(BEIDOU_GEO_TILT_RAD)
    gx = xyz[..., 0]
    gy = cp * xyz[..., 1] + sp * xyz[..., 2]
    gz = -sp * xyz[..., 1] + cp * xyz[..., 2]
    rot = omega_e_rad_s * tk_s
    cr, sr = np.cos(rot), np.sin(rot)
    turned = np.stack([cr * gx + sr * gy, -sr * gx + cr * gy, gz], axis=-1)
    return np.where(geo[..., None], turned, xyz)


def glonass_ecef_m(state: F64, dt_s: F64) -> F64:
    """GLONASS positions from broadcast state vectors (GLONASS ICD 5.1, appendix A.3.1.2).

    The PZ-90 equations of motion in the rotating frame (central term, J2, centrifugal and
    Coriolis terms, the record's constant lunisolar acceleration) integrated by 4th-order
    Runge-Kutta from the record's time, every integration in as many equal steps as the longest
    needs (at most ``GLONASS_STEP_S`` each).

    Parameters
    ----------
    state : (m, 9) position (m), velocity (m/s), lunisolar acceleration (m/s^2), PZ-90
    dt_s : (m,) seconds from the record's time (either sign)

    Returns
    -------
    sat_ecef_m : (m, 3) metres
    """
    acc = state[:, 6:9]
    w = GLONASS_OMEGA_E_RAD_S

    def deriv(y: F64) -> F64:
        r, v = y[:, :3], y[:, 3:]
        r2 = np.sum(r * r, axis=1)
        rr = np.sqrt(r2)
        k = GLONASS_MU_M3_S2 / (rr * r2)
        j = 1.5 * GLONASS_J2 * GLONASS_MU_M3_S2 * GLONASS_AE_M**2 / (r2 * r2 * rr)
        z2 = 5.0 * r[:, 2] ** 2 / r2
        a = np.empty_like(r)
        a[:, 0] = -k * r[:, 0] - j * r[:, 0] * (1.0 - z2) + w * w * r[:, 0] + 2.0 * w * v[:, 1]
        a[:, 1] = -k * r[:, 1] - j * r[:, 1] * (1.0 - z2) + w * w * r[:, 1] - 2.0 * w * v[:, 0]
        a[:, 2] = -k * r[:, 2] - j * r[:, 2] * (3.0 - z2)
        return np.concatenate([v, a + acc], axis=1)

    dt = np.asarray(dt_s, dtype=float)
    steps = max(1, int(np.ceil(np.max(np.abs(dt), initial=0.0) / GLONASS_STEP_S)))
    h = (dt / steps)[:, None]
    y = np.array(state[:, :6], dtype=float)
    for _ in range(steps):
        k1 = deriv(y)
        k2 = deriv(y + 0.5 * h * k1)
        k3 = deriv(y + 0.5 * h * k2)
        k4 = deriv(y + h * k3)
        y = y + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return y[:, :3]


def is_rinex_nav(path: str | Path) -> bool:
    """Whether a file's first line is a RINEX navigation header (``N`` or ``G`` type in
    column 21 of ``RINEX VERSION / TYPE``)."""
    try:
        with open(path, "rb") as f:
            first = f.readline(200).decode("ascii", "replace")
    except OSError:
        return False
    return "RINEX VERSION / TYPE" in first and first[20:21] in ("N", "G")


def read_rinex_nav(path: str | Path, systems_kept: str | None = None) -> BroadcastEphemeris:
    """Read the GPS, Galileo, BeiDou and GLONASS records of a RINEX 2 or 3 navigation file
    (a mixed RINEX 3 file holds them all).

    systems_kept : RINEX letters of the systems to keep (e.g. ``"G"``); None: every one read

    Raises
    ------
    InputFileError
        naming the file: georinex missing, the file unreadable, or no healthy record of the
        systems kept
    """
    path = Path(path)
    try:
        import georinex
    except ImportError:
        raise InputFileError(path, "reading RINEX navigation files needs georinex: pip install "
                             "'virtualgps[rinex]'") from None
    letters = [x for x in "GECR" if systems_kept is None or x in systems_kept]
    try:
        with warnings.catch_warnings():  # xarray's notices about georinex's merges, not ours
            warnings.simplefilter("ignore", FutureWarning)
            nav = georinex.load(path, use=set(letters))
    except Exception as exc:  # georinex raises many kinds on a bad file: name the file
        raise InputFileError(path, f"not a readable RINEX navigation file ({exc})") from None
    if nav is None or not getattr(nav, "data_vars", {}):
        raise InputFileError(path, "no navigation records")
    svs = np.array([str(x) for x in nav["sv"].values])
    t_utc = (nav["time"].values.astype("datetime64[ns]").astype(np.int64) / 1e9)
    vals = {k: nav[k].values.astype(float) for k in nav.data_vars}
    recs: list[tuple[int, float, dict, F64, float]] = []  # (number, toe_gps, el, glo, age)
    nan_glo = np.full(9, np.nan)
    for c, sv in enumerate(svs):
        letter, own = sv[0], int(sv[1:])
        if letter not in letters:
            continue
        if letter in _KEPLER:
            off, mu, we, week, health, week0, gps_minus = _KEPLER[letter]
            col = {k: vals[k][:, c] for k in (*_FIELDS, week, health) if k in vals}
            if len(col) < len(_FIELDS) + 2:
                continue
            for ti in np.flatnonzero(np.isfinite(col["sqrtA"]) & np.isfinite(col["Toe"])
                                     & (col[health] == 0)):
                el = {k: float(col[k][ti]) for k in _FIELDS}
                el.update(mu=mu, omega_e=we,
                          geo=float(letter == "C" and own in BEIDOU_GEO))
                toe = (col[week][ti] + week0) * WEEK_S + el["Toe"] + gps_minus
                recs.append((off + own, toe, el, nan_glo, MAX_AGE_S))
        else:  # GLONASS: the record's time is UTC
            if not all(k in vals for k in _GLONASS_FIELDS):
                continue
            state = np.stack([vals[k][:, c] for k in _GLONASS_FIELDS], axis=1)
            health = vals.get("health", np.zeros((len(t_utc), len(svs))))[:, c]
            for ti in np.flatnonzero(np.isfinite(state).all(axis=1) & (health == 0)):
                toe = t_utc[ti] - GPS_EPOCH_UNIX_S + float(gps_minus_utc_s(t_utc[ti]))
                recs.append((GLONASS_OFFSET + own, toe, {}, state[ti], GLONASS_MAX_AGE_S))
    if not recs:
        names = {"G": "GPS", "E": "Galileo", "C": "BeiDou", "R": "GLONASS"}
        raise InputFileError(path, "no healthy " + "/".join(names[x] for x in letters)
                             + " records")
    number = np.array([r[0] for r in recs], dtype=np.int64)
    toe = np.array([r[1] for r in recs])
    prns = np.unique(number)
    rec_sat = np.searchsorted(prns, number)
    order = np.lexsort((toe, rec_sat))
    keys = (*_FIELDS, "mu", "omega_e", "geo")
    elements = {k: np.array([r[2].get(k, np.nan) for r in recs])[order] for k in keys}
    glonass = np.stack([r[3] for r in recs])[order]
    age = np.array([r[4] for r in recs])[order]
    return BroadcastEphemeris(prns, rec_sat[order].astype(np.int64), toe[order], elements,
                              glonass, age, str(path))
