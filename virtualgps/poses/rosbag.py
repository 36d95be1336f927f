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
several candidates is an error naming them.
"""

from __future__ import annotations

import math
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


def is_bag(path: str | Path) -> bool:
    """A ROS 1 bag file, a ROS 2 bag folder (``metadata.yaml``) or one of its storage files."""
    p = Path(path)
    return p.suffix in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").is_file())


def _bag_paths(p: Path) -> Path:
    """What rosbags opens: the ``.bag`` file, or the ROS 2 bag folder."""
    if p.suffix in (".db3", ".mcap") and (p.parent / "metadata.yaml").is_file():
        return p.parent
    return p


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
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise InputFileError(p, "reading ROS bags needs rosbags: pip install "
                             "'virtualgps[ros]'") from None
    t, xyz = [], []
    try:
        with AnyReader([_bag_paths(p)], default_typestore=get_typestore(Stores.LATEST)) as reader:
            conns = [c for c in reader.connections if c.msgtype in POSE_TYPES]
            chosen = _pick(p, topic, conns, reader.connections)
            frame = POSE_TYPES[chosen[0].msgtype]
            for conn, stamp_ns, raw in reader.messages(connections=chosen):
                msg = reader.deserialize(raw, conn.msgtype)
                row = _position(msg, conn.msgtype)
                if row is None:
                    continue
                st = msg.header.stamp
                t_s = st.sec + 1e-9 * st.nanosec if (st.sec or st.nanosec) else 1e-9 * stamp_ns
                t.append(t_s)
                xyz.append(row)
    except InputFileError:
        raise
    except Exception as exc:  # rosbags raises its own kinds on a bad bag: name the bag
        raise InputFileError(p, f"not a readable ROS bag ({exc})") from None
    if not t:
        raise InputFileError(p, f"no poses on {chosen[0].topic}")
    order = np.argsort(np.asarray(t), kind="stable")  # messages of a topic may interleave
    t_arr = np.asarray(t, dtype=float)[order]
    xyz_arr = np.asarray(xyz, dtype=float)[order]
    keep = np.ones(t_arr.size, bool)
    keep[1:] = np.diff(t_arr) > 0  # an exact repeat of the previous time is dropped
    return PoseTrack(t_arr[keep], frame, xyz_arr[keep], np.full((keep.sum(), 3), np.nan))


def _pick(p: Path, topic: str | None, conns: list, every: list) -> list:
    """The connections of the chosen topic (one topic may have several connections)."""
    listing = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in conns})) or "none"
    if topic is not None:
        mine = [c for c in conns if c.topic == topic]
        if not mine:
            other = [c.msgtype for c in every if c.topic == topic]
            why = f"is a {other[0]}, not a pose" if other else "is not in the bag"
            raise InputFileError(p, f"topic {topic} {why}; pose topics: {listing}")
        return mine
    topics = sorted({c.topic for c in conns})
    if not topics:
        raise InputFileError(p, "no pose topic (geometry_msgs/PoseStamped, nav_msgs/Odometry or "
                             "sensor_msgs/NavSatFix)")
    if len(topics) > 1:
        raise InputFileError(p, f"several pose topics: {listing}; pick one with --topic")
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
