"""Pose logs from ROS bags: ROS 1 ``.bag`` and ROS 2 bags (``.db3``, ``.mcap``), via rosbags.

Three message types carry a pose (``virtualgps replay run.bag``, ``run --poses run.bag``):

- ``geometry_msgs/PoseStamped``: ``pose.position`` in the scene frame (ENU metres);
- ``nav_msgs/Odometry``: ``pose.pose.position`` in the scene frame (its twist is in the child
  frame, so velocities come from the positions, as for other logs without them);
- ``sensor_msgs/NavSatFix``: latitude, longitude and altitude above the WGS-84 ellipsoid
  (REP 145), geodetic; messages with ``status.status`` < 0 (no fix) or NaN fields are left
  out.

Each pose is dated by its header stamp (the time it was measured), or by the bag's record time
where the stamp is zero. ``--topic`` picks one topic where several fit; without it a bag with
several candidates is an error naming them. ``gap``, which takes several logs, names the topic
after the bag, ``run.bag:/ground_truth`` (:func:`split_topic`).

A real receiver kept in a bag is read by :func:`read_bag_receiver` (``virtualgps gap --real
run.bag``): its NMEA (``nmea_msgs/Sentence``, what nmea_navsat_driver's
``nmea_topic_serial_reader`` publishes) as the lines of an NMEA log, else its
``sensor_msgs/NavSatFix`` fixes, messages without a fix included.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from virtualgps.exceptions import InputFileError
from virtualgps.poses.pose import PoseTrack

POSE_TYPES = {
    "geometry_msgs/msg/PoseStamped": "enu",
    "nav_msgs/msg/Odometry": "enu",
    "sensor_msgs/msg/NavSatFix": "geodetic",
}
BAG_SUFFIXES = (".bag", ".db3", ".mcap")
SENTENCE_TYPE = "nmea_msgs/msg/Sentence"
NAVSATFIX_TYPE = "sensor_msgs/msg/NavSatFix"
# ros-drivers/nmea_msgs msg/Sentence.msg; registered for ROS 2 bags that carry no definitions
_SENTENCE_DEF = "std_msgs/Header header\nstring sentence\n"
_POSE_KINDS = ("pose", "geometry_msgs/PoseStamped, nav_msgs/Odometry or sensor_msgs/NavSatFix")
_RECEIVER_KINDS = ("receiver", "nmea_msgs/Sentence, as nmea_navsat_driver's "
                   "nmea_topic_serial_reader publishes a receiver's sentences, or "
                   "sensor_msgs/NavSatFix")


def is_bag(path: str | Path) -> bool:
    """A ROS 1 bag file, a ROS 2 bag folder (``metadata.yaml``) or one of its storage files."""
    p = Path(path)
    return p.suffix in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").is_file())


def _bag_paths(p: Path) -> Path:
    """What rosbags opens: the ``.bag`` file, or the ROS 2 bag folder."""
    if p.suffix in (".db3", ".mcap") and (p.parent / "metadata.yaml").is_file():
        return p.parent
    return p


def split_topic(spec: str) -> tuple[str, str | None]:
    """A log given with its bag topic, ``BAG:TOPIC`` (``run.bag:/fix``), as ``(BAG, TOPIC)``;
    anything else (a file or folder that exists, a text log) as ``(spec, None)``. ROS names
    hold no ``:``, so the last one parts them."""
    base, sep, topic = spec.rpartition(":")
    if not sep or not topic or Path(spec).exists() or not (is_bag(base) and Path(base).exists()):
        return spec, None
    return base, topic


def _typestore():
    """The newest ROS 2 message types, and ``nmea_msgs/Sentence``: ROS 1 bags and newer ROS 2
    ones bring their own definitions, older ROS 2 bags name the type only."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.LATEST)
    ts.register(get_types_from_msg(_SENTENCE_DEF, SENTENCE_TYPE))
    return ts


def _reader(p: Path):
    """A rosbags reader of the bag, not yet opened (InputFileError without rosbags)."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise InputFileError(p, "reading ROS bags needs rosbags: pip install "
                             "'virtualgps[ros]'") from None
    return AnyReader([_bag_paths(p)], default_typestore=_typestore())


def _messages(p: Path, topic: str | None, types: Iterable[str], kinds: tuple[str, str]):
    """(msgtype, record time ns, message) of the chosen topic, in the bag's record order.

    Raises
    ------
    InputFileError : naming the bag (see :func:`read_bag`)
    """
    try:
        with _reader(p) as reader:
            conns = [c for c in reader.connections if c.msgtype in types]
            chosen = _pick(p, topic, conns, reader.connections, kinds)
            for conn, stamp_ns, raw in reader.messages(connections=chosen):
                yield conn.msgtype, stamp_ns, reader.deserialize(raw, conn.msgtype)
    except InputFileError:
        raise
    except Exception as exc:  # rosbags raises its own kinds on a bad bag: name the bag
        raise InputFileError(p, f"not a readable ROS bag ({exc})") from None


@dataclass(frozen=True)
class BagFixes:
    """A receiver's ``sensor_msgs/NavSatFix`` messages, in the bag's record order: (n,) arrays.

    t_unix_s : header stamps (the record time where a stamp is zero), UTC seconds
    lat_deg, lon_deg, alt_hae_m : the fix (REP 145: height above the WGS-84 ellipsoid); NaN
        without one
    status : ``status.status``: -1 no fix, 0 fix, 1 SBAS, 2 GBAS
    """

    t_unix_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_hae_m: np.ndarray
    status: np.ndarray


def read_bag_receiver(path: str | Path, topic: str | None = None) -> list[str] | BagFixes:
    """A real receiver's output kept in a ROS bag: the sentences of its ``nmea_msgs/Sentence``
    topic as the lines of a log, in the bag's record order (the order the receiver sent them),
    or, in a bag without sentences (or with ``topic`` one), the fixes of its
    ``sensor_msgs/NavSatFix`` topic (all its messages: those without a fix are epochs too).

    Parameters
    ----------
    path : the bag (see :func:`is_bag`)
    topic : the topic to read; None: the bag's only sentence topic, else its only NavSatFix one

    Returns
    -------
    lines (one per sentence; a message holding several lines gives each), or BagFixes

    Raises
    ------
    InputFileError : as :func:`read_bag`, for receiver topics
    """
    p = Path(path)
    held = _topics(p)
    sentences = topic is None and any(t == SENTENCE_TYPE for t in held.values())
    types = (SENTENCE_TYPE,) if sentences else (SENTENCE_TYPE, NAVSATFIX_TYPE)
    lines: list[str] = []
    fixes: list[tuple[float, float, float, float, int]] = []
    for msgtype, stamp_ns, msg in _messages(p, topic, types, _RECEIVER_KINDS):
        if msgtype == SENTENCE_TYPE:
            lines.extend(str(msg.sentence).replace("\r", "").split("\n"))
            continue
        t = _stamp_s(msg, stamp_ns)
        ok = msg.status.status >= 0
        pos = (float(msg.latitude), float(msg.longitude), float(msg.altitude))
        fixes.append((t, *(pos if ok else (math.nan,) * 3), int(msg.status.status)))
    if not fixes:
        return lines
    a = np.array(fixes, dtype=float)
    return BagFixes(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4].astype(np.int8))


def _stamp_s(msg, record_ns: int) -> float:
    """A message's time, UTC seconds: its header stamp, or its record time where that is 0."""
    st = msg.header.stamp
    return st.sec + 1e-9 * st.nanosec if (st.sec or st.nanosec) else 1e-9 * record_ns


def _topics(p: Path) -> dict[str, str]:
    """{topic: message type} of a bag (InputFileError naming it where it is unreadable)."""
    try:
        with _reader(p) as reader:
            return {c.topic: c.msgtype for c in reader.connections}
    except InputFileError:
        raise
    except Exception as exc:  # rosbags raises its own kinds on a bad bag: name the bag
        raise InputFileError(p, f"not a readable ROS bag ({exc})") from None


def read_bag(path: str | Path, topic: str | None = None):
    """Read the poses of one topic of a ROS bag.

    Parameters
    ----------
    path : the bag (see :func:`is_bag`)
    topic : the topic to read; None: the bag's only pose topic

    Returns
    -------
    PoseTrack : ``"enu"`` (PoseStamped, Odometry) or ``"geodetic"`` (NavSatFix)

    Raises
    ------
    InputFileError
        naming the bag: rosbags missing, an unreadable bag, no pose topic, several without
        ``--topic`` (naming them), a topic that is not there or not a pose.
    """
    p = Path(path)
    t, xyz, frames = [], [], set()
    for msgtype, stamp_ns, msg in _messages(p, topic, POSE_TYPES, _POSE_KINDS):
        frames.add(POSE_TYPES[msgtype])
        row = _position(msg, msgtype)
        if row is None:
            continue
        t.append(_stamp_s(msg, stamp_ns))
        xyz.append(row)
    if not t:
        raise InputFileError(p, f"no poses on {topic or 'its pose topic'}")
    (frame,) = frames  # one topic, one message type
    order = np.argsort(np.asarray(t), kind="stable")  # messages of a topic may interleave
    t_arr = np.asarray(t, dtype=float)[order]
    xyz_arr = np.asarray(xyz, dtype=float)[order]
    keep = np.ones(t_arr.size, bool)
    keep[1:] = np.diff(t_arr) > 0  # an exact repeat of the previous time is dropped
    return PoseTrack(t_arr[keep], frame, xyz_arr[keep], np.full((keep.sum(), 3), np.nan))


def _pick(p: Path, topic: str | None, conns: list, every: list, kinds: tuple[str, str]
          ) -> list:
    """The connections of the chosen topic (one topic may have several connections).

    kinds : (what the topics carry, e.g. ``"pose"``; the message types that carry it, for
        people)
    """
    what, types = kinds
    listing = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in conns})) or "none"
    if topic is not None:
        mine = [c for c in conns if c.topic == topic]
        if not mine:
            other = [c.msgtype for c in every if c.topic == topic]
            why = f"is a {other[0]}, not a {what} topic" if other else "is not in the bag"
            raise InputFileError(p, f"topic {topic} {why}; {what} topics: {listing}")
        return mine
    topics = sorted({c.topic for c in conns})
    if not topics:
        held = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in every})) or "none"
        raise InputFileError(p, f"no {what} topic ({types}); it holds: {held}")
    if len(topics) > 1:
        raise InputFileError(p, f"several {what} topics: {listing}; pick one with --topic, or "
                             f"for gap after the bag: {p}:TOPIC")
    return [c for c in conns if c.topic == topics[0]]


def _position(msg, msgtype: str) -> tuple[float, float, float] | None:
    """(x, y, z) scene ENU metres or (lat, lon, alt HAE); None for a NavSatFix without a fix."""
    if msgtype == "sensor_msgs/msg/NavSatFix":
        v = (float(msg.latitude), float(msg.longitude), float(msg.altitude))
        if msg.status.status < 0 or not all(math.isfinite(x) for x in v):
            return None
        return v
    pos = msg.pose.pose.position if msgtype == "nav_msgs/msg/Odometry" else msg.pose.position
    return float(pos.x), float(pos.y), float(pos.z)
