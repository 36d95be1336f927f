"""Real receiver logs -> per-epoch arrays, in the shape the metrics take (see :mod:`metrics`).

Owns the readers of the real logs used to calibrate receiver profiles (``../shared/data``, see
its ``SOURCES.md``) and :func:`real_calibration_stats`, the "real" column of the calibration
table:

- :func:`read_nmea_epochs`: an NMEA log grouped into epochs (GGA/GLL/RMC carry the time; GSA and
  GSV, which carry none, belong to the epoch of the latest timed sentence, as MTK firmware writes
  them: GGA, GLL, GSA, GSV x n, RMC, VTG). Per epoch: time, position, quality, satellites used
  (GGA and GSA), DOPs, per-satellite GSV elevation/azimuth/SNR, satellites in view.
  Used for mt3339-static/hour_test_1.txt (starts with binary junk, has a 5 min output gap and
  a few lines broken by it) and the gpsd-mtk captures.
- :func:`read_mtk_logger_csv`: the GPSBabel ``mtk_logger`` CSV export of an MTK data logger
  (Holux M-241, Qstarz BT-Q1000XT): position, height, speed, DOPs, satellites used (in view),
  and, where logged, per-satellite SNR with ``#`` marking the used ones.

Both records expose the attributes :func:`virtualgps.metrics.summary` reads (``t_unix_s``,
``lat_deg``, ``lon_deg``, ``quality``, ``hdop``, ``sats_used``, ``sats_in_view``, ...), with the
names and shapes of :class:`virtualgps.records.Fixes`, so real and simulated epochs go through
the same code. Corrupt lines are skipped and counted (``n_bad``), never raised: one bad line
must not lose an hour of log.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from datetime import UTC, date, datetime
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps.exceptions import InputFileError
from virtualgps.metrics import count_stats, summary
from virtualgps.nmea import MPS_TO_KMH, MPS_TO_KNOTS, parse_sentence, read_text_lines
from virtualgps.records import QUALITY_DGPS, QUALITY_GPS, QUALITY_NONE

# The real logs of the calibration (paths below ../shared/data; SOURCES.md).
MT3339_STATIC_LOG = "mt3339-static/hour_test_1.txt"
M241_TRACK_CSV = "mtk-logger/mtk_logger_m241.csv"

# Speed above which an M-241 record counts as moving (m/s); MTK's static-navigation threshold
# (PMTK386) is typically 0.4-2 m/s, so 2 m/s is clear of the hold.
M241_MOVING_MIN_SPEED_MPS = 2.0

# The facts SOURCES.md states for the MT3339 static hour ("Facts worth knowing, measured on these
# files"), by the key of the same statistic in :func:`virtualgps.metrics.summary`. The
# autocorrelation time is given there as a range, 125-170 s; first fix "after about 31 s".
MT3339_SOURCES_FACTS: dict[str, float] = {
    "cep50_m": 4.5,
    "r95_m": 10.4,
    "sigma_e_m": 3.2,
    "sigma_n_m": 5.3,
    "sigma_u_m": 4.6,
    "hdop_median": 0.99,
    "sats_used_median": 9.0,
    "sats_used_min": 3.0,
    "sats_used_max": 10.0,
    "sats_in_view_median": 12.0,
    "cn0_median_dbhz": 26.0,
    "ttff_s": 31.0,
}
MT3339_SOURCES_AUTOCORR_RANGE_S = (125.0, 170.0)

_UNIX_EPOCH_ORDINAL = 719163  # date(1970, 1, 1).toordinal()
_TIMED = ("GGA", "GLL", "RMC")


@dataclass(frozen=True)
class NmeaEpochs:
    """The epochs of an NMEA log: ``n_t`` epochs, ``n_sat`` satellites (PRNs) seen in it.

    Attributes
    ----------
    t_unix_s : (n_t,) float64, UTC seconds of the epoch (its GGA/GLL/RMC time, dated by RMC)
    lat_deg, lon_deg : (n_t,) float64, degrees, WGS-84; NaN without a position (GGA, else RMC/GLL)
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
    sats_in_view : (n_t,) int, GSV's "satellites in view" field; -1 without GSV
    gsv_complete : (n_t,) bool, every GSV message 1..N of the epoch arrived (valid checksums)
    prn : (n_sat,) int, the satellites' PRNs (columns of the per-satellite arrays), ascending
    el_deg, az_deg : (n_t, n_sat) float64, GSV elevation and azimuth, degrees; NaN if not listed
        or empty (MTK lists satellites without almanac as ``34,,,``)
    cn0_dbhz : (n_t, n_sat) float64, GSV SNR (C/N0), dB-Hz; NaN when not tracked (empty field)
    in_view : (n_t, n_sat) bool, listed in the epoch's GSV
    used : (n_t, n_sat) bool, listed in the epoch's GSA
    line : (n_t,) int, 1-based line of the epoch's first timed sentence
    n_bad : int, lines holding a ``$`` that failed the checksum or had malformed fields
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

    def __len__(self) -> int:
        return int(self.t_unix_s.shape[0])


class _Epoch:
    """Mutable accumulator of one epoch while reading (plain attributes, no numpy)."""

    __slots__ = (
        "tod", "line", "days", "lat", "lon", "alt", "sep", "quality", "mode", "hdop", "hdop_gsa",
        "pdop", "vdop", "speed", "course", "n_gga", "gsa_prns", "n_view", "gsv_total",
        "gsv_seen", "sats",
    )  # fmt: skip

    def __init__(self, tod: float, line: int) -> None:
        self.tod, self.line = tod, line
        self.days: int | None = None
        self.lat = self.lon = self.alt = self.sep = math.nan
        self.hdop = self.hdop_gsa = self.pdop = self.vdop = self.speed = self.course = math.nan
        self.quality = self.mode = 0
        self.n_gga = -1
        self.gsa_prns: set[int] | None = None
        self.n_view = -1
        self.gsv_total = 0
        self.gsv_seen: set[tuple[str, int]] = set()
        self.sats: dict[int, tuple[float, float, float]] = {}  # prn -> (el, az, snr)


def _tod_s(field: str) -> float:
    """Seconds of day of ``hhmmss[.sss]``; ValueError if malformed."""
    if len(field) < 6 or not field[:6].isdigit():
        raise ValueError(field)
    h, m, s = int(field[0:2]), int(field[2:4]), float(field[4:])
    if h > 23 or m > 59 or not 0.0 <= s < 61.0:
        raise ValueError(field)
    return h * 3600.0 + m * 60.0 + s


def _dm_deg(value: str, hemi: str, neg: str) -> float:
    """Degrees of ``(d)ddmm.mmmm`` with its hemisphere letter; NaN if empty."""
    if not value:
        return math.nan
    x = float(value)
    deg = math.floor(x / 100.0)
    v = deg + (x - 100.0 * deg) / 60.0
    return -v if hemi == neg else v


def _f(value: str) -> float:
    return float(value) if value else math.nan


def read_nmea_epochs(path: str | Path, default_date: date | None = None) -> NmeaEpochs:
    """Read an NMEA log as epochs (see :func:`nmea_epochs_from_lines`).

    Parameters
    ----------
    path : the log file; text before ``$`` on a line and undecodable bytes are tolerated
    default_date : UTC date used when the log has no RMC with a date

    Returns
    -------
    NmeaEpochs
    """
    try:
        lines = read_text_lines(path)
    except OSError as e:
        raise InputFileError(path, f"cannot read the NMEA log: {e.strerror}") from None
    return nmea_epochs_from_lines(lines, path, default_date)


def nmea_epochs_from_lines(
    lines: list[str], source: object = "<nmea>", default_date: date | None = None
) -> NmeaEpochs:
    """Group NMEA lines into epochs and collect each epoch's fix and satellites.

    A GGA, GLL or RMC with a time different from the current epoch's starts a new epoch; GSA and
    GSV, which carry no time, go to the current epoch (those before the first timed sentence are
    dropped). An epoch whose GSV messages did not all arrive keeps the satellites of those that
    did (``gsv_complete`` False). Several GSA/GSV talkers (GP, GL, GN) in one epoch add up. Each
    epoch is dated by its own RMC, else by the nearest epoch's RMC, choosing among that date and
    its neighbours the one nearest in time (a midnight between them is handled).

    Parameters
    ----------
    lines : the text lines of the log
    source : name of the log, for error messages
    default_date : UTC date used when no RMC gives one

    Returns
    -------
    NmeaEpochs

    Raises
    ------
    InputFileError
        when no RMC gives a date and ``default_date`` is None.
    """
    epochs: list[_Epoch] = []
    cur: _Epoch | None = None
    n_bad = 0
    for no, raw in enumerate(lines, start=1):
        if "$" not in raw:
            continue
        parsed = parse_sentence(raw)
        if parsed is None:
            n_bad += 1
            continue
        addr, f = parsed
        kind = addr[-3:]
        try:
            if kind in _TIMED:
                t_field = {"GGA": 0, "RMC": 0, "GLL": 4}[kind]
                if len(f) <= t_field or not f[t_field]:
                    continue  # no time (receiver just powered up): cannot be placed
                tod = _tod_s(f[t_field])
                if cur is None or tod != cur.tod:
                    cur = _Epoch(tod, no)
                    epochs.append(cur)
                if kind == "GGA" and len(f) >= 11:
                    cur.lat = _dm_deg(f[1], f[2], "S")
                    cur.lon = _dm_deg(f[3], f[4], "W")
                    cur.quality = int(f[5]) if f[5] else 0
                    cur.n_gga = int(f[6]) if f[6] else -1
                    cur.hdop, cur.alt, cur.sep = _f(f[7]), _f(f[8]), _f(f[10])
                elif kind == "RMC" and len(f) >= 9:
                    if math.isnan(cur.lat) and f[1] == "A":
                        cur.lat = _dm_deg(f[2], f[3], "S")
                        cur.lon = _dm_deg(f[4], f[5], "W")
                    cur.speed = _f(f[6]) / MPS_TO_KNOTS
                    cur.course = _f(f[7])
                    if len(f[8]) == 6:
                        dd, mo, yy = int(f[8][0:2]), int(f[8][2:4]), int(f[8][4:6])
                        # two-digit years: GPS began in 1980 (MTK's RTC starts at 050180)
                        year = yy + (1900 if yy >= 80 else 2000)
                        cur.days = date(year, mo, dd).toordinal() - _UNIX_EPOCH_ORDINAL
                elif kind == "GLL" and len(f) >= 6 and math.isnan(cur.lat) and f[5] == "A":
                    cur.lat = _dm_deg(f[0], f[1], "S")
                    cur.lon = _dm_deg(f[2], f[3], "W")
            elif cur is None:
                continue
            elif kind == "GSA" and len(f) >= 17:
                prns = {int(p) for p in f[2:14] if p}
                cur.gsa_prns = prns if cur.gsa_prns is None else cur.gsa_prns | prns
                if cur.mode == 0:
                    cur.mode = int(f[1]) if f[1] else 0
                    cur.pdop, cur.hdop_gsa, cur.vdop = _f(f[14]), _f(f[15]), _f(f[16])
            elif kind == "GSV" and len(f) >= 3:
                total, num, n_view = int(f[0]), int(f[1]), int(f[2])
                if num == 1:
                    cur.n_view = n_view if cur.gsv_total == 0 else cur.n_view + n_view
                    cur.gsv_total += total
                cur.gsv_seen.add((addr, num))
                for k in range(3, len(f) - 3, 4):
                    if f[k]:
                        cur.sats[int(f[k])] = (_f(f[k + 1]), _f(f[k + 2]), _f(f[k + 3]))
        except (ValueError, IndexError):
            n_bad += 1

    n_t = len(epochs)
    if n_t == 0:
        return _empty_epochs(n_bad)
    days = np.array([-1 if e.days is None else e.days for e in epochs], dtype=np.int64)
    tod = np.array([e.tod for e in epochs])
    dated = np.flatnonzero(days >= 0)
    if dated.size == 0:
        if default_date is None:
            raise InputFileError(
                source,
                "no RMC sentence gives the date of the epochs; expected RMC lines with a "
                "ddmmyy date, or pass default_date",
            )
        days[:] = default_date.toordinal() - _UNIX_EPOCH_ORDINAL
    else:
        # nearest dated epoch (in file order) for each epoch
        pos = np.clip(np.searchsorted(dated, np.arange(n_t)), 1, max(dated.size - 1, 1))
        lo, hi = dated[np.maximum(pos - 1, 0)], dated[np.minimum(pos, dated.size - 1)]
        near = np.where(np.abs(np.arange(n_t) - lo) <= np.abs(hi - np.arange(n_t)), lo, hi)
        anchor_t = days[near] * 86400.0 + tod[near]
        cand = (days[near] * 86400.0 + tod)[:, None] + np.array([-86400.0, 0.0, 86400.0])
        pick = np.argmin(np.abs(cand - anchor_t[:, None]), axis=1)
        t = cand[np.arange(n_t), pick]
        days = np.floor(t / 86400.0).astype(np.int64)
    t_unix_s = days * 86400.0 + tod

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

    def arr(name: str, dtype: Any = np.float64) -> np.ndarray:
        return np.array([getattr(e, name) for e in epochs], dtype=dtype)

    n_gga = arr("n_gga", np.int64)
    n_gsa = np.array([-1 if e.gsa_prns is None else len(e.gsa_prns) for e in epochs])
    hdop = arr("hdop")
    return NmeaEpochs(
        t_unix_s=t_unix_s,
        lat_deg=arr("lat"),
        lon_deg=arr("lon"),
        alt_msl_m=arr("alt"),
        geoid_sep_m=arr("sep"),
        quality=arr("quality", np.int8),
        mode=arr("mode", np.int8),
        hdop=np.where(np.isnan(hdop), arr("hdop_gsa"), hdop),
        pdop=arr("pdop"),
        vdop=arr("vdop"),
        speed_mps=arr("speed"),
        course_deg=arr("course"),
        sats_used=np.where(n_gga >= 0, n_gga, n_gsa),
        sats_used_gga=n_gga,
        sats_used_gsa=n_gsa.astype(np.int64),
        sats_in_view=arr("n_view", np.int64),
        gsv_complete=np.array([e.gsv_total > 0 and len(e.gsv_seen) == e.gsv_total for e in epochs]),
        prn=prn,
        el_deg=el,
        az_deg=az,
        cn0_dbhz=cn0,
        in_view=in_view,
        used=used,
        line=arr("line", np.int64),
        n_bad=n_bad,
    )


def _empty_epochs(n_bad: int) -> NmeaEpochs:
    z = np.zeros(0)
    zi = np.zeros(0, dtype=np.int64)
    z2 = np.zeros((0, 0))
    return NmeaEpochs(
        z, z, z, z, z, zi.astype(np.int8), zi.astype(np.int8), z, z, z, z, z, zi, zi, zi, zi,
        np.zeros(0, dtype=bool), zi, z2, z2, z2, z2.astype(bool), z2.astype(bool), zi, n_bad,
    )  # fmt: skip


@dataclass(frozen=True)
class LoggerTrack:
    """An MTK data logger's track as GPSBabel's ``mtk_logger`` CSV export writes it.

    Attributes
    ----------
    t_unix_s : (n_t,) float64, UTC seconds (DATE, TIME)
    lat_deg, lon_deg : (n_t,) float64, degrees, WGS-84
    alt_hae_m : (n_t,) float64, HEIGHT, metres. Apparently above the WGS-84 ellipsoid: the
        BT-Q1000XT, static in Norwich (ground ~20-30 m above sea, geoid +46 m), logs ~70 m
    quality : (n_t,) int8, VALID: SPS -> 1, DGPS -> 2, else 0
    record_reason : (n_t,) str, RCR: T time, S speed, D distance, B button (combinations)
    speed_mps : (n_t,) float64, SPEED converted from km/h
    pdop, hdop, vdop : (n_t,) float64; NaN where the column is absent
    sats_used, sats_in_view : (n_t,) int, NSAT ``used(view)``; -1 where absent
    prn : (n_sat,) int, PRNs in SAT INFO (empty if that column is absent)
    cn0_dbhz : (n_t, n_sat) float64, SAT INFO SNR, dB-Hz; NaN where not listed or 0 (not tracked)
    in_view : (n_t, n_sat) bool, listed in SAT INFO
    used : (n_t, n_sat) bool, marked ``#`` (used in the fix) in SAT INFO
    n_bad : int, rows that could not be read (skipped)
    """

    t_unix_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_hae_m: np.ndarray
    quality: np.ndarray
    record_reason: np.ndarray
    speed_mps: np.ndarray
    pdop: np.ndarray
    hdop: np.ndarray
    vdop: np.ndarray
    sats_used: np.ndarray
    sats_in_view: np.ndarray
    prn: np.ndarray
    cn0_dbhz: np.ndarray
    in_view: np.ndarray
    used: np.ndarray
    n_bad: int

    def __len__(self) -> int:
        return int(self.t_unix_s.shape[0])


def _num(text: str) -> float:
    """A number with an optional unit suffix (``374.812 m``, ``0.865 km/h``); NaN if empty."""
    s = text.strip().split(" ")[0]
    return float(s) if s else math.nan


def read_mtk_logger_csv(path: str | Path) -> LoggerTrack:
    """Read GPSBabel's CSV export of an MTK logger (``gpsbabel -i mtk ... -o csv`` style).

    Columns are found by their header names (INDEX, RCR, DATE, TIME, VALID, LATITUDE, N/S,
    LONGITUDE, E/W, HEIGHT, SPEED, PDOP, HDOP, VDOP, NSAT (USED/VIEW), SAT INFO (SID-SNR));
    absent optional columns give NaN / -1. A row that cannot be read is skipped and counted.

    Parameters
    ----------
    path : the CSV file

    Returns
    -------
    LoggerTrack
    """
    try:
        with open(path, newline="", encoding="latin-1") as fh:
            rows = list(csv.reader(fh))
    except OSError as e:
        raise InputFileError(path, f"cannot read the logger CSV: {e.strerror}") from None
    if not rows:
        raise InputFileError(path, "empty file; expected GPSBabel's MTK logger CSV with a header")
    col = {name.strip().upper(): k for k, name in enumerate(rows[0])}
    for need in ("DATE", "TIME", "LATITUDE", "LONGITUDE"):
        if need not in col:
            raise InputFileError(
                path,
                f"no {need} column in the header {rows[0]!r}; expected GPSBabel's MTK logger CSV",
            )

    def get(row: list[str], name: str) -> str:
        k = col.get(name)
        return row[k].strip() if k is not None and k < len(row) else ""

    recs: list[tuple] = []
    sats: list[tuple[int, int, float, bool]] = []  # (row, prn, snr, used)
    n_bad = 0
    for row in rows[1:]:
        if not any(c.strip() for c in row):
            continue
        try:
            dt = datetime.strptime(
                get(row, "DATE") + " " + get(row, "TIME"), "%Y/%m/%d %H:%M:%S.%f"
            )
            lat = _num(get(row, "LATITUDE")) * (-1.0 if get(row, "N/S") == "S" else 1.0)
            lon = _num(get(row, "LONGITUDE")) * (-1.0 if get(row, "E/W") == "W" else 1.0)
            valid = get(row, "VALID").upper()
            quality = {"SPS": QUALITY_GPS, "DGPS": QUALITY_DGPS}.get(valid, QUALITY_NONE)
            nsat = get(row, "NSAT (USED/VIEW)")
            if nsat:
                used_s, _, view_s = nsat.partition("(")
                n_used, n_view = int(used_s), int(view_s.rstrip(")"))
            else:
                n_used = n_view = -1
            rec = (
                dt.replace(tzinfo=UTC).timestamp(),
                lat,
                lon,
                _num(get(row, "HEIGHT")),
                quality,
                get(row, "RCR"),
                _num(get(row, "SPEED")) / MPS_TO_KMH,
                _num(get(row, "PDOP")),
                _num(get(row, "HDOP")),
                _num(get(row, "VDOP")),
                n_used,
                n_view,
            )
            row_sats = []
            for item in filter(None, get(row, "SAT INFO (SID-SNR)").split(";")):
                prn_s, _, snr_s = item.partition("-")
                row_sats.append((int(prn_s.lstrip("#")), float(snr_s), prn_s.startswith("#")))
        except ValueError:
            n_bad += 1
            continue
        sats.extend((len(recs), p, s, u) for p, s, u in row_sats)
        recs.append(rec)

    n_t = len(recs)
    cols = list(zip(*recs, strict=True)) if n_t else [()] * 12
    prn = np.unique(np.array([s[1] for s in sats], dtype=np.int64))
    cn0 = np.full((n_t, prn.size), np.nan)
    in_view = np.zeros((n_t, prn.size), dtype=bool)
    used = np.zeros((n_t, prn.size), dtype=bool)
    if sats:
        r = np.array([s[0] for s in sats])
        c = np.searchsorted(prn, np.array([s[1] for s in sats]))
        snr = np.array([s[2] for s in sats])
        cn0[r, c] = np.where(snr > 0, snr, np.nan)  # SNR 0: listed but not tracked
        in_view[r, c] = True
        used[r, c] = np.array([s[3] for s in sats])
    return LoggerTrack(
        t_unix_s=np.array(cols[0], dtype=np.float64),
        lat_deg=np.array(cols[1], dtype=np.float64),
        lon_deg=np.array(cols[2], dtype=np.float64),
        alt_hae_m=np.array(cols[3], dtype=np.float64),
        quality=np.array(cols[4], dtype=np.int8),
        record_reason=np.array(cols[5], dtype=str),
        speed_mps=np.array(cols[6], dtype=np.float64),
        pdop=np.array(cols[7], dtype=np.float64),
        hdop=np.array(cols[8], dtype=np.float64),
        vdop=np.array(cols[9], dtype=np.float64),
        sats_used=np.array(cols[10], dtype=np.int64),
        sats_in_view=np.array(cols[11], dtype=np.int64),
        prn=prn,
        cn0_dbhz=cn0,
        in_view=in_view,
        used=used,
        n_bad=n_bad,
    )


def real_calibration_stats(shared_data_dir: str | Path) -> dict[str, dict[str, float]]:
    """The "real" column of the calibration table of the ``holux-m1000`` profile.

    - ``"mt3339_static"``: :func:`virtualgps.metrics.summary` of the MT3339 static hour
      (errors about its median position; C/N0 from GSV; start-up), plus the satellites used
      counted from GSA (``sats_used_gsa_*``) as a cross-check of GGA's count.
    - ``"m241_moving"``: satellites used / in view and HDOP of the M-241 car track, over the
      records logged while moving (speed >= 2 m/s, ~7 km/h: MTK static navigation holds the
      fix below ~1-2 m/s); no position errors (no truth). ``"m241_all"``: the whole track.

    Parameters
    ----------
    shared_data_dir : the ``../shared/data`` folder (see its SOURCES.md)

    Returns
    -------
    stats : {log name: {statistic name (unit in the name): value}}
    """
    root = Path(shared_data_dir)
    mt = read_nmea_epochs(root / MT3339_STATIC_LOG)
    static = summary(mt, reference="median")
    gsa = mt.sats_used_gsa[(mt.quality > 0) & (mt.sats_used_gsa >= 0)]
    static.update({f"sats_used_gsa_{k}": v for k, v in count_stats(gsa).items()})
    static["n_bad_lines"] = float(mt.n_bad)

    track = read_mtk_logger_csv(root / M241_TRACK_CSV)
    moving = track.speed_mps >= M241_MOVING_MIN_SPEED_MPS
    out = {"mt3339_static": static}
    out["m241_moving"] = summary(_select(track, moving), reference=None)
    out["m241_all"] = summary(track, reference=None)
    for k in ("m241_moving", "m241_all"):
        out[k]["ttff_s"] = float("nan")  # a logger stores fixes only: no start-up to see
    return out


def _select(track: LoggerTrack, mask: np.ndarray) -> LoggerTrack:
    """The records of ``track`` where ``mask`` (n_t,) is True."""
    kw = {
        name: (getattr(track, name)[mask] if name not in ("prn", "n_bad") else getattr(track, name))
        for name in track.__dataclass_fields__
    }
    return LoggerTrack(**kw)
