"""NMEA 0183 output: fixes -> sentences as a MediaTek (MTK) receiver writes them (v2.3), or
as a multi-system receiver does (v4.11: per-system GSA and GSV, see :func:`_groups`).

Owns the sentence layout (NMEA 0183 v2.3 fields, in the habits of MTK firmware) and the output
format of a receiver profile (:class:`~virtualgps.receiver.nmea_format.NmeaFormat`, the profile's
``[nmea]`` table). No I/O.

What an MTK receiver writes, taken from the real logs in ``../shared/data`` (file:line):

- Epoch order GGA, GSA, GSV x n, RMC, VTG; every sentence of an epoch carries the same UTC time
  ``hhmmss.sss`` (gpsd-mtk/tr737A+.log, an i-Blue 737-class MT3329, the M-1000's generation).
- Before the first fix MT3301/MT3329 firmware writes a placeholder position, altitude and geoid
  separation: ``$GPGGA,071733.929,8960.0000,N,00000.0000,E,0,0,,137.0,M,13.0,M,,*40`` and
  ``$GPRMC,071733.929,V,8960.0000,N,00000.0000,E,0.00,0.00,111111,,,N*72`` (tr737A+.log:8,12;
  the same in mtk-3301.log with 6 decimals), ``$GPGSA,A,1,,,,,,,,,,,,,,,*1E`` and
  ``$GPVTG,0.00,T,,M,0.000,N,0.000,K,N*32`` (mtk-3301.log). While the solution is not yet valid
  it may already print the position estimate with quality 0 and an empty HDOP
  (``...,W,0,4,,1127.8,M,-19.6,M,,``, tr737A+.log:13). Later MT3339 firmware instead leaves the
  fields empty (``$GPGGA,184006.290,,,,,0,04,,,M,,M,,*7C``, mt3339-static/hour_test_1.txt:4, and
  again when it loses the fix, line 20495): our ``no_fix_style = "empty"``.
- GSV lists the satellites by decreasing elevation, those with unknown elevation/azimuth last
  with empty fields (``26,,,48``) in channel order, SNR empty when not tracked; the last
  sentence is not padded (mt3339.log:22-24, mtk-3301.log).
- GSA lists the used PRNs in channel order, not sorted (bt-q818.log:12); we take the column order
  of :attr:`Fixes.prn` as the channel order.
- With SBAS (quality 2) the DGPS age/station fields read ``0000,0000`` (bt-q818.log, mt3339.log);
  with quality 1 they are empty (mtk-3329.log).
- GST (MT3339-based Quectel L70): ``$GPGST,150119.000,004.0,008.7,004.7,132.3,006.8,007.2,...``.
- ZDA (mt3339.log): ``$GPZDA,202640.000,13,04,2015,,*54`` (local zone empty; ``00,00`` is the
  default here, as NMEA 0183 v2.3 describes, see ``zda_local_zone``).

Speed (DESIGN section 8; ``tools/bench_nmea.py``): :func:`render_batch` builds whole batches in
numpy as NUL-padded character matrices (checksums by one XOR reduction per sentence row), about
10 us per epoch for the default sentences with 12 satellites in view; a daemon's single epoch
takes a scalar path of plain f-strings (about 80 us), which follows the same rules and is tested
to give identical bytes.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import date
from typing import Any

import numpy as np

from virtualgps.device.nmea.sentence import (
    MPS_TO_KMH,
    MPS_TO_KNOTS,
    UNIX_EPOCH_ORDINAL,
    format_sentence,
)
from virtualgps.receiver.nmea_format import NmeaFormat
from virtualgps.receiver.records import QUALITY_DGPS, QUALITY_NONE, Fixes
from virtualgps.sky import systems

# u-blox's DOPs without a fix (NEO-M8N logs quoted in public repositories:
# $GNGGA,,,,,,0,00,99.99,,,,,,*56 and $GNGSA,A,1,,,,,,,,,,,,,99.99,99.99,99.99*2E).
UBLOX_NO_FIX_DOP = 99.99
# MTK placeholders before the first fix (gpsd-mtk/tr737A+.log, mtk-3301.log).
MTK_PLACEHOLDER_LAT_DEG = 90.0  # printed as 8960.0000 (89 deg 60 min), MTK's habit
MTK_PLACEHOLDER_ALT_MSL_M = 137.0
MTK_PLACEHOLDER_GEOID_SEP_M = 13.0

# GGA/GSA: NMEA 0183 v2.3 has 12 PRN slots in GSA.
GSA_SLOTS = 12

_GST_KEYS = ("range_rms_m", "semi_major_m", "semi_minor_m", "orient_deg", "lat_m", "lon_m", "alt_m")


@dataclass(frozen=True)
class _Group:
    """The satellites one GSA or one run of GSV sentences lists.

    talker : the sentences' talker; cols : (k,) their columns of :class:`Fixes`, channel
    order (a slice of all of them in 2.3: no copies on the MTK path); ids : (k,) the
    satellite IDs printed; tail : text after the last field (NMEA 4.11: ``,<system ID>`` in
    GSA, ``,<signal ID>`` in GSV; empty in 2.3)
    """

    talker: str
    cols: np.ndarray | slice
    ids: np.ndarray
    tail: str


@functools.lru_cache(maxsize=64)
def _groups(prn: tuple[int, ...], talker: str, version: str) -> tuple[tuple[_Group, ...],
                                                                     tuple[_Group, ...]]:
    """The GSA and GSV groups of a constellation's columns.

    NMEA 0183 v2.3: one of each, every satellite by its number, the profile's talker.
    v4.11 (as u-blox M8/M9 and phones write it): a GSA per system of the constellation, talker
    the profile's (``GN`` for several systems), ending in its system ID, and a run of GSV per
    talker (GP with SBAS, GL, GA, GB, GQ) ending in the signal ID, satellites by their NMEA IDs
    (GLONASS 65-96, Galileo 1-36, ...: :mod:`virtualgps.sky.systems`); systems in system ID
    order. A number of no known system is listed with GPS as it is.
    """
    nums = np.asarray(prn, dtype=np.int64)
    if version == "2.3":
        whole = _Group(talker, slice(None), nums, "")
        return (whole,), (whole,)
    by_id: dict[int, list[int]] = {}
    for c, n in enumerate(prn):
        s = systems.system_of(n) or systems.GPS
        by_id.setdefault(s.nmea_id, []).append(c)
    gsa, gsv = [], []
    for sid in sorted(by_id):
        cc = np.array(by_id[sid], dtype=np.int64)
        ids = np.array([n - (systems.system_of(n) or systems.GPS).nmea_offset
                        for n in nums[cc].tolist()], dtype=np.int64)
        s = next(x for x in systems.SYSTEMS if x.nmea_id == sid)
        gsa.append(_Group(talker, cc, ids, f",{sid:X}"))
        gsv.append(_Group(s.talker, cc, ids, f",{s.nmea_signal:X}"))
    return tuple(gsa), tuple(gsv)


# --- vectorised rendering ---------------------------------------------------------------------
#
# Every field of every epoch is built as a row of ASCII codes in a uint8 matrix, fixed width per
# field, unused positions NUL (0). NUL is neutral for XOR, so a sentence's checksum is the XOR
# reduction of its row; the epoch's text is its row with the NULs removed. Leading zeros that a
# field does not print, empty fields and sentences not written this epoch are NULs.

_NUL = 0
_DIGIT0 = ord("0")
_POW10 = 10 ** np.arange(19, dtype=np.int64)
_HEX = np.frombuffer(b"".join(b"%02X" % c for c in range(256)), dtype=np.uint8).reshape(256, 2)
# NMEA 2.3 mode letter by GGA quality (0 invalid .. 8 simulator); RMC/VTG/GLL.
_MODE_LETTERS = np.frombuffer(b"NADPRFEMS", dtype=np.uint8)
_CHUNK = 2048  # epochs per block: bounds the matrices to a few MB
_SMALL = 48  # batches shorter than this take the scalar path (numpy calls cost ~2 ms a batch)
# Absurd values are clipped before the integer conversion (no int64 overflow); they then print
# as the field's largest number. Valid fixes never come near.
_ABS_MAX = 1.0e12
_ABS_MAX_DEG = 1.0e6
_TABLE_MAX_WIDTH = 4  # fields up to this many digits print by table lookup (10**4 rows, 40 kB)


def _text(s: str | bytes, n: int) -> np.ndarray:
    """(n, len(s)) uint8: a constant text in every row."""
    b = s.encode("ascii") if isinstance(s, str) else s
    return np.broadcast_to(np.frombuffer(b, dtype=np.uint8), (n, len(b)))


def _cat(n: int, parts: list) -> np.ndarray:
    """Concatenate field matrices and constant texts (str) along the row."""
    return np.concatenate([_text(p, n) if isinstance(p, str | bytes) else p for p in parts], axis=1)


def _digit_rows(v: np.ndarray, width: int, min_digits: int) -> np.ndarray:
    """(n, width) uint8: the rows of :func:`_digits` for ``v`` already in [0, 10**width)."""
    p = _POW10[width - 1 :: -1]  # 10**(width-1) ... 1
    col = (v[:, None] // p) % 10
    n_dig = 1 + (v[:, None] >= p[:-1]).sum(axis=1)
    keep = np.arange(width) >= width - np.maximum(n_dig, min_digits)[:, None]
    return np.where(keep, col + _DIGIT0, _NUL).astype(np.uint8)


@functools.cache
def _digit_table(width: int, min_digits: int) -> np.ndarray:
    """(10**width, width) uint8: the :func:`_digits` row of every value of ``width`` digits."""
    table = _digit_rows(np.arange(_POW10[width], dtype=np.int64), width, min_digits)
    table.flags.writeable = False  # shared by every call
    return table


def _digits(v: np.ndarray, width: int, min_digits: int) -> np.ndarray:
    """(n, width) uint8: decimal digits of non-negative integers, right-aligned, at least
    ``min_digits`` digits (zero-padded), NUL to the left. Values beyond ``width`` digits are
    clipped (they never occur for valid fixes)."""
    v = np.clip(v, 0, _POW10[width] - 1).astype(np.int64)
    if width <= _TABLE_MAX_WIDTH:
        # one gather instead of ~10 array passes: most fields are 2-4 digits wide
        return _digit_table(width, min_digits)[v]
    return _digit_rows(v, width, min_digits)


def _fixed(
    x: np.ndarray, int_width: int, decimals: int, empty: np.ndarray, min_int: int = 1
) -> np.ndarray:
    """(n, w) uint8: ``x`` with ``decimals`` decimals (as ``%.{decimals}f``), a ``-`` sign when
    the rounded value is negative, NUL where ``empty``."""
    xf = np.nan_to_num(np.asarray(x, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    k = np.rint(np.minimum(np.abs(xf), _ABS_MAX) * 10.0**decimals).astype(np.int64)
    ip, fp = np.divmod(k, _POW10[decimals])
    sign = np.where((xf < 0) & (k > 0), ord("-"), _NUL).astype(np.uint8)[:, None]
    parts = [sign, _digits(ip, int_width, min_int)]
    if decimals:
        parts += [_text(".", len(xf)), _digits(fp, decimals, decimals)]
    out = np.concatenate(parts, axis=1)
    out[empty] = _NUL
    return out


def _choose(mask: np.ndarray, a: str, b: str) -> np.ndarray:
    """(n, w) uint8: text ``a`` where ``mask`` else ``b`` (the shorter padded with NUL)."""
    w = max(len(a), len(b))
    ta = np.frombuffer(a.encode("ascii").ljust(w, b"\0"), dtype=np.uint8)
    tb = np.frombuffer(b.encode("ascii").ljust(w, b"\0"), dtype=np.uint8)
    return np.where(mask[:, None], ta, tb).astype(np.uint8)


def _clip_finite(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Clip finite values to [lo, hi]; non-finite ones become NaN (empty fields)."""
    return np.where(np.isfinite(x), np.clip(x, lo, hi), np.nan)


def _char(codes: np.ndarray) -> np.ndarray:
    return np.asarray(codes, dtype=np.uint8)[:, None]


def _sentence(n: int, body: list, emit: np.ndarray | None) -> np.ndarray:
    """(n, w) uint8: ``$body*HH\\r\\n`` per row; all NUL where ``emit`` is False."""
    b = _cat(n, body)
    cs = np.bitwise_xor.reduce(b, axis=1)
    out = _cat(n, ["$", b, "*", _HEX[cs], "\r\n"])
    if emit is not None:
        out[~emit] = _NUL
    return out


def _civil_from_days(days: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gregorian (year, month, day) of days since 1970-01-01 (the inverse of H. Hinnant's
    ``days_from_civil``, exact for any int64 day count)."""
    z = days + 719468
    era = np.floor_divide(z, 146097)
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    y = yoe + era * 400
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    d = doy - (153 * mp + 2) // 5 + 1
    m = np.where(mp < 10, mp + 3, mp - 9)
    return y + (m <= 2), m, d


def _latlon(lat_deg: np.ndarray, lon_deg: np.ndarray, fmt: NmeaFormat) -> np.ndarray:
    """(n, w) uint8: ``ddmm.mmmm,N,dddmm.mmmm,E``, rounded once in units of the last printed
    digit, so 59.99999' carries into the degrees instead of printing 60.0000'."""
    n = lat_deg.shape[0]
    ld = fmt.latlon_decimals
    scale = 10**ld
    missing = ~(np.isfinite(lat_deg) & np.isfinite(lon_deg))
    mtk = fmt.no_fix_style == "mtk"
    parts: list = []
    for v, deg_w, hemis in ((lat_deg, 2, b"NS"), (lon_deg, 3, b"EW")):
        v = np.where(missing, 0.0, v)
        k = np.rint(np.minimum(np.abs(v), _ABS_MAX_DEG) * (60 * scale)).astype(np.int64)
        deg, rem = np.divmod(k, 60 * scale)
        mi, mf = np.divmod(rem, scale)
        # the sign of the rounded value: -1e-9 deg prints as 0000.0000,N
        hemi = np.where((v < 0) & (k > 0), hemis[1], hemis[0])
        if mtk:
            # MTK's placeholder before a fix: 8960.0000,N,00000.0000,E (tr737A+.log:8)
            deg = np.where(missing, 89 if deg_w == 2 else 0, deg)
            mi = np.where(missing, 60 if deg_w == 2 else 0, mi)
            mf = np.where(missing, 0, mf)
            hemi = np.where(missing, hemis[0], hemi)
        field = _cat(n, [_digits(deg, deg_w, deg_w), _digits(mi, 2, 2), ".", _digits(mf, ld, ld)])
        h = _char(hemi)
        if not mtk:
            field[missing] = _NUL
            h = np.where(missing[:, None], _NUL, h).astype(np.uint8)
        parts += [field, ",", h, ","]
    return _cat(n, parts[:-1])


def _render_block(
    fixes: Fixes, fmt: NmeaFormat, sigma_m: Mapping[str, np.ndarray] | None, sl: slice
) -> list[bytes]:
    t = np.asarray(fixes.t_unix_s[sl], dtype=np.float64)
    n = t.shape[0]
    if not np.isfinite(t).all():
        raise ValueError("fixes.t_unix_s must be finite to be written as NMEA time")
    mtk = fmt.no_fix_style == "mtk"
    ublox = fmt.no_fix_style == "ublox"
    T = fmt.talker
    none = np.zeros(n, dtype=bool)

    # UTC time, rounded once per epoch to the printed decimals in integer units, so
    # 23:59:59.9996 becomes 00:00:00.000 of the next day (date included), never 23:59:60.000.
    td = fmt.time_decimals
    k = np.rint(t * 10.0**td).astype(np.int64)
    day, r = np.divmod(k, 86400 * _POW10[td])
    s, frac = np.divmod(r, _POW10[td])
    tparts = [_digits(s // 3600, 2, 2), _digits(s // 60 % 60, 2, 2), _digits(s % 60, 2, 2)]
    if td:
        tparts += [".", _digits(frac, td, td)]
    time = _cat(n, tparts)
    yy, mo, dd = _civil_from_days(day)
    dd2, mo2 = _digits(dd, 2, 2), _digits(mo, 2, 2)

    latlon = _latlon(
        np.asarray(fixes.lat_deg[sl], dtype=np.float64),
        np.asarray(fixes.lon_deg[sl], dtype=np.float64),
        fmt,
    )
    q = np.clip(np.asarray(fixes.quality[sl]).astype(np.int64), 0, 8)
    no_fix = q == QUALITY_NONE
    mode = np.asarray(fixes.mode[sl]).astype(np.int64)
    mode_none = mode <= 1
    used = np.asarray(fixes.used[sl], dtype=bool)
    gsa_groups, gsv_groups = _groups(tuple(np.asarray(fixes.prn).astype(np.int64).tolist()),
                                     T, fmt.version)

    def fx(
        x: Any,
        int_w: int,
        dec: int,
        empty: np.ndarray,
        placeholder: float | None = None,
        min_int: int = 1,
    ) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        nan = ~np.isfinite(x)
        if placeholder is not None and mtk:
            x = np.where(nan, placeholder, x)
            return _fixed(x, int_w, dec, empty, min_int)
        return _fixed(x, int_w, dec, empty | nan, min_int)

    ad, dd_, sd, cd = fmt.alt_decimals, fmt.dop_decimals, fmt.speed_decimals, fmt.course_decimals
    alt = fx(fixes.alt_msl_m[sl], 6, ad, none, MTK_PLACEHOLDER_ALT_MSL_M)
    # No fix, no geoid separation: MTK prints its placeholder (13.0, tr737A+.log:8,
    # mtk-3301.log), others an empty field (mt3339-static, telit-he910.log).
    geoid_m = np.where(no_fix, np.nan, np.asarray(fixes.geoid_sep_m[sl], dtype=np.float64))
    geoid = fx(geoid_m, 4, ad, none, MTK_PLACEHOLDER_GEOID_SEP_M)
    dops = [
        _clip_finite(np.asarray(a[sl], dtype=np.float64), 0.0, 99.0)
        for a in (fixes.pdop, fixes.hdop, fixes.vdop)
    ]
    if ublox:  # u-blox: DOPs 99.99 without a fix (NEO-M8N logs: $GNGGA,,,,,,0,00,99.99,...)
        pdop, hdop, vdop = (fx(np.where(mode_none, UBLOX_NO_FIX_DOP, a), 2, dd_, none)
                            for a in dops)
        hdop_gga = fx(np.where(no_fix, UBLOX_NO_FIX_DOP, dops[1]), 2, dd_, none)
    else:
        pdop, hdop, vdop = (fx(a, 2, dd_, mode_none) for a in dops)
        hdop_gga = fx(dops[1], 2, dd_, no_fix)  # MTK: empty HDOP with quality 0 (tr737A+.log:13)
    # u-blox leaves the unit letters of empty fields empty too ($GNVTG,,,,,,,,,N)
    unit_m = _choose(no_fix, ",,", ",M,") if ublox else ",M,"
    speed = np.asarray(fixes.speed_mps[sl], dtype=np.float64)
    # MTK writes 0.00 speed and course without a fix (tr737A+.log:12, mtk-3301.log VTG)
    knots = fx(speed * MPS_TO_KNOTS, 4, sd, none, 0.0)
    kmh = fx(speed * MPS_TO_KMH, 5, sd, none, 0.0)
    course_deg = np.asarray(fixes.course_deg[sl], dtype=np.float64)
    course_deg = np.where(np.isfinite(course_deg), course_deg, np.nan)
    course_deg = np.mod(np.rint(course_deg * 10.0**cd) / 10.0**cd, 360.0)  # 359.999 -> 0.00
    course = fx(course_deg, 3, cd, none, 0.0)
    status = _char(np.where(no_fix, ord("V"), ord("A")))
    letter = [",", _char(_MODE_LETTERS[q])] if fmt.mode_letter else []
    # NMEA 4.10+: RMC's navigational status after the mode; "V", no status given (as u-blox)
    nav_status = [",V"] if fmt.version != "2.3" else []
    every = dict(fmt.every)
    emit: dict[str, np.ndarray | None] = {name: None for name in fmt.sentences}
    if every:
        # PMTK314 rates: the sentence is written when the fix number is a multiple of n.
        fix_no = np.rint(t * fmt.fix_rate_hz).astype(np.int64)
        for name, m in every.items():
            emit[name] = fix_no % m == 0

    out_parts = []
    for name in fmt.sentences:
        if name == "GGA":
            sats = _digits(used.sum(axis=1), 2, fmt.sats_used_digits)
            # MTK: DGPS age/station 0000,0000 with SBAS (bt-q818.log, mt3339.log)
            dgps_on = (q == QUALITY_DGPS) if fmt.dgps_fields == "mtk" else none
            body = [
                T + "GGA,",
                time,
                ",",
                latlon,
                ",",
                _char(q + _DIGIT0),
                ",",
                sats,
                ",",
                hdop_gga,
                ",",
                alt,
                unit_m,
                geoid,
                unit_m,
                _choose(dgps_on, "0000,0000", ","),
            ]
        elif name == "GSA":
            for g in gsa_groups:
                # used PRNs in channel (column) order, 12 slots (bt-q818.log:12)
                used_g = used[:, g.cols]
                order = np.argsort(~used_g, axis=1, kind="stable")[:, :GSA_SLOTS]
                slot_used = np.take_along_axis(used_g, order, axis=1) & ~mode_none[:, None]
                slot_prn = g.ids[order] if g.ids.size else np.zeros(order.shape, dtype=np.int64)
                ns = slot_prn.shape[1]
                ch = _digits(slot_prn.reshape(-1), 3, 2).reshape(n, ns, 3)
                ch[~slot_used] = _NUL
                sep = np.full((n, ns, 1), ord(","), dtype=np.uint8)
                slots = np.concatenate([ch, sep], axis=2).reshape(n, ns * 4)
                body = [
                    g.talker + "GSA,A,",
                    _char(np.where(mode_none, 1, mode) + _DIGIT0),
                    ",",
                    slots,
                    "," * (GSA_SLOTS - ns),
                    pdop,
                    ",",
                    hdop,
                    ",",
                    vdop,
                    g.tail,
                ]
                out_parts.append(_sentence(n, body, emit[name]))
            continue
        elif name == "GSV":
            out_parts += [_gsv(fixes, fmt, sl, emit[name], g) for g in gsv_groups]
            continue
        elif name == "RMC":
            date = _cat(n, [dd2, mo2, _digits(yy % 100, 2, 2)])
            body = [
                T + "RMC,",
                time,
                ",",
                status,
                ",",
                latlon,
                ",",
                knots,
                ",",
                course,
                ",",
                date,
                ",,",
                *letter,
                *nav_status,
            ]
        elif name == "VTG":
            if ublox:
                body = [T + "VTG,", course, _choose(no_fix, ",,,,", ",T,,M,"), knots,
                        _choose(no_fix, ",,", ",N,"), kmh, _choose(no_fix, ",", ",K"), *letter]
            else:
                body = [T + "VTG,", course, ",T,,M,", knots, ",N,", kmh, ",K", *letter]
        elif name == "GLL":
            body = [T + "GLL,", latlon, ",", time, ",", status, *letter]
        elif name == "GST":
            body = [T + "GST,", time]
            for key in _GST_KEYS:
                if sigma_m is not None and key in sigma_m:
                    v = np.broadcast_to(np.asarray(sigma_m[key], dtype=np.float64), (len(fixes),))[
                        sl
                    ]
                    # MTK/Quectel L70 style 004.0 (%05.1f)
                    body += [",", fx(v, 5, 1, no_fix, min_int=3)]
                else:
                    body.append(",")
        elif name == "ZDA":
            zone = ",00,00" if fmt.zda_local_zone == "zero" else ",,"
            body = [T + "ZDA,", time, ",", dd2, ",", mo2, ",", _digits(yy, 4, 4), zone]
        else:  # pragma: no cover - NmeaFormat validates the names
            raise AssertionError(name)
        out_parts.append(_sentence(n, body, emit[name]))

    m = np.concatenate(out_parts, axis=1)
    # drop the NULs of the whole block at once, then cut it at each epoch's end
    keep = m != _NUL
    data = m[keep].tobytes()
    ends = np.cumsum(keep.sum(axis=1)).tolist()
    return [data[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]


def _gsv(fixes: Fixes, fmt: NmeaFormat, sl: slice, emit: np.ndarray | None, g: _Group
         ) -> np.ndarray:
    """(n, w) uint8: the GSV sentences of each epoch for the satellites of group ``g``:
    satellites in view by decreasing elevation, unknown elevation last with empty fields, ties
    and unknown elevations in channel (column) order (mt3339.log:22, mtk-3301.log), 4 per
    sentence, the last one not padded (mtk-3329.log); ``GSV,1,1,00`` when none is in view."""
    in_view = np.asarray(fixes.in_view[sl], dtype=bool)[:, g.cols]
    n, n_sat = in_view.shape
    el = np.asarray(fixes.el_deg[sl], dtype=np.float64)[:, g.cols]
    az = np.asarray(fixes.az_deg[sl], dtype=np.float64)[:, g.cols]
    cn0 = np.asarray(fixes.cn0_dbhz[sl], dtype=np.float64)[:, g.cols]
    prn = np.broadcast_to(g.ids, (n, n_sat))
    el_nan = np.isnan(el)
    # lexsort is stable: equal keys keep the column (channel) order
    order = np.lexsort((-np.nan_to_num(el, nan=0.0), el_nan, ~in_view), axis=-1)
    n_view = np.minimum(in_view.sum(axis=1), fmt.gsv_max_sats)
    # columns for the most satellites any epoch lists, not for every satellite of the TLE set
    # (~31, of which ~12 are in view): the text is the same, the matrices a third the size
    n_ent = int(n_view.max(initial=0))
    n_msg_max = max(1, (n_ent + 3) // 4)
    slots = 4 * n_msg_max
    order = order[:, :n_ent]

    def take(a: np.ndarray) -> np.ndarray:
        out = np.zeros((n, slots), dtype=a.dtype)
        out[:, :n_ent] = np.take_along_axis(a, order, axis=1)
        return out.reshape(-1)

    present = (np.arange(slots) < n_view[:, None]).reshape(-1)
    el_s, az_s, cn0_s = take(el), take(az), take(cn0)
    m = n * slots
    ent = _cat(
        m,
        [
            ",",
            _digits(take(prn), 3, 2),
            ",",
            _fixed(np.clip(el_s, 0.0, 90.0), 2, 0, np.isnan(el_s), 2),
            ",",
            _fixed(np.mod(np.rint(np.nan_to_num(az_s)), 360.0), 3, 0, np.isnan(az_s), 3),
            ",",
            _fixed(np.clip(cn0_s, 0.0, 99.0), 2, 0, np.isnan(cn0_s), 2),
        ],
    )
    ent[~present] = _NUL
    ent = ent.reshape(n, n_msg_max, 4 * ent.shape[1])

    n_msg = np.maximum(1, (n_view + 3) // 4)
    msg_no = np.broadcast_to(np.arange(1, n_msg_max + 1), (n, n_msg_max)).reshape(-1)
    nm = n * n_msg_max
    body = [
        g.talker + "GSV,",
        _char(np.repeat(n_msg, n_msg_max) + _DIGIT0),
        ",",
        _char(msg_no + _DIGIT0),
        ",",
        _digits(np.repeat(n_view, n_msg_max), 2, 2),
        ent.reshape(nm, -1),
        g.tail,
    ]
    msg_on = msg_no <= np.repeat(n_msg, n_msg_max)
    if emit is not None:
        msg_on &= np.repeat(emit, n_msg_max)
    return _sentence(nm, body, msg_on).reshape(n, -1)


# --- scalar rendering (small batches: the daemon's one epoch) ---------------------------------
#
# The same rules as the vectorised path, on Python numbers; tests check both give identical
# bytes on random batches.


def _fx_s(x: float, int_w: int, dec: int, min_int: int = 1) -> str:
    """Scalar twin of :func:`_fixed` for a finite ``x``."""
    k = round(min(abs(x), _ABS_MAX) * 10.0**dec)
    ip, fp = divmod(k, 10**dec)
    ip = min(ip, 10**int_w - 1)
    sign = "-" if x < 0 and k > 0 else ""
    if dec:
        return f"{sign}{ip:0{min_int}d}.{fp:0{dec}d}"
    return f"{sign}{ip:0{min_int}d}"


def _opt_s(x: float, int_w: int, dec: int, placeholder: float | None, min_int: int = 1) -> str:
    if not math.isfinite(x):
        if placeholder is None:
            return ""
        x = placeholder
    return _fx_s(x, int_w, dec, min_int)


def _render_scalar(
    fixes: Fixes, fmt: NmeaFormat, sigma_m: Mapping[str, np.ndarray] | None, i: int
) -> bytes:
    t = float(fixes.t_unix_s[i])
    if not math.isfinite(t):
        raise ValueError("fixes.t_unix_s must be finite to be written as NMEA time")
    mtk = fmt.no_fix_style == "mtk"
    T = fmt.talker
    td = fmt.time_decimals
    k = round(t * 10.0**td)
    day, r = divmod(k, 86400 * 10**td)
    sec, frac = divmod(r, 10**td)
    time = f"{sec // 3600:02d}{sec // 60 % 60:02d}{sec % 60:02d}"
    if td:
        time += f".{frac:0{td}d}"
    ymd = date.fromordinal(day + UNIX_EPOCH_ORDINAL)
    yy, mo, dd = ymd.year, ymd.month, ymd.day

    lat, lon = float(fixes.lat_deg[i]), float(fixes.lon_deg[i])
    ld = fmt.latlon_decimals
    scale = 10**ld
    if math.isfinite(lat) and math.isfinite(lon):
        ll = []
        for v, w, pos, neg in ((lat, 2, "N", "S"), (lon, 3, "E", "W")):
            kk = round(min(abs(v), _ABS_MAX_DEG) * (60 * scale))
            deg, rem = divmod(kk, 60 * scale)
            mi, mf = divmod(rem, scale)
            deg = min(deg, 10**w - 1)
            ll.append(f"{deg:0{w}d}{mi:02d}.{mf:0{ld}d},{neg if v < 0 and kk > 0 else pos}")
        latlon = ",".join(ll)
    elif mtk:
        latlon = f"8960.{0:0{ld}d},N,00000.{0:0{ld}d},E"
    else:
        latlon = ",,,"

    q = min(max(int(fixes.quality[i]), 0), 8)
    no_fix = q == QUALITY_NONE
    mode = int(fixes.mode[i])
    mode_none = mode <= 1
    used_row = np.asarray(fixes.used[i], dtype=bool).tolist()
    gsa_groups, gsv_groups = _groups(tuple(np.asarray(fixes.prn).astype(np.int64).tolist()),
                                     T, fmt.version)
    ph = mtk  # placeholders for NaN (MTK style)
    ad, dd_, sd, cd = fmt.alt_decimals, fmt.dop_decimals, fmt.speed_decimals, fmt.course_decimals
    alt = _opt_s(float(fixes.alt_msl_m[i]), 6, ad, MTK_PLACEHOLDER_ALT_MSL_M if ph else None)
    geoid_m = math.nan if no_fix else float(fixes.geoid_sep_m[i])  # (see _render_block)
    geoid = _opt_s(geoid_m, 4, ad, MTK_PLACEHOLDER_GEOID_SEP_M if ph else None)

    ublox = fmt.no_fix_style == "ublox"

    def dop(x: float, empty: bool) -> str:
        if empty and ublox:
            return _fx_s(UBLOX_NO_FIX_DOP, 2, dd_)
        if empty or not math.isfinite(x):
            return ""
        return _fx_s(min(max(x, 0.0), 99.0), 2, dd_)

    pdop_v, hdop_v, vdop_v = float(fixes.pdop[i]), float(fixes.hdop[i]), float(fixes.vdop[i])
    speed = float(fixes.speed_mps[i])
    zero = 0.0 if ph else None
    knots = _opt_s(speed * MPS_TO_KNOTS, 4, sd, zero)
    kmh = _opt_s(speed * MPS_TO_KMH, 5, sd, zero)
    c = float(fixes.course_deg[i])
    if math.isfinite(c):
        c = (round(c * 10.0**cd) / 10.0**cd) % 360.0
    course = _opt_s(c, 3, cd, zero)
    status = "V" if no_fix else "A"
    letter = "," + "NADPRFEMS"[q] if fmt.mode_letter else ""
    nav_status = ",V" if fmt.version != "2.3" else ""  # (see _render_block)
    every = dict(fmt.every)
    fix_no = round(t * fmt.fix_rate_hz) if every else 0

    out = []
    for name in fmt.sentences:
        if name in every and fix_no % every[name] != 0:
            continue
        if name == "GGA":
            n_used = sum(used_row)
            sats = f"{n_used:02d}" if fmt.sats_used_digits == 2 else str(n_used)
            dgps = "0000,0000" if fmt.dgps_fields == "mtk" and q == QUALITY_DGPS else ","
            m = "" if ublox and no_fix else "M"
            out.append(
                f"{T}GGA,{time},{latlon},{q},{sats},{dop(hdop_v, no_fix)},{alt},{m},{geoid},{m},"
                f"{dgps}"
            )
        elif name == "GSA":
            for g in gsa_groups:
                if mode_none:
                    dops = ",".join([dop(math.nan, True)] * 3)
                    out.append(g.talker + "GSA,A,1,,,,,,,,,,,,," + dops + g.tail)
                    continue
                mine = (used_row if isinstance(g.cols, slice)
                        else [used_row[c] for c in g.cols.tolist()])
                ids = [f"{p:02d}" for p, u in zip(g.ids.tolist(), mine, strict=True) if u]
                ids = ids[:GSA_SLOTS]
                slots = ",".join(ids + [""] * (GSA_SLOTS - len(ids)))
                out.append(
                    f"{g.talker}GSA,A,{mode},{slots},{dop(pdop_v, False)},{dop(hdop_v, False)},"
                    f"{dop(vdop_v, False)}{g.tail}"
                )
        elif name == "GSV":
            for g in gsv_groups:
                out += _gsv_scalar(fixes, fmt, i, g)
        elif name == "RMC":
            out.append(
                f"{T}RMC,{time},{status},{latlon},{knots},{course},{dd:02d}{mo:02d}{yy % 100:02d}"
                f",,{letter}{nav_status}"
            )
        elif name == "VTG":
            if ublox and no_fix:
                out.append(f"{T}VTG,{course},,,,{knots},,{kmh},{letter}")
            else:
                out.append(f"{T}VTG,{course},T,,M,{knots},N,{kmh},K{letter}")
        elif name == "GLL":
            out.append(f"{T}GLL,{latlon},{time},{status}{letter}")
        elif name == "GST":
            f = []
            for key in _GST_KEYS:
                if sigma_m is not None and key in sigma_m and not no_fix:
                    v = float(
                        np.broadcast_to(np.asarray(sigma_m[key], dtype=np.float64), (len(fixes),))[
                            i
                        ]
                    )
                    f.append(_opt_s(v, 5, 1, None, 3))
                else:
                    f.append("")
            out.append(f"{T}GST,{time},{','.join(f)}")
        elif name == "ZDA":
            zone = "00,00" if fmt.zda_local_zone == "zero" else ","
            out.append(f"{T}ZDA,{time},{dd:02d},{mo:02d},{yy:04d},{zone}")
    return "".join([format_sentence(b) for b in out]).encode("ascii")


def _gsv_scalar(fixes: Fixes, fmt: NmeaFormat, i: int, g: _Group) -> list[str]:
    """GSV bodies of epoch ``i`` for group ``g`` (scalar twin of :func:`_gsv`)."""
    in_view = np.asarray(fixes.in_view[i], dtype=bool)[g.cols].tolist()
    el = np.asarray(fixes.el_deg[i], dtype=np.float64)[g.cols].tolist()
    az = np.asarray(fixes.az_deg[i], dtype=np.float64)[g.cols].tolist()
    cn0 = np.asarray(fixes.cn0_dbhz[i], dtype=np.float64)[g.cols].tolist()
    prn = g.ids.tolist()

    # (keys built in one pass: a key function called per satellite costs more)
    keys = [(not v, e != e, -(0.0 if e != e else e)) for v, e in zip(in_view, el, strict=True)]
    order = sorted(range(len(prn)), key=keys.__getitem__)  # stable: ties in column order
    n_view = min(sum(in_view), fmt.gsv_max_sats)
    if n_view == 0:
        return [g.talker + "GSV,1,1,00" + g.tail]
    sats = []
    for j in order[:n_view]:
        e, a, s = el[j], az[j], cn0[j]
        # round() on a float is half-to-even, as np.rint in the vectorised path
        e_t = "" if math.isnan(e) else f"{round(min(max(e, 0.0), 90.0)):02d}"
        a_t = "" if math.isnan(a) else f"{round(a) % 360:03d}"
        s_t = "" if math.isnan(s) else f"{round(min(max(s, 0.0), 99.0)):02d}"
        sats.append(f"{prn[j]:02d},{e_t},{a_t},{s_t}")
    n_msg = (n_view + 3) // 4
    return [
        f"{g.talker}GSV,{n_msg},{m + 1},{n_view:02d},{','.join(sats[4 * m : 4 * m + 4])}"
        f"{g.tail}"
        for m in range(n_msg)
    ]


def render_batch(
    fixes: Fixes,
    fmt: NmeaFormat,
    sigma_m: Mapping[str, np.ndarray] | None = None,
    start: int = 0,
    stop: int | None = None,
) -> list[bytes]:
    """Write the NMEA sentences of every epoch of a batch.

    Parameters
    ----------
    fixes : the batch, ``n_t`` epochs
    fmt : the profile's output format
    sigma_m : optional GST error estimates, each ``(n_t,)`` float: ``range_rms_m``,
        ``semi_major_m``, ``semi_minor_m`` (metres), ``orient_deg`` (degrees from true north),
        ``lat_m``, ``lon_m``, ``alt_m`` (1-sigma, metres); missing keys or NaN give empty fields
    start, stop : the epochs to write, ``fixes[start:stop]``

    Returns
    -------
    epochs : list of ``stop - start`` bytes objects, each the epoch's sentences in
        ``fmt.sentences`` order, ``$...*HH\\r\\n`` each, ASCII

    Notes
    -----
    Fields follow NMEA 0183 v2.3 as MTK firmware writes them (see the module docstring). With
    quality 0 GGA's HDOP is empty (tr737A+.log:13); with GSA mode 1 the PRN and DOP fields are
    empty (every MTK log). A position given with quality 0 is printed (MTK prints its estimate
    before the fix is valid; a receiver model may hold its last fix that way); NaN positions
    print as the style's no-fix placeholders. DOPs are clipped to 99.
    """
    if sigma_m is None and "GST" in fmt.sentences:  # (only GST prints it)
        sigma_m = fixes.gst_sigma_m()  # the receiver's own error estimate, where it has one
    lo, hi, _ = slice(start, stop).indices(len(fixes))
    if hi - lo < _SMALL:
        return [_render_scalar(fixes, fmt, sigma_m, i) for i in range(lo, hi)]
    out: list[bytes] = []
    for a in range(lo, hi, _CHUNK):
        out += _render_block(fixes, fmt, sigma_m, slice(a, min(a + _CHUNK, hi)))
    return out


def epoch_sentences(
    fixes: Fixes, i: int, fmt: NmeaFormat, sigma_m: Mapping[str, np.ndarray] | None = None
) -> bytes:
    """Write all sentences of epoch ``i`` (see :func:`render_batch`).

    Parameters
    ----------
    fixes : the batch
    i : epoch index, ``0 <= i < len(fixes)`` (negative counts from the end)
    fmt : the output format
    sigma_m : optional GST error estimates, ``(n_t,)`` arrays (see :func:`render_batch`)

    Returns
    -------
    sentences : bytes, ASCII, ``$...*HH\\r\\n`` per sentence, in ``fmt.sentences`` order
    """
    n = len(fixes)
    if not -n <= i < n:
        raise IndexError(f"epoch {i} out of range for {n} epochs")
    i %= n
    return render_batch(fixes, fmt, sigma_m, start=i, stop=i + 1)[0]
