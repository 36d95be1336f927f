"""Pose messages, pose logs in every format, conversion to the scene frame, interpolation.

References: pymap3d for geodetic -> ENU, pynmea2 for NMEA logs, closed-form tracks for
interpolation; a fuzz loop for the message parser's only-PoseError contract.
"""

from __future__ import annotations

import json
import math
import random
from datetime import UTC, datetime

import numpy as np
import pymap3d
import pynmea2
import pytest

from virtualgps import geodesy
from virtualgps.device import nmea
from virtualgps.exceptions import InputFileError, PoseError
from virtualgps.poses import logs as pose_logs
from virtualgps.poses import pose
from virtualgps.poses.pose import Pose, PoseTrack

MM = 1e-3  # metres
UM_PER_S = 1e-6  # m/s


# --- messages ---------------------------------------------------------------------------------


def test_enu_message_with_velocity():
    p = pose.parse_pose_message(
        b'{"t": 1711630000.25, "x": 12.0, "y": -3.5, "z": 0, "vx": 1.5, "vy": 0, "vz": -0.25,'
        b' "frame_id": "base_link", "extra": {"nested": [1, 2]}}',
        arrival_unix_s=5.0,
    )
    assert p == Pose(1711630000.25, "enu", (12.0, -3.5, 0.0), (1.5, 0.0, -0.25))


def test_arrival_time_when_t_absent_or_null_and_partial_velocity():
    p = pose.parse_pose_message('{"x": 1, "y": 2, "z": 3, "vx": 0.5}', 1711630001.5)
    assert p.t_unix_s == 1711630001.5
    assert p.vel_enu_mps[0] == 0.5 and math.isnan(p.vel_enu_mps[1]) and math.isnan(p.vel_enu_mps[2])
    p = pose.parse_pose_message('{"t": null, "x": 1, "y": 2, "z": 3, "vy": null}', 7.0)
    assert p.t_unix_s == 7.0 and math.isnan(p.vel_enu_mps[1])


def test_geodetic_message_alt_hae_and_alt_msl():
    p = pose.parse_pose_message('{"t": 1.0, "lat": 52.14, "lon": 11.64, "alt": 98.5}', 0.0)
    assert p.frame == "geodetic" and p.xyz == (52.14, 11.64, 98.5)
    q = pose.parse_pose_message('{"t": 1.0, "lat": 52.14, "lon": 11.64, "alt_msl": 55.0}', 0.0)
    n_m = float(geodesy.geoid_sep_m(52.14, 11.64))
    assert abs(q.xyz[2] - (55.0 + n_m)) < MM
    # EGM96 at Magdeburg is ~44 m (the campus phone logs print 45.0, its own coarser model)
    assert 42.0 < n_m < 46.0


@pytest.mark.parametrize(
    "data, kind",
    [
        (b"\xff\xfe\x00garbage", "not-json"),
        (b"{", "not-json"),
        (b"", "not-json"),
        (b"[" * 3000 + b"]" * 3000, "too-long"),
        (b"[" * 2000 + b"]" * 2000, "not-json"),  # nesting beyond json's recursion limit
        (b"1" * 4000, "not-object"),  # 4000 digits: a valid JSON number, but no object
        (b"[1, 2]", "not-object"),
        (b'"x"', "not-object"),
        (b"null", "not-object"),
        (b"{}", "no-position"),
        (b'{"t": 1, "x": 1, "y": 2}', "no-position"),
        (b'{"t": 1, "lat": 1, "lon": 2}', "no-position"),
        (b'{"t": 1, "lat": 1, "alt": 2}', "no-position"),
        (b'{"t": 1, "x": 1, "y": 2, "z": 3, "lat": 1}', "mixed-frames"),
        (b'{"t": 1, "lat": 1, "lon": 2, "alt": 3, "alt_msl": 3}', "mixed-frames"),
        (b'{"t": 1, "x": "1", "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "x": true, "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "x": null, "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "x": NaN, "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "x": Infinity, "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "x": 1e999, "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "x": ' + b"9" * 400 + b', "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "x": [1], "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "x": 1, "y": 2, "z": 3, "vx": "fast"}', "bad-number"),
        (b'{"t": -1, "x": 1, "y": 2, "z": 3}', "bad-time"),
        (b'{"t": 1e12, "x": 1, "y": 2, "z": 3}', "bad-time"),
        (b'{"t": "now", "x": 1, "y": 2, "z": 3}', "bad-number"),
        (b'{"t": 1, "lat": 91, "lon": 2, "alt": 3}', "out-of-range"),
        (b'{"t": 1, "lat": 1, "lon": 400, "alt": 3}', "out-of-range"),
        (b'{"t": 1, "lat": 1, "lon": 2, "alt": 1e7}', "out-of-range"),
        (b'{"t": 1, "x": 1e9, "y": 2, "z": 3}', "out-of-range"),
        (b'{"t": 1, "x": 1, "y": 2, "z": 3, "vz": 1e6}', "out-of-range"),
    ],
)
def test_malformed_messages_raise_pose_error_of_a_kind(data, kind):
    with pytest.raises(PoseError) as e:
        pose.parse_pose_message(data, 1711630000.0)
    assert e.value.kind == kind
    assert len(str(e.value)) < 200  # one line, junk not echoed in full


def test_message_without_t_needs_an_arrival_time():
    with pytest.raises(PoseError) as e:
        pose.parse_pose_message('{"x": 1, "y": 2, "z": 3}', math.nan)
    assert e.value.kind == "bad-time"


def _random_json(rng: random.Random, depth: int = 0) -> object:
    choices = [
        lambda: rng.choice([None, True, False]),
        lambda: rng.randint(-(10**30), 10**30),
        lambda: rng.choice([rng.uniform(-1e6, 1e6), 1e308, -0.0, 5e-324]),
        lambda: "".join(chr(rng.randint(0, 0x2FF)) for _ in range(rng.randint(0, 8))),
    ]
    if depth < 4:
        keys = ["t", "x", "y", "z", "lat", "lon", "alt", "alt_msl", "vx", "vy", "vz", "q"]
        choices += [
            lambda: [_random_json(rng, depth + 1) for _ in range(rng.randint(0, 3))],
            lambda: {
                rng.choice(keys): _random_json(rng, depth + 1) for _ in range(rng.randint(0, 8))
            },
        ]
    return rng.choice(choices)()


def test_fuzz_messages_only_ever_raise_pose_error():
    rng = random.Random(20240328)
    n_ok = 0
    for k in range(4000):
        if k % 3 == 0:
            data: bytes | str = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 64)))
        elif k % 3 == 1:
            data = json.dumps(_random_json(rng), allow_nan=True)
        else:  # a valid pose with one field mutated
            obj = {"t": 1711630000.0, "x": 1.0, "y": 2.0, "z": 3.0}
            obj[rng.choice(list(obj) + ["lat", "vx"])] = _random_json(rng, 3)
            data = json.dumps(obj).encode()
            if rng.random() < 0.3:
                b = bytearray(data)
                b[rng.randrange(len(b))] = rng.getrandbits(8)
                data = bytes(b)
        try:
            p = pose.parse_pose_message(data, 1711630000.0)
        except PoseError as e:
            assert e.kind in {
                "too-long",
                "not-json",
                "not-object",
                "no-position",
                "mixed-frames",
                "bad-number",
                "bad-time",
                "out-of-range",
            }
        else:
            n_ok += 1
            assert all(math.isfinite(v) for v in p.xyz) and math.isfinite(p.t_unix_s)
    assert n_ok > 50  # the mutations leave some valid poses: the accepting path ran too


# --- tracks -----------------------------------------------------------------------------------


def test_from_poses_sorts_and_keeps_the_last_of_equal_times():
    poses = [
        Pose(2.0, "enu", (2.0, 0.0, 0.0)),
        Pose(1.0, "enu", (1.0, 0.0, 0.0)),
        Pose(2.0, "enu", (2.5, 0.0, 0.0)),
    ]
    tr = pose.from_poses(poses)
    assert tr.t_unix_s.tolist() == [1.0, 2.0] and tr.xyz[:, 0].tolist() == [1.0, 2.5]
    assert len(pose.from_poses([])) == 0
    with pytest.raises(PoseError) as e:
        pose.from_poses([Pose(1.0, "enu", (0, 0, 0)), Pose(2.0, "geodetic", (1, 2, 3))])
    assert e.value.kind == "mixed-frames"


def test_to_enu_matches_pymap3d_and_rotates_velocities():
    lat0, lon0, h0 = 52.1400665, 11.643243, 51.6
    lat = np.array([52.1400665, 52.141, 52.2, 53.1400665, 52.15])
    lon = np.array([11.643243, 11.645, 11.5, 11.643243, 11.64])
    h = np.array([51.6, 55.0, 80.0, 100.0, 60.0])
    vel = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0, 1.0, 0], [0, 1.0, np.nan]])
    tr = PoseTrack(np.arange(5.0), "geodetic", np.stack([lat, lon, h], -1), vel)
    enu = pose.to_enu(tr, lat0, lon0, h0)
    e, n, u = pymap3d.geodetic2enu(lat, lon, h, lat0, lon0, h0)
    assert enu.frame == "enu"
    assert np.abs(enu.xyz - np.stack([e, n, u], -1)).max() < MM
    # velocity: the direction between two pymap3d points ~1 m apart along the local north
    dn = 1.0 / 111_250.0  # degrees
    e1, n1, u1 = pymap3d.geodetic2enu(lat[1] + dn, lon[1], h[1], lat0, lon0, h0)
    step = np.array([e1 - e[1], n1 - n[1], u1 - u[1]])
    assert np.abs(enu.vel_enu_mps[1] - step / np.linalg.norm(step)).max() < 1e-6
    # one degree north on the same meridian, the local north tilts down by exactly one degree
    d = math.radians(1.0)
    assert np.abs(enu.vel_enu_mps[3] - [0.0, math.cos(d), -math.sin(d)]).max() < 1e-12
    assert np.isnan(enu.vel_enu_mps[4]).all()  # a missing component stays missing
    assert pose.to_enu(enu, lat0, lon0, h0) is enu


def enu_track(t, xyz, vel=None) -> PoseTrack:
    xyz = np.asarray(xyz, dtype=float)
    vel = np.full_like(xyz, np.nan) if vel is None else np.asarray(vel, dtype=float)
    return PoseTrack(np.asarray(t, dtype=float), "enu", xyz, vel)


def test_interpolate_closed_form():
    tr = enu_track([10.0, 12.0, 13.0], [[0, 0, 0], [4, -2, 2], [4, -2, 5]])
    q = np.array([9.9, 10.0, 11.0, 12.0, 12.5, 13.0, 13.25, 14.0, 14.01, np.nan])
    pos, vel, ok = pose.interpolate(tr, q, max_gap_s=1.0)
    assert ok.tolist() == [False, True, False, True, True, True, True, True, False, False]
    # the 2 s segment is a gap for max_gap 1 s: valid only exactly at its first pose
    assert pos[1].tolist() == [0, 0, 0] and vel[1].tolist() == [2, -1, 1]
    assert pos[4].tolist() == [4, -2, 3.5] and vel[4].tolist() == [0, 0, 3]
    # extrapolated past the last pose with the last segment's velocity
    assert pos[6].tolist() == [4, -2, 5.75] and pos[7].tolist() == [4, -2, 8]
    assert np.isnan(pos[~ok]).all() and np.isnan(vel[~ok]).all()
    pos, vel, ok = pose.interpolate(tr, np.array([11.0]), max_gap_s=2.0)
    assert ok[0] and pos[0].tolist() == [2, -1, 1] and vel[0].tolist() == [2, -1, 1]


def test_interpolate_uses_the_tracks_own_velocity_component_wise():
    vel = [[1.0, 5.0, np.nan], [3.0, 5.0, np.nan]]
    tr = enu_track([0.0, 2.0], [[0, 0, 0], [4, 10, 2]], vel)
    pos, v, ok = pose.interpolate(tr, np.array([0.5, 3.0]), max_gap_s=5.0)
    assert ok.all()
    assert v[0].tolist() == [1.5, 5.0, 1.0]  # vz from the finite difference
    assert v[1].tolist() == [3.0, 5.0, 1.0] and pos[1].tolist() == [7.0, 15.0, 3.0]


def test_interpolate_single_pose_holds_and_empty_track():
    tr = enu_track([5.0], [[1, 2, 3]])
    pos, vel, ok = pose.interpolate(tr, np.array([4.0, 5.0, 6.0, 8.0]), max_gap_s=2.0)
    assert ok.tolist() == [False, True, True, False]
    assert pos[2].tolist() == [1, 2, 3] and vel[2].tolist() == [0, 0, 0]
    pos, vel, ok = pose.interpolate(pose.from_poses([]), np.array([1.0]), max_gap_s=2.0)
    assert not ok.any() and pos.shape == (1, 3)


def test_interpolate_geodetic_velocity_in_metres_per_second():
    lat0, lon0 = 52.14, 11.64
    lat1, lon1 = lat0 + 1e-4, lon0 + 2e-4
    tr = PoseTrack(
        np.array([0.0, 1.0]),
        "geodetic",
        np.array([[lat0, lon0, 50.0], [lat1, lon1, 51.0]]),
        np.full((2, 3), np.nan),
    )
    _, vel, ok = pose.interpolate(tr, np.array([0.5, 1.5]), max_gap_s=1.0)
    e, n, u = pymap3d.geodetic2enu(lat1, lon1, 51.0, lat0, lon0, 50.0)
    assert ok.all()
    assert np.abs(vel[0] - [e, n, u]).max() < 0.01  # m/s; first-order over 11 m
    pos, _, _ = pose.interpolate(tr, np.array([1.5]), max_gap_s=1.0)
    assert abs(pos[0, 0] - (lat1 + 0.5e-4)) < 1e-9 and abs(pos[0, 1] - (lon1 + 1e-4)) < 1e-9


# --- logs -------------------------------------------------------------------------------------


def test_jsonl_log(tmp_path):
    p = tmp_path / "poses.jsonl"
    p.write_text(
        '{"t": 1.0, "x": 0, "y": 0, "z": 0}\n\n{"t": 2.0, "x": 1, "y": 0, "z": 0, "vx": 1}\n'
        '{"t": 2.0, "x": 9, "y": 9, "z": 9}\n'
    )
    tr = pose_logs.read_pose_log(p)
    assert tr.frame == "enu" and tr.t_unix_s.tolist() == [1.0, 2.0]
    assert tr.xyz[1].tolist() == [1, 0, 0] and tr.vel_enu_mps[1, 0] == 1.0  # duplicate dropped


@pytest.mark.parametrize("geodetic", [False, True])
@pytest.mark.parametrize("with_velocity", [False, True])
def test_uniform_jsonl_reads_as_line_by_line(tmp_path, geodetic, with_velocity):
    """The vectorised reader of plain logs gives what the line-by-line one gives (an ignored
    extra key sends the same log down the line-by-line path); out-of-range values, bools and
    nulls fall back to it, so its error names the line."""
    rng = np.random.default_rng(5)
    n = 200
    keys = ("lat", "lon", "alt") if geodetic else ("x", "y", "z")
    pos = rng.uniform([50, 10, 0], [52, 12, 300], (n, 3)) if geodetic else \
        rng.uniform(-500, 500, (n, 3))
    rows = [{"t": 1.49e9 + i * 0.1, **dict(zip(keys, map(float, p), strict=True))}
            for i, p in enumerate(pos)]
    rows[3][keys[0]] = int(round(pos[3, 0]))  # a whole number is a number too
    if with_velocity:
        for r in rows:
            r.update(vx=float(rng.normal()), vy=1, vz=0.0)
    fast, slow = tmp_path / "fast.jsonl", tmp_path / "slow.jsonl"
    fast.write_text("".join(json.dumps(r) + "\n" for r in rows))
    slow.write_text("".join(json.dumps({**r, "note": "x"}) + "\n" for r in rows))
    assert pose_logs._jsonl_uniform(list(enumerate(fast.read_text().splitlines(), 1))) is not None
    assert pose_logs._jsonl_uniform(list(enumerate(slow.read_text().splitlines(), 1))) is None
    a, b = pose_logs.read_pose_log(fast), pose_logs.read_pose_log(slow)
    assert a.frame == b.frame == ("geodetic" if geodetic else "enu")
    for x, y in ((a.t_unix_s, b.t_unix_s), (a.xyz, b.xyz), (a.vel_enu_mps, b.vel_enu_mps)):
        np.testing.assert_array_equal(x, y)
    for bad in ({keys[0]: True}, {keys[1]: None}, {"t": -5.0}, {keys[2]: 1e12}):
        broken = [dict(r) for r in rows]
        broken[7].update(bad)
        fast.write_text("".join(json.dumps(r) + "\n" for r in broken))
        with pytest.raises(InputFileError) as e:
            pose_logs.read_pose_log(fast)
        assert e.value.line == 8


@pytest.mark.parametrize(
    "text, line, what",
    [
        ('{"t": 1.0, "x": 0, "y": 0, "z": 0}\n{"t": 2.0, "x": 0, "y": 0}\n', 2, "lacks z"),
        ('{"t": 1.0, "x": 0, "y": 0, "z": 0}\nnot json\n', 2, "not JSON"),
        ('{"x": 0, "y": 0, "z": 0}\n', 1, '"t"'),
        ('{"t": 2.0, "x": 0, "y": 0, "z": 0}\n{"t": 1.0, "x": 0, "y": 0, "z": 0}\n', 2, "earlier"),
        (
            '{"t": 1.0, "x": 0, "y": 0, "z": 0}\n{"t": 2.0, "lat": 0, "lon": 0, "alt": 0}\n',
            2,
            "one frame",
        ),
    ],
)
def test_jsonl_errors_name_file_and_line(tmp_path, text, line, what):
    p = tmp_path / "bad.jsonl"
    p.write_text(text)
    with pytest.raises(InputFileError) as e:
        pose_logs.read_pose_log(p)
    assert e.value.line == line and str(e.value).startswith(f"{p}:{line}: ")
    assert what in str(e.value)


def test_csv_logs_enu_geodetic_msl_and_velocities(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("# exported\nt_unix_s, x, y, z, vx, vy, vz, note\n1,0,0,0,,,,a\n2,1,2,3,1,2,3,b\n")
    tr = pose_logs.read_pose_log(p)
    assert tr.frame == "enu" and tr.xyz.tolist() == [[0, 0, 0], [1, 2, 3]]
    assert np.isnan(tr.vel_enu_mps[0]).all() and tr.vel_enu_mps[1].tolist() == [1, 2, 3]

    p = tmp_path / "b.csv"
    p.write_text("lat;lon;alt_msl;t\n52.14;11.64;55.0;1711630000\n")
    tr = pose_logs.read_pose_log(p)
    assert tr.frame == "geodetic"
    assert abs(tr.xyz[0, 2] - (55.0 + float(geodesy.geoid_sep_m(52.14, 11.64)))) < MM

    p = tmp_path / "c.txt"  # detected from the content
    p.write_text("t,lat_deg,lon_deg,alt_hae_m\n1,52.14,11.64,98.0\n")
    assert pose_logs.read_pose_log(p).xyz.tolist() == [[52.14, 11.64, 98.0]]


@pytest.mark.parametrize(
    "text, line",
    [
        ("t,x,y\n1,2,3\n", 1),  # no z
        ("time,x,y,z\n1,2,3,4\n", 1),  # no t
        ("t,x,y,z,lat,lon,alt\n1,2,3,4,5,6,7\n", 1),  # both frames
        ("t,x,y,z\n1,2,3,4\n2,2,3\n", 3),  # short row
        ("t,x,y,z\n1,2,3,4\n2,2,three,4\n", 3),
        ("t,x,y,z\n1,2,3,4\n2,2,nan,4\n", 3),
        ("t,x,y,z\n1,2,3,4\n2,2,,4\n", 3),
        ("t,x,y,z\n5,2,3,4\n2,2,3,4\n", 3),
    ],
)
def test_csv_errors_name_file_and_line(tmp_path, text, line):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputFileError) as e:
        pose_logs.read_pose_log(p)
    assert e.value.line == line and "expected" in str(e.value)


def test_tum_log(tmp_path):
    p = tmp_path / "traj.txt"
    p.write_text(
        "# timestamp tx ty tz qx qy qz qw\n"
        "1403636579.758 4.688 -1.786 0.783 -0.153 -0.827 -0.082 0.535\n"
        "1403636579.763 4.689 -1.786 0.787 -0.153 -0.827 -0.082 0.535\n"
    )
    tr = pose_logs.read_pose_log(p)
    assert tr.frame == "enu" and len(tr) == 2 and tr.xyz[1].tolist() == [4.689, -1.786, 0.787]
    assert np.isnan(tr.vel_enu_mps).all()
    p.write_text("1 2 3 4 0 0 0 1\n2 2 3 4 0 0 1\n")
    with pytest.raises(InputFileError) as e:
        pose_logs.read_pose_log(p)
    assert e.value.line == 2 and "t x y z qx qy qz qw" in str(e.value)


def test_unknown_and_empty_logs(tmp_path):
    p = tmp_path / "what.txt"
    p.write_text("hello world\n")
    with pytest.raises(InputFileError, match="cannot tell the pose log format"):
        pose_logs.read_pose_log(p)
    p = tmp_path / "empty.jsonl"
    p.write_text("\n")
    with pytest.raises(InputFileError, match="no poses"):
        pose_logs.read_pose_log(p)
    with pytest.raises(InputFileError, match="cannot read"):
        pose_logs.read_pose_log(tmp_path / "missing.csv")


def test_nmea_log_as_geodetic_track(tmp_path):
    body = [
        "GPGGA,120000.000,5208.4040,N,01138.5946,E,1,06,0.94,55.3,M,44.7,M,,",
        "GPRMC,120000.000,A,5208.4040,N,01138.5946,E,1.00,90.00,260317,,,A",
        "GPGGA,120001.000,,,,,0,03,,,M,,M,,",
        "GPGGA,120002.000,5208.4041,N,01138.5947,E,1,06,0.94,55.4,M,,M,,",
    ]
    p = tmp_path / "ref.log"
    p.write_text("".join(nmea.format_sentence(b) for b in body))
    tr = pose_logs.read_pose_log(p)
    t0 = datetime(2017, 3, 26, 12, tzinfo=UTC).timestamp()
    assert tr.frame == "geodetic" and tr.t_unix_s.tolist() == [t0, t0 + 2]
    assert abs(tr.xyz[0, 0] - (52 + 8.4040 / 60)) < 1e-12
    assert abs(tr.xyz[0, 2] - (55.3 + 44.7)) < MM
    # empty geoid field: EGM96
    lat, lon = tr.xyz[1, :2]
    assert abs(tr.xyz[1, 2] - (55.4 + float(geodesy.geoid_sep_m(lat, lon)))) < MM


def test_gzip_compressed_logs_read_as_the_plain_ones(tmp_path):
    """A log kept compressed (``.jsonl.gz``, ``.nmea.gz``, or a gzip file under any name) reads
    as the plain file; a truncated one is one clear error naming the file."""
    import gzip

    text = '{"t": 1.0, "x": 0, "y": 0, "z": 0}\n{"t": 2.0, "x": 1, "y": 2, "z": 3}\n'
    plain = tmp_path / "poses.jsonl"
    plain.write_text(text)
    packed = tmp_path / "poses.jsonl.gz"
    packed.write_bytes(gzip.compress(text.encode()))
    a, b = pose_logs.read_pose_log(plain), pose_logs.read_pose_log(packed)
    assert b.t_unix_s.tolist() == a.t_unix_s.tolist() and b.xyz.tolist() == a.xyz.tolist()
    body = "".join(nmea.format_sentence(s) for s in (
        "GPGGA,120000.000,5208.4040,N,01138.5946,E,1,06,0.94,55.3,M,44.7,M,,",
        "GPRMC,120000.000,A,5208.4040,N,01138.5946,E,1.00,90.00,260317,,,A"))
    (tmp_path / "ref.log").write_bytes(gzip.compress(body.encode()))
    assert nmea.read_text_lines(tmp_path / "ref.log") == body.replace("\r", "").split("\n")
    assert pose_logs.read_pose_log(tmp_path / "ref.log").frame == "geodetic"
    cut = tmp_path / "cut.jsonl.gz"
    cut.write_bytes(packed.read_bytes()[:20])
    with pytest.raises(InputFileError, match="cut.jsonl.gz.*does not decompress"):
        pose_logs.read_pose_log(cut)


def test_logs_written_as_utf16_or_with_a_bom_read_as_the_plain_ones(tmp_path):
    """Windows PowerShell's ``>`` and ``Out-File`` write a captured log as UTF-16 with a
    byte-order mark; some editors put UTF-8's mark before a log. Each reads as the plain file
    (UTF-16 read as UTF-8 held no sentence: every other byte a NUL)."""
    body = "".join(nmea.format_sentence(s) for s in (
        "GPGGA,120000.000,5208.4040,N,01138.5946,E,1,06,0.94,55.3,M,44.7,M,,",
        "GPRMC,120000.000,A,5208.4040,N,01138.5946,E,1.00,90.00,260317,,,A"))
    plain = tmp_path / "plain.nmea"
    plain.write_bytes(body.encode("ascii"))
    want = nmea.read_text_lines(plain)
    assert want == body.replace("\r", "").split("\n")
    for enc in ("utf-16", "utf-16-le", "utf-16-be", "utf-8-sig"):
        data = body.encode(enc)
        if enc in ("utf-16-le", "utf-16-be"):  # their mark written by hand, as Windows does
            data = "\ufeff".encode(enc) + data
        p = tmp_path / f"{enc}.nmea"
        p.write_bytes(data)
        assert nmea.read_text_lines(p) == want, enc
        assert pose_logs.read_pose_log(p).xyz.tolist() == pose_logs.read_pose_log(
            plain).xyz.tolist()


def test_real_span_reference_log(shared_data):
    path = shared_data / "gsdc-2020-05-14-mtv" / "SPAN_Pixel4_1Hz.nmea"
    tr = pose_logs.read_pose_log(path)
    ref = [pynmea2.parse(ln, check=True) for ln in path.read_text().splitlines() if "GGA" in ln]
    ref = [m for m in ref if m.gps_qual > 0]
    assert len(tr) == len(ref) == 2120
    assert tr.frame == "geodetic" and np.all(np.diff(tr.t_unix_s) > 0)
    for k in (0, 1000, len(ref) - 1):
        assert abs(tr.xyz[k, 0] - ref[k].latitude) * 60 < 1e-6
        assert abs(tr.xyz[k, 1] - ref[k].longitude) * 60 < 1e-6
        # SPAN writes ellipsoidal height with geoid separation 0.0 (SOURCES.md: check datums)
        assert abs(tr.xyz[k, 2] - (ref[k].altitude + float(ref[k].geo_sep))) < MM
    start = datetime.fromtimestamp(tr.t_unix_s[0], UTC)
    assert (start.date().isoformat(), start.hour) == ("2020-05-14", 22)
    # a 1 Hz drive: interpolation between fixes gives car speeds
    enu = pose.to_enu(tr, *tr.xyz[0])
    _, vel, ok = pose.interpolate(enu, enu.t_unix_s[:-1] + 0.5, max_gap_s=1.5)
    speed = np.linalg.norm(vel[ok, :2], axis=1)
    assert ok.mean() > 0.95 and 5.0 < np.median(speed[speed > 1]) < 40.0


def test_real_magdeburg_phone_log_with_prefixes(shared_data):
    path = sorted((shared_data / "magdeburg-campus" / "nmea").glob("NMEA_Log__*.txt"))[0]
    tr = pose_logs.read_pose_log(path)
    assert tr.frame == "geodetic" and len(tr) > 0
    # on the campus (the mesh origin is 52.1400665, 11.643243): within 1 km
    e, n, _ = pymap3d.geodetic2enu(
        tr.xyz[:, 0], tr.xyz[:, 1], tr.xyz[:, 2], 52.1400665, 11.643243, 0
    )
    assert np.hypot(e, n).max() < 1000.0
