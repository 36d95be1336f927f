"""Which TLE set a run's sky comes from: one rule for ``run``, ``replay``, ``sky`` and ``gap``.

``--tle`` wins. Otherwise the set whose epoch centre lies nearest the run's start, among the
scene's set (``tle`` in ``scene.toml``), the bundled GPS sets (``ephemeris/gps-ops-*.tle``) and
the sets ``virtualgps ephemeris fetch`` cached (:mod:`virtualgps.sky.tlecache`): a simulated or
replayed day gets its own day's sky where one is at hand, and the sky-time shift
(:func:`virtualgps.sky.ephemeris.sidereal_shift_s`) covers the rest. A receiver log and its
simulation then share one sky, which per-satellite comparisons (the gap tool) need. Where other
systems are asked for (``sky --systems``), each system's set is chosen the same way among the
bundled and fetched sets of its group (``glo-ops-*.tle``, ``galileo-*.tle``).
"""

from __future__ import annotations

import time
from pathlib import Path

from virtualgps.exceptions import ConfigError, VirtualGPSError
from virtualgps.sky import ephemeris as eph
from virtualgps.sky import systems

# (resolved path, mtime in ns, size in bytes) -> epoch centre, UTC Unix seconds. Choosing reads
# every candidate's epochs; each file is parsed once per process (a fleet resolves its set per
# profile, the gap tool per run), and again only when it changes.
_EPOCHS: dict[tuple[str, int, int], float] = {}


def epoch_center_unix_s(path: Path) -> float:
    """The epoch centre (median TLE epoch; a lookup table's or navigation file's own) of an
    ephemeris file, UTC Unix seconds, cached per path and modification time.

    Raises
    ------
    OSError, ValueError, VirtualGPSError
        when the file cannot be read or is no ephemeris
    """
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    if key not in _EPOCHS:
        # (dating a candidate says nothing: warnings about its satellites come, once, when the
        # chosen set is loaded)
        was, eph.log.disabled = eph.log.disabled, True
        try:
            _EPOCHS[key] = float(eph.load_ephemeris_file(path, None).epoch_center_unix_s)
        finally:
            eph.log.disabled = was
    return _EPOCHS[key]


def choose_tle_set(tle: str | Path | None, scene_tle: Path | None,
                   t_unix_s: float | None, group: str = "gps-ops") -> tuple[Path, str]:
    """The ephemeris file for a run starting at ``t_unix_s``, and one line saying why.

    Parameters
    ----------
    tle : ``--tle`` (wins whenever given), or None
    scene_tle : the scene's set (``Scene.tle_path``), or None
    t_unix_s : the run's start, UTC seconds (a replay's first pose or ``--start-time``); None
        for a live run starting now
    group : whose sets are candidates, bundled and fetched (:data:`virtualgps.sky.systems.
        GROUPS`; a scene's set is a
        GPS set)

    Returns
    -------
    path : the chosen file
    line : e.g. ``ephemeris: gps-ops-2017-03-28.tle (a bundled set; epoch 2017-03-26, 2.0 days
        from the run's start, the nearest of 3 sets)``

    Raises
    ------
    ConfigError
        when no candidate set can be read
    """
    if tle is not None:
        return Path(tle), f"ephemeris: --tle {tle}"
    from virtualgps.sky import tlecache

    now = time.time()
    t = now if t_unix_s is None else float(t_unix_s)
    # In order of precedence on equal distance: the scene's set was picked for its scene, and
    # a fetched set of the same epoch as a bundled one is the user's deliberate choice.
    candidates: list[tuple[Path, float | None, str]] = []
    gps = group == systems.GROUPS["G"]
    if scene_tle is not None and gps:
        candidates.append((Path(scene_tle), None, "the scene's set"))
    for c in tlecache.cached_sets(group=group):
        age_d = (now - c.fetched_unix_s) / 86400.0
        candidates.append((c.path, c.epoch_center_unix_s,
                           f"a TLE set fetched {age_d:.1f} days ago from {c.url}"))
    candidates += [(p, None, "a bundled set")
                   for p in sorted(eph.BUNDLED_EPHEMERIS_DIR.glob(f"{group}-*.tle"))]
    best: tuple[Path, float, str] | None = None
    seen: set[Path] = set()
    for path, epoch, why in candidates:
        real = path.resolve()
        if real in seen:  # (the bundled scene's set is a bundled set too: counted once)
            continue
        if epoch is None:
            try:
                epoch = epoch_center_unix_s(path)
            except (OSError, ValueError, VirtualGPSError):
                continue  # unreadable: the next nearest serves
        seen.add(real)
        if best is None or abs(epoch - t) < abs(best[1] - t):
            best = (path, epoch, why)
    if best is None:
        if not gps:
            raise ConfigError(f"no {group} TLE set is at hand: give one with --tle PATH")
        raise ConfigError("no TLE set could be read (the scene's, the bundled or the fetched "
                          "ones): give --tle PATH to a TLE file")
    path, epoch, why = best
    day = time.strftime("%Y-%m-%d", time.gmtime(epoch))
    return path, (f"ephemeris: {path.name} ({why}; epoch {day}, {abs(t - epoch) / 86400.0:.1f} "
                  f"days from the run's start, the nearest of {len(seen)} sets)")


def choose_system_sets(letters: str, t_unix_s: float | None, scene_tle: Path | None = None
                       ) -> tuple[list[tuple[Path, str]], list[tuple[str, ConfigError]]]:
    """Per system, the TLE set nearest the run's start (:func:`choose_tle_set` with the
    system's group; the scene's set is a candidate for GPS alone): what ``run``, ``replay``,
    ``gap`` and the self-check's trials choose when no ``--tle`` is given.

    Parameters
    ----------
    letters : RINEX letters of the systems, in the order wanted (e.g. ``"GR"``)
    t_unix_s : the run's start, UTC seconds (None: now); scene_tle : the scene's set, or None

    Returns
    -------
    found : (path, the line saying why) per system with a set at hand, in ``letters``' order
    missing : (system name, the reason) per system with none (no sets of it are bundled or
        fetched, e.g. BeiDou)
    """
    found: list[tuple[Path, str]] = []
    missing: list[tuple[str, ConfigError]] = []
    for letter in dict.fromkeys(letters):
        name = systems.system_named(letter).name
        try:
            if letter not in systems.GROUPS:
                raise ConfigError(f"no {name} TLE sets are bundled: give one with --tle PATH")
            found.append(choose_tle_set(None, scene_tle if letter == "G" else None, t_unix_s,
                                        systems.GROUPS[letter]))
        except ConfigError as exc:
            missing.append((name, exc))
    return found, missing
