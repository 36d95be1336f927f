"""Real runs for the gap tool: a real receiver's NMEA log and its truth, read as they come.
(gpsd's JSON of a receiver, ``gpspipe -w``, is read by :mod:`virtualgps.gap.gpsdlog` into the
same epochs, a u-blox's UBX by :mod:`virtualgps.gap.ubxlog`; a ROS bag's
``nmea_msgs/Sentence`` topic as the lines of a log, its ``sensor_msgs/NavSatFix`` messages as
fixes without satellites.)

Logs are read the way receivers and loggers write them (:func:`virtualgps.device.nmea.
nmea_epochs_from_lines`: text before ``$``, any talker, GSV without SNR, missing sentence
types, binary noise, bad checksums, truncated lines, a midnight in the log); nothing raises on a
bad line: every skipped line is counted by reason and reported. A fix is any GGA quality above
0 with a position (phones write 7 on every fix); in a log without GGA, an RMC or GLL position
with status A. Epochs are put in time order, one per time. A log that no RMC or ZDA dates takes
the date of its truth's times.

The truth is a pose log of DESIGN section 4 (any format, geodetic or scene ENU), ``static``
(stood still at an unknown point: the run's median fix) or ``static:LAT,LON,ALT_HAE``. Where the
truth moves, a constant clock offset between log and truth is estimated
(:func:`estimate_time_offset_s`) and applied when it clearly improves the match.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, fields, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from virtualgps import geodesy
from virtualgps.device.nmea import (
    NmeaEpochs,
    UndatedLogError,
    nmea_epochs_from_lines,
    read_log_bytes,
    text_lines,
)
from virtualgps.exceptions import ConfigError, InputFileError
from virtualgps.gap import gpsdlog, ubxlog
from virtualgps.gap.metrics import median_position
from virtualgps.poses import logs as pose_logs
from virtualgps.poses import pose, rosbag
from virtualgps.receiver.definition import Georef

TRUTH_MAX_GAP_S = 3.0  # truth poses further apart than this leave the epochs between unknown
MOVING_PATH_M = 30.0  # a truth whose path is longer than this "moves": its clock offset is sought
# Clock offsets searched (seconds either way): the first window, widened while the best lies at
# its end. GPS time against UTC is 18 s (since 2017); a truth logged with a clock that drifted
# or was set by hand may be minutes off. Hours (a time zone) are no offset of a clock: the log
# and the truth then do not overlap, which is its own clear error.
OFFSET_WINDOWS_S = (30.0, 120.0, 600.0)
OFFSET_MIN_GAIN = 0.9  # apply an offset only if it lowers the median distance by 10 % or more
# Offsets up to this are reported, not applied: a receiver's own lag looks the same (an output
# latency of up to ~2 s, a navigation filter's lag of its time constant, several seconds).
LATENCY_LIKE_S = 5.0
KNOWN = {"GGA", "RMC", "GSA", "GSV", "VTG", "GLL", "ZDA", "GNS", "GST", "TXT"}
# Epochs further apart than this split a log into stretches. A stretch without a fix is left
# out: a receiver whose clock is not set yet prints a placeholder time (mtk-3301.log counts
# from 23:59:46 until its first fix at 08:14:36), which says nothing of when it ran.
CLOCK_JUMP_S = 3600.0
# A run of one session spans at most this: the time grids of its statistics are sized by it (a
# log of epochs decades apart would fill the memory)
MAX_RUN_SPAN_S = 7 * 86400.0


@dataclass(frozen=True)
class Truth:
    """Where the antenna really was.

    kind : "track" (a pose log), "static" (an unknown point: the run's median fix), or
        "static_point" (``static:LAT,LON,ALT_HAE``)
    track : the poses as read (geodetic or scene ENU frame), for "track"
    lat_deg, lon_deg, alt_hae_m : the point, for "static_point" (degrees, metres HAE)
    source : the spec or file it came from
    """

    kind: str
    track: pose.PoseTrack | None = None
    lat_deg: float = math.nan
    lon_deg: float = math.nan
    alt_hae_m: float = math.nan
    source: str = ""


@dataclass(frozen=True)
class RealRun:
    """One real run: its log's epochs, its truth and what reading them found.

    time_offset_s : real log time = truth time + time_offset_s
    offset_info : how the offset was found ({"method", ...})
    skipped : {reason: lines}; sentences : {sentence type: valid sentences read};
    quality_codes : {GGA quality: epochs}
    has_gsv : some GSV lists a GPS PRN (1-32) with an elevation; has_cn0 : some GPS SNR;
    has_gsa : some GSA lists PRNs
    dated_by : "log" (its RMC/ZDA) or "truth" (a log without dates, dated by its truth's times)
    """

    name: str
    path: Path
    epochs: NmeaEpochs
    truth: Truth
    time_offset_s: float = 0.0
    offset_info: dict = field(default_factory=dict)
    skipped: dict = field(default_factory=dict)
    sentences: dict = field(default_factory=dict)
    quality_codes: dict = field(default_factory=dict)
    has_gsv: bool = False
    has_cn0: bool = False
    has_gsa: bool = False
    dated_by: str = "log"


def parse_truth(spec: str) -> Truth:
    """Read a truth spec: ``static``, ``static:LAT,LON,ALT_HAE`` or a pose log path (a ROS
    bag's pose topic named after it where it has several: ``run.bag:/ground_truth``).

    Raises
    ------
    ConfigError : a malformed ``static:`` spec (the message says the expected form)
    InputFileError : an unreadable or malformed pose log
    """
    if spec == "static":
        return Truth("static", source=spec)
    if spec.startswith("static:"):
        parts = spec[len("static:"):].split(",")
        try:
            lat, lon, alt = (float(p) for p in parts)
        except ValueError:
            raise ConfigError(f"--truth {spec!r}: expected static:LAT,LON,ALT_HAE (degrees, "
                              "degrees, metres above the ellipsoid)") from None
        if not (abs(lat) <= 90.0 and abs(lon) <= 180.0 and math.isfinite(alt)):
            raise ConfigError(f"--truth {spec!r}: latitude must be within +-90 and longitude "
                              "within +-180 degrees")
        return Truth("static_point", None, lat, lon, alt, spec)
    log, topic = rosbag.split_topic(spec)
    path = Path(log)
    if not path.exists():
        raise ConfigError(f"--truth {spec!r}: no such file; give a pose log, 'static' or "
                          "static:LAT,LON,ALT_HAE")
    return Truth("track", pose_logs.read_pose_log(path, topic), source=spec)


def _census(tally: Counter) -> tuple[Counter, Counter]:
    """Valid sentences per type, and lines skipped by reason, from the reader's tally of the
    log's lines (:func:`virtualgps.device.nmea.reader.nmea_epochs_from_lines`)."""
    sentences: Counter = Counter()
    skipped: Counter = Counter()
    for what, n in tally.items():
        if what in ("not_nmea", "truncated", "bad_checksum"):
            skipped[what] += n
            continue
        kind = what[-3:] if not what.startswith("P") else "proprietary"
        if kind in KNOWN:
            sentences[kind] += n
        else:
            skipped["not_used" if kind == "proprietary" else f"unknown_{kind}"] += n
    return sentences, skipped


def take_epochs(epochs: NmeaEpochs, keep: np.ndarray) -> NmeaEpochs:
    """The epochs at the indices (or mask) ``keep``, every per-epoch array cut alike."""
    n = len(epochs)
    cut = {f.name: getattr(epochs, f.name)[keep] for f in fields(epochs)
           if isinstance(getattr(epochs, f.name), np.ndarray)
           and getattr(epochs, f.name).shape[:1] == (n,)}
    return replace(epochs, **cut)


def read_real_log(path: str | Path, near_unix_s: float | None = None, topic: str | None = None
                  ) -> tuple[NmeaEpochs, dict, dict, str]:
    """Read a real NMEA log as time-ordered epochs, one per time; stretches of epochs without
    a fix that lie more than :data:`CLOCK_JUMP_S` apart from those with one are left out
    (``epochs_clock_not_set``).

    path : a log (NMEA, gpsd's JSON: :mod:`virtualgps.gap.gpsdlog`, UBX:
        :mod:`virtualgps.gap.ubxlog`), or a ROS bag
        of the receiver's sentences or fixes (:func:`virtualgps.poses.rosbag.read_bag_receiver`)
    near_unix_s : UTC seconds near the log's start (its truth's first pose), which dates a log
        that no RMC or ZDA dates (a GGA-only log): its first epoch goes on the day that puts it
        nearest this time. None: such a log is an error.
    topic : the bag's receiver topic (None: its only sentence topic, else NavSatFix topic)

    Returns
    -------
    epochs : NmeaEpochs
    skipped : {reason: lines (epochs for ``duplicate_epoch`` and ``epochs_clock_not_set``)}
    sentences : {type: valid sentences}
    dated_by : ``"log"`` (its RMC/ZDA) or ``"truth"`` (``near_unix_s``)

    Raises
    ------
    InputFileError : unreadable, empty, undated without ``near_unix_s``, no epoch with a fix,
        or fixes spanning more than :data:`MAX_RUN_SPAN_S` (one clear line)
    """
    try:
        got = (rosbag.read_bag_receiver(path, topic) if rosbag.is_bag(path)
               else read_log_bytes(path))
    except OSError as e:
        raise InputFileError(path, f"cannot read the NMEA log: {e.strerror}") from None
    dated_by = "log"
    frames = ubxlog.ubx_frames(got) if isinstance(got, bytes) else None
    lines = text_lines(got) if isinstance(got, bytes) and frames is None else got
    if isinstance(got, rosbag.BagFixes):
        ep, sentences = _navsatfix_epochs(got), Counter(NavSatFix=got.status.size)
        skipped: Counter = Counter()
    elif frames is not None:
        ep, sentences, skipped = ubxlog.ubx_epochs(frames)
    elif not any(ln.strip() for ln in lines):
        raise InputFileError(path, "the log is empty")
    elif gpsdlog.holds_gpsd_fixes(lines):
        ep, sentences, skipped = gpsdlog.gpsd_epochs(lines, path)
    else:
        ep, sentences, skipped, dated_by = _read_nmea(lines, path, near_unix_s)
    ok = np.isfinite(ep.t_unix_s)
    order = np.argsort(np.where(ok, ep.t_unix_s, np.inf), kind="stable")
    order = order[ok[order]]
    t = ep.t_unix_s[order]
    first = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)
    if (~first).any():
        skipped["duplicate_epoch"] = int((~first).sum())
    ep = take_epochs(ep, order[first])
    fix = (ep.quality > 0) & np.isfinite(ep.lat_deg)
    if not fix.any():
        raise InputFileError(path, "no epoch of the log has a fix (GGA quality > 0 with a "
                             "position)")
    stretch = np.concatenate([[0], np.cumsum(np.diff(ep.t_unix_s) > CLOCK_JUMP_S)])
    kept = np.isin(stretch, stretch[fix])
    if not kept.all():
        skipped["epochs_clock_not_set"] = int((~kept).sum())
        ep = take_epochs(ep, kept)
    span_s = float(ep.t_unix_s[-1] - ep.t_unix_s[0])
    if span_s > MAX_RUN_SPAN_S:
        raise InputFileError(path, f"its epochs with a fix span {span_s / 86400.0:.0f} days: a "
                             "run is one session of a receiver; give each session as its own "
                             "--real log")
    return ep, {k: int(v) for k, v in skipped.items() if v}, dict(sentences), dated_by


def _read_nmea(lines: list[str], path: str | Path, near_unix_s: float | None
               ) -> tuple[NmeaEpochs, Counter, Counter, str]:
    """The epochs of an NMEA log in file order, its sentences per type, the lines skipped by
    reason and what dated it (see :func:`read_real_log`)."""
    tally: Counter = Counter()
    near_date = (None if near_unix_s is None
                 else datetime.fromtimestamp(near_unix_s, UTC).date())
    try:
        ep = nmea_epochs_from_lines(lines, path, near_date, tally)
    except UndatedLogError:
        raise InputFileError(path, "no RMC or ZDA sentence gives the date of its epochs; "
                             "give a log with RMC or ZDA lines, or a truth pose log whose "
                             "times date it (--truth static cannot)") from None
    dated_by = "log" if ep.dated else "truth"
    if not ep.dated:
        ep = _dated_near(ep, near_unix_s)
    sentences, skipped = _census(tally)
    if not (sentences["GGA"] or sentences["RMC"] or sentences["GLL"]):
        raise InputFileError(path, "no GGA, RMC or GLL sentence: not an NMEA log of fixes "
                             "(nor a gpsd JSON log: no TPV)")
    if ep.n_bad > sum(skipped.values()):
        skipped["malformed_fields"] = ep.n_bad - skipped["bad_checksum"] - skipped["truncated"]
    if not sentences["GGA"]:
        # RMC or GLL alone: a position with status A is a fix (of quality unknown: 1)
        ep = replace(ep, quality=np.where(np.isfinite(ep.lat_deg), 1, 0).astype(np.int8))
    return ep, sentences, skipped, dated_by


# sensor_msgs/NavSatStatus status -> GGA quality: no fix, fix, SBAS (DGPS), GBAS (RTK)
_NAVSAT_QUALITY = {-1: 0, 0: 1, 1: 2, 2: 4}
#: what a real log's records are called where they hold an altitude and a fix quality (GGA's
#: fields): logs of RMC or GLL alone lack both
FULL_FIX_RECORDS = ("GGA", "TPV", "NAV-PVT", "NavSatFix")


def _navsatfix_epochs(fixes: rosbag.BagFixes) -> NmeaEpochs:
    """The epochs of a receiver's NavSatFix messages: positions, heights (above the ellipsoid:
    kept as EGM96 altitude plus separation) and fix qualities; no satellites, DOPs or speeds."""
    n = fixes.status.size
    nan = np.full(n, np.nan)
    sep = geodesy.geoid_sep_m(np.nan_to_num(fixes.lat_deg), np.nan_to_num(fixes.lon_deg))
    none = np.full(n, -1, np.int64)
    empty = np.zeros((n, 0))
    return NmeaEpochs(
        t_unix_s=fixes.t_unix_s, lat_deg=fixes.lat_deg, lon_deg=fixes.lon_deg,
        alt_msl_m=fixes.alt_hae_m - sep, geoid_sep_m=sep,
        quality=np.array([_NAVSAT_QUALITY.get(int(s), 1) for s in fixes.status], np.int8),
        mode=np.zeros(n, np.int8), hdop=nan, pdop=nan, vdop=nan, speed_mps=nan,
        course_deg=nan, sats_used=none, sats_used_gga=none, sats_used_gsa=none,
        sats_in_view=none, gsv_complete=np.zeros(n, bool), prn=np.zeros(0, np.int64),
        el_deg=empty, az_deg=empty, cn0_dbhz=empty, in_view=empty.astype(bool),
        used=empty.astype(bool), line=np.arange(1, n + 1), n_bad=0,
    )


def ingest_notes(run: dict) -> list[str]:
    """What the report says of how a run was read, for people: a log that its truth dated, a
    clock offset the search could not place. ``run``: the report's ``runs[]`` entry."""
    notes = []
    if run.get("dated_by") == "truth":
        notes.append("no RMC or ZDA dates its epochs: dated by its truth's times")
    if run.get("checksummed") is False:
        notes.append("no sentence carries a checksum (NMEA 0183 makes it optional): read "
                     "without, so a line cut short or corrupted cannot be told from a good one")
    off = run.get("offset") or {}
    if off.get("at_edge"):
        notes.append(f"its fixes match the truth best at a clock offset of {off['best_s']:+.0f} "
                     f"s, the end of the {off['searched_s'][1]:.0f} s searched: no offset was "
                     "taken out; check that the truth is this log's, and both clocks")
    return notes


def _dated_near(ep: NmeaEpochs, near_unix_s: float) -> NmeaEpochs:
    """Epochs dated on one day, moved by whole days so that the first lies nearest
    ``near_unix_s`` (a log that starts just before the truth's midnight)."""
    first = ep.t_unix_s[np.isfinite(ep.t_unix_s)]
    days = round((near_unix_s - first[0]) / 86400.0) if first.size else 0
    return replace(ep, t_unix_s=ep.t_unix_s + 86400.0 * days)


def load_run(real_path: str | Path, truth_spec: str, name: str | None = None) -> RealRun:
    """Read one run: its NMEA log and its truth, and estimate their clock offset.

    Parameters
    ----------
    real_path : the real receiver's log (NMEA, gpsd's JSON, UBX), or a ROS bag of its sentences
        or NavSatFix messages (``run.bag``, or ``run.bag:TOPIC`` where it has several)
    truth_spec : a pose log path (a bag's topic named so too), ``static`` or
        ``static:LAT,LON,ALT_HAE``
    name : the run's name (default: the log's file stem)

    Returns
    -------
    RealRun : its ``path`` as given (a bag with its topic)
    """
    log, topic = rosbag.split_topic(str(real_path))
    truth = parse_truth(truth_spec)
    ep, skipped, sentences, dated_by = read_real_log(log, _dating_time_s(truth), topic)
    gps = (ep.prn >= 1) & (ep.prn <= 32)
    run = RealRun(
        name=name or Path(log).stem, path=Path(real_path), epochs=ep, truth=truth,
        skipped=skipped, sentences=sentences, dated_by=dated_by,
        quality_codes={int(q): int(c) for q, c in zip(*np.unique(ep.quality, return_counts=True),
                                                       strict=True)},
        has_gsv=bool((ep.in_view[:, gps] & np.isfinite(ep.el_deg[:, gps])).any()),
        has_cn0=bool(np.isfinite(ep.cn0_dbhz[:, gps]).any()),
        has_gsa=bool((ep.sats_used_gsa >= 0).any()),
    )
    if truth.kind != "track":
        return replace(run, offset_info={"method": "none", "reason": "static truth"})
    if truth.track.frame != "geodetic":
        return replace(run, offset_info={"method": "none",
                                         "reason": "scene-frame truth (needs the scene)"})
    fixed = (ep.quality > 0) & np.isfinite(ep.lat_deg)
    offset, info = estimate_time_offset_s(ep.t_unix_s[fixed], ep.lat_deg[fixed],
                                          ep.lon_deg[fixed], truth.track)
    return replace(run, time_offset_s=offset, offset_info=info)


# The first GPS week: a truth's times before it are not dates (a pose log timed from 0)
GPS_EPOCH_UNIX_S = 315964800.0


def _dating_time_s(truth: Truth) -> float | None:
    """The truth's first time where it can date a log (a pose log on the UTC clock), else None."""
    if truth.kind != "track" or not len(truth.track):
        return None
    t0 = float(truth.track.t_unix_s[0])
    return t0 if t0 >= GPS_EPOCH_UNIX_S else None


def _horizontal_m(lat_deg, lon_deg, ref_lat_deg, ref_lon_deg) -> np.ndarray:
    """Local horizontal distances, metres (equirectangular: fine over a few hundred metres)."""
    r = 6371000.0
    dn = np.radians(lat_deg - ref_lat_deg) * r
    de = np.radians(lon_deg - ref_lon_deg) * r * np.cos(np.radians(ref_lat_deg))
    return np.hypot(de, dn)


def _median_dist(offset_s: float, t, lat, lon, track: pose.PoseTrack) -> float:
    return _median_dist_n(offset_s, t, lat, lon, track)[0]


def _median_dist_n(offset_s: float, t, lat, lon, track: pose.PoseTrack) -> tuple[float, int]:
    """Median horizontal distance, metres, of the fixes to the truth at ``t - offset_s``, and
    the number of fixes the truth covers there (inf under 10)."""
    p, _, ok = pose.interpolate(track, t - offset_s, TRUTH_MAX_GAP_S)
    n = int(ok.sum())
    if n < 10:
        return math.inf, n
    return float(np.median(_horizontal_m(lat[ok], lon[ok], p[ok, 0], p[ok, 1]))), n


def estimate_time_offset_s(
    real_t_unix_s: np.ndarray, real_lat_deg: np.ndarray, real_lon_deg: np.ndarray,
    truth: pose.PoseTrack, windows_s: tuple[float, ...] = OFFSET_WINDOWS_S,
) -> tuple[float, dict]:
    """A constant clock offset between a real log and a moving geodetic truth.

    The offset minimises the median horizontal distance between the real fixes and the truth
    at ``t - offset``: a 1 s grid over +-``windows_s[0]``, widened to the next window while the
    best lies at the grid's end, then golden-section refinement to 0.02 s around the best.
    Offsets where the truth covers under half the fixes it covers at its best overlap are not
    candidates (a few fixes that happen to lie on the track). It is sought only where the
    truth moves (a path over MOVING_PATH_M), and applied only when it lowers the distance by
    10 % or more against no offset, exceeds LATENCY_LIKE_S (a smaller lag cannot be told from
    the receiver's own output latency, the ``latency`` effect, which the diagnosis then
    measures) and lies inside the widest window (``at_edge``: the clocks differ by more, or
    the truth is not this log's); it is reported either way.

    Returns
    -------
    offset_s : float, real time = truth time + offset_s
    info : {"method", "searched_s", "median_m_at_0", "median_m", "best_s", "at_edge",
        "applied"}
    """
    xyz = truth.xyz
    path_m = float(np.sum(_horizontal_m(xyz[1:, 0], xyz[1:, 1], xyz[:-1, 0], xyz[:-1, 1])))
    if path_m < MOVING_PATH_M or real_t_unix_s.size < 30:
        return 0.0, {"method": "none", "reason": f"the truth does not move ({path_m:.0f} m)"}
    args = (real_t_unix_s, real_lat_deg, real_lon_deg, truth)
    tried: dict[float, tuple[float, int]] = {}
    for width in windows_s:
        grid = np.arange(-width, width + 0.5, 1.0)
        for o in grid:
            if float(o) not in tried:
                tried[float(o)] = _median_dist_n(float(o), *args)
        cost = np.array([tried[float(o)][0] for o in grid])
        n = np.array([tried[float(o)][1] for o in grid])
        cost[n < 0.5 * n.max()] = math.inf
        k = int(np.argmin(cost))
        at_edge = bool(abs(grid[k]) >= width)
        if not at_edge:
            break
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = _median_dist(c, *args), _median_dist(d, *args)
    while b - a > 0.02:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = _median_dist(c, *args)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = _median_dist(d, *args)
    best = float(round((a + b) / 2.0, 2))
    at0, at_best = _median_dist(0.0, *args), _median_dist(best, *args)
    # A lag of a second or two is what a receiver's own output latency looks like (the
    # ``latency`` effect): it is reported, not removed; a larger one is a clock offset.
    applied = bool(at_best <= OFFSET_MIN_GAIN * at0 and abs(best) > LATENCY_LIKE_S
                   and not at_edge)
    info = {"method": "median distance to the truth, grid then golden section",
            "searched_s": [-width, width], "median_m_at_0": at0,
            "median_m": at_best, "best_s": float(best), "at_edge": at_edge,
            "applied": applied}
    return (best if applied else 0.0), info


def truth_positions(
    run: RealRun, t_unix_s: np.ndarray, georef: Georef | None = None,
    max_gap_s: float = TRUTH_MAX_GAP_S,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The truth at the real log's epochs (the clock offset applied).

    Parameters
    ----------
    run : the run
    t_unix_s : (n,) UTC seconds, the real epochs
    georef : the scene origin (needed for a truth in the scene's ENU frame)
    max_gap_s : truth poses further apart than this, seconds, leave the epochs between
        unknown (those are interpolated linearly)

    Returns
    -------
    lat_deg, lon_deg, alt_hae_m : (n,) float, the truth (NaN where unknown)
    valid : (n,) bool, the truth is known (inside the truth's span, not in a gap over
        ``max_gap_s``)
    """
    n = np.asarray(t_unix_s).size
    tr = run.truth
    if tr.kind == "static_point":
        return (np.full(n, tr.lat_deg), np.full(n, tr.lon_deg), np.full(n, tr.alt_hae_m),
                np.ones(n, bool))
    if tr.kind == "static":
        ep = run.epochs
        ok = (ep.quality > 0) & np.isfinite(ep.lat_deg) & np.isfinite(ep.lon_deg)
        sep = np.where(np.isfinite(ep.geoid_sep_m), ep.geoid_sep_m,
                       geodesy.geoid_sep_m(np.nan_to_num(ep.lat_deg), np.nan_to_num(ep.lon_deg)))
        alt = np.where(np.isfinite(ep.alt_msl_m), ep.alt_msl_m + sep, np.nan)
        has_alt = ok & np.isfinite(alt)
        lat, lon, h = median_position(ep.lat_deg[ok], ep.lon_deg[ok],
                                      np.where(has_alt, alt, 0.0)[ok])
        if not has_alt.any():
            h = 0.0
        return np.full(n, lat), np.full(n, lon), np.full(n, h), np.ones(n, bool)
    track = tr.track
    if track.frame != "geodetic":
        if georef is None:
            raise ConfigError(f"--truth {tr.source}: a truth in scene coordinates (x, y, z) "
                              "needs a scene with a georeference (--scene)")
        track = _enu_track_to_geodetic(track, georef)
    p, _, ok = pose.interpolate(track, np.asarray(t_unix_s, float) - run.time_offset_s,
                                max_gap_s)
    return p[:, 0], p[:, 1], p[:, 2], ok


def _enu_track_to_geodetic(track: pose.PoseTrack, georef: Georef) -> pose.PoseTrack:
    """A scene-frame track as geodetic poses (lat, lon, alt HAE)."""
    ecef = geodesy.enu_to_ecef(track.xyz, georef.lat0_deg, georef.lon0_deg, georef.alt0_hae_m)
    lat, lon, alt = geodesy.ecef_to_geodetic(ecef)
    return replace(track, frame="geodetic", xyz=np.stack([lat, lon, alt], axis=-1))
