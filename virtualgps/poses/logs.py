"""Pose logs on disk: JSONL, CSV, TUM and NMEA files and ROS bags, each read whole into a
:class:`~virtualgps.poses.pose.PoseTrack` (or one per receiver id), with errors that name the
file, line and expected layout. The format is told by the file's suffix and first lines.
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np

from virtualgps import geodesy
from virtualgps.device.nmea import nmea_fixes_from_lines, parse_sentence, read_text_lines
from virtualgps.exceptions import InputFileError, PoseError
from virtualgps.poses.pose import (
    ALT_MAX_M,
    ALT_MIN_M,
    ENU_MAX_M,
    FRAME_ENU,
    FRAME_GEODETIC,
    SPEED_MAX_MPS,
    T_MAX_UNIX_S,
    PoseTrack,
    _short,
    parse_pose_message,
    pose_from_mapping,
)

_JSONL_EXAMPLE = '{"t": 1711630000.25, "x": 12.0, "y": -3.5, "z": 0.0}'
_CSV_LAYOUT = (
    "a header naming t (or t_unix_s) and x,y,z or lat,lon,alt (or alt_msl), optional vx,vy,vz"
)
_TUM_LAYOUT = "8 numbers 't x y z qx qy qz qw' separated by spaces (TUM trajectory format)"


_NMEA_RE = re.compile(r"\$[A-Z]{2}[A-Z]{3},")


def _detect_format(path: Path, lines: list[str]) -> str:
    """``jsonl``, ``csv``, ``tum`` or ``nmea`` from the extension (before a ``.gz``), else
    from the content."""
    ext = (path.with_suffix("") if path.suffix.lower() == ".gz" else path).suffix.lower()
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
