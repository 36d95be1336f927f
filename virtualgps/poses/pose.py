"""Poses: the pose message, pose logs in every supported format, and interpolation in time.

Owns the pose contract of DESIGN section 4: one JSON object per message, with the antenna in
scene ENU metres (``x, y, z``) or WGS-84 geodetic (``lat, lon`` and ``alt`` above the ellipsoid or
``alt_msl``), ``t`` in UTC Unix seconds (arrival time when absent) and optional ``vx, vy, vz``
(m/s, ENU). Logs (``.jsonl``, ``.csv``, TUM, NMEA) become a :class:`PoseTrack`; a track is
interpolated to epoch times with :func:`interpolate`.

Messages come from the network: :func:`parse_pose_message` raises nothing but
:class:`PoseError`, whatever the bytes. Logs are files: every problem is an
:class:`InputFileError` naming the file, the line and the expected layout.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps import geodesy
from virtualgps.device.nmea import nmea_fixes_from_lines, parse_sentence, read_text_lines
from virtualgps.exceptions import InputFileError, PoseError

FRAME_ENU = "enu"
FRAME_GEODETIC = "geodetic"

# A pose is ~100 bytes of JSON; anything far longer is not a pose (and bounds json's recursion).
MAX_MESSAGE_BYTES = 4096
MAX_RECEIVER_ID = 65535  # the "id" of a fleet's receiver (virtualgps run --receivers)
# Plausibility bounds: beyond them a value is an error, not a pose.
T_MAX_UNIX_S = 7.0e9  # year 2191
ENU_MAX_M = 1.0e7  # a scene frame is local; 10,000 km is already meaningless
ALT_MIN_M, ALT_MAX_M = -1.0e4, 1.0e5  # ocean trenches to 100 km
SPEED_MAX_MPS = 1.0e4

_JSONL_EXAMPLE = '{"t": 1711630000.25, "x": 12.0, "y": -3.5, "z": 0.0}'
_CSV_LAYOUT = (
    "a header naming t (or t_unix_s) and x,y,z or lat,lon,alt (or alt_msl), optional vx,vy,vz"
)
_TUM_LAYOUT = "8 numbers 't x y z qx qy qz qw' separated by spaces (TUM trajectory format)"


@dataclass(frozen=True)
class Pose:
    """One antenna pose.

    Attributes
    ----------
    t_unix_s : float, UTC seconds
    frame : ``"enu"`` (scene ENU) or ``"geodetic"`` (WGS-84)
    xyz : (3,) tuple: x, y, z metres (ENU), or lat_deg, lon_deg, alt_hae_m (geodetic)
    vel_enu_mps : (3,) tuple, m/s, local East/North/Up; NaN components where not given
    receiver_id : int, the receiver of a fleet the pose is for (the message's ``"id"``; 0
        where absent)
    """

    t_unix_s: float
    frame: str
    xyz: tuple[float, float, float]
    vel_enu_mps: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    receiver_id: int = 0


@dataclass(frozen=True)
class PoseTrack:
    """Poses in time order (strictly increasing times).

    Attributes
    ----------
    t_unix_s : (n,) float64, UTC seconds, strictly increasing
    frame : ``"enu"`` or ``"geodetic"``
    xyz : (n, 3) float64: scene ENU metres, or lat_deg, lon_deg, alt_hae_m
    vel_enu_mps : (n, 3) float64, m/s, ENU; NaN where not given
    """

    t_unix_s: np.ndarray
    frame: str
    xyz: np.ndarray
    vel_enu_mps: np.ndarray

    def __len__(self) -> int:
        return int(self.t_unix_s.shape[0])


# --- messages ---------------------------------------------------------------------------------


def _short(v: object) -> str:
    r = repr(v)
    return r if len(r) <= 40 else r[:37] + "..."


def _number(obj: Mapping[str, Any], key: str) -> float:
    """A finite float from a JSON value; PoseError("bad-number") otherwise."""
    v = obj[key]
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise PoseError("bad-number", f'"{key}" must be a number, got {_short(v)}')
    try:
        f = float(v)
    except OverflowError:
        raise PoseError("bad-number", f'"{key}" is too large: {_short(v)}') from None
    if not math.isfinite(f):
        raise PoseError("bad-number", f'"{key}" must be finite, got {_short(v)}')
    return f


def _check_time(t: float) -> float:
    if not 0.0 <= t <= T_MAX_UNIX_S:
        raise PoseError(
            "bad-time", f'"t" must be UTC Unix seconds between 0 and {T_MAX_UNIX_S:.0f}, got {t!r}'
        )
    return t


def _check_position(frame: str, xyz: tuple[float, float, float]) -> None:
    a, b, c = xyz
    if frame == FRAME_ENU:
        if max(abs(a), abs(b), abs(c)) > ENU_MAX_M:
            raise PoseError("out-of-range", f"x, y, z must be within +-{ENU_MAX_M:.0f} m")
    else:
        if not -90.0 <= a <= 90.0:
            raise PoseError("out-of-range", f'"lat" must be in [-90, 90] degrees, got {a!r}')
        if not -180.0 <= b <= 360.0:
            raise PoseError("out-of-range", f'"lon" must be in [-180, 360] degrees, got {b!r}')
        if not ALT_MIN_M <= c <= ALT_MAX_M:
            raise PoseError(
                "out-of-range",
                f"altitude must be in [{ALT_MIN_M:.0f}, {ALT_MAX_M:.0f}] m, got {c!r}",
            )


def pose_from_mapping(obj: Mapping[str, Any], arrival_unix_s: float) -> Pose:
    """Build a :class:`Pose` from a decoded JSON object (see :func:`parse_pose_message`).

    Parameters
    ----------
    obj : the message's keys and values
    arrival_unix_s : UTC seconds used when ``t`` is absent (NaN: ``t`` is required)

    Returns
    -------
    Pose

    Raises
    ------
    PoseError
        kinds ``no-position``, ``mixed-frames``, ``bad-number``, ``bad-time``, ``out-of-range``,
        ``bad-id``.
    """
    rid = obj.get("id", 0)
    if type(rid) is not int or not 0 <= rid <= MAX_RECEIVER_ID:
        raise PoseError("bad-id", f'"id" must be a receiver number 0..{MAX_RECEIVER_ID}, '
                        f"not {_short(repr(rid))}")
    enu_keys = [k for k in ("x", "y", "z") if k in obj]
    geo_keys = [k for k in ("lat", "lon", "alt", "alt_msl") if k in obj]
    if enu_keys and geo_keys:
        raise PoseError(
            "mixed-frames",
            f"give either x, y, z (scene ENU) or lat, lon, alt (geodetic), not both "
            f"({', '.join(enu_keys + geo_keys)})",
        )
    if "alt" in obj and "alt_msl" in obj:
        raise PoseError("mixed-frames", 'give either "alt" (ellipsoidal) or "alt_msl", not both')
    if enu_keys:
        missing = [k for k in ("x", "y", "z") if k not in obj]
        if missing:
            raise PoseError("no-position", f"ENU pose lacks {', '.join(missing)}")
        frame = FRAME_ENU
        xyz = (_number(obj, "x"), _number(obj, "y"), _number(obj, "z"))
    elif geo_keys:
        missing = [k for k in ("lat", "lon") if k not in obj]
        if "alt" not in obj and "alt_msl" not in obj:
            missing.append("alt (or alt_msl)")
        if missing:
            raise PoseError("no-position", f"geodetic pose lacks {', '.join(missing)}")
        frame = FRAME_GEODETIC
        lat, lon = _number(obj, "lat"), _number(obj, "lon")
        alt = _number(obj, "alt" if "alt" in obj else "alt_msl")
        _check_position(frame, (lat, lon, alt))
        if "alt_msl" in obj:
            alt += float(geodesy.geoid_sep_m(lat, lon))  # h = H + N (EGM96)
        xyz = (lat, lon, alt)
    else:
        raise PoseError("no-position", "pose has no x, y, z nor lat, lon, alt")
    _check_position(frame, xyz)

    if obj.get("t") is None:  # absent or null: the arrival time
        if not math.isfinite(arrival_unix_s):
            raise PoseError("bad-time", 'pose lacks "t" (UTC Unix seconds)')
        t = _check_time(float(arrival_unix_s))
    else:
        t = _check_time(_number(obj, "t"))

    vel = []
    for k in ("vx", "vy", "vz"):
        if obj.get(k) is None:
            vel.append(math.nan)
            continue
        v = _number(obj, k)
        if abs(v) > SPEED_MAX_MPS:
            raise PoseError("out-of-range", f'"{k}" must be within +-{SPEED_MAX_MPS:.0f} m/s')
        vel.append(v)
    return Pose(t_unix_s=t, frame=frame, xyz=xyz, vel_enu_mps=(vel[0], vel[1], vel[2]),
                receiver_id=rid)


def parse_pose_message(data: bytes | str, arrival_unix_s: float) -> Pose:
    """Decode one pose message (a UDP datagram, or one TCP/stdin/JSONL line).

    Parameters
    ----------
    data : UTF-8 JSON text of one object, e.g. ``{"t": 1711630000.25, "x": 12.0, "y": -3.5,
        "z": 0.0}`` or ``{"lat": 52.14, "lon": 11.64, "alt_msl": 55.0}``; unknown keys ignored
    arrival_unix_s : UTC seconds the message arrived; used when ``t`` is absent or null

    Returns
    -------
    Pose : geodetic altitude converted to height above the ellipsoid (``alt_msl`` + EGM96 N)

    Raises
    ------
    PoseError
        and nothing else, whatever the input. ``kind`` is one of ``too-long``, ``not-json``,
        ``not-object``, ``no-position``, ``mixed-frames``, ``bad-number`` (not a number, NaN,
        infinite, boolean), ``bad-time`` (outside 0 .. 7e9 s), ``out-of-range``.
    """
    if isinstance(data, bytes | bytearray | memoryview):
        if len(data) > MAX_MESSAGE_BYTES:
            raise PoseError(
                "too-long", f"pose message of {len(data)} bytes exceeds {MAX_MESSAGE_BYTES}"
            )
        try:
            text = bytes(data).decode("utf-8")
        except UnicodeDecodeError:
            raise PoseError("not-json", "pose message is not UTF-8 text") from None
    elif isinstance(data, str):
        text = data
        if len(text) > MAX_MESSAGE_BYTES:
            raise PoseError(
                "too-long", f"pose message of {len(text)} characters exceeds {MAX_MESSAGE_BYTES}"
            )
    else:
        raise PoseError(
            "not-json", f"pose message must be bytes or text, got {type(data).__name__}"
        )
    try:
        obj = json.loads(text)
    except (ValueError, RecursionError) as e:  # JSONDecodeError, int digit limit, deep nesting
        raise PoseError("not-json", f"pose message is not JSON: {_short(str(e))}") from None
    if not isinstance(obj, dict):
        raise PoseError(
            "not-object", f"pose message must be a JSON object, got {type(obj).__name__}"
        )
    try:
        return pose_from_mapping(obj, arrival_unix_s)
    except PoseError:
        raise
    except Exception as e:  # the contract: a message never raises anything but PoseError
        raise PoseError("bad-number", f"pose message could not be read: {_short(str(e))}") from None


# --- tracks -----------------------------------------------------------------------------------


def from_poses(poses: Sequence[Pose]) -> PoseTrack:
    """Make a track of poses received in any order (e.g. UDP).

    Poses are sorted by time; of poses with equal times the last one given wins (a correction).

    Parameters
    ----------
    poses : poses, all in one frame

    Returns
    -------
    PoseTrack : possibly empty (then frame ``"enu"``)

    Raises
    ------
    PoseError
        ``mixed-frames`` when the poses are not all in one frame.
    """
    if not poses:
        z = np.zeros((0, 3))
        return PoseTrack(np.zeros(0), FRAME_ENU, z, z.copy())
    frame = poses[0].frame
    if any(p.frame != frame for p in poses):
        raise PoseError("mixed-frames", "poses mix scene ENU and geodetic positions")
    t = np.array([p.t_unix_s for p in poses], dtype=np.float64)
    xyz = np.array([p.xyz for p in poses], dtype=np.float64).reshape(-1, 3)
    vel = np.array([p.vel_enu_mps for p in poses], dtype=np.float64).reshape(-1, 3)
    # the last pose of each time: stable sort of the reversed list, first of each time
    rev = np.arange(len(poses))[::-1]
    order = rev[np.argsort(t[rev], kind="stable")]
    t_sorted = t[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = t_sorted[1:] != t_sorted[:-1]
    keep = order[first]
    return PoseTrack(t[keep], frame, xyz[keep], vel[keep])


def to_enu(track: PoseTrack, lat0_deg: float, lon0_deg: float, alt0_hae_m: float) -> PoseTrack:
    """Express a geodetic track in the scene's ENU frame (ENU tracks are returned unchanged).

    Velocities, given in each pose's local ENU frame, are rotated into the origin's ENU frame
    (exact; the rotation differs from identity by the angle between the two verticals).

    Parameters
    ----------
    track : the track
    lat0_deg, lon0_deg, alt0_hae_m : the scene origin (degrees, metres above the ellipsoid)

    Returns
    -------
    PoseTrack : frame ``"enu"``, xyz in metres
    """
    if track.frame == FRAME_ENU:
        return track
    ecef = geodesy.geodetic_to_ecef(track.xyz[:, 0], track.xyz[:, 1], track.xyz[:, 2])
    enu = geodesy.ecef_to_enu(ecef, lat0_deg, lon0_deg, alt0_hae_m)
    rot0 = geodesy.ecef_to_enu_matrix(lat0_deg, lon0_deg)  # (3, 3)
    rot_p = geodesy.ecef_to_enu_matrix(track.xyz[:, 0], track.xyz[:, 1])  # (n, 3, 3)
    vel_ecef = np.einsum("nji,nj->ni", rot_p, track.vel_enu_mps)
    vel = np.einsum("ij,nj->ni", rot0, vel_ecef)
    # NaN components stay NaN (a NaN in one component spreads through the rotation)
    vel = np.where(np.isnan(track.vel_enu_mps).any(axis=1, keepdims=True), np.nan, vel)
    return PoseTrack(track.t_unix_s.copy(), FRAME_ENU, enu.reshape(-1, 3), vel.reshape(-1, 3))


def interpolate(
    track: PoseTrack, t_unix_s: np.ndarray, max_gap_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions and velocities of a track at given times.

    Between two poses at most ``max_gap_s`` apart the position is interpolated linearly. The
    velocity is the track's own (interpolated linearly) where given, else the segment's finite
    difference, component by component. Past the last pose the position is extrapolated with
    the last velocity for up to ``max_gap_s`` (a live pose stream always lags the epoch a
    little; with one pose and no velocity the pose is held, velocity 0). Epochs before the first
    pose, more than ``max_gap_s`` after the last one, or inside a gap longer than ``max_gap_s``
    (except exactly at its poses) are not valid: there is no pose to report.

    Parameters
    ----------
    track : the poses (any frame; geodetic tracks interpolate degrees linearly, fine over
        ``max_gap_s`` of robot motion)
    t_unix_s : (n,) float, epoch times, UTC seconds (any order)
    max_gap_s : float, seconds

    Returns
    -------
    pos : (n, 3) float, the track's frame; NaN where not valid
    vel_enu_mps : (n, 3) float, m/s; NaN where not valid
    valid : (n,) bool
    """
    t = np.asarray(t_unix_s, dtype=np.float64).reshape(-1)
    n_q = t.shape[0]
    pos = np.full((n_q, 3), np.nan)
    vel = np.full((n_q, 3), np.nan)
    valid = np.zeros(n_q, dtype=bool)
    n = len(track)
    if n == 0:
        return pos, vel, valid
    tt, p, v = track.t_unix_s, track.xyz, track.vel_enu_mps
    finite = np.isfinite(t)
    i0 = np.searchsorted(tt, np.where(finite, t, -np.inf), side="right") - 1
    # Only the segments the epochs fall in (the live loop asks for one epoch of a lap or a
    # history of thousands of poses: per-pose work there would dominate), and only what the
    # epochs need: finite differences where the track has no velocity, the last pose's rate
    # for epochs after it.
    j = np.flatnonzero(finite & (i0 >= 0) & (i0 < n - 1))
    if j.size:
        a = i0[j]
        dt = tt[a + 1] - tt[a]
        w = ((t[j] - tt[a]) / dt)[:, None]
        pos[j] = p[a] + w * (p[a + 1] - p[a])
        v_i = v[a] + w * (v[a + 1] - v[a])
        no_vel = np.isnan(v_i)
        if no_vel.any():
            v_i = np.where(no_vel, _segment_velocity_enu(track, a), v_i)
        vel[j] = v_i
        valid[j] = (dt <= max_gap_s) | (t[j] == tt[a])

    j = np.flatnonzero(finite & (i0 == n - 1))
    if j.size:
        # The last pose's own velocity, else the last segment's finite difference, else 0 (hold).
        last_v = v[-1].copy()
        if n > 1 and np.isnan(last_v).any():
            last_v = np.where(np.isnan(last_v), _segment_velocity_enu(track, np.array([n - 2]))[0],
                              last_v)
        last_v = np.where(np.isnan(last_v), 0.0, last_v)
        # Coordinate rates per m/s of velocity: 1 for ENU tracks; for geodetic tracks (lat, lon,
        # h) rates per m/s (north, east, up): degrees over the radii of curvature there.
        last_rate = _enu_to_native(last_v[None, :], _rate_per_mps(p[-1:], track.frame),
                                   track.frame)[0]
        age = t[j] - tt[-1]
        pos[j] = p[-1] + age[:, None] * last_rate
        vel[j] = last_v
        valid[j] = age <= max_gap_s

    pos[~valid] = np.nan
    vel[~valid] = np.nan
    return pos, vel, valid


def _segment_velocity_enu(track: PoseTrack, seg: np.ndarray) -> np.ndarray:
    """The finite-difference velocity of segments ``seg`` (poses k -> k + 1) of a track.

    Returns
    -------
    vel_enu_mps : (len(seg), 3) float, ENU m/s
    """
    tt, p = track.t_unix_s, track.xyz
    rate = (p[seg + 1] - p[seg]) / (tt[seg + 1] - tt[seg])[:, None]  # native units per second
    return _native_to_enu(rate, _rate_per_mps(p[seg], track.frame), track.frame)


def _rate_per_mps(xyz: np.ndarray, frame: str) -> np.ndarray:
    """Coordinate rates per m/s of velocity at poses ``xyz`` (m, 3) of the track's frame.

    Returns
    -------
    k : (m, 3) float: ones for ENU tracks; for geodetic ones (lat, lon, h), degrees per metre
        north, degrees per metre east (the radii of curvature at the pose's height) and 1
    """
    if frame != FRAME_GEODETIC:
        return np.ones((len(xyz), 3))
    m_m, n_m = geodesy.radii_of_curvature_m(xyz[:, 0])
    coslat = np.maximum(np.cos(np.radians(xyz[:, 0])), 1e-12)
    return np.stack(
        [
            np.degrees(1.0 / (m_m + xyz[:, 2])),
            np.degrees(1.0 / ((n_m + xyz[:, 2]) * coslat)),
            np.ones(len(xyz)),
        ],
        axis=-1,
    )


def _native_to_enu(rate: np.ndarray, k: np.ndarray, frame: str) -> np.ndarray:
    """(m, 3) coordinate rates of the track's frame -> (m, 3) ENU m/s."""
    if frame != FRAME_GEODETIC:
        return rate
    e = rate / k  # (lat, lon, h) rates -> (north, east, up) m/s
    return np.stack([e[:, 1], e[:, 0], e[:, 2]], axis=-1)


def _enu_to_native(vel: np.ndarray, k: np.ndarray, frame: str) -> np.ndarray:
    """(m, 3) ENU m/s -> (m, 3) coordinate rates of the track's frame."""
    if frame != FRAME_GEODETIC:
        return vel
    return np.stack([vel[:, 1], vel[:, 0], vel[:, 2]], axis=-1) * k


# --- logs -------------------------------------------------------------------------------------

_NMEA_RE = re.compile(r"\$[A-Z]{2}[A-Z]{3},")


def _detect_format(path: Path, lines: list[str]) -> str:
    """``jsonl``, ``csv``, ``tum`` or ``nmea`` from the extension, else from the content."""
    ext = path.suffix.lower()
    if ext in (".jsonl", ".ndjson", ".json"):
        return "jsonl"
    if ext == ".csv":
        return "csv"
    if ext == ".tum":
        return "tum"
    if ext in (".nmea", ".nma", ".gps"):
        return "nmea"
    meaningful = [ln.strip() for ln in lines[:200] if ln.strip()]
    if any(_NMEA_RE.search(ln) and parse_sentence(ln) is not None for ln in meaningful[:50]):
        return "nmea"
    for ln in meaningful:
        if ln.startswith("#"):
            continue
        if ln.startswith("{"):
            return "jsonl"
        tokens = ln.split()
        if len(tokens) == 8 and all(_is_float(x) for x in tokens):
            return "tum"
        if re.search(r"[A-Za-z_]", ln) and re.search(r"[,;\t]", ln):
            return "csv"
        break
    raise InputFileError(
        path,
        "cannot tell the pose log format; expected .jsonl (one JSON pose per line), .csv with "
        "a header, TUM 't x y z qx qy qz qw' lines, or NMEA (GGA/RMC)",
    )


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def read_pose_log(path: str | Path, topic: str | None = None) -> PoseTrack:
    """Read a pose log, its format detected from the extension or the content.

    Formats (DESIGN section 4): ``.jsonl`` (one pose message per line, ``t`` required); ``.csv``
    with a header naming ``t`` (or ``t_unix_s``) and ``x,y,z`` or ``lat,lon,alt`` (or
    ``alt_msl``), optional ``vx,vy,vz`` (unit-suffixed names such as ``lat_deg``, ``alt_hae_m``,
    ``alt_msl_m``, ``x_m`` and ``vx_mps`` are accepted too); TUM trajectories (``t x y z qx qy qz
    qw``, ``#`` comments; x, y, z taken as scene ENU, the orientation ignored); NMEA logs (GGA
    fixes with quality > 0, dated by RMC/ZDA; height = altitude MSL + geoid separation, EGM96
    where the field is empty; lines with bad checksums are skipped, as a real log holds some);
    ROS 1 and ROS 2 bags (:mod:`virtualgps.poses.rosbag`; ``topic`` picks one where several fit).

    Times must not decrease; a pose repeating the previous pose's time exactly is dropped.

    Parameters
    ----------
    path : the log file (or ROS 2 bag folder)
    topic : the bag topic to read (bags only)

    Returns
    -------
    PoseTrack : ``"enu"`` (jsonl/csv with x,y,z; TUM; PoseStamped, Odometry) or ``"geodetic"``
        (lat/lon; NMEA; NavSatFix)

    Raises
    ------
    InputFileError
        naming the file, the line and the expected layout, for any malformed line, mixed
        frames, decreasing times or a log without poses.
    """
    from virtualgps.poses import rosbag

    path = Path(path)
    if rosbag.is_bag(path):
        return rosbag.read_bag(path, topic)
    if topic is not None:
        raise InputFileError(path, f"--topic {topic} is for ROS bags; this is not one")
    try:
        lines = read_text_lines(path)
    except OSError as e:
        raise InputFileError(path, f"cannot read the pose log: {e.strerror}") from None
    kind = _detect_format(path, lines)
    if kind == "jsonl":
        rows = _read_jsonl(path, list(enumerate(lines, start=1)))
    elif kind == "csv":
        rows = _read_csv(path, lines)
    elif kind == "tum":
        rows = _read_tum(path, lines)
    else:
        rows = _read_nmea(path, lines)
    return _finish(path, *rows)


def read_pose_logs_by_id(path: str | Path, topic: str | None = None) -> dict[int, PoseTrack]:
    """Read a pose log of one receiver or of a fleet: one track per receiver id.

    A JSONL log whose messages carry ``"id"`` (DESIGN section 4's message plus the receiver's
    number, as ``virtualgps run --receivers`` reads them live) gives each id its own track;
    lines without ``"id"`` are receiver 0's. Every other log is receiver 0's alone. Each
    receiver's poses must be in time order on their own (the ids may interleave).

    Parameters
    ----------
    path : the log file (or ROS 2 bag folder)
    topic : the bag topic to read (bags only)

    Returns
    -------
    tracks : {receiver id: PoseTrack}, ids in increasing order

    Raises
    ------
    InputFileError
        as :func:`read_pose_log`, naming the line.
    """
    path = Path(path)
    from virtualgps.poses import rosbag

    if rosbag.is_bag(path) or topic is not None:
        return {0: read_pose_log(path, topic)}
    try:
        lines = read_text_lines(path)
    except OSError as e:
        raise InputFileError(path, f"cannot read the pose log: {e.strerror}") from None
    if _detect_format(path, lines) != "jsonl" or not any('"id"' in ln for ln in lines):
        return {0: read_pose_log(path)}
    groups: dict[int, list[tuple[int, str]]] = {}
    for no, ln in enumerate(lines, start=1):
        if not ln.strip():
            continue
        try:
            obj = json.loads(ln)
            rid = obj.get("id", 0) if isinstance(obj, dict) else 0
        except (ValueError, RecursionError):
            rid = 0  # (reported with its line by the reader of receiver 0's poses)
        if type(rid) is not int:
            rid = -1  # (reported the same way: not a receiver number)
        groups.setdefault(rid, []).append((no, ln))
    if -1 in groups:
        _read_jsonl(path, groups[-1])  # raises, naming the first such line
    return {rid: _finish(path, *_read_jsonl(path, rows)) for rid, rows in sorted(groups.items())}


_Rows = tuple[np.ndarray, str, np.ndarray, np.ndarray, np.ndarray]  # t, frame, xyz, vel, line


# The layouts a JSONL log usually has, read in one vectorised pass (see _jsonl_uniform).
_JSONL_LAYOUTS = {
    frozenset("txyz"): FRAME_ENU, frozenset(("t", "x", "y", "z", "vx", "vy", "vz")): FRAME_ENU,
    frozenset(("t", "lat", "lon", "alt")): FRAME_GEODETIC,
    frozenset(("t", "lat", "lon", "alt", "vx", "vy", "vz")): FRAME_GEODETIC,
}


def _jsonl_uniform(lines: list[tuple[int, str]]) -> _Rows | None:
    """A log whose every line is a JSON object with one plain layout (t and x, y, z or lat,
    lon, alt, optionally vx, vy, vz) of finite numbers in range, read at once; None for any
    other log, which the line-by-line reader then reads or reports (the same poses either
    way: the same checks, vectorised)."""
    rows = [(no, ln) for no, ln in lines if ln.strip()]
    try:  # one parse of all lines as an array (a parse per line cost twice as much)
        objs = json.loads("[" + ",".join([ln for _, ln in rows]) + "]")
    except (ValueError, RecursionError):
        return None
    # (as many objects as lines: no line held two, or half of one)
    if not objs or len(objs) != len(rows) or not all(type(o) is dict for o in objs):
        return None
    keys0 = frozenset(objs[0])
    frame = _JSONL_LAYOUTS.get(keys0)
    if frame is None or any(len(o) != len(keys0) or o.keys() != keys0 for o in objs):
        return None
    pos_keys = ("x", "y", "z") if frame == FRAME_ENU else ("lat", "lon", "alt")
    vel_keys = ("vx", "vy", "vz") if "vx" in keys0 else ()
    order = ("t", *pos_keys, *vel_keys)
    vals = [o[k] for o in objs for k in order]
    if not all(type(v) is float or type(v) is int for v in vals):  # (bool is not int here)
        return None
    try:
        a = np.array(vals, dtype=np.float64).reshape(len(objs), len(order))
    except OverflowError:
        return None
    t, xyz = a[:, 0], a[:, 1:4]
    vel = a[:, 4:7] if vel_keys else np.full((len(objs), 3), np.nan)
    ok = np.isfinite(a).all() and ((t >= 0.0) & (t <= T_MAX_UNIX_S)).all()
    if frame == FRAME_ENU:
        ok = ok and (np.abs(xyz) <= ENU_MAX_M).all()
    else:
        ok = ok and ((xyz[:, 0] >= -90.0) & (xyz[:, 0] <= 90.0) & (xyz[:, 1] >= -180.0)
                     & (xyz[:, 1] <= 360.0) & (xyz[:, 2] >= ALT_MIN_M)
                     & (xyz[:, 2] <= ALT_MAX_M)).all()
    ok = ok and (np.abs(vel[np.isfinite(vel)]) <= SPEED_MAX_MPS).all()
    if not ok:
        return None
    return t.copy(), frame, xyz.copy(), vel.copy(), np.array([no for no, _ in rows], np.int64)


def _read_jsonl(path: Path, lines: list[tuple[int, str]]) -> _Rows:
    """The poses of numbered JSONL lines (line number, text), all of one receiver."""
    uniform = _jsonl_uniform(lines)
    if uniform is not None:
        return uniform
    t, xyz, vel, line_no = [], [], [], []
    frame = None
    rid = None
    for no, ln in lines:
        if not ln.strip():
            continue
        try:
            p = parse_pose_message(ln, math.nan)
        except PoseError as e:
            raise InputFileError(
                path, f"{e}; expected one JSON pose per line, e.g. {_JSONL_EXAMPLE}", no
            ) from None
        if rid is None:
            rid = p.receiver_id
        elif p.receiver_id != rid:
            raise InputFileError(
                path, f"poses of receivers {rid} and {p.receiver_id} in one log: replay and gap "
                "read one receiver's poses (virtualgps run --receivers reads them all)", no
            )
        if frame is None:
            frame = p.frame
        elif p.frame != frame:
            raise InputFileError(
                path, f"{p.frame} pose in a log of {frame} poses; use one frame throughout", no
            )
        t.append(p.t_unix_s)
        xyz.append(p.xyz)
        vel.append(p.vel_enu_mps)
        line_no.append(no)
    return _arrays(t, frame or FRAME_ENU, xyz, vel, line_no)


def _arrays(t: list, frame: str, xyz: list, vel: list, line_no: list) -> _Rows:
    return (
        np.array(t, dtype=np.float64),
        frame,
        np.array(xyz, dtype=np.float64).reshape(-1, 3),
        np.array(vel, dtype=np.float64).reshape(-1, 3),
        np.array(line_no, dtype=np.int64),
    )


_CSV_ALIASES = {
    "t": ("t", "t_unix_s"),
    "x": ("x", "x_m", "east_m"),
    "y": ("y", "y_m", "north_m"),
    "z": ("z", "z_m", "up_m"),
    "lat": ("lat", "lat_deg"),
    "lon": ("lon", "lon_deg"),
    "alt": ("alt", "alt_hae_m"),
    "alt_msl": ("alt_msl", "alt_msl_m"),
    "vx": ("vx", "vx_mps", "ve_mps"),
    "vy": ("vy", "vy_mps", "vn_mps"),
    "vz": ("vz", "vz_mps", "vu_mps"),
}


def _read_csv(path: Path, lines: list[str]) -> _Rows:
    header_no = next(
        (
            no
            for no, ln in enumerate(lines, start=1)
            if ln.strip() and not ln.lstrip().startswith("#")
        ),
        None,
    )
    if header_no is None:
        raise InputFileError(path, f"empty CSV pose log; expected {_CSV_LAYOUT}")
    header = lines[header_no - 1]
    delim = "," if "," in header else (";" if ";" in header else "\t")
    names = [c.strip().lower() for c in next(csv.reader([header], delimiter=delim))]
    col: dict[str, int] = {}
    for key, aliases in _CSV_ALIASES.items():
        for a in aliases:
            if a in names:
                col[key] = names.index(a)
                break
    enu = all(k in col for k in ("x", "y", "z"))
    geo = "lat" in col and "lon" in col and ("alt" in col or "alt_msl" in col)
    if "t" not in col or enu == geo or ("alt" in col and "alt_msl" in col):
        raise InputFileError(
            path, f"header {header.strip()!r} does not fit; expected {_CSV_LAYOUT}", header_no
        )
    pos_keys = ("x", "y", "z") if enu else ("lat", "lon", "alt" if "alt" in col else "alt_msl")
    t, xyz, vel, line_no = [], [], [], []
    n_cols = len(names)
    for no in range(header_no + 1, len(lines) + 1):
        ln = lines[no - 1]
        if not ln.strip() or ln.lstrip().startswith("#"):
            continue
        cells = next(csv.reader([ln], delimiter=delim))
        if len(cells) != n_cols:
            raise InputFileError(
                path,
                f"{len(cells)} columns where the header has {n_cols}; expected {_CSV_LAYOUT}",
                no,
            )
        try:
            obj: dict[str, float] = {}
            for key in ("t", *pos_keys):
                obj[key] = _cell(cells[col[key]], key, required=True)
            for key in ("vx", "vy", "vz"):
                if key in col:
                    v = _cell(cells[col[key]], key, required=False)
                    if not math.isnan(v):
                        obj[key] = v
            p = pose_from_mapping(obj, math.nan)
        except PoseError as e:
            raise InputFileError(path, f"{e}; expected {_CSV_LAYOUT}", no) from None
        t.append(p.t_unix_s)
        xyz.append(p.xyz)
        vel.append(p.vel_enu_mps)
        line_no.append(no)
    return _arrays(t, FRAME_ENU if enu else FRAME_GEODETIC, xyz, vel, line_no)


def _cell(text: str, key: str, required: bool) -> float:
    s = text.strip()
    if not s:
        if required:
            raise PoseError("bad-number", f"empty {key}")
        return math.nan
    try:
        v = float(s)
    except ValueError:
        raise PoseError("bad-number", f"{key} {_short(s)} is not a number") from None
    if not math.isfinite(v):
        raise PoseError("bad-number", f"{key} must be finite, got {_short(s)}")
    return v


def _read_tum(path: Path, lines: list[str]) -> _Rows:
    t, xyz, line_no = [], [], []
    for no, ln in enumerate(lines, start=1):
        s = ln.strip()
        if not s or s.startswith("#"):
            continue
        tokens = s.split()
        try:
            if len(tokens) != 8:
                raise ValueError
            vals = [float(x) for x in tokens]
            if not all(math.isfinite(v) for v in vals):
                raise ValueError
            p = pose_from_mapping(
                {"t": vals[0], "x": vals[1], "y": vals[2], "z": vals[3]}, math.nan
            )
        except ValueError:
            raise InputFileError(
                path, f"{_short(s)} does not fit; expected {_TUM_LAYOUT}", no
            ) from None
        except PoseError as e:
            raise InputFileError(path, f"{e}; expected {_TUM_LAYOUT}", no) from None
        t.append(p.t_unix_s)
        xyz.append(p.xyz)
        line_no.append(no)
    vel = [(math.nan,) * 3] * len(t)
    return _arrays(t, FRAME_ENU, xyz, vel, line_no)


def _read_nmea(path: Path, lines: list[str]) -> _Rows:
    log = nmea_fixes_from_lines(lines, path)
    ok = (
        (log.quality > 0)
        & np.isfinite(log.lat_deg)
        & np.isfinite(log.lon_deg)
        & np.isfinite(log.alt_msl_m)
    )
    lat, lon = log.lat_deg[ok], log.lon_deg[ok]
    sep = log.geoid_sep_m[ok]
    # GGA's geoid separation where given (the receiver's own model), else EGM96
    sep = np.where(np.isnan(sep), geodesy.geoid_sep_m(lat, lon), sep)
    xyz = np.stack([lat, lon, log.alt_msl_m[ok] + sep], axis=-1).reshape(-1, 3)
    # Velocity stays NaN: RMC gives speed and course only (no vertical); interpolation then
    # uses finite differences of the fixes.
    vel = np.full_like(xyz, np.nan)
    return log.t_unix_s[ok], FRAME_GEODETIC, xyz, vel, log.line[ok]


def _finish(
    path: Path, t: np.ndarray, frame: str, xyz: np.ndarray, vel: np.ndarray, line_no: np.ndarray
) -> PoseTrack:
    if t.shape[0] == 0:
        raise InputFileError(
            path, "no poses in the log; expected jsonl, csv, TUM or NMEA (GGA with a fix) lines"
        )
    dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    if back.size:
        k = int(back[0]) + 1
        raise InputFileError(
            path,
            f"time {float(t[k])!r} is earlier than the previous pose's {float(t[k - 1])!r}; "
            "expected poses in increasing time order",
            int(line_no[k]),
        )
    keep = np.ones(t.shape[0], dtype=bool)
    keep[1:] = dt > 0  # an exact repeat of the previous time is dropped
    return PoseTrack(t[keep], frame, xyz[keep], vel[keep])
