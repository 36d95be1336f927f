"""NMEA 0183 input: the one reader of NMEA logs, ours and real receivers'.

One pass groups sentences into epochs (:func:`_read_epochs`); two views of it:
:func:`nmea_epochs_from_lines` with GSA/GSV satellites for the metrics,
:func:`nmea_fixes_from_lines` with the GGA fixes for pose logs. No I/O except
:func:`read_nmea_epochs` and :func:`read_nmea_fixes`, which read one file (and
:func:`read_text_lines`).
"""

from __future__ import annotations

import codecs
import errno
import gzip
import math
import zlib
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps.device.nmea.sentence import MPS_TO_KNOTS, UNIX_EPOCH_ORDINAL, parse_sentence
from virtualgps.exceptions import InputFileError
from virtualgps.sky import systems

# NMEA satellite IDs -> our satellite numbers (virtualgps.sky.systems), by the system a talker
# (GSV, and GSA but GN) or NMEA 4.11's system ID (a GN GSA's last field) names: NMEA 4.11 gives
# Galileo 1-36 under GA, BeiDou 1-63 under GB (BD in 4.10), QZSS 1-10 under GQ; GPS and
# GLONASS IDs (1-32, SBAS 33-64, GLONASS 65-96) stand as they are under any talker, as receivers
# before 4.10 wrote every system under GP or GN. QZSS also comes under QZ (Telit SL869, as
# gpsd's regression logs show it) and Quectel's PQ, by ID 1-10 or by PRN 193-202.
_TALKER_SYSTEM = {"GA": systems.GALILEO, "GB": systems.BEIDOU, "BD": systems.BEIDOU,
                  "GQ": systems.QZSS, "QZ": systems.QZSS, "PQ": systems.QZSS}
_NMEA_ID_SYSTEM = {s.nmea_id: s for s in (systems.GALILEO, systems.BEIDOU, systems.QZSS)}
# NavIC (NMEA 4.11: talker GI, system ID 6) is numbered and simulated nowhere here: its
# satellites (IDs 1-14) are left out of the satellite lists, not taken for GPS PRNs 1-14
_UNNUMBERED_TALKERS = {"GI"}
_UNNUMBERED_IDS = {6}


def _sat_number(system: systems.System | None, ident: int) -> int:
    """Our number of satellite ``ident`` as a talker of ``system`` lists it (None: GPS's
    numbering, SBAS 33-64 included)."""
    if system is None:
        return ident + systems.SBAS.nmea_offset if 33 <= ident <= 64 else ident
    if system is systems.QZSS and ident > 10:  # (QZSS by its PRN 193-202, as before 4.11)
        return ident
    return ident + system.nmea_offset

# The sentences that carry the time of day, by the index of their time field. An epoch of a log
# is a run of sentences with one time: GSA and GSV carry none and belong to the epoch of the
# latest timed sentence, as MTK firmware writes them (GGA, GLL, GSA, GSV x n, RMC, VTG, ZDA).
_TIME_FIELD = {"GGA": 0, "RMC": 0, "ZDA": 0, "GLL": 4}


@dataclass(frozen=True)
class NmeaEpochs:
    """The epochs of an NMEA log: ``n_t`` epochs, ``n_sat`` satellites (PRNs) seen in it.

    Attributes
    ----------
    t_unix_s : (n_t,) float64, UTC seconds of the epoch (its timed sentences' time, dated by
        RMC/ZDA)
    lat_deg, lon_deg : (n_t,) float64, degrees, WGS-84; NaN without a position (GGA, else the
        first RMC/GLL with status A)
    alt_msl_m : (n_t,) float64, GGA altitude above mean sea level, metres; NaN if empty
    geoid_sep_m : (n_t,) float64, GGA geoid separation, metres; NaN if empty
    quality : (n_t,) int8, GGA quality (0 no fix, 1 GPS, 2 DGPS); 0 without GGA
    mode : (n_t,) int8, GSA mode (1 none, 2 2D, 3 3D); 0 without GSA
    hdop : (n_t,) float64, GGA HDOP (GSA's where GGA has none); NaN if empty
    pdop, vdop : (n_t,) float64, GSA PDOP and VDOP; NaN if empty
    speed_mps, course_deg : (n_t,) float64, RMC speed over ground (m/s) and course (degrees true)
    sats_used : (n_t,) int, satellites used: GGA's field, else the GSA PRN count; -1 if neither
    sats_used_gga : (n_t,) int, GGA's satellites-used field; -1 if empty or no GGA
    sats_used_gsa : (n_t,) int, PRNs listed in the epoch's GSA sentences; -1 without GSA
    sats_in_view : (n_t,) int, GSV's "satellites in view" field; -1 without GSV (NavIC's GIGSV,
        a system simulated nowhere here, is left out of it and of the satellite lists)
    gsv_complete : (n_t,) bool, every GSV message 1..N of the epoch arrived (valid checksums)
    prn : (n_sat,) int, the satellites' numbers (columns of the per-satellite arrays),
        ascending, as :mod:`virtualgps.sky.systems` numbers them: NMEA 4.11 IDs mapped by
        talker or system ID (GAGSV 11 is Galileo E11, 311; GPGSV 36 is SBAS PRN 123)
    el_deg, az_deg : (n_t, n_sat) float64, GSV elevation and azimuth, degrees; NaN if not listed
        or empty (MTK lists satellites without almanac as ``34,,,``)
    cn0_dbhz : (n_t, n_sat) float64, GSV SNR (C/N0), dB-Hz; NaN when not tracked (empty field)
    in_view : (n_t, n_sat) bool, listed in the epoch's GSV
    used : (n_t, n_sat) bool, listed in the epoch's GSA
    line : (n_t,) int, 1-based line of the epoch's first timed sentence
    n_bad : int, lines holding a ``$`` that failed the checksum or had malformed fields
    dated : bool, the log's own RMC/ZDA date its epochs (False: the caller's default date,
        no RMC or ZDA having one)
    checksummed : bool, its sentences carry checksums (False: none in the log has a valid one,
        and it was read without, :func:`_read_epochs`)
    """

    t_unix_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_msl_m: np.ndarray
    geoid_sep_m: np.ndarray
    quality: np.ndarray
    mode: np.ndarray
    hdop: np.ndarray
    pdop: np.ndarray
    vdop: np.ndarray
    speed_mps: np.ndarray
    course_deg: np.ndarray
    sats_used: np.ndarray
    sats_used_gga: np.ndarray
    sats_used_gsa: np.ndarray
    sats_in_view: np.ndarray
    gsv_complete: np.ndarray
    prn: np.ndarray
    el_deg: np.ndarray
    az_deg: np.ndarray
    cn0_dbhz: np.ndarray
    in_view: np.ndarray
    used: np.ndarray
    line: np.ndarray
    n_bad: int
    dated: bool = True
    checksummed: bool = True

    def __len__(self) -> int:
        return int(self.t_unix_s.shape[0])


@dataclass(frozen=True)
class NmeaFixLog:
    """GGA fixes of an NMEA log: the epochs that hold a GGA, one per time.

    Attributes
    ----------
    t_unix_s : (n,) float64, UTC seconds
    lat_deg, lon_deg : (n,) float64, degrees; NaN where GGA has no position
    alt_msl_m : (n,) float64, GGA altitude above mean sea level; NaN if empty
    geoid_sep_m : (n,) float64, GGA geoid separation; NaN if empty
    quality : (n,) int, GGA fix quality (0 = no fix)
    sats_used : (n,) int, GGA satellites used; -1 if empty
    hdop : (n,) float64; NaN if empty
    speed_mps, course_deg : (n,) float64, from the RMC of the same epoch; NaN if absent
    line : (n,) int, 1-based line number of each GGA in the file
    n_bad : int, lines holding a ``$`` whose checksum or fields were invalid (skipped)
    """

    t_unix_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_msl_m: np.ndarray
    geoid_sep_m: np.ndarray
    quality: np.ndarray
    sats_used: np.ndarray
    hdop: np.ndarray
    speed_mps: np.ndarray
    course_deg: np.ndarray
    line: np.ndarray
    n_bad: int

    def __len__(self) -> int:
        return int(self.t_unix_s.shape[0])


class _Epoch:
    """One epoch while reading (plain attributes, no numpy). Of several sentences of a kind
    with the epoch's time (several talkers), the first GGA, RMC, GLL and ZDA count; the GSA and
    GSV of all talkers add up."""

    __slots__ = (
        "tod", "line", "days", "days_void", "gga", "rmc", "latlon", "mode", "pdop", "hdop_gsa",
        "vdop", "gsa_prns", "view_by_group", "gsv_total", "gsv_seen", "sats",
    )  # fmt: skip

    def __init__(self, tod: float, line: int) -> None:
        self.tod, self.line = tod, line
        self.days: int | None = None  # days since 1970-01-01, from RMC (status A) or ZDA
        # from an RMC with status V: a receiver whose clock is not set yet prints a placeholder
        # (MTK's RTC: 050180), so such a date counts only where the log has no other
        self.days_void: int | None = None
        # (line, lat, lon, alt_msl, geoid_sep, quality, sats_used, hdop)
        self.gga: tuple[int, float, float, float, float, int, int, float] | None = None
        self.rmc: tuple[float, float] | None = None  # (speed m/s, course deg)
        self.latlon: tuple[float, float] | None = None  # of the first RMC/GLL with status A
        self.mode = 0
        self.pdop = self.hdop_gsa = self.vdop = math.nan
        self.gsa_prns: set[int] | None = None
        self.view_by_group: dict[tuple[str, str], int] = {}  # (talker, signal) -> in view
        self.gsv_total = 0
        self.gsv_seen: set[tuple[str, str, int]] = set()
        self.sats: dict[int, tuple[float, float, float]] = {}  # prn -> (el, az, snr)


def _in_view(e: _Epoch) -> int:
    """GSV's "satellites in view" of an epoch: summed over talkers (GP, GL, ...), each talker's
    the largest of its signals' lists (L1 lists every satellite in view, L5 those that send it);
    -1 without GSV."""
    best: dict[str, int] = {}
    for (talker, _), n in e.view_by_group.items():
        best[talker] = max(best.get(talker, 0), n)
    return sum(best.values()) if best else -1


def _tod_s(field: str) -> float:
    """Seconds of day of ``hhmmss[.sss]``; ValueError if malformed."""
    if len(field) < 6 or not field[:6].isdigit():
        raise ValueError(field)
    h, m = int(field[0:2]), int(field[2:4])
    s = float(field[4:])
    if h > 23 or m > 59 or not 0.0 <= s < 61.0:
        raise ValueError(field)
    return h * 3600.0 + m * 60.0 + s


def _dm_deg(value: str, hemi: str, pos: str, neg: str) -> float:
    """Degrees of ``(d)ddmm.mmmm`` with hemisphere letter; NaN if empty; ValueError if bad."""
    if not value and not hemi:
        return math.nan
    x = float(value)
    if hemi not in (pos, neg) or not math.isfinite(x) or x < 0:
        raise ValueError(value)
    deg = math.floor(x / 100.0)
    v = deg + (x - 100.0 * deg) / 60.0
    return -v if hemi == neg else v


def _opt_float(value: str) -> float:
    return float(value) if value else math.nan


class UndatedLogError(InputFileError):
    """A log whose epochs no RMC or ZDA dates, read without a default date (a caller that knows
    the date another way, e.g. from a truth log, reads it again with one)."""


def _days(y: int, m: int, d: int) -> int:
    return date(y, m, d).toordinal() - UNIX_EPOCH_ORDINAL


def _read_timed(e: _Epoch, kind: str, f: list[str], no: int) -> None:
    """Take the fields of a GGA/RMC/GLL/ZDA (``f``, line ``no``) into its epoch ``e``.

    All fields are parsed before any is kept, so a malformed sentence (ValueError) adds nothing.
    """
    if kind == "GGA" and len(f) >= 11:
        gga = (
            no,
            _dm_deg(f[1], f[2], "N", "S"),
            _dm_deg(f[3], f[4], "E", "W"),
            _opt_float(f[8]),
            _opt_float(f[10]),
            int(f[5]) if f[5] else 0,
            int(f[6]) if f[6] else -1,
            _opt_float(f[7]),
        )
        if e.gga is None:
            e.gga = gga
    elif kind == "RMC" and len(f) >= 9:
        latlon = (_dm_deg(f[2], f[3], "N", "S"), _dm_deg(f[4], f[5], "E", "W"))
        rmc = (_opt_float(f[6]) / MPS_TO_KNOTS, _opt_float(f[7]))
        days = None
        if len(f[8]) == 6:
            dd, mo, yy = int(f[8][0:2]), int(f[8][2:4]), int(f[8][4:6])
            # two-digit years: GPS began in 1980 (MTK's RTC starts at 050180)
            days = _days(yy + (1900 if yy >= 80 else 2000), mo, dd)
        if e.rmc is None:
            e.rmc = rmc
            if f[1] == "A" and e.latlon is None:
                e.latlon = latlon
        if f[1] != "A":
            if e.days_void is None:
                e.days_void = days
        elif e.days is None:
            e.days = days
    elif kind == "GLL" and len(f) >= 6 and f[5] == "A":
        latlon = (_dm_deg(f[0], f[1], "N", "S"), _dm_deg(f[2], f[3], "E", "W"))
        if e.latlon is None:
            e.latlon = latlon
    elif kind == "ZDA" and len(f) >= 4 and f[3]:
        days = _days(int(f[3]), int(f[2]), int(f[1]))
        if e.days is None:
            e.days = days


def _read_epochs(lines: Iterable[str], tally: Counter | None = None
                 ) -> tuple[list[_Epoch], int, bool]:
    """Group NMEA lines into epochs: the one reading pass of every log reader here.

    A timed sentence (GGA, RMC, GLL, ZDA) with a time different from the current epoch's starts
    a new epoch; one without a time (a receiver just powered up) is skipped. GSA and GSV go to
    the current epoch (those before the first timed sentence are dropped). Text before ``$`` is
    ignored (:func:`parse_sentence`). NMEA 0183 makes the checksum optional and some loggers
    strip it: a log in which no line carries a valid one is read without (as gpsd reads such
    sentences); in a log whose sentences carry one, a line without is a line cut short.

    tally : where given, counts every line: each sentence by its address (``GPGGA``), and the
    lines that hold none by why (``not_nmea``: text without ``$``; ``truncated``: no ``*HH``
    at its end; ``bad_checksum``)

    Returns
    -------
    epochs : in file order
    n_bad : lines holding a ``$`` with a bad checksum or malformed fields (skipped)
    checksummed : the log's sentences carry checksums (False: read without)
    """
    lines = list(lines)
    checksummed = any(parse_sentence(raw) is not None for raw in lines if "$" in raw)
    epochs: list[_Epoch] = []
    cur: _Epoch | None = None
    n_bad = 0
    for no, raw in enumerate(lines, start=1):
        if "$" not in raw:
            if tally is not None and raw.strip():
                tally["not_nmea"] += 1
            continue
        parsed = parse_sentence(raw, require_checksum=checksummed)
        if parsed is None:
            n_bad += 1
            if tally is not None:
                star = raw.rfind("*")
                tally["truncated" if star < 0 or len(raw.rstrip()) - star < 3
                      else "bad_checksum"] += 1
            continue
        addr, f = parsed
        if tally is not None:
            tally[addr] += 1
        kind = addr[-3:]
        try:
            if kind in _TIME_FIELD:
                k = _TIME_FIELD[kind]
                if len(f) <= k or not f[k]:
                    continue
                tod = _tod_s(f[k])
                if cur is None or tod != cur.tod:
                    cur = _Epoch(tod, no)
                    epochs.append(cur)
                _read_timed(cur, kind, f, no)
            elif cur is None:
                continue
            elif kind == "GSA" and len(f) >= 17:
                sys_id = int(f[17], 16) if len(f) > 17 and f[17] else None
                sys_gsa = (_NMEA_ID_SYSTEM.get(sys_id) if sys_id is not None
                           else _TALKER_SYSTEM.get(addr[:2]))
                unnumbered = (sys_id in _UNNUMBERED_IDS if sys_id is not None
                              else addr[:2] in _UNNUMBERED_TALKERS)
                prns = set() if unnumbered else {_sat_number(sys_gsa, int(p))
                                                 for p in f[2:14] if p}
                cur.gsa_prns = prns if cur.gsa_prns is None else cur.gsa_prns | prns
                if cur.mode == 0:
                    cur.mode = int(f[1]) if f[1] else 0
                    cur.pdop, cur.hdop_gsa, cur.vdop = (_opt_float(x) for x in f[14:17])
            elif kind == "GSV" and len(f) >= 3 and addr[:2] not in _UNNUMBERED_TALKERS:
                total, num, n_view = int(f[0]), int(f[1]), int(f[2])
                # NMEA 4.10+ ends a GSV with its signal ID: a dual-band receiver lists each
                # talker's satellites once per signal, each list numbered 1..N of its own
                group = (addr, f[-1] if (len(f) - 3) % 4 == 1 else "")
                if num == 1:
                    cur.view_by_group[group] = n_view
                    cur.gsv_total += total
                cur.gsv_seen.add((*group, num))
                sys_gsv = _TALKER_SYSTEM.get(addr[:2])
                for j in range(3, len(f) - 3, 4):
                    if f[j]:
                        # (a second signal of a satellite, e.g. L5 after L1: the first counts)
                        cur.sats.setdefault(_sat_number(sys_gsv, int(f[j])),
                                            tuple(_opt_float(x) for x in f[j + 1 : j + 4]))
        except (ValueError, IndexError):
            n_bad += 1
    return epochs, n_bad, checksummed


def _epoch_times_s(epochs: list[_Epoch], source: object, default_date: date | None
                   ) -> tuple[np.ndarray, bool]:
    """UTC seconds of each epoch: its time of day on its own RMC/ZDA date, else on the date of
    the nearest dated epoch (in file order, the earlier on a tie), choosing among that date and
    its neighbours the one nearest in time (so a midnight between them is handled). The dates
    of RMC with status V count only where no RMC with status A or ZDA dates the log: before its
    first fix a receiver prints its clock's placeholder (mtk-3301.log: 050180 until 2008-08-23).

    Returns
    -------
    t_unix_s : (len(epochs),) float64
    dated : whether an RMC or ZDA dated them (False: ``default_date`` did)

    Without any date, the first epoch is dated ``default_date`` and the later ones roll past
    midnight.

    Raises
    ------
    InputFileError
        when no epoch is dated and ``default_date`` is None.
    """
    n_t = len(epochs)
    days = np.array([-1 if e.days is None else e.days for e in epochs], dtype=np.int64)
    if not (days >= 0).any():
        days = np.array([-1 if e.days_void is None else e.days_void for e in epochs],
                        dtype=np.int64)
    tod = np.array([e.tod for e in epochs], dtype=np.float64)
    dated = np.flatnonzero(days >= 0)
    if n_t and dated.size == 0:
        if default_date is None:
            raise UndatedLogError(
                source,
                "no RMC or ZDA sentence gives the date of the epochs; expected RMC (ddmmyy) "
                "or ZDA lines",
            )
        # the first epoch on the default date, the later ones past each midnight they cross
        # (the time of day falling back by more than half a day, in file order)
        days[:] = _days(default_date.year, default_date.month, default_date.day)
        days += np.concatenate([[0], np.cumsum(np.diff(tod) < -43200.0)]).astype(np.int64)
        return days * 86400.0 + tod, False
    if n_t:
        idx = np.arange(n_t)
        pos = np.clip(np.searchsorted(dated, idx), 1, max(dated.size - 1, 1))
        lo, hi = dated[np.maximum(pos - 1, 0)], dated[np.minimum(pos, dated.size - 1)]
        near = np.where(np.abs(idx - lo) <= np.abs(hi - idx), lo, hi)
        anchor_t = days[near] * 86400.0 + tod[near]
        cand = (days[near] * 86400.0 + tod)[:, None] + np.array([-86400.0, 0.0, 86400.0])
        t = cand[idx, np.argmin(np.abs(cand - anchor_t[:, None]), axis=1)]
        days = np.floor(t / 86400.0).astype(np.int64)
    return days * 86400.0 + tod, True


def satellite_arrays(rows: Sequence[Sequence[tuple[int, float, float, float, bool]] | None]
                     ) -> tuple[np.ndarray, ...]:
    """The per-satellite arrays of :class:`NmeaEpochs` from each epoch's listed satellites, for
    logs that list them as records rather than GSV and GSA (gpsd's SKY, u-blox's NAV-SAT).

    Parameters
    ----------
    rows : per epoch, its satellites as (number, elevation deg, azimuth deg, C/N0 dB-Hz, used);
        NaN for what is not known; None or empty for an epoch without a list

    Returns
    -------
    prn : (n_sat,) int, ascending; el_deg, az_deg, cn0_dbhz : (n_t, n_sat) float64, NaN where
    not listed; in_view, used : (n_t, n_sat) bool
    """
    listed = [(i, *sat) for i, row in enumerate(rows) for sat in row or ()]
    n_t = len(rows)
    prn = np.unique(np.array([x[1] for x in listed], dtype=np.int64))
    el = np.full((n_t, prn.size), np.nan)
    az, cn0 = el.copy(), el.copy()
    in_view = np.zeros((n_t, prn.size), dtype=bool)
    used = in_view.copy()
    if listed:
        a = np.array(listed, dtype=np.float64)
        r, c = a[:, 0].astype(np.int64), np.searchsorted(prn, a[:, 1].astype(np.int64))
        el[r, c], az[r, c], cn0[r, c] = a[:, 2], a[:, 3], a[:, 4]
        in_view[r, c], used[r, c] = True, a[:, 5] != 0
    return prn, el, az, cn0, in_view, used


def nmea_epochs_from_lines(
    lines: Iterable[str], source: object = "<nmea>", default_date: date | None = None,
    tally: Counter | None = None,
) -> NmeaEpochs:
    """Group NMEA lines into epochs and collect each epoch's fix and satellites.

    Used for real receiver logs (mt3339-static/hour_test_1.txt starts with binary junk and has
    a 5 min output gap with a few lines broken by it; the gpsd-mtk captures; phone logs with a
    prefix before ``$``) and for our own output. A GGA, RMC, GLL or ZDA with a time different
    from the current epoch's starts a new epoch; GSA and GSV, which carry no time, go to the
    current epoch. An epoch whose GSV messages did not all arrive keeps the satellites of those
    that did (``gsv_complete`` False). Several GSA/GSV talkers (GP, GL, GN) in one epoch add up.
    Each epoch is dated by its own RMC/ZDA, else by the nearest dated epoch's, choosing among
    that date and its neighbours the one nearest in time (a midnight between them is handled).
    Corrupt lines are skipped and counted (``n_bad``), never raised: one bad line must not lose
    an hour of log.

    Parameters
    ----------
    lines : the text lines of the log
    source : name of the log, for error messages
    default_date : UTC date of the first epoch when no RMC or ZDA gives one (later epochs roll
        past midnight)
    tally : where given, every line is counted into it (see :func:`_read_epochs`)

    Returns
    -------
    NmeaEpochs

    Raises
    ------
    InputFileError
        when no RMC/ZDA gives a date and ``default_date`` is None.
    """
    epochs, n_bad, checksummed = _read_epochs(lines, tally)
    n_t = len(epochs)
    t_unix_s, dated = _epoch_times_s(epochs, source, default_date)

    # per-satellite arrays: one column per PRN seen in GSV or GSA, filled by index arrays
    rows, prns, vals, urows, uprns = [], [], [], [], []
    for i, e in enumerate(epochs):
        for p, v in e.sats.items():
            rows.append(i)
            prns.append(p)
            vals.append(v)
        for p in e.gsa_prns or ():
            urows.append(i)
            uprns.append(p)
    prn = np.unique(np.array(prns + uprns, dtype=np.int64))
    n_sat = prn.size
    el = np.full((n_t, n_sat), np.nan)
    az = np.full((n_t, n_sat), np.nan)
    cn0 = np.full((n_t, n_sat), np.nan)
    in_view = np.zeros((n_t, n_sat), dtype=bool)
    used = np.zeros((n_t, n_sat), dtype=bool)
    if rows:
        r, c = np.array(rows), np.searchsorted(prn, np.array(prns))
        v = np.array(vals, dtype=np.float64).reshape(-1, 3)
        el[r, c], az[r, c], cn0[r, c] = v[:, 0], v[:, 1], v[:, 2]
        in_view[r, c] = True
    if urows:
        used[np.array(urows), np.searchsorted(prn, np.array(uprns))] = True

    def arr(values: Iterable[Any], dtype: Any = np.float64) -> np.ndarray:
        return np.array(list(values), dtype=dtype)

    no_gga = (-1, math.nan, math.nan, math.nan, math.nan, 0, -1, math.nan)
    gga = [no_gga if e.gga is None else e.gga for e in epochs]
    gga_lat = arr(g[1] for g in gga)
    alt_ll = [(math.nan, math.nan) if e.latlon is None else e.latlon for e in epochs]
    has_gga_pos = np.isfinite(gga_lat)
    n_gga = arr((g[6] for g in gga), np.int64)
    n_gsa = arr((-1 if e.gsa_prns is None else len(e.gsa_prns) for e in epochs), np.int64)
    hdop = arr(g[7] for g in gga)
    rmc = [(math.nan, math.nan) if e.rmc is None else e.rmc for e in epochs]
    return NmeaEpochs(
        t_unix_s=t_unix_s,
        lat_deg=np.where(has_gga_pos, gga_lat, arr(a[0] for a in alt_ll)),
        lon_deg=np.where(has_gga_pos, arr(g[2] for g in gga), arr(a[1] for a in alt_ll)),
        alt_msl_m=arr(g[3] for g in gga),
        geoid_sep_m=arr(g[4] for g in gga),
        quality=arr((g[5] for g in gga), np.int8),
        mode=arr((e.mode for e in epochs), np.int8),
        hdop=np.where(np.isnan(hdop), arr(e.hdop_gsa for e in epochs), hdop),
        pdop=arr(e.pdop for e in epochs),
        vdop=arr(e.vdop for e in epochs),
        speed_mps=arr(r[0] for r in rmc),
        course_deg=arr(r[1] for r in rmc),
        sats_used=np.where(n_gga >= 0, n_gga, n_gsa),
        sats_used_gga=n_gga,
        sats_used_gsa=n_gsa,
        sats_in_view=arr((_in_view(e) for e in epochs), np.int64),
        gsv_complete=arr(
            (e.gsv_total > 0 and len(e.gsv_seen) == e.gsv_total for e in epochs), bool
        ),
        prn=prn,
        el_deg=el,
        az_deg=az,
        cn0_dbhz=cn0,
        in_view=in_view,
        used=used,
        line=arr((e.line for e in epochs), np.int64),
        n_bad=n_bad,
        dated=dated,
        checksummed=checksummed,
    )


def nmea_fixes_from_lines(
    lines: Iterable[str], source: object = "<nmea>", default_date: date | None = None
) -> NmeaFixLog:
    """Collect the GGA fixes of NMEA text lines (any talker; prefixes before ``$`` tolerated).

    The epochs of :func:`nmea_epochs_from_lines` that hold a GGA, dated the same way (a GGA
    carries only the time of day). Lines with a bad checksum or malformed fields are skipped
    and counted (real logs hold corrupt lines, e.g. binary noise at the start of
    mt3339-static/hour_test_1.txt). Of several GGA with one time (several talkers, or a time
    repeated later in the file), the first is kept.

    Parameters
    ----------
    lines : the text lines
    source : name of the file, for error messages
    default_date : UTC date of the first epoch when the log has no RMC or ZDA

    Returns
    -------
    NmeaFixLog

    Raises
    ------
    InputFileError
        when the log has GGA fixes, no RMC/ZDA gives a date and ``default_date`` is None.
    """
    epochs, n_bad, _ = _read_epochs(lines)
    has_gga = np.array([e.gga is not None for e in epochs], dtype=bool)
    t = np.zeros(0)
    if has_gga.any():
        t = _epoch_times_s(epochs, source, default_date)[0][has_gga]
    _, first = np.unique(t, return_index=True)
    keep = np.sort(first)  # first GGA of each time, in file order
    fix_epochs = [epochs[i] for i in np.flatnonzero(has_gga)[keep]]
    gga = [e.gga for e in fix_epochs if e.gga is not None]  # all of them
    rmc = [(math.nan, math.nan) if e.rmc is None else e.rmc for e in fix_epochs]

    def col(k: int, dtype: Any = np.float64) -> np.ndarray:
        return np.array([g[k] for g in gga], dtype=dtype)

    return NmeaFixLog(
        t_unix_s=t[keep],
        lat_deg=col(1),
        lon_deg=col(2),
        alt_msl_m=col(3),
        geoid_sep_m=col(4),
        quality=col(5, np.int64),
        sats_used=col(6, np.int64),
        hdop=col(7),
        speed_mps=np.array([r[0] for r in rmc], dtype=np.float64),
        course_deg=np.array([r[1] for r in rmc], dtype=np.float64),
        line=col(0, np.int64),
        n_bad=n_bad,
    )


# Byte-order marks and the codecs that read past them (codecs.BOM_*).
_BOMS = ((codecs.BOM_UTF8, "utf-8-sig"), (codecs.BOM_UTF16_LE, "utf-16"),
         (codecs.BOM_UTF16_BE, "utf-16"))


def read_log_bytes(path: str | Path) -> bytes:
    """A log file's bytes; a gzip-compressed one (by its magic bytes, whatever its name)
    decompressed: logs are often kept as ``.nmea.gz``.

    Raises
    ------
    OSError : unreadable, or a gzip file that does not decompress (a truncated download)
    """
    with open(path, "rb") as f:
        data = f.read()
    if data[:2] == b"\x1f\x8b":
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as e:
            raise OSError(errno.EIO, f"a gzip file that does not decompress ({e})") from None
    return data


def text_lines(data: bytes) -> list[str]:
    """A text log's bytes as lines, undecodable bytes replaced (real logs hold binary noise).

    Bytes that start with a UTF-16 byte-order mark are read as UTF-16 (Windows PowerShell's
    ``>`` and ``Out-File`` write logs so), those with UTF-8's without it. Lines are split on LF
    only (CR stripped), so line numbers match what editors show.
    """
    bom = next((enc for mark, enc in _BOMS if data.startswith(mark)), "utf-8")
    return [ln.rstrip("\r") for ln in data.decode(bom, errors="replace").split("\n")]


def read_text_lines(path: str | Path) -> list[str]:
    """Read a text file as lines (:func:`read_log_bytes`, then :func:`text_lines`).

    Raises
    ------
    OSError : unreadable, or a gzip file that does not decompress (a truncated download)
    """
    return text_lines(read_log_bytes(path))


def _read_log_lines(path: str | Path) -> list[str]:
    try:
        return read_text_lines(path)
    except OSError as e:
        raise InputFileError(path, f"cannot read the NMEA log: {e.strerror}") from None


def read_nmea_fixes(path: str | Path, default_date: date | None = None) -> NmeaFixLog:
    """Read the GGA fixes of an NMEA log file (see :func:`nmea_fixes_from_lines`).

    Parameters
    ----------
    path : the log; any prefix before ``$`` on a line is ignored
    default_date : UTC date of the first epoch when the log has no RMC or ZDA

    Returns
    -------
    NmeaFixLog
    """
    return nmea_fixes_from_lines(_read_log_lines(path), path, default_date)


def read_nmea_epochs(path: str | Path, default_date: date | None = None) -> NmeaEpochs:
    """Read an NMEA log as epochs (see :func:`nmea_epochs_from_lines`).

    Parameters
    ----------
    path : the log file; text before ``$`` on a line and undecodable bytes are tolerated
    default_date : UTC date of the first epoch when the log has no RMC or ZDA

    Returns
    -------
    NmeaEpochs
    """
    return nmea_epochs_from_lines(_read_log_lines(path), path, default_date)
