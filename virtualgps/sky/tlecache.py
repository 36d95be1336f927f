"""Today's sky: current TLE sets fetched into the user's cache, and the one that fits a run.

``virtualgps ephemeris fetch`` downloads each system's group (GPS ``gps-ops``, GLONASS
``glo-ops``, Galileo ``galileo``, BeiDou ``beidou``) from CelesTrak's GP query
(https://celestrak.org/NORAD/documentation/gp-data-formats.php; ``--url`` to override) into
``$XDG_CACHE_HOME/virtualgps/tle`` (``~/.cache/virtualgps/tle``), one file per group and fetch
named by both (``galileo-20261126T1900Z.tle``), with a JSON sidecar (source, fetch time, TLE
epoch, satellites). A download is parsed before it is kept, so a failed or garbled fetch never
replaces a good set; a set whose satellites cannot be numbered (GLONASS satellites the slot
table does not place at its date) is not kept either.

The cached sets are candidates beside the scene's and the bundled sets: ``run``, ``replay``,
``sky`` and ``gap`` take the one whose epoch lies nearest their start time
(:func:`virtualgps.sky.skytime.choose_tle_set`).
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

from virtualgps.exceptions import VirtualGPSError
from virtualgps.sky import ephemeris as eph
from virtualgps.sky import systems
from virtualgps.usercache import user_cache_dir

log = logging.getLogger(__name__)

CELESTRAK_URL = "https://celestrak.org/NORAD/elements/gp.php?GROUP={group}&FORMAT=tle"
FETCH_TIMEOUT_S = 30.0
MAX_BYTES = 1 << 20  # a group's set is 5-15 KB; anything near a megabyte is not one


@dataclass(frozen=True)
class CachedSet:
    """One fetched TLE set.

    path : the TLE file; url : where it came from
    fetched_unix_s : UTC seconds of the fetch; epoch_center_unix_s : its satellites' mean epoch
    n_sat : its satellites (of its group's system)
    """

    path: Path
    url: str
    fetched_unix_s: float
    epoch_center_unix_s: float
    n_sat: int


def cache_dir() -> Path:
    """The TLE cache folder: ``$XDG_CACHE_HOME/virtualgps/tle``, else ``~/.cache/...``."""
    return user_cache_dir("tle")


def fetch(url: str | None = None, cache: Path | None = None,
          timeout_s: float = FETCH_TIMEOUT_S, group: str = "gps-ops") -> CachedSet:
    """Download one group's TLE set into the cache.

    Parameters
    ----------
    url : http(s) or file URL of a 2- or 3-line TLE set (default: CelesTrak's for the group)
    cache : the cache folder (default :func:`cache_dir`)
    timeout_s : seconds before the download is given up
    group : the group (:data:`virtualgps.sky.systems.GROUPS`): names the file, and the set
        must hold that system's satellites

    Returns
    -------
    cached : the new set

    Raises
    ------
    VirtualGPSError
        one line naming the URL: unreachable, an HTTP error, too large, or not a GPS TLE set
    """
    import urllib.error  # (here: every run reads the cache; only a fetch needs http, 15 ms)
    import urllib.request

    letter = next((x for x, g in systems.GROUPS.items() if g == group), None)
    if letter is None:
        raise VirtualGPSError(f"unknown group {group!r}: expected one of "
                              + ", ".join(systems.GROUPS.values()))
    what = f"{systems.system_named(letter).name} TLE set"
    url = url or CELESTRAK_URL.format(group=group)
    folder = cache or cache_dir()
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:  # noqa: S310 (user's URL)
            data = resp.read(MAX_BYTES + 1)
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", None) or exc
        if isinstance(exc, urllib.error.HTTPError):
            reason = f"HTTP {exc.code} {reason}"
        raise VirtualGPSError(f"cannot fetch {url}: {reason} (without a fetched set, the "
                              "bundled sets and the sky-time shift are used)") from None
    if len(data) > MAX_BYTES:
        raise VirtualGPSError(f"{url}: more than {MAX_BYTES} bytes: not a {what}")
    fetched = time.time()
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(fetched))
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"{group}-{stamp}.tle"
    tmp = folder / f".{final.name}.part"
    tmp.write_bytes(data)
    try:
        sats = eph.load_tle(tmp, systems_kept=letter)
    except VirtualGPSError as exc:
        tmp.unlink()
        raise VirtualGPSError(f"{url} did not give a {what}: {exc}") from None
    os.replace(tmp, final)
    cached = CachedSet(final, url, fetched, float(sats.epoch_center_unix_s), len(sats.prn))
    meta = {"url": url, "fetched_unix_s": fetched,
            "epoch_center_unix_s": cached.epoch_center_unix_s, "n_sat": cached.n_sat}
    final.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")
    return cached


def cached_sets(cache: Path | None = None, group: str = "gps-ops") -> list[CachedSet]:
    """One group's fetched sets in the cache, newest fetch first (a set without a readable
    sidecar is left out)."""
    folder = cache or cache_dir()
    out = []
    for side in folder.glob(f"{group}-*.json") if folder.is_dir() else ():
        tle = side.with_suffix(".tle")
        try:
            m = json.loads(side.read_text())
            out.append(CachedSet(tle, str(m["url"]), float(m["fetched_unix_s"]),
                                 float(m["epoch_center_unix_s"]), int(m["n_sat"])))
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return sorted((c for c in out if c.path.is_file()), key=lambda c: -c.fetched_unix_s)
