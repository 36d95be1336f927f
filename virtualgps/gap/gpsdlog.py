"""A gpsd JSON log (``gpspipe -w``, ``gpsdecode``) read as the epochs of an NMEA log.

A robot that runs gpsd often keeps what gpsd reports rather than the receiver's sentences:
``gpspipe -w > drive.json`` writes one JSON object a line (gpsd's client protocol,
https://gpsd.io/gpsd_json.html): a TPV per navigation cycle (time, mode, position, altitudes,
speed and track; ``status`` 2 for DGPS) and a SKY with the satellites (``PRN``, ``el``, ``az``,
``ss``, ``used``, and from gpsd 3.18 ``gnssid``/``svid``) and the DOPs, among VERSION, DEVICES,
WATCH and other objects, which are counted and left. The epochs come out as
:class:`~virtualgps.device.nmea.NmeaEpochs`, so the gap tool reads them as it reads NMEA:

- the TPVs of one time are an epoch (gpsd may report a cycle's fix after each of its
  sentences, each report adding to the last: they are merged in order); ``mode`` < 2 is one
  without a fix (its position is not taken); the fix quality is GGA's: 1, 2 for ``status`` 2
  (DGPS), 4/5 for RTK fixed/float, 6 for dead reckoning; a TPV without a time (gpsd's first
  reports, before an RMC dates the cycle) is counted and left;
- an epoch's SKY is the fullest one gpsd reported between the previous epoch's last TPV and
  its own (a SKY follows each system's GSV group, listing what the cycle has so far); a SKY
  with a time goes with the epoch of that time. gpsd 3.22 fed the MTK order and u-blox's
  gives each epoch its own sky so (``tests/test_gap_ingest.py``);
- ``ss`` 0 is a satellite not tracked and ``el``, ``az`` both 0 a position not known (gpsd
  3.22 prints 0 for NMEA's empty fields: the MT3339's SBAS satellites); ``used`` is GSA's
  list; satellites are numbered as :mod:`virtualgps.sky.systems` numbers them (by
  ``gnssid``/``svid``, else gpsd's ``PRN``, which uses the same ranges);
- ``altMSL`` (``alt`` before gpsd 3.20) and ``geoidSep`` are GGA's altitude and separation.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Sequence
from datetime import datetime

import numpy as np

from virtualgps.device.nmea import NmeaEpochs
from virtualgps.device.nmea.reader import satellite_arrays
from virtualgps.device.ubx.messages import numbers_of_ubx_ids
from virtualgps.exceptions import InputFileError

# gpsd's TPV status -> GGA quality: 2 DGPS, 3 RTK fixed, 4 RTK float, 5/6 dead reckoning
_STATUS_QUALITY = {2: 2, 3: 4, 4: 5, 5: 6, 6: 6}


def holds_gpsd_fixes(lines: Sequence[str]) -> bool:
    """Whether ``lines`` are a gpsd JSON log: some line is a TPV object (``"class":"TPV"``) and
    none an NMEA GGA, RMC or GLL sentence (``gpspipe -wr`` keeps both: the raw sentences, nearer
    the receiver, are read then)."""
    tpv = nmea = False
    for ln in lines:
        if '"TPV"' in ln and "{" in ln:
            tpv = True
        elif "$" in ln and any(k in ln for k in ("GGA,", "RMC,", "GLL,")):
            nmea = True
            break
    return tpv and not nmea


def _time_s(text: str) -> float:
    """UTC seconds of gpsd's ISO 8601 time (``2017-03-28T14:52:49.000Z``)."""
    return datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()


def _number(sat: dict) -> int | None:
    """A SKY satellite's number here (None: IMES, or a system's unknown slot)."""
    gnss, svid = sat.get("gnssid"), sat.get("svid")
    if isinstance(gnss, int) and isinstance(svid, int):
        return int(numbers_of_ubx_ids(gnss, svid)) or None  # (u-blox's gnssId convention)
    prn = sat.get("PRN")
    return int(prn) if isinstance(prn, int | float) and prn > 0 else None


def _listed(number: int, sat: dict) -> tuple[int, float, float, float, bool]:
    """(number, el, az, C/N0, used) of a SKY satellite: ``ss`` 0 is not tracked, and ``el``
    and ``az`` both 0 unknown (gpsd 3.22 prints 0 for NMEA's empty fields)."""
    e, a, ss = _float(sat, "el"), _float(sat, "az"), _float(sat, "ss")
    if e == 0.0 and a == 0.0:
        e = a = math.nan
    return number, e, a, ss if ss > 0 else math.nan, bool(sat.get("used", False))


def _float(obj: dict, *keys: str) -> float:
    """The first of ``keys`` present in ``obj`` as a float, else NaN."""
    for k in keys:
        v = obj.get(k)
        if isinstance(v, int | float) and not isinstance(v, bool):
            return float(v)
    return math.nan


def gpsd_epochs(lines: Sequence[str], source: object) -> tuple[NmeaEpochs, Counter, Counter]:
    """The epochs of a gpsd JSON log (see the module's docstring).

    Parameters
    ----------
    lines : the log's text lines (text before a line's first ``{``, a ``gpspipe -t`` time
        stamp, is ignored)
    source : the log, for error messages

    Returns
    -------
    epochs : one per time of the TPVs, in the order the times first appear (``dated`` True:
        gpsd's times carry dates)
    objects : {class: objects read} (TPV, SKY, ...)
    skipped : {reason: lines}: ``not_json``, ``tpv_without_time``, and each class the gap
        tool does not read (``not_used``)

    Raises
    ------
    InputFileError : the TPVs of several devices (naming them): give one receiver's
    """
    objects: Counter = Counter()
    skipped: Counter = Counter()
    tpvs: list[tuple[int, float, dict]] = []  # (line, time, object)
    skies: list[tuple[int, float, dict]] = []  # (line, time or NaN, object)
    devices: list[str] = []
    for no, raw in enumerate(lines, start=1):
        k = raw.find("{")
        if k < 0:
            if raw.strip():
                skipped["not_json"] += 1
            continue
        try:
            obj = json.loads(raw[k:])
            cls = obj["class"]
            t = _time_s(obj["time"]) if isinstance(obj.get("time"), str) else math.nan
        except (ValueError, KeyError, TypeError):
            skipped["not_json"] += 1
            continue
        objects[cls] += 1
        if cls == "TPV":
            if not math.isfinite(t):
                skipped["tpv_without_time"] += 1  # (before RMC or ZDA dates a cycle)
                continue
            dev = str(obj.get("device", ""))
            if dev not in devices:
                devices.append(dev)
            tpvs.append((no, t, obj))
        elif cls == "SKY":
            skies.append((no, t, obj))
        else:
            skipped["not_used"] += 1
    if len(devices) > 1:
        raise InputFileError(source, "holds the fixes of several devices ("
                             + ", ".join(devices) + "): give one receiver's log (gpspipe -w "
                             "for one device, or filter the lines of its \"device\")")
    cycles = _cycles(tpvs)
    return _epochs(cycles, _skies_of(cycles, skies)), objects, skipped


def _cycles(tpvs: list[tuple[int, float, dict]]) -> list[tuple[int, int, float, dict]]:
    """One TPV per time: gpsd may report a cycle's fix more than once (after each sentence
    until it has learned which one ends the cycle), each report adding what the last sentence
    told, so a time's reports are merged in order. Returns (first line, last line, time,
    merged TPV) in the order the times first appear."""
    out: dict[float, list] = {}
    for no, t, obj in tpvs:
        if t in out:
            out[t][1] = no
            out[t][3] = {**out[t][3], **obj}
        else:
            out[t] = [no, no, t, dict(obj)]
    return [tuple(c) for c in out.values()]


def _skies_of(cycles: list, skies: list) -> list[dict | None]:
    """Each cycle's SKY: where the SKYs carry times, the fullest of its time; else the fullest
    of those reported after the previous cycle's last TPV and before its own last one (gpsd
    reports a SKY after each system's GSV group, each listing what the cycle has so far), else
    the last one before (the sky persists), else the first of the log."""

    def fullest(cands: list[dict]) -> dict | None:
        return max(reversed(cands), key=lambda s: len(s.get("satellites") or []), default=None)

    timed: dict[float, list[dict]] = {}
    for _, t, s in skies:
        if math.isfinite(t):
            timed.setdefault(t, []).append(s)
    if timed or not cycles:
        return [fullest(timed.get(t, [])) for _, _, t, _ in cycles]
    # each cycle's window of the log, found by bisection (a scan per cycle was quadratic: 15 s
    # for an hour at 5 Hz)
    lines = np.array([no for no, _, _ in skies], dtype=np.int64)
    ends = np.array([end for _, end, _, _ in cycles], dtype=np.int64)
    lo = np.searchsorted(lines, np.concatenate([[0], ends[:-1]]), side="right")
    hi = np.searchsorted(lines, ends, side="left")
    out: list[dict | None] = []
    for a, b in zip(lo.tolist(), hi.tolist(), strict=True):
        window = fullest([s for _, _, s in skies[a:b]])
        out.append(window or (skies[b - 1][2] if b > 0 else (skies[0][2] if skies else None)))
    return out


def _epochs(cycles: list, sky_of: list[dict | None]) -> NmeaEpochs:
    """The arrays of :class:`NmeaEpochs` from the cycles' TPVs and their SKYs."""
    tpvs = [(first, t, obj) for first, _, t, obj in cycles]
    n = len(tpvs)
    sats = [None if sky is None else [_listed(num, s) for s in sky.get("satellites") or []
                                      if isinstance(s, dict) and (num := _number(s))]
            for sky in sky_of]
    prn, el, az, cn0, in_view, used = satellite_arrays(sats)
    mode = np.array([int(o.get("mode", 0) or 0) for _, _, o in tpvs], dtype=np.int8)
    fix = mode >= 2
    lat = np.array([_float(o, "lat") for _, _, o in tpvs])
    lon = np.array([_float(o, "lon") for _, _, o in tpvs])
    alt_msl = np.array([_float(o, "altMSL", "alt") for _, _, o in tpvs])
    alt_hae = np.array([_float(o, "altHAE") for _, _, o in tpvs])
    geoid = np.array([_float(o, "geoidSep") for _, _, o in tpvs])
    geoid = np.where(np.isnan(geoid), alt_hae - alt_msl, geoid)
    status = [int(o.get("status", 1) or 1) for _, _, o in tpvs]
    quality = np.where(fix, [_STATUS_QUALITY.get(s, 1) for s in status], 0).astype(np.int8)
    has_sky = np.array([sky is not None for sky in sky_of], bool)
    n_used = np.where(has_sky, used.sum(1), -1).astype(np.int64)
    n_view = np.array([int(sky.get("nSat", len(r))) if sky is not None else -1
                       for sky, r in zip(sky_of, sats, strict=True)], dtype=np.int64)
    skyf = [sky or {} for sky in sky_of]
    return NmeaEpochs(
        t_unix_s=np.array([t for _, t, _ in tpvs], dtype=np.float64),
        lat_deg=np.where(fix, lat, np.nan), lon_deg=np.where(fix, lon, np.nan),
        alt_msl_m=np.where(fix, alt_msl, np.nan), geoid_sep_m=geoid,
        quality=quality, mode=mode,
        hdop=np.array([_float(s, "hdop") for s in skyf]),
        pdop=np.array([_float(s, "pdop") for s in skyf]),
        vdop=np.array([_float(s, "vdop") for s in skyf]),
        speed_mps=np.array([_float(o, "speed") for _, _, o in tpvs]),
        course_deg=np.array([_float(o, "track") for _, _, o in tpvs]),
        sats_used=n_used, sats_used_gga=np.full(n, -1, np.int64), sats_used_gsa=n_used,
        sats_in_view=n_view, gsv_complete=has_sky,
        prn=prn, el_deg=el, az_deg=az, cn0_dbhz=cn0, in_view=in_view, used=used,
        line=np.array([no for no, _, _ in tpvs], dtype=np.int64), n_bad=0,
    )
