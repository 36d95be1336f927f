"""A u-blox receiver's UBX log (u-center's ``.ubx``, a capture of the port) read as the epochs
of an NMEA log.

A u-blox module set to UBX output (as PX4, ArduPilot and gpsd set it) writes no NMEA fixes:
its log is binary frames (UBX-13003221, "UBX frame structure"), possibly among NMEA lines and
noise. The epochs come out as :class:`~virtualgps.device.nmea.NmeaEpochs`, so the gap tool
reads them as it reads NMEA:

- each UBX-NAV-PVT (0x01 0x07, 92 bytes; u-blox 7's 84) whose UTC date and time are valid
  (``valid`` bits 0 and 1) is an epoch; the others are counted (``pvt_without_time``); a fix
  is ``gnssFixOK`` with ``fixType`` 2, 3 or 4 (GNSS + dead reckoning), of GGA quality 1, 2 with
  ``diffSoln``, 5/4 with a float/fixed carrier solution, 6 for dead reckoning alone;
  ``hMSL`` and ``height`` - ``hMSL`` are GGA's altitude and geoid separation; ``numSV`` GGA's
  satellites used, ``pDOP`` GSA's;
- UBX-NAV-SAT (0x01 0x35) of the same iTOW lists the satellites (``cno`` 0: not tracked,
  ``svUsed``, elevation and azimuth, unknown where out of range), numbered as
  :mod:`virtualgps.sky.systems` numbers them (:func:`numbers_of_ubx_ids`); without any NAV-SAT,
  UBX-NAV-SVINFO (0x01 0x30) does; UBX-NAV-DOP (0x01 0x04) gives HDOP and VDOP.

A log whose lines hold NMEA fixes (GGA, RMC or GLL) as well is read as NMEA, as a gpsd log that
keeps the raw sentences is: one reading of each receiver.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from datetime import UTC, datetime

import numpy as np

from virtualgps.device.nmea import NmeaEpochs, parse_sentence
from virtualgps.device.nmea.reader import satellite_arrays
from virtualgps.device.ubx.frame import SYNC, InputSplitter
from virtualgps.device.ubx.messages import numbers_of_svinfo_ids, numbers_of_ubx_ids

NAV_DOP, NAV_PVT, NAV_SVINFO, NAV_SAT = (0x01, 0x04), (0x01, 0x07), (0x01, 0x30), (0x01, 0x35)
#: Longest payload read from a log: NAV-SAT of 255 satellites (8 + 12 * 255 bytes)
MAX_LOG_PAYLOAD_BYTES = 8 + 12 * 255
_PVT = struct.Struct("<IHBBBBBBIiBBBBiiiiIIiiiiiIIH")  # iTOW .. pDOP: u-blox 7's 84 bytes and on


def ubx_frames(data: bytes) -> list[tuple[int, int, bytes]] | None:
    """The UBX frames of a log where it is one of UBX fixes: it holds a NAV-PVT and no line
    with an NMEA fix (GGA, RMC or GLL); else None (an NMEA log, or text)."""
    if SYNC + bytes(NAV_PVT) not in data:
        return None
    items = InputSplitter(max_payload=MAX_LOG_PAYLOAD_BYTES).feed(data + b"\n")
    frames, nmea_fix = [], False
    for item in items:
        if item[:2] == SYNC:
            frames.append((item[2], item[3], item[6:-2]))  # (checksum verified by the splitter)
        elif not nmea_fix:
            parsed = parse_sentence(item.decode("ascii", "replace"))
            nmea_fix = parsed is not None and parsed[0][-3:] in ("GGA", "RMC", "GLL")
    if nmea_fix or not any(f[:2] == NAV_PVT for f in frames):
        return None
    return frames


def _utc_s(pvt: tuple) -> float:
    """UTC seconds of a NAV-PVT's date and time (NaN where ``valid`` lacks either)."""
    _, year, month, day, hour, minute, sec, valid, _, nano = pvt[:10]
    if valid & 0x03 != 0x03:
        return math.nan
    try:
        return datetime(year, month, day, hour, minute, sec, tzinfo=UTC).timestamp() + nano * 1e-9
    except ValueError:  # (a receiver whose time is "valid" but out of range)
        return math.nan


def _quality(fix_type: int, flags: int) -> int:
    """GGA's quality of a NAV-PVT's fixType and flags (gnssFixOK, diffSoln, carrSoln)."""
    if not flags & 0x01:
        return 0
    if fix_type == 1:
        return 6
    if fix_type not in (2, 3, 4):
        return 0
    return {1: 5, 2: 4}.get(flags >> 6, 2 if flags & 0x02 else 1)


def _sats(payload: bytes, svinfo: bool) -> list[tuple[int, float, float, float, bool]]:
    """(number, elevation deg, azimuth deg, C/N0 dB-Hz, used) of a NAV-SAT or NAV-SVINFO."""
    if svinfo:  # iTOW, numCh, globalFlags, 2 reserved; 12 bytes a channel
        rec = np.frombuffer(payload, dtype=np.dtype([
            ("chn", "u1"), ("svid", "u1"), ("flags", "u1"), ("quality", "u1"), ("cno", "u1"),
            ("elev", "i1"), ("azim", "<i2"), ("prRes", "<i4")]), count=payload[4], offset=8)
        num = numbers_of_svinfo_ids(rec["svid"])
        used = rec["flags"] & 0x01 != 0
    else:  # iTOW, version, numSvs, 2 reserved; 12 bytes a satellite
        rec = np.frombuffer(payload, dtype=np.dtype([
            ("gnssId", "u1"), ("svId", "u1"), ("cno", "u1"), ("elev", "i1"), ("azim", "<i2"),
            ("prRes", "<i2"), ("flags", "<u4")]), count=payload[5], offset=8)
        num = numbers_of_ubx_ids(rec["gnssId"], rec["svId"])
        used = rec["flags"] & 0x08 != 0  # svUsed
    el = np.where(np.abs(rec["elev"]) <= 90, rec["elev"], np.nan)
    az = np.where((rec["azim"] >= 0) & (rec["azim"] <= 360), rec["azim"], np.nan)
    cn0 = np.where(rec["cno"] > 0, rec["cno"], np.nan)
    return [(int(n), float(e), float(a), float(c), bool(u))
            for n, e, a, c, u in zip(num, el, az, cn0, used, strict=True) if n > 0]


def ubx_epochs(frames: list[tuple[int, int, bytes]]) -> tuple[NmeaEpochs, Counter, Counter]:
    """The epochs of a UBX log's frames (see the module's docstring).

    Returns
    -------
    epochs : one per NAV-PVT with a valid date and time, in log order
    messages : {name: frames read} ("NAV-PVT", "NAV-SAT", ...; others by class and id)
    skipped : {reason: frames}: ``pvt_without_time``, ``not_used`` (other messages),
        ``bad_length``
    """
    names = {NAV_PVT: "NAV-PVT", NAV_SAT: "NAV-SAT", NAV_SVINFO: "NAV-SVINFO",
             NAV_DOP: "NAV-DOP"}
    messages: Counter = Counter()
    skipped: Counter = Counter()
    pvts: list[tuple] = []
    by_itow: dict[tuple[int, int], dict[int, bytes]] = {NAV_SAT: {}, NAV_SVINFO: {},
                                                        NAV_DOP: {}}
    for cls, mid, payload in frames:
        key = (cls, mid)
        messages[names.get(key, f"{cls:02X}-{mid:02X}")] += 1
        minimum = {NAV_PVT: 84, NAV_DOP: 18, NAV_SAT: 8, NAV_SVINFO: 8}.get(key)
        if minimum is None:
            skipped["not_used"] += 1
        elif len(payload) < minimum or (key == NAV_SAT and len(payload) < 8 + 12 * payload[5]) \
                or (key == NAV_SVINFO and len(payload) < 8 + 12 * payload[4]):
            skipped["bad_length"] += 1
        elif key == NAV_PVT:
            pvts.append(_PVT.unpack_from(payload))
        else:
            by_itow[key][struct.unpack_from("<I", payload)[0]] = payload
    svinfo = not by_itow[NAV_SAT] and bool(by_itow[NAV_SVINFO])
    sat_frames = by_itow[NAV_SVINFO if svinfo else NAV_SAT]
    t = np.array([_utc_s(p) for p in pvts])
    if np.isnan(t).any():
        skipped["pvt_without_time"] += int(np.isnan(t).sum())
    pvts = [p for p, ti in zip(pvts, t, strict=True) if math.isfinite(ti)]
    t = t[np.isfinite(t)]
    n = len(pvts)
    sats = [_sats(sat_frames[p[0]], svinfo) if p[0] in sat_frames else None for p in pvts]
    prn, el, az, cn0, in_view, used = satellite_arrays(sats)
    col = np.array(pvts, dtype=np.float64).reshape(n, 28)  # (the 28 fields of _PVT)
    fix_type, flags = col[:, 10].astype(int), col[:, 11].astype(int)
    quality = np.array([_quality(ft, fl) for ft, fl in zip(fix_type, flags, strict=True)],
                       dtype=np.int8)
    fix = quality > 0
    height, hmsl = col[:, 16] * 1e-3, col[:, 17] * 1e-3
    dops = [by_itow[NAV_DOP].get(p[0]) for p in pvts]
    hdop = np.array([struct.unpack_from("<H", d, 12)[0] * 0.01 if d else math.nan for d in dops])
    vdop = np.array([struct.unpack_from("<H", d, 10)[0] * 0.01 if d else math.nan for d in dops])
    has_sats = np.array([row is not None for row in sats], bool)
    n_used = np.where(has_sats, used.sum(1), -1).astype(np.int64)
    num_sv = col[:, 13].astype(np.int64)
    nan = np.full(n, np.nan)
    return NmeaEpochs(
        t_unix_s=t, lat_deg=np.where(fix, col[:, 15] * 1e-7, nan),
        lon_deg=np.where(fix, col[:, 14] * 1e-7, nan), alt_msl_m=np.where(fix, hmsl, nan),
        geoid_sep_m=np.where(fix, height - hmsl, nan), quality=quality,
        mode=np.where(fix & (fix_type >= 3), 3, np.where(fix, 2, 1)).astype(np.int8),
        hdop=np.where(fix, hdop, nan), pdop=np.where(fix, col[:, 27] * 0.01, nan),
        vdop=np.where(fix, vdop, nan), speed_mps=np.where(fix, col[:, 23] * 1e-3, nan),
        course_deg=np.where(fix, col[:, 24] * 1e-5, nan),
        sats_used=num_sv, sats_used_gga=num_sv, sats_used_gsa=n_used,
        sats_in_view=np.where(has_sats, in_view.sum(1), -1).astype(np.int64),
        gsv_complete=has_sats, prn=prn, el_deg=el, az_deg=az, cn0_dbhz=cn0, in_view=in_view,
        used=used, line=np.arange(1, n + 1), n_bad=0,
    ), messages, skipped
