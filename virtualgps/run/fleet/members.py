"""Who is in a fleet: ``--receivers N`` (alike but for id, seed and link) or a fleet file.

A fleet file (TOML) lists the receivers, each with any of: ``id`` (default: its place in the
list), ``profile`` (name or path), ``seed`` (default: the run's seed + id), ``link`` (default:
the ``--link`` pattern with ``{id}`` replaced), ``baud`` and ``antenna_offset_m`` (east, north,
up metres added to the receiver's poses: the antenna's place on the robot, where poses give
the robot's reference point). A ``[defaults]`` table sets any of these but ``id``, ``seed``
and ``link`` for every receiver::

    [defaults]
    profile = "holux-m1000"
    baud = 115200

    [[receiver]]
    id = 0

    [[receiver]]
    id = 7
    profile = "usarsim"
    seed = 42
    link = "/tmp/gps-drone7"
    antenna_offset_m = [0.0, 0.0, 0.3]
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from virtualgps.exceptions import ConfigError
from virtualgps.poses.pose import MAX_RECEIVER_ID
from virtualgps.tomlfile import read_toml

ID_FIELD = "{id}"
_KEYS = {"id", "profile", "seed", "link", "baud", "antenna_offset_m"}
_DEFAULT_KEYS = {"profile", "baud", "antenna_offset_m"}


@dataclass(frozen=True)
class Member:
    """One receiver of a fleet.

    receiver_id : its number (the ``"id"`` of its pose messages)
    seed : its random seed
    link : the stable symlink to its pty
    profile : profile name or path, or None for the run's
    baud : baud rate, or None for the profile's
    antenna_offset_enu_m : (east, north, up) metres added to its poses
    """

    receiver_id: int
    seed: int
    link: str
    profile: str | None = None
    baud: int | None = None
    antenna_offset_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


def link_for(pattern: str, receiver_id: int) -> str:
    """The link of receiver ``receiver_id``: ``pattern`` with ``{id}`` replaced."""
    return pattern.replace(ID_FIELD, str(receiver_id))


def fleet_members(
    n_receivers: int | None, fleet_file: str | None, seed: int, link_pattern: str
) -> list[Member]:
    """The receivers of a run.

    Parameters
    ----------
    n_receivers : ``--receivers`` (None: one, or as many as the fleet file lists)
    fleet_file : ``--fleet`` path, or None
    seed : the run's seed (receiver ``id`` gets ``seed + id`` unless the file says otherwise)
    link_pattern : ``--link``; must contain ``{id}`` when several receivers take it

    Returns
    -------
    members : in the file's order (or by id)

    Raises
    ------
    ConfigError
        naming the file and the receiver, for unknown keys, bad values, repeated ids or links,
        or a count that disagrees with ``--receivers``.
    """
    # (No cap here: what bounds a fleet is the system's, see virtualgps.run.fleet.limits.)
    if n_receivers is not None and not 1 <= n_receivers <= MAX_RECEIVER_ID + 1:
        raise ConfigError(f"--receivers must be 1..{MAX_RECEIVER_ID + 1} (receiver ids are "
                          f"0..{MAX_RECEIVER_ID}), not {n_receivers}")
    if fleet_file is None:
        n = n_receivers or 1
        entries: list[dict] = [{"id": i} for i in range(n)]
        defaults: dict = {}
        where = "--receivers"
    else:
        doc = read_toml(Path(fleet_file))
        where = str(fleet_file)
        unknown = set(doc) - {"defaults", "receiver"}
        if unknown:
            raise ConfigError(f"{where}: unknown table or key {sorted(unknown)[0]!r} (expected "
                              "[defaults] and [[receiver]] entries)")
        entries = doc.get("receiver", [])
        defaults = doc.get("defaults", {})
        if not isinstance(entries, list) or not entries or not all(
                isinstance(e, dict) for e in entries):
            raise ConfigError(f"{where}: no [[receiver]] entries")
        if not isinstance(defaults, dict):
            raise ConfigError(f"{where}: [defaults] must be a table")
        bad = set(defaults) - _DEFAULT_KEYS
        if bad:
            raise ConfigError(f"{where}: [defaults] may set {', '.join(sorted(_DEFAULT_KEYS))}; "
                              f"not {sorted(bad)[0]!r}")
        if n_receivers is not None and n_receivers != len(entries):
            raise ConfigError(f"--receivers {n_receivers} but {where} lists {len(entries)} "
                              "receivers (give one or the other)")
    members = [_member(i, {**defaults, **e}, seed, link_pattern, where)
               for i, e in enumerate(entries)]
    ids = [m.receiver_id for m in members]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise ConfigError(f"{where}: receiver id {dup} appears twice")
    links = [str(Path(m.link).absolute()) for m in members]
    if len(set(links)) != len(links):
        if ID_FIELD not in link_pattern:
            raise ConfigError(f"--link {link_pattern!r} names one link for {len(members)} "
                              f"receivers: put {ID_FIELD} in it (e.g. ./virtualgps{ID_FIELD})")
        dup = next(x for x in links if links.count(x) > 1)
        raise ConfigError(f"{where}: two receivers have the link {dup}")
    return members


def parse_ids(text: str) -> tuple[int, int]:
    """``--ids LO-HI`` (or one id ``N``): the inclusive range of receiver ids this host runs.

    Raises
    ------
    ConfigError
        for anything but ``N`` or ``LO-HI`` with 0 <= LO <= HI.
    """
    lo, sep, hi = text.strip().partition("-")
    try:
        a = int(lo)
        b = int(hi) if sep else a
    except ValueError:
        a = b = -1
    if not 0 <= a <= b:
        raise ConfigError(f"--ids must be LO-HI receiver ids (e.g. 0-4999), not {text!r}")
    return a, b


def select_ids(members: list[Member], ids: tuple[int, int]) -> list[Member]:
    """The members whose id lies in ``ids`` (inclusive): this host's share of a fleet split
    across hosts. Raises ConfigError when none does."""
    lo, hi = ids
    mine = [m for m in members if lo <= m.receiver_id <= hi]
    if not mine:
        all_ids = [m.receiver_id for m in members]
        raise ConfigError(f"--ids {lo}-{hi} selects none of the fleet's receivers (ids "
                          f"{min(all_ids)}..{max(all_ids)})")
    return mine


def _member(index: int, e: dict, seed: int, link_pattern: str, where: str) -> Member:
    """One fleet file entry (defaults merged) as a Member."""
    rid = e.get("id", index)
    what = f"{where}: receiver {rid!r}"
    unknown = set(e) - _KEYS
    if unknown:
        raise ConfigError(f"{what}: unknown key {sorted(unknown)[0]!r} (expected "
                          f"{', '.join(sorted(_KEYS))})")
    if type(rid) is not int or not 0 <= rid <= MAX_RECEIVER_ID:
        raise ConfigError(f"{what}: id must be an integer 0..{MAX_RECEIVER_ID}")
    s = e.get("seed", seed + rid)
    if type(s) is not int or s < 0:
        raise ConfigError(f"{what}: seed must be a non-negative integer, not {s!r}")
    profile = e.get("profile")
    if profile is not None and (not isinstance(profile, str) or not profile):
        raise ConfigError(f"{what}: profile must be a profile name or path")
    baud = e.get("baud")
    if baud is not None and (type(baud) is not int or baud <= 0):
        raise ConfigError(f"{what}: baud must be a positive integer, not {baud!r}")
    link = e.get("link")
    if link is not None and (not isinstance(link, str) or not link):
        raise ConfigError(f"{what}: link must be a path")
    off = e.get("antenna_offset_m", [0.0, 0.0, 0.0])
    if (not isinstance(off, list) or len(off) != 3
            or not all(type(v) in (int, float) and math.isfinite(v) for v in off)):
        raise ConfigError(f"{what}: antenna_offset_m must be [east, north, up] metres")
    return Member(
        receiver_id=rid,
        seed=s,
        link=link if link is not None else link_for(link_pattern, rid),
        profile=profile,
        baud=baud,
        antenna_offset_enu_m=(float(off[0]), float(off[1]), float(off[2])),
    )
