"""ROS bags as pose logs (issue #9): bags written here with rosbags (ROS 1 .bag; ROS 2 .db3 and
.mcap), replayed, and compared byte for byte with the same poses replayed from JSONL; and as a
real receiver's log for ``gap`` (its nmea_msgs/Sentence or sensor_msgs/NavSatFix), read as the
same epochs as the NMEA it holds."""

from __future__ import annotations

import contextlib
import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from virtualgps import geodesy
from virtualgps.exceptions import InputFileError

pytest.importorskip("rosbags")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

T0 = 1490712768.0  # 2017-03-28T14:52:48Z, the Magdeburg waypoint logs
N = 30
# A walk across the Magdeburg campus between buildings, 1.5 m above the ground (scene ENU).
XYZ = np.column_stack([-60.0 + 1.4 * np.arange(N), np.full(N, -80.0), np.full(N, 55.0)])
T = T0 + np.arange(N, dtype=float)
ORIGIN = (52.14, 11.645, 100.0)  # open-sky runs: geodetic poses around here


def _stamp(ts, t: float, ros1: bool):
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int(round(t % 1 * 1e9)))
    fields = {"stamp": stamp, "frame_id": "map"}
    return ts.types["std_msgs/msg/Header"](**({"seq": 0} | fields if ros1 else fields))


def _point_pose(ts, xyz):
    msg = ts.types
    return msg["geometry_msgs/msg/Pose"](
        position=msg["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
        orientation=msg["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))


def _messages(ts, kind: str, ros1: bool):
    """(time, message) of one pose message type along the walk."""
    m = ts.types
    out = []
    lla = np.column_stack(geodesy.ecef_to_geodetic(geodesy.enu_to_ecef(
        np.column_stack([XYZ[:, :2], np.zeros(N)]), *ORIGIN)))
    for i, t in enumerate(T):
        h = _stamp(ts, t, ros1)
        if kind == "pose":
            msg = m["geometry_msgs/msg/PoseStamped"](header=h, pose=_point_pose(ts, XYZ[i]))
        elif kind == "odom":
            v3 = m["geometry_msgs/msg/Vector3"]
            twist = m["geometry_msgs/msg/Twist"](linear=v3(x=1.4, y=0.0, z=0.0),
                                                 angular=v3(x=0.0, y=0.0, z=0.0))
            msg = m["nav_msgs/msg/Odometry"](
                header=h, child_frame_id="base_link",
                pose=m["geometry_msgs/msg/PoseWithCovariance"](pose=_point_pose(ts, XYZ[i]),
                                                               covariance=np.zeros(36)),
                twist=m["geometry_msgs/msg/TwistWithCovariance"](twist=twist,
                                                                 covariance=np.zeros(36)))
        else:
            status = m["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
            msg = m["sensor_msgs/msg/NavSatFix"](
                header=h, status=status, latitude=lla[i, 0], longitude=lla[i, 1],
                altitude=lla[i, 2], position_covariance=np.zeros(9),
                position_covariance_type=0)
        out.append((t, msg))
    return out


TYPES = {"pose": "geometry_msgs/msg/PoseStamped", "odom": "nav_msgs/msg/Odometry",
         "fix": "sensor_msgs/msg/NavSatFix"}


def write_bag(path: Path, topics: dict[str, str], storage: str) -> Path:
    """A bag with the walk on each topic ({topic: kind}); storage 'bag', 'db3' or 'mcap'."""
    ros1 = storage == "bag"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    plugin = {"db3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}.get(storage)
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=plugin)
    with writer as w:
        for topic, kind in topics.items():
            conn = w.add_connection(topic, TYPES[kind], typestore=ts)
            for t, msg in _messages(ts, kind, ros1):
                raw = (ts.serialize_ros1 if ros1 else ts.serialize_cdr)(msg, TYPES[kind])
                w.write(conn, int(t * 1e9) + 5_000_000, raw)  # recorded 5 ms after the stamp
    return path


def _replay(poses: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "virtualgps", "replay", str(poses), "--out",
                           str(out), "--seed", "3", *extra], capture_output=True, text=True,
                          timeout=120)


def _jsonl(path: Path, geodetic: bool) -> Path:
    if geodetic:
        lla = geodesy.ecef_to_geodetic(geodesy.enu_to_ecef(
            np.column_stack([XYZ[:, :2], np.zeros(N)]), *ORIGIN))
        rows = [{"t": t, "lat": a, "lon": b, "alt": c} for t, a, b, c in zip(T, *lla, strict=True)]
    else:
        rows = [{"t": t, "x": x, "y": y, "z": z} for t, (x, y, z) in zip(T, XYZ, strict=True)]
    path.write_text("".join(json.dumps({k: float(v) for k, v in r.items()}) + "\n" for r in rows))
    return path


@pytest.mark.parametrize(("storage", "kind"), [("bag", "pose"), ("db3", "odom"),
                                               ("mcap", "fix"), ("bag", "fix")])
def test_bag_replays_as_its_poses_do(tmp_path, storage, kind):
    name = "walk.bag" if storage == "bag" else "walk"
    bag = write_bag(tmp_path / name, {f"/{kind}": kind}, storage)
    geodetic = kind == "fix"
    extra = ["--scene", "none"] if geodetic else []
    r_bag = _replay(bag, tmp_path / "bag.nmea", *extra)
    r_ref = _replay(_jsonl(tmp_path / "ref.jsonl", geodetic), tmp_path / "ref.nmea", *extra)
    assert r_bag.returncode == 0 and r_ref.returncode == 0, r_bag.stderr + r_ref.stderr
    nmea = (tmp_path / "bag.nmea").read_bytes()
    assert nmea.count(b"$GPGGA") == N and nmea == (tmp_path / "ref.nmea").read_bytes()
    if storage != "bag":  # a ROS 2 bag's storage file names the bag too
        (store,) = bag.glob(f"*.{storage}")
        assert _replay(store, tmp_path / "s.nmea", *extra).returncode == 0


def test_topic_picks_one_and_errors_name_the_candidates(tmp_path):
    bag = write_bag(tmp_path / "two.bag", {"/robot/pose": "pose", "/robot/odom": "odom"}, "bag")
    r = _replay(bag, tmp_path / "x.nmea")
    assert r.returncode != 0 and "/robot/pose (geometry_msgs/msg/PoseStamped)" in r.stderr
    assert "/robot/odom (nav_msgs/msg/Odometry)" in r.stderr and "--topic" in r.stderr
    assert _replay(bag, tmp_path / "x.nmea", "--topic", "/robot/odom").returncode == 0
    r = _replay(bag, tmp_path / "x.nmea", "--topic", "/nope")
    assert r.returncode != 0 and "/nope is not in the bag" in r.stderr
    assert "Traceback" not in r.stderr
    broken = tmp_path / "broken.bag"
    broken.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 64)
    r = _replay(broken, tmp_path / "x.nmea")
    assert r.returncode != 0 and "broken.bag" in r.stderr and "Traceback" not in r.stderr


def _sentence_bag(path: Path, nmea_lines: list[str], topics: dict[str, str], storage: str,
                  definitions: bool = True) -> Path:
    """A bag holding a receiver's sentences on /nmea_sentence (nmea_msgs/Sentence, one line a
    message, as nmea_navsat_driver's nmea_topic_serial_reader publishes them) beside the walk
    on each of ``topics`` ({topic: kind}); ``definitions`` False: a ROS 2 bag whose types are
    named but not defined, as rosbag2 wrote them before Iron."""
    from rosbags.typesys import get_types_from_msg

    ros1 = storage == "bag"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg("std_msgs/Header header\nstring sentence\n",
                                   "nmea_msgs/msg/Sentence"))
    writer = (Writer1(path) if ros1 else
              Writer2(path, version=9, storage_plugin=StoragePlugin.SQLITE3))
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    with writer as w:
        conn = w.add_connection("/nmea_sentence", "nmea_msgs/msg/Sentence", typestore=ts)
        t = T0
        for line in nmea_lines:
            if line.startswith("$GPGGA"):
                t += 1.0
            msg = ts.types["nmea_msgs/msg/Sentence"](header=_stamp(ts, t + 0.2, ros1),
                                                     sentence=line)
            w.write(conn, int((t + 0.2) * 1e9), serialize(msg, "nmea_msgs/msg/Sentence"))
        for topic, kind in topics.items():
            conn = w.add_connection(topic, TYPES[kind], typestore=ts)
            for t_pose, msg in _messages(ts, kind, ros1):
                w.write(conn, int(t_pose * 1e9) + 5_000_000, serialize(msg, TYPES[kind]))
    if not definitions:
        with contextlib.closing(sqlite3.connect(next(path.glob("*.db3")))) as db:
            db.execute("DELETE FROM message_definitions")
            db.commit()
    return path


def test_a_receivers_sentences_in_a_bag_are_diagnosed_as_its_log(tmp_path):
    """A robot keeps its receiver's NMEA in a bag (nmea_msgs/Sentence) beside the ground truth:
    ``gap --real run.bag --truth run.bag:/ground_truth`` reads the same epochs and writes the
    same diagnosis as the text log and a pose log, from ROS 1 and ROS 2 bags (an old ROS 2
    bag names nmea_msgs/Sentence without defining it); a bag without a receiver's topic, or a
    topic that is not one, is one clear error."""
    from virtualgps.gap.ingest import read_real_log

    walk = _jsonl(tmp_path / "walk.jsonl", geodetic=True)
    log = tmp_path / "walk.nmea"
    assert _replay(walk, log, "--scene", "none").returncode == 0
    lines = log.read_text().splitlines()
    ref = read_real_log(log)
    for storage, definitions in (("bag", True), ("db3", True), ("db3", False)):
        name = f"walk-{storage}-{definitions}{'.bag' * (storage == 'bag')}"
        bag = _sentence_bag(tmp_path / name, lines, {"/fix": "fix"}, storage, definitions)
        got = read_real_log(bag)
        np.testing.assert_array_equal(got[0].t_unix_s, ref[0].t_unix_s)
        np.testing.assert_array_equal(got[0].lat_deg, ref[0].lat_deg)
        np.testing.assert_array_equal(got[0].cn0_dbhz, ref[0].cn0_dbhz)
        assert got[1:] == ref[1:]

    bag = _sentence_bag(tmp_path / "run.bag", lines, {"/fix": "fix", "/ground_truth": "fix"},
                        "bag")

    def gap(real, truth, out):
        return subprocess.run(
            [sys.executable, "-m", "virtualgps", "gap", "--real", str(real), "--truth",
             str(truth), "--scene", "none", "--effects", "none", "--seeds", "4", "--jobs", "1",
             "--out", str(tmp_path / out)], capture_output=True, text=True, timeout=300)

    r_bag = gap(bag, f"{bag}:/ground_truth", "bag")
    r_ref = gap(log, walk, "ref")
    assert r_bag.returncode == 0 and r_ref.returncode == 0, r_bag.stderr + r_ref.stderr
    rep_bag = json.loads((tmp_path / "bag" / "report.json").read_text())
    rep_ref = json.loads((tmp_path / "ref" / "report.json").read_text())
    assert rep_bag["runs"][0]["name"] == "run" and rep_bag["runs"][0]["real"] == str(bag)
    assert rep_bag["headline"] == rep_ref["headline"] and rep_bag["where"] == rep_ref["where"]
    # the truth's bag holds two pose topics: one must be named; no sentence topic, one error
    r = gap(bag, bag, "x")
    assert r.returncode == 2 and "several pose topics" in r.stderr and ":TOPIC" in r.stderr
    poses_only = write_bag(tmp_path / "poses.bag", {"/pose": "pose"}, "bag")
    r = gap(poses_only, walk, "x")
    assert r.returncode == 2 and "no receiver topic (nmea_msgs/Sentence" in r.stderr
    assert "/pose (geometry_msgs/msg/PoseStamped)" in r.stderr and "Traceback" not in r.stderr
    r = gap(f"{poses_only}:/pose", walk, "x")
    assert r.returncode == 2 and "/pose is a geometry_msgs/msg/PoseStamped, not a receiver" in (
        r.stderr)


def test_a_receivers_navsatfix_in_a_bag_is_its_fixes(tmp_path):
    """A robot that records only the driver's ``fix`` (sensor_msgs/NavSatFix): read as the
    receiver's epochs, those without a fix (status -1) included, the height above the
    ellipsoid kept (altitude above EGM96 plus the separation); ``run.bag:/gps/fix`` picks it
    beside the truth's NavSatFix. Its times are the messages' stamps."""
    from virtualgps.gap.ingest import load_run, read_real_log

    walk = _jsonl(tmp_path / "walk.jsonl", geodetic=True)
    log = tmp_path / "walk.nmea"
    assert _replay(walk, log, "--scene", "none").returncode == 0
    ref = read_real_log(log)[0]
    hae = ref.alt_msl_m + ref.geoid_sep_m
    ts = get_typestore(Stores.ROS2_HUMBLE)
    m = ts.types
    bag = tmp_path / "fixes"
    with Writer2(bag, version=9) as w:
        conn = w.add_connection("/gps/fix", TYPES["fix"], typestore=ts)
        for k, t in enumerate(ref.t_unix_s):
            fix = ref.quality[k] > 0
            msg = m["sensor_msgs/msg/NavSatFix"](
                header=_stamp(ts, t, False),
                status=m["sensor_msgs/msg/NavSatStatus"](status=0 if fix else -1, service=1),
                latitude=ref.lat_deg[k] if fix else np.nan,
                longitude=ref.lon_deg[k] if fix else np.nan, altitude=hae[k] if fix else np.nan,
                position_covariance=np.zeros(9), position_covariance_type=0)
            w.write(conn, int(t * 1e9) + 80_000_000, ts.serialize_cdr(msg, TYPES["fix"]))
        conn = w.add_connection("/ground_truth", TYPES["fix"], typestore=ts)
        for t, msg in _messages(ts, "fix", False):
            w.write(conn, int(t * 1e9), ts.serialize_cdr(msg, TYPES["fix"]))
    got, skipped, records, dated_by = read_real_log(bag, topic="/gps/fix")
    assert records == {"NavSatFix": len(ref)} and not skipped and dated_by == "log"
    np.testing.assert_array_equal(got.t_unix_s, ref.t_unix_s)
    np.testing.assert_array_equal(got.quality, np.where(ref.quality > 0, 1, 0))
    fix = ref.quality > 0
    assert fix.sum() >= len(ref) - 3 and np.isnan(got.lat_deg[~fix]).all()
    np.testing.assert_array_equal(got.lat_deg[fix], ref.lat_deg[fix])
    np.testing.assert_allclose((got.alt_msl_m + got.geoid_sep_m)[fix], hae[fix], rtol=0,
                               atol=1e-9)
    assert got.prn.size == 0 and (got.sats_used == -1).all()
    run = load_run(f"{bag}:/gps/fix", f"{bag}:/ground_truth")
    assert run.name == "fixes" and not run.has_gsv and run.sentences == {"NavSatFix": len(ref)}
    with pytest.raises(InputFileError, match="several receiver topics"):
        read_real_log(bag)
