"""Real receiver logs -> per-epoch arrays, in the shape the metrics take (see :mod:`metrics`).

Owns the real logs used to calibrate receiver profiles (``../shared/data``, see its
``SOURCES.md``) and :func:`real_calibration_stats`, the "real" column of the calibration table:

- NMEA logs (mt3339-static/hour_test_1.txt, the gpsd-mtk captures) are read as epochs by
  :func:`virtualgps.device.nmea.read_nmea_epochs`, the one NMEA log reader (it reads our own output
  back too).
- :func:`read_mtk_logger_csv`: the GPSBabel ``mtk_logger`` CSV export of an MTK data logger
  (Holux M-241, Qstarz BT-Q1000XT): position, height, speed, DOPs, satellites used (in view),
  and, where logged, per-satellite SNR with ``#`` marking the used ones.

Both records (:class:`virtualgps.device.nmea.NmeaEpochs`, :class:`LoggerTrack`) expose the
attributes :func:`virtualgps.gap.metrics.summary` reads (``t_unix_s``, ``lat_deg``, ``lon_deg``,
``quality``, ``hdop``, ``sats_used``, ``sats_in_view``, ...), with the names and shapes of
:class:`virtualgps.receiver.records.Fixes`, so real and simulated epochs go through the same code.
Corrupt lines are skipped and counted (``n_bad``), never raised: one bad line must not lose an
hour of log.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from virtualgps.device.nmea import MPS_TO_KMH, read_nmea_epochs
from virtualgps.exceptions import InputFileError
from virtualgps.gap.metrics import count_stats, summary
from virtualgps.receiver.records import QUALITY_DGPS, QUALITY_GPS, QUALITY_NONE

# The real logs of the calibration (paths below ../shared/data; SOURCES.md).
MT3339_STATIC_LOG = "mt3339-static/hour_test_1.txt"
M241_TRACK_CSV = "mtk-logger/mtk_logger_m241.csv"

# Speed above which an M-241 record counts as moving (m/s); MTK's static-navigation threshold
# (PMTK386) is typically 0.4-2 m/s, so 2 m/s is clear of the hold.
M241_MOVING_MIN_SPEED_MPS = 2.0

# The facts SOURCES.md states for the MT3339 static hour ("Facts worth knowing, measured on these
# files"), by the key of the same statistic in :func:`virtualgps.gap.metrics.summary`. The
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

    - ``"mt3339_static"``: :func:`virtualgps.gap.metrics.summary` of the MT3339 static hour
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
