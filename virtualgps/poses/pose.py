"""Poses: the pose message, pose tracks and their interpolation in time.

Owns the pose contract of DESIGN section 4: one JSON object per message, with the antenna in
scene ENU metres (``x, y, z``) or WGS-84 geodetic (``lat, lon`` and ``alt`` above the ellipsoid or
``alt_msl``), ``t`` in UTC Unix seconds (arrival time when absent) and optional ``vx, vy, vz``
(m/s, ENU). Logs (:mod:`virtualgps.poses.logs`) become a :class:`PoseTrack`; a track is
interpolated to epoch times with :func:`interpolate`.

Messages come from the network: :func:`parse_pose_message` raises nothing but
:class:`PoseError`, whatever the bytes.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from virtualgps import geodesy
from virtualgps.exceptions import PoseError

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































