"""UBX output messages built from fix records: NAV, MON and ACK frames. Pure: no I/O, no clock.

Layouts follow the u-blox 8 / u-blox M8 receiver description UBX-13003221 (R25: the UBX-NAV,
UBX-MON and UBX-ACK message descriptions) and the u-blox M9 SPG 4.04 interface description (its
UBX-NAV-PVT, UBX-NAV-SAT, UBX-MON-RF); pyubx2's definitions were read as a cross-check. All
multi-byte fields are little-endian.

Epoch values are computed once per :class:`~virtualgps.receiver.records.Fixes` batch,
vectorised over epochs (:func:`solution`); each encoder then writes one epoch ``i`` of it.

Choices (where the documents leave the value to the receiver's firmware):

- **Time.** ``iTOW`` is the epoch's GPS time of week in ms: UTC ``t_unix_s`` rounded to the
  millisecond (iTOW's resolution; the NMEA writer rounds the same time), plus GPS - UTC from
  the leap-second table of :func:`virtualgps.sky.broadcast.gps_minus_utc_s` (IERS Bulletin C;
  18 s since 2017-01-01, none announced since). UTC fields come from the same millisecond, so
  ``nano`` is a whole number of ms and ``fTOW`` is 0. The date and time are flagged valid
  (``validDate``/``validTime``, ``validTOW``/``validWKN``) once any satellite is tracked, and
  ``fullyResolved``/``validUTC`` only with a fix (a receiver knows GPS time from one
  satellite's subframes, and resolves it fully with its solution; UBX-13003221, "Clocks and time").
- **No fix** (``mode`` 1 or a NaN position): ``fixType`` 0, ``gnssFixOK`` 0, position 0 with
  ``hMSL`` = -17 000 mm (0 m above the ellipsoid at 0 N 0 E, where the EGM96 geoid is +17 m),
  velocities 0, ``hAcc``/``vAcc``/``tAcc``/``pAcc`` 0xFFFFFFFF, ``sAcc`` 20 m/s, ``headAcc`` 180
  deg, every DOP 99.99: what u-blox modules write after a cold start as recalled from their
  logs (the NMEA of a NEO-M8N before a fix, quoted in public repositories, has DOPs 99.99; the
  UBX values are not confirmed: the documents do not specify pre-fix contents). A real module keeps
  its last position after losing a fix; the fix record has none to keep, so this does not.
- **Accuracies.** ``hAcc`` = sqrt(sigma_e^2 + sigma_n^2) and ``vAcc`` = sigma_u from the
  receiver's own ``sigma_enu_m`` (as GST reports it); where that is absent, HDOP (VDOP) times
  ``range_rms_m``; where that is absent too, HDOP (VDOP) times :data:`FALLBACK_UERE_M`.
  ``sAcc`` = PDOP x :data:`RANGE_RATE_SIGMA_MPS` (the fix record carries no velocity sigma);
  ``headAcc`` = atan(sAcc / gSpeed) (180 deg at rest); ``tAcc`` = TDOP x range sigma / c.
  These are placeholders for profile parameters to calibrate, not datasheet values.
- **DOPs.** hDOP, vDOP and pDOP are the fix record's (so NAV-DOP agrees with GSA). tDOP and the
  split of hDOP into nDOP/eDOP come from the used satellites' az/el with one receiver clock
  (nDOP, eDOP scaled so that nDOP^2 + eDOP^2 = hDOP^2); with fewer than 4 usable satellites
  eDOP = nDOP = hDOP / sqrt(2) and tDOP = :data:`TDOP_PER_PDOP` x pDOP. gDOP = sqrt(pDOP^2 +
  tDOP^2).
- **Velocity.** velN/velE from ``speed_mps`` and ``course_deg``; velD 0 (the record has no
  vertical speed); headMot = course. heading-of-vehicle and magnetic fields are 0 and invalid.
- **Satellites** (NAV-SAT, NAV-SVINFO): every satellite in view, tracked or used; cno 0 when not
  tracked; an unknown elevation is written -91 and azimuth 0 ("unknown if out of range",
  UBX-13003221 UBX-NAV-SAT). qualityInd 7 (code and carrier locked) for used satellites, 4 (code
  locked) for tracked ones, 1 (searching) otherwise; health 1 (healthy) for tracked satellites
  and 0 (unknown) otherwise; orbit source ephemeris when tracked, almanac otherwise; diffCorr
  and sbasCorrUsed on used satellites of a DGPS (SBAS) fix; pseudorange residual 0 (the record
  has none). Rounding of el/az/C/N0 is the NMEA writer's (half to even), so NAV-SAT and GSV
  agree.
- **MON-HW / MON-RF**: noise level, AGC count and jamming indicator are constants
  (:data:`MON_HW_DEFAULTS`), antenna OK and powered; pin fields 0.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from virtualgps.device.ubx.frame import encode
from virtualgps.geodesy import ecef_to_enu_matrix, geodetic_to_ecef
from virtualgps.receiver.records import MODE_2D, MODE_3D, QUALITY_DGPS, Fixes
from virtualgps.sky.broadcast import GPS_EPOCH_UNIX_S, gps_minus_utc_s
from virtualgps.sky.systems import BEIDOU, GALILEO, GLONASS, GPS, QZSS, SBAS

# Message (class, id) pairs (UBX-13003221, "UBX messages overview").
NAV_POSLLH = (0x01, 0x02)
NAV_STATUS = (0x01, 0x03)
NAV_DOP = (0x01, 0x04)
NAV_SOL = (0x01, 0x06)
NAV_PVT = (0x01, 0x07)
NAV_VELNED = (0x01, 0x12)
NAV_TIMEGPS = (0x01, 0x20)
NAV_TIMEUTC = (0x01, 0x21)
NAV_SVINFO = (0x01, 0x30)
NAV_SAT = (0x01, 0x35)
NAV_EOE = (0x01, 0x61)
ACK_NAK = (0x05, 0x00)
ACK_ACK = (0x05, 0x01)
MON_VER = (0x0A, 0x04)
MON_HW = (0x0A, 0x09)
MON_RF = (0x0A, 0x38)

SPEED_OF_LIGHT_MPS = 299_792_458.0
WEEK_MS = 604_800_000
U32_MAX = 0xFFFF_FFFF
#: UERE used for hAcc/vAcc when the record has neither sigma_enu_m nor range_rms_m, metres
#: (GPS SPS performance standard 2020: 95 % URE <= 7.8 m, i.e. sigma ~ 4 m, plus atmosphere).
FALLBACK_UERE_M = 5.0
#: Range-rate sigma behind sAcc, m/s (Doppler velocity; a placeholder to calibrate).
RANGE_RATE_SIGMA_MPS = 0.1
#: tDOP / pDOP where the geometry is unknown (open-sky constellations give 0.4-0.7).
TDOP_PER_PDOP = 0.55
NO_FIX_HMSL_MM = -17_000  # EGM96 geoid height at 0 N 0 E is +17 m
NO_FIX_SACC_MMPS = 20_000
NO_FIX_HEADACC_E5 = 18_000_000  # 180 deg
NO_FIX_DOP_E2 = 9999  # 99.99
#: MON-HW / MON-RF values that no fix record carries: noise per ms, AGC count (0..8191),
#: jamming indicator (0..255), antenna status 2 (OK), antenna power 1 (on), jamming state 1
#: (no significant jamming). Illustrative, not from a datasheet.
MON_HW_DEFAULTS = {"noise_per_ms": 90, "agc_cnt": 4000, "jam_ind": 5, "a_status": 2,
                   "a_power": 1, "jamming_state": 1}

# gnssId (UBX-13003221 appendix A "GNSS identifiers").
GNSS_GPS, GNSS_SBAS, GNSS_GALILEO, GNSS_BEIDOU, GNSS_IMES, GNSS_QZSS, GNSS_GLONASS = range(7)


@dataclass(frozen=True)
class Solution:
    """The UBX fields of every epoch of one :class:`Fixes` batch, scaled to UBX units.

    Every array is (n_t,) int64 unless noted; ``fixes`` is the batch itself (for the
    per-satellite messages).

    itow_ms, week : GPS time of week (ms) and GPS week
    year, month, day, hour, minute, second, nano_ns : UTC of the epoch
    time_valid, fix_ok, diff : bool (time known; a 2D/3D fix with a finite position; DGPS)
    fix_type : 0 no fix, 2 2D, 3 3D
    num_sv : satellites used
    lat_e7, lon_e7 : 1e-7 deg; height_mm (above the ellipsoid), hmsl_mm
    hacc_mm, vacc_mm, tacc_ns, sacc_mmps, headacc_e5 : accuracies
    vel_n_mmps, vel_e_mmps, vel_d_mmps, gspeed_mmps : mm/s, NED; head_e5 : 1e-5 deg
    gdop_e2, pdop_e2, tdop_e2, vdop_e2, hdop_e2, ndop_e2, edop_e2 : DOP x 100
    ecef_cm, ecef_vel_cmps : (n_t, 3) int64, ECEF position (cm) and velocity (cm/s)
    sat_cols : (k,) int, the prn columns with a UBX identity, in (gnssId, svId) order
    gnss_id, sv_id, svinfo_id : (k,) int, their identities (svinfo_id 0: none)
    """

    fixes: Fixes
    itow_ms: np.ndarray
    week: np.ndarray
    year: np.ndarray
    month: np.ndarray
    day: np.ndarray
    hour: np.ndarray
    minute: np.ndarray
    second: np.ndarray
    nano_ns: np.ndarray
    time_valid: np.ndarray
    fix_ok: np.ndarray
    diff: np.ndarray
    fix_type: np.ndarray
    num_sv: np.ndarray
    lat_e7: np.ndarray
    lon_e7: np.ndarray
    height_mm: np.ndarray
    hmsl_mm: np.ndarray
    hacc_mm: np.ndarray
    vacc_mm: np.ndarray
    tacc_ns: np.ndarray
    sacc_mmps: np.ndarray
    headacc_e5: np.ndarray
    vel_n_mmps: np.ndarray
    vel_e_mmps: np.ndarray
    vel_d_mmps: np.ndarray
    gspeed_mmps: np.ndarray
    head_e5: np.ndarray
    gdop_e2: np.ndarray
    pdop_e2: np.ndarray
    tdop_e2: np.ndarray
    vdop_e2: np.ndarray
    hdop_e2: np.ndarray
    ndop_e2: np.ndarray
    edop_e2: np.ndarray
    ecef_cm: np.ndarray
    ecef_vel_cmps: np.ndarray
    sat_cols: np.ndarray
    gnss_id: np.ndarray
    sv_id: np.ndarray
    svinfo_id: np.ndarray


def _scaled(x: np.ndarray, scale: float, fill: int, lo: int, hi: int) -> np.ndarray:
    """``x * scale`` rounded (half to even) and clipped to [lo, hi] as int64; ``fill`` where
    ``x`` is not finite."""
    v = np.asarray(x, dtype=float) * scale
    ok = np.isfinite(v)
    return np.where(ok, np.clip(np.rint(np.where(ok, v, 0.0)), lo, hi), fill).astype(np.int64)


def ubx_ids(prn: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """UBX identities of satellite numbers (virtualgps.sky.systems numbering).

    gnssId/svId follow UBX-13003221 appendix A (GPS 1-32, SBAS 120-158, Galileo 1-36, BeiDou
    1-63, QZSS 1-10, GLONASS slot 1-32); the single-number "UBX" svid of NAV-SVINFO follows the
    same appendix: GPS 1-32, SBAS 120-158, Galileo 211-246, BeiDou 1-5 -> 159-163 and 6-37 ->
    33-64, QZSS 193-202, GLONASS 65-96 (gpsd's ubx_to_prn reads it the same way).

    Parameters
    ----------
    prn : (n_sat,) int, satellite numbers

    Returns
    -------
    gnss_id : (n_sat,) int, -1 for a number outside every system
    sv_id : (n_sat,) int
    svinfo_id : (n_sat,) int, 0 where NAV-SVINFO has no number (BeiDou above 37)
    """
    p = np.asarray(prn, dtype=np.int64)
    gnss = np.full(p.shape, -1, dtype=np.int64)
    sv = np.zeros(p.shape, dtype=np.int64)
    svinfo = np.zeros(p.shape, dtype=np.int64)
    for system, gid, info_offset in ((GPS, GNSS_GPS, 0), (SBAS, GNSS_SBAS, 0),
                                     (GALILEO, GNSS_GALILEO, 210), (BEIDOU, GNSS_BEIDOU, None),
                                     (QZSS, GNSS_QZSS, 192), (GLONASS, GNSS_GLONASS, 64)):
        m = (p >= system.first) & (p <= system.last)
        own = p - system.offset  # PRN (SBAS: 120-158) or GLONASS slot
        if system is QZSS:
            own = p - 192
        gnss[m], sv[m] = gid, own[m]
        if info_offset is not None:
            svinfo[m] = own[m] + info_offset
        else:  # BeiDou
            svinfo[m] = np.where(own[m] <= 5, own[m] + 158, np.where(own[m] <= 37, own[m] + 27, 0))
    return gnss, sv, svinfo


def _civil(days: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Year, month, day of days since 1970-01-01 (H. Hinnant, "chrono-compatible low-level
    date algorithms", civil_from_days)."""
    z = days + 719468
    era = np.floor_divide(z, 146097)
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    day = doy - (153 * mp + 2) // 5 + 1
    month = np.where(mp < 10, mp + 3, mp - 9)
    year = yoe + era * 400 + (month <= 2)
    return year, month, day


def _geometry_dops(fixes: Fixes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(eDOP, nDOP, vDOP, tDOP), each (n_t,), of the used satellites with one clock; NaN with
    fewer than 4 usable satellites or a degenerate geometry."""
    el = np.radians(np.asarray(fixes.el_deg, dtype=float))
    az = np.radians(np.asarray(fixes.az_deg, dtype=float))
    ok = np.asarray(fixes.used, dtype=bool) & np.isfinite(el) & np.isfinite(az)
    ce = np.cos(el)
    g = np.stack([ce * np.sin(az), ce * np.cos(az), np.sin(el), np.ones_like(el)], axis=-1)
    g = np.where(ok[..., None], g, 0.0)
    gtg = np.einsum("tsi,tsj->tij", g, g)
    out = np.full((el.shape[0], 4), np.nan)
    good = ok.sum(axis=1) >= 4
    if good.any():
        sub = gtg[good]
        fine = np.linalg.cond(sub) < 1e10  # batched SVD: never raises on a singular matrix
        q = np.full(sub.shape, np.nan)
        if fine.any():
            q[fine] = np.linalg.inv(sub[fine])
        out[good] = np.sqrt(np.abs(np.diagonal(q, axis1=1, axis2=2)))
    return out[:, 0], out[:, 1], out[:, 2], out[:, 3]


def solution(fixes: Fixes, uere_m: float = FALLBACK_UERE_M) -> Solution:
    """Every epoch's UBX fields, vectorised over the batch.

    Parameters
    ----------
    fixes : the epochs (see :class:`~virtualgps.receiver.records.Fixes`)
    uere_m : metres, range error sigma where the record has neither ``sigma_enu_m`` nor
        ``range_rms_m``

    Returns
    -------
    Solution
    """
    n = len(fixes)
    t = np.asarray(fixes.t_unix_s, dtype=float)
    t_ok = np.isfinite(t)
    ms_utc = np.where(t_ok, np.rint(np.where(t_ok, t, 0.0) * 1000.0), 0.0).astype(np.int64)
    leap_s = gps_minus_utc_s(ms_utc / 1000.0).astype(np.int64)
    gps_ms = ms_utc - int(GPS_EPOCH_UNIX_S) * 1000 + leap_s * 1000
    week, itow = np.divmod(gps_ms, WEEK_MS)
    s_utc, ms_of_s = np.divmod(ms_utc, 1000)
    days, s_of_day = np.divmod(s_utc, 86400)
    year, month, day = _civil(days)

    mode = np.asarray(fixes.mode)
    lat, lon = np.asarray(fixes.lat_deg, float), np.asarray(fixes.lon_deg, float)
    alt = np.asarray(fixes.alt_msl_m, float)
    geoid = np.nan_to_num(np.asarray(fixes.geoid_sep_m, float))  # unknown geoid: 0 m
    fix_ok = ((mode == MODE_2D) | (mode == MODE_3D)) & np.isfinite(lat) & np.isfinite(lon) \
        & np.isfinite(alt)
    fix_type = np.where(fix_ok, np.where(mode == MODE_3D, 3, 2), 0).astype(np.int64)
    diff = fix_ok & (np.asarray(fixes.quality) == QUALITY_DGPS)
    used = np.asarray(fixes.used, dtype=bool)
    cn0 = np.asarray(fixes.cn0_dbhz, dtype=float)
    tracked = (np.isfinite(cn0) & (cn0 > 0)) | used
    time_valid = t_ok & (fix_ok | tracked.any(axis=1))

    def nofix(x: np.ndarray) -> np.ndarray:
        return np.where(fix_ok, x, np.nan)

    hdop, vdop, pdop = (np.asarray(x, float) for x in (fixes.hdop, fixes.vdop, fixes.pdop))
    # Accuracies, metres: the receiver's own sigma, else DOP x range sigma (see module doc).
    sig_h = np.full(n, np.nan)
    sig_v = np.full(n, np.nan)
    if fixes.sigma_enu_m is not None:
        s = np.asarray(fixes.sigma_enu_m, float)
        sig_h, sig_v = np.hypot(s[:, 0], s[:, 1]), s[:, 2].copy()
    rng = np.full(n, uere_m)
    if fixes.range_rms_m is not None:
        rr = np.asarray(fixes.range_rms_m, float)
        rng = np.where(np.isfinite(rr), rr, uere_m)
    sig_h = np.where(np.isfinite(sig_h), sig_h, hdop * rng)
    sig_v = np.where(np.isfinite(sig_v), sig_v, vdop * rng)

    e_geo, n_geo, _, t_geo = _geometry_dops(fixes)
    h_geo = np.hypot(e_geo, n_geo)
    split = np.isfinite(h_geo) & (h_geo > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        edop = np.where(split, e_geo * hdop / np.where(split, h_geo, 1.0), hdop / np.sqrt(2.0))
        ndop = np.where(split, n_geo * hdop / np.where(split, h_geo, 1.0), hdop / np.sqrt(2.0))
    tdop = np.where(np.isfinite(t_geo), t_geo, TDOP_PER_PDOP * pdop)
    gdop = np.hypot(pdop, tdop)

    def dop(x: np.ndarray) -> np.ndarray:
        return _scaled(nofix(x), 100.0, NO_FIX_DOP_E2, 0, 0xFFFF)

    speed = nofix(np.asarray(fixes.speed_mps, float))
    course = nofix(np.asarray(fixes.course_deg, float))
    has_course = np.isfinite(course)
    c_rad = np.radians(np.where(has_course, course, 0.0))
    v_n = np.where(has_course, speed * np.cos(c_rad), 0.0)
    v_e = np.where(has_course, speed * np.sin(c_rad), 0.0)
    sacc_mps = pdop * RANGE_RATE_SIGMA_MPS
    with np.errstate(invalid="ignore", divide="ignore"):
        head_acc_deg = np.degrees(np.arctan2(sacc_mps, np.nan_to_num(speed)))
    head_acc_deg = np.where(np.isfinite(speed) & has_course, head_acc_deg, 180.0)

    height = alt + geoid
    llh_ok = fix_ok[:, None]
    ecef = geodetic_to_ecef(np.where(fix_ok, lat, 0.0), np.where(fix_ok, lon, 0.0),
                            np.where(fix_ok, height, 0.0))
    rot = ecef_to_enu_matrix(np.where(fix_ok, lat, 0.0), np.where(fix_ok, lon, 0.0))
    v_enu = np.stack([np.nan_to_num(v_e), np.nan_to_num(v_n), np.zeros(n)], axis=-1)
    v_ecef = np.einsum("tji,tj->ti", rot, v_enu)  # rot is ECEF->ENU: its transpose back
    i32 = (-(2**31), 2**31 - 1)
    gspeed = np.nan_to_num(speed)
    gnss_id, sv_id, svinfo_id = ubx_ids(fixes.prn)
    known = np.flatnonzero(gnss_id >= 0)
    order = known[np.lexsort((sv_id[known], gnss_id[known]))]

    return Solution(
        fixes=fixes,
        itow_ms=itow, week=week,
        year=year, month=month, day=day,
        hour=s_of_day // 3600, minute=(s_of_day // 60) % 60, second=s_of_day % 60,
        nano_ns=ms_of_s * 1_000_000,
        time_valid=time_valid, fix_ok=fix_ok, diff=diff, fix_type=fix_type,
        num_sv=used.sum(axis=1).astype(np.int64),
        lat_e7=_scaled(nofix(lat), 1e7, 0, *i32),
        lon_e7=_scaled(nofix(lon), 1e7, 0, *i32),
        height_mm=_scaled(nofix(height), 1e3, 0, *i32),
        hmsl_mm=_scaled(nofix(alt), 1e3, NO_FIX_HMSL_MM, *i32),
        hacc_mm=_scaled(nofix(sig_h), 1e3, U32_MAX, 0, U32_MAX),
        vacc_mm=_scaled(nofix(sig_v), 1e3, U32_MAX, 0, U32_MAX),
        tacc_ns=_scaled(nofix(tdop * rng / SPEED_OF_LIGHT_MPS), 1e9, U32_MAX, 0, U32_MAX),
        sacc_mmps=_scaled(nofix(sacc_mps), 1e3, NO_FIX_SACC_MMPS, 0, U32_MAX),
        headacc_e5=_scaled(nofix(head_acc_deg), 1e5, NO_FIX_HEADACC_E5, 0, U32_MAX),
        vel_n_mmps=_scaled(v_n, 1e3, 0, *i32),
        vel_e_mmps=_scaled(v_e, 1e3, 0, *i32),
        vel_d_mmps=np.zeros(n, dtype=np.int64),
        gspeed_mmps=_scaled(gspeed, 1e3, 0, 0, 2**31 - 1),
        head_e5=_scaled(np.where(has_course, course, np.nan), 1e5, 0, *i32),
        gdop_e2=dop(gdop), pdop_e2=dop(pdop), tdop_e2=dop(tdop), vdop_e2=dop(vdop),
        hdop_e2=dop(hdop), ndop_e2=dop(ndop), edop_e2=dop(edop),
        ecef_cm=_scaled(np.where(llh_ok, ecef, np.nan), 100.0, 0, *i32),
        ecef_vel_cmps=_scaled(np.where(llh_ok, v_ecef, np.nan), 100.0, 0, *i32),
        sat_cols=order, gnss_id=gnss_id[order], sv_id=sv_id[order], svinfo_id=svinfo_id[order],
    )


def numbers_of_ubx_ids(gnss_id: np.ndarray, sv_id: np.ndarray) -> np.ndarray:
    """Satellite numbers (virtualgps.sky.systems numbering) of UBX gnssId/svId pairs, the
    inverse of :func:`ubx_ids` (gpsd's JSON ``gnssid``/``svid`` follow the same appendix).

    Returns
    -------
    (n,) int: 0 where the pair names no satellite here (IMES, a GLONASS slot unknown: 255)
    """
    g, sv = np.asarray(gnss_id, dtype=np.int64), np.asarray(sv_id, dtype=np.int64)
    out = np.zeros(np.broadcast(g, sv).shape, dtype=np.int64)
    for system, gid in ((GPS, GNSS_GPS), (SBAS, GNSS_SBAS), (GALILEO, GNSS_GALILEO),
                        (BEIDOU, GNSS_BEIDOU), (QZSS, GNSS_QZSS), (GLONASS, GNSS_GLONASS)):
        number = sv + (192 if system is QZSS else system.offset)
        m = (g == gid) & (number >= system.first) & (number <= system.last)
        out = np.where(m, number, out)
    return out


def numbers_of_svinfo_ids(svid: np.ndarray) -> np.ndarray:
    """Satellite numbers of NAV-SVINFO's single "UBX" svid (see :func:`ubx_ids`); 0 for none."""
    v = np.asarray(svid, dtype=np.int64)
    ranges = ((1, 32, 0), (120, 158, 0), (211, 246, 90), (159, 163, 242), (33, 64, 373),
              (193, 202, 0), (65, 96, 0))  # (first, last, number - svid): GPS SBAS GAL BDS QZSS GLO
    out = np.zeros(v.shape, dtype=np.int64)
    for lo, hi, shift in ranges:
        out = np.where((v >= lo) & (v <= hi), v + shift, out)
    return out


# --- NAV messages, one epoch each ------------------------------------------------------------


def nav_pvt(sol: Solution, i: int, protver: float = 18.0) -> bytes:
    """UBX-NAV-PVT (0x01 0x07), 92 bytes of payload: time, fix, position, velocity, accuracies.

    Parameters
    ----------
    sol : from :func:`solution`; i : epoch index
    protver : protocol version: flags2's confirmed-date/time bits are written from 19.00 on
        (reserved before), flags3's invalidLlh from 27.00 on (M9 UBX-NAV-PVT)
    """
    ok, tv = bool(sol.fix_ok[i]), bool(sol.time_valid[i])
    valid = (0x03 if tv else 0) | (0x04 if ok else 0)  # validDate, validTime, fullyResolved
    flags = (0x01 if ok else 0) | (0x02 if sol.diff[i] else 0)  # gnssFixOK, diffSoln
    flags2 = 0
    if protver >= 19.0:
        flags2 = 0x20 | (0xC0 if ok and tv else 0)  # confirmedAvai, confirmedDate/Time
    flags3 = 0x0001 if (protver >= 27.0 and not ok) else 0  # invalidLlh
    payload = struct.pack(
        "<IHBBBBBBIiBBBBiiiiIIiiiiiIIHH4xihH",
        sol.itow_ms[i], sol.year[i], sol.month[i], sol.day[i], sol.hour[i], sol.minute[i],
        sol.second[i], valid, U32_MAX if not ok else sol.tacc_ns[i], sol.nano_ns[i],
        sol.fix_type[i], flags, flags2, min(int(sol.num_sv[i]), 255),
        sol.lon_e7[i], sol.lat_e7[i], sol.height_mm[i], sol.hmsl_mm[i],
        sol.hacc_mm[i], sol.vacc_mm[i],
        sol.vel_n_mmps[i], sol.vel_e_mmps[i], sol.vel_d_mmps[i], sol.gspeed_mmps[i],
        sol.head_e5[i], sol.sacc_mmps[i], sol.headacc_e5[i], sol.pdop_e2[i], flags3,
        0, 0, 0,  # headVeh, magDec, magAcc: not valid (flags.headVehValid 0, valid.validMag 0)
    )
    return encode(*NAV_PVT, payload)


def nav_posllh(sol: Solution, i: int) -> bytes:
    """UBX-NAV-POSLLH (0x01 0x02), 28 bytes: geodetic position, mm and 1e-7 deg."""
    return encode(*NAV_POSLLH, struct.pack(
        "<IiiiiII", sol.itow_ms[i], sol.lon_e7[i], sol.lat_e7[i], sol.height_mm[i],
        sol.hmsl_mm[i], sol.hacc_mm[i], sol.vacc_mm[i]))


def nav_velned(sol: Solution, i: int) -> bytes:
    """UBX-NAV-VELNED (0x01 0x12), 36 bytes: NED velocity in cm/s, heading 1e-5 deg."""
    cm = [int(np.rint(v / 10.0)) for v in (sol.vel_n_mmps[i], sol.vel_e_mmps[i],
                                           sol.vel_d_mmps[i], sol.gspeed_mmps[i])]
    speed_3d = int(np.rint(np.hypot(cm[3], cm[2])))
    return encode(*NAV_VELNED, struct.pack(
        "<IiiiIIiII", sol.itow_ms[i], cm[0], cm[1], cm[2], speed_3d, cm[3], sol.head_e5[i],
        int(np.rint(sol.sacc_mmps[i] / 10.0)), sol.headacc_e5[i]))


def _nav_flags(sol: Solution, i: int) -> int:
    """NAV-SOL / NAV-STATUS flags: gpsFixOk, diffSoln, wknSet, towSet."""
    tv = 0x0C if sol.time_valid[i] else 0
    return (0x01 if sol.fix_ok[i] else 0) | (0x02 if sol.diff[i] else 0) | tv


def nav_sol(sol: Solution, i: int) -> bytes:
    """UBX-NAV-SOL (0x01 0x06), 52 bytes: ECEF solution (M8; absent from M9 firmware)."""
    p_acc = U32_MAX if not sol.fix_ok[i] else int(
        np.rint(np.hypot(float(sol.hacc_mm[i]), float(sol.vacc_mm[i])) / 10.0))
    x, y, z = (int(v) for v in sol.ecef_cm[i])
    vx, vy, vz = (int(v) for v in sol.ecef_vel_cmps[i])
    return encode(*NAV_SOL, struct.pack(
        "<IihBBiiiIiiiIHxB4x", sol.itow_ms[i], 0, sol.week[i], sol.fix_type[i],
        _nav_flags(sol, i), x, y, z, p_acc, vx, vy, vz,
        int(np.rint(sol.sacc_mmps[i] / 10.0)), sol.pdop_e2[i], min(int(sol.num_sv[i]), 255)))


def nav_status(sol: Solution, i: int, ttff_ms: int, msss_ms: int) -> bytes:
    """UBX-NAV-STATUS (0x01 0x03), 16 bytes.

    Parameters
    ----------
    ttff_ms : time to first fix, ms (0 before the first fix)
    msss_ms : ms since start-up or reset
    """
    fix_stat = 0x01 if sol.diff[i] else 0  # diffCorr: differential corrections available
    return encode(*NAV_STATUS, struct.pack(
        "<IBBBBII", sol.itow_ms[i], sol.fix_type[i], _nav_flags(sol, i), fix_stat, 0,
        max(int(ttff_ms), 0) & U32_MAX, max(int(msss_ms), 0) & U32_MAX))


def nav_dop(sol: Solution, i: int) -> bytes:
    """UBX-NAV-DOP (0x01 0x04), 18 bytes: g, p, t, v, h, n, e DOP x 100."""
    return encode(*NAV_DOP, struct.pack(
        "<I7H", sol.itow_ms[i], sol.gdop_e2[i], sol.pdop_e2[i], sol.tdop_e2[i],
        sol.vdop_e2[i], sol.hdop_e2[i], sol.ndop_e2[i], sol.edop_e2[i]))


def nav_timeutc(sol: Solution, i: int) -> bytes:
    """UBX-NAV-TIMEUTC (0x01 0x21), 20 bytes; utcStandard 3 (USNO, the GPS source) when
    valid."""
    tv = bool(sol.time_valid[i])
    valid = (0x03 if tv else 0) | (0x04 if sol.fix_ok[i] else 0) | (0x30 if tv else 0)
    return encode(*NAV_TIMEUTC, struct.pack(
        "<IIiHBBBBBB", sol.itow_ms[i], sol.tacc_ns[i], sol.nano_ns[i], sol.year[i],
        sol.month[i], sol.day[i], sol.hour[i], sol.minute[i], sol.second[i], valid))


def nav_timegps(sol: Solution, i: int) -> bytes:
    """UBX-NAV-TIMEGPS (0x01 0x20), 16 bytes: GPS week, time of week and leap seconds."""
    tv = bool(sol.time_valid[i])
    leap = int(gps_minus_utc_s(sol.fixes.t_unix_s[i])) if tv else 0
    valid = (0x03 if tv else 0) | (0x04 if sol.fix_ok[i] else 0)  # tow, week, leapS valid
    return encode(*NAV_TIMEGPS, struct.pack(
        "<IihbBI", sol.itow_ms[i], 0, sol.week[i], leap, valid, sol.tacc_ns[i]))


def nav_eoe(sol: Solution, i: int) -> bytes:
    """UBX-NAV-EOE (0x01 0x61), 4 bytes: the end-of-epoch marker (protocol 18 on)."""
    return encode(*NAV_EOE, struct.pack("<I", sol.itow_ms[i]))


def _sat_table(sol: Solution, i: int) -> dict[str, np.ndarray]:
    """The listed satellites of epoch ``i`` (in view, tracked or used), in (gnssId, svId) order,
    with their UBX fields: gnss_id, sv_id, svinfo_id, cno, elev, azim, quality, used, tracked,
    diff; each (k,)."""
    f, cols = sol.fixes, sol.sat_cols
    cn0 = np.asarray(f.cn0_dbhz, float)[i, cols]
    used = np.asarray(f.used, bool)[i, cols]
    tracked = (np.isfinite(cn0) & (cn0 > 0)) | used
    listed = np.asarray(f.in_view, bool)[i, cols] | tracked
    el = np.asarray(f.el_deg, float)[i, cols]
    az = np.asarray(f.az_deg, float)[i, cols]
    el_known = np.isfinite(el) & np.isfinite(az)
    pick = np.flatnonzero(listed)[:255]
    quality = np.where(used, 7, np.where(tracked, 4, 1))
    return {
        "gnss_id": sol.gnss_id[pick], "sv_id": sol.sv_id[pick], "svinfo_id": sol.svinfo_id[pick],
        "cno": np.where(tracked, _scaled(cn0, 1.0, 0, 0, 255), 0)[pick],
        "elev": np.where(el_known, _scaled(el, 1.0, -91, -90, 90), -91)[pick],
        "azim": np.where(el_known, _scaled(az, 1.0, 0, -(2**15), 2**15 - 1) % 360, 0)[pick],
        "el_known": el_known[pick], "quality": quality[pick], "used": used[pick],
        "tracked": tracked[pick], "diff": (used & bool(sol.diff[i]))[pick],
    }


_SAT_DTYPE = np.dtype([("gnssId", "u1"), ("svId", "u1"), ("cno", "u1"), ("elev", "i1"),
                       ("azim", "<i2"), ("prRes", "<i2"), ("flags", "<u4")])
_SVINFO_DTYPE = np.dtype([("chn", "u1"), ("svid", "u1"), ("flags", "u1"), ("quality", "u1"),
                          ("cno", "u1"), ("elev", "i1"), ("azim", "<i2"), ("prRes", "<i4")])


def nav_sat(sol: Solution, i: int) -> bytes:
    """UBX-NAV-SAT (0x01 0x35), version 1: 8 + 12 bytes per listed satellite.

    flags (UBX-13003221 UBX-NAV-SAT): qualityInd bits 0-2, svUsed 3, health 4-5, diffCorr 6,
    orbitSource 8-10 (1 ephemeris, 2 almanac), ephAvail 11, almAvail 12, sbasCorrUsed 16,
    prCorrUsed 20.
    """
    s = _sat_table(sol, i)
    rec = np.zeros(len(s["gnss_id"]), dtype=_SAT_DTYPE)
    rec["gnssId"], rec["svId"], rec["cno"] = s["gnss_id"], s["sv_id"], s["cno"]
    rec["elev"], rec["azim"] = s["elev"], s["azim"]
    tr, dc = s["tracked"].astype(np.uint32), s["diff"].astype(np.uint32)
    rec["flags"] = (s["quality"].astype(np.uint32) | (s["used"].astype(np.uint32) << 3)
                    | (tr << 4) | (dc << 6) | (np.where(tr == 1, 1, 2).astype(np.uint32) << 8)
                    | (tr << 11) | (np.uint32(1) << 12) | (dc << 16) | (dc << 20))
    head = struct.pack("<IBB2x", sol.itow_ms[i], 1, len(rec))
    return encode(*NAV_SAT, head + rec.tobytes())


def nav_svinfo(sol: Solution, i: int) -> bytes:
    """UBX-NAV-SVINFO (0x01 0x30): 8 + 12 bytes per listed satellite with a UBX svid (M8).

    Channels are numbered 0.. over the tracked satellites, 255 for the others; globalFlags
    chipGen 4 (u-blox 8 / M8). flags: svUsed 0, diffCorr 1, orbitAvail 2, orbitEph 3, orbitAlm
    5.
    """
    s = _sat_table(sol, i)
    keep = s["svinfo_id"] > 0
    s = {k: v[keep] for k, v in s.items()}
    rec = np.zeros(len(s["svinfo_id"]), dtype=_SVINFO_DTYPE)
    tr = s["tracked"]
    rec["chn"] = np.where(tr, np.cumsum(tr) - 1, 255)
    rec["svid"], rec["cno"] = s["svinfo_id"], s["cno"]
    rec["elev"] = np.where(s["el_known"], s["elev"], 0)
    rec["azim"] = s["azim"]
    known = s["el_known"].astype(np.uint8)
    rec["flags"] = (s["used"].astype(np.uint8) | (s["diff"].astype(np.uint8) << 1)
                    | (known << 2) | ((tr & s["el_known"]).astype(np.uint8) << 3)
                    | ((~tr & s["el_known"]).astype(np.uint8) << 5))
    rec["quality"] = s["quality"]
    head = struct.pack("<IBB2x", sol.itow_ms[i], len(rec), 4)
    return encode(*NAV_SVINFO, head + rec.tobytes())


# --- MON and ACK ---------------------------------------------------------------------------


def _text(s: str, size: int) -> bytes:
    """A NUL-terminated, NUL-padded character field of ``size`` bytes (ASCII; longer text is
    cut to ``size - 1``)."""
    raw = s.encode("ascii", "replace")[: size - 1]
    return raw + b"\x00" * (size - len(raw))


def mon_ver(sw_version: str, hw_version: str, extensions: tuple[str, ...]) -> bytes:
    """UBX-MON-VER (0x0A 0x04): swVersion (30 chars), hwVersion (10), extensions (30 each)."""
    payload = _text(sw_version, 30) + _text(hw_version, 10)
    payload += b"".join(_text(e, 30) for e in extensions)
    return encode(*MON_VER, payload)


def mon_hw(noise_per_ms: int = 90, agc_cnt: int = 4000, jam_ind: int = 5, a_status: int = 2,
           a_power: int = 1, jamming_state: int = 1) -> bytes:
    """UBX-MON-HW (0x0A 0x09), 60 bytes: antenna and RF front-end status (M8 layout).

    Parameters
    ----------
    noise_per_ms, agc_cnt (0..8191), jam_ind (0..255) : front-end levels (see
        :data:`MON_HW_DEFAULTS`)
    a_status : 0 init, 1 unknown, 2 OK, 3 short, 4 open; a_power : 0 off, 1 on, 2 unknown
    jamming_state : 0 unknown, 1 OK, 2 warning, 3 critical
    """
    flags = 0x01 | ((jamming_state & 0x3) << 2)  # rtcCalib, jammingState
    return encode(*MON_HW, struct.pack(
        "<IIIIHHBBBBI17sB2xIII", 0, 0, 0, 0, noise_per_ms & 0xFFFF, agc_cnt & 0xFFFF,
        a_status, a_power, flags, 0, 0, bytes(17), jam_ind & 0xFF, 0, 0, 0))


def mon_rf(noise_per_ms: int = 90, agc_cnt: int = 4000, jam_ind: int = 5, a_status: int = 2,
           a_power: int = 1, jamming_state: int = 1) -> bytes:
    """UBX-MON-RF (0x0A 0x38): one RF block (protocol 27 on; M9's successor of MON-HW).

    Parameters as :func:`mon_hw`.
    """
    head = struct.pack("<BBBx", 0, 1, 0)
    block = struct.pack("<BBBBI4xHHBbBbB3x", 0, jamming_state & 0x3, a_status, a_power, 0,
                        noise_per_ms & 0xFFFF, agc_cnt & 0xFFFF, jam_ind & 0xFF, 0, 0, 0, 0)
    return encode(*MON_RF, head + block)


def ack(msg_class: int, msg_id: int) -> bytes:
    """UBX-ACK-ACK (0x05 0x01) for the message (class, id)."""
    return encode(*ACK_ACK, bytes((msg_class & 0xFF, msg_id & 0xFF)))


def nak(msg_class: int, msg_id: int) -> bytes:
    """UBX-ACK-NAK (0x05 0x00) for the message (class, id)."""
    return encode(*ACK_NAK, bytes((msg_class & 0xFF, msg_id & 0xFF)))
