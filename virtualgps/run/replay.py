"""Batch replay: a pose log through the receiver as fast as possible, NMEA (and a fixes CSV) out.

The same :func:`virtualgps.receiver.core.simulate` as the live daemon, called on chunks of epochs
with the state carried across, so the output does not depend on the chunk size: same seed and inputs
give the same bytes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import BinaryIO, TextIO

import numpy as np

from virtualgps.device import nmea
from virtualgps.poses import pose
from virtualgps.receiver.core import simulate
from virtualgps.receiver.definition import Georef, Receiver
from virtualgps.receiver.records import Fixes
from virtualgps.receiver.skyview import compute_sky
from virtualgps.receiver.state import initial_state

# Epochs per chunk. The main thread waits for the next chunk's sky where the sky of a chunk
# takes longer than the errors and NMEA of the one before: after the short first chunk, and
# where the walk's chunks differ. At 2048 those waits were 0.20-0.28 s of the 10 Hz hour,
# 0.37-0.42 s at 4096 (in-process 1.33-1.36 s against 1.44-1.47 s); on one core it is no
# slower (1.90-1.95 s against 1.94-2.03 s).
CHUNK_EPOCHS = 2048

FIXES_COLUMNS = (
    "t_unix_s",
    "lat_deg",
    "lon_deg",
    "alt_msl_m",
    "geoid_sep_m",
    "quality",
    "mode",
    "sats_used",
    "sats_in_view",
    "hdop",
    "vdop",
    "pdop",
    "speed_mps",
    "course_deg",
    "used_prns",
    "truth_lat_deg",
    "truth_lon_deg",
    "truth_alt_hae_m",
)


@dataclass(frozen=True)
class EpochGrid:
    """Epoch times for a pose log: multiples of the output period inside the log's span.

    t_unix_s : (n_t,) epoch times on the simulated clock
    shift_s : seconds added to the log's times (``--start-time``), 0 otherwise
    """

    t_unix_s: np.ndarray
    shift_s: float


def epoch_grid(
    track_t_unix_s: np.ndarray, rate_hz: float, start_time_unix_s: float | None
) -> EpochGrid:
    """Epochs on whole multiples of 1/rate of simulated UTC that lie within the pose log.

    Parameters
    ----------
    track_t_unix_s : (n,) pose times, UTC seconds, increasing
    rate_hz : output rate
    start_time_unix_s : if given, pose times are shifted so the log starts then

    Returns
    -------
    grid : EpochGrid
    """
    shift = 0.0 if start_time_unix_s is None else start_time_unix_s - float(track_t_unix_s[0])
    t0, t1 = float(track_t_unix_s[0]) + shift, float(track_t_unix_s[-1]) + shift
    # Integer epoch counters keep the times exact multiples of the period (no float drift).
    k0, k1 = math.ceil(round(t0 * rate_hz, 6)), math.floor(round(t1 * rate_hz, 6))
    return EpochGrid(np.arange(k0, k1 + 1, dtype=np.int64) / rate_hz, shift)


def track_in_scene(track: pose.PoseTrack, georef: Georef) -> pose.PoseTrack:
    """Express a pose track in the scene's ENU frame (geodetic tracks are converted)."""
    if track.frame == "enu":
        return track
    return pose.to_enu(track, georef.lat0_deg, georef.lon0_deg, georef.alt0_hae_m)


def run_replay(
    rx: Receiver,
    track: pose.PoseTrack,
    grid: EpochGrid,
    fmt: nmea.NmeaFormat,
    out: BinaryIO,
    seed: int,
    fixes_out: TextIO | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> int:
    """Run the receiver over every epoch of ``grid`` and write NMEA (and the fixes CSV).

    Parameters
    ----------
    rx : the receiver
    track : poses in the scene ENU frame (log times, unshifted)
    grid : the epochs
    fmt : NMEA format of the profile
    out : binary stream for the NMEA
    seed : random seed
    fixes_out : text stream for the fixes CSV, or None
    progress : called with (epochs done, epochs total) after each chunk

    Returns
    -------
    n_epochs : number of epochs written
    """
    rng = np.random.default_rng(seed)
    # The same power-on as the live daemon (a start of the profile's cold_start.power_on kind).
    state = initial_state(rx.profile, float(grid.t_unix_s[0]), rng, len(rx.ephemeris.prn))
    n = len(grid.t_unix_s)
    max_gap_s = rx.profile.pose_timeout_s
    if fixes_out is not None:
        fixes_out.write(",".join(FIXES_COLUMNS) + "\n")

    def epochs(a: int, b: int) -> tuple:
        """Epochs a to b's times, poses and sky (what does not depend on the random numbers)."""
        t = grid.t_unix_s[a:b]
        pos, vel, valid = pose.interpolate(track, t - grid.shift_s, max_gap_s)
        return t, pos, vel, valid, compute_sky(rx, t, np.where(valid[:, None], pos, 0.0))

    def write(b: int, t, pos, vel, valid, sky) -> None:
        nonlocal state
        fixes, state = simulate(rx, t, pos, vel, valid, state, rng, sky=sky)
        data = b"".join(nmea.render_batch(fixes, fmt))
        rows = fixes_csv_rows(fixes) if fixes_out is not None else ""
        try:
            out.write(data)
            if fixes_out is not None:
                fixes_out.write(rows)
        except KeyboardInterrupt:  # a file's write is not interrupted: these epochs count
            if progress is not None:
                progress(b, n)
            raise
        if progress is not None:
            progress(b, n)

    if n <= CHUNK_EPOCHS:  # one chunk: nothing to overlap (and no thread to start)
        if n:
            write(n, *epochs(0, n))
        return n
    # The sky of the next chunk is computed in a second thread while this one's errors and
    # NMEA are: the sky is half the work, mostly Embree and numpy on large arrays, which
    # release the GIL (the 10 Hz hour on this project's two cores: 1.8-2.0 s in-process
    # against 2.4-3.2 s on one). Only that thread computes skies, so the caches they fill
    # (walls per cell, satellite nodes, ray engines) see one thread; the bytes are the same.
    from concurrent.futures import ThreadPoolExecutor

    # The first chunk is a quarter of the others: nothing runs beside its sky.
    ends = [*range(CHUNK_EPOCHS // 4, n, CHUNK_EPOCHS), n]
    with ThreadPoolExecutor(1, thread_name_prefix="virtualgps-sky") as pool:
        ahead = pool.submit(epochs, 0, ends[0])
        for a, b in zip(ends[:-1], ends[1:], strict=True):
            chunk = ahead.result()
            ahead = pool.submit(epochs, a, b)
            write(a, *chunk)
        write(n, *ahead.result())
    return n


def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed blocks of up to 32 MB for reuse in this process, in one
    arena.

    Every chunk of a replay allocates and frees the same numpy temporaries (~100 MB in chunks
    of 4096 epochs), blocks of 0.1-3 MB. By default glibc serves such blocks with fresh mmaps
    (or trims the heap after them), and the replay's second thread gets an arena of its own,
    trimmed apart, so every chunk touches new pages, each a page fault that the kernel
    zero-fills: the 10 Hz hour in chunks of 4096 took 120,000-175,000 faults and 0.25-0.45 s of
    system time; kept for reuse in one arena, 56,000-58,000 and 0.16-0.19 s, and no slower on
    two cores (five whole processes each, alternately: 1.56-1.63 s against 1.58-1.96 s); in
    chunks of 2048 (CHUNK_EPOCHS since 2026-11-26), 43,000 faults and 0.10-0.11 s. The cost:
    the process keeps its peak heap until it exits, so the ``virtualgps replay`` command calls
    this (it exits after its replay), not :func:`run_replay`, which other processes call too;
    the gap tool's workers call it once each (they run jobs of the same size again and again,
    so their peak is what they need anyway).
    (M_MMAP_THRESHOLD -3, M_TRIM_THRESHOLD -1, M_ARENA_MAX -8 in glibc's malloc.h; 32 MB is
    the largest mmap threshold it accepts on 64-bit.)

    Returns
    -------
    applied : False where the C library has no ``mallopt`` (not glibc) or refused the values
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mmap_ok = mallopt(-3, 32 * 1024 * 1024)  # M_MMAP_THRESHOLD
    trim_ok = mallopt(-1, 1024 * 1024 * 1024)  # M_TRIM_THRESHOLD
    arena_ok = mallopt(-8, 1)  # M_ARENA_MAX
    return bool(mmap_ok and trim_ok and arena_ok)


def _col(values: np.ndarray, fmt: str) -> list[str]:
    return ["" if not np.isfinite(v) else fmt % v for v in values.tolist()]


def fixes_csv_rows(fixes: Fixes) -> str:
    """The fixes as CSV rows (columns :data:`FIXES_COLUMNS`; empty fields where NaN).

    Parameters
    ----------
    fixes : Fixes over n_t epochs

    Returns
    -------
    text : n_t lines
    """
    prn = fixes.prn
    used_prns = [" ".join(str(p) for p in prn[row]) for row in fixes.used]
    cols = [
        _col(fixes.t_unix_s, "%.3f"),
        _col(fixes.lat_deg, "%.9f"),
        _col(fixes.lon_deg, "%.9f"),
        _col(fixes.alt_msl_m, "%.3f"),
        _col(fixes.geoid_sep_m, "%.3f"),
        [str(v) for v in fixes.quality.tolist()],
        [str(v) for v in fixes.mode.tolist()],
        [str(v) for v in fixes.sats_used.tolist()],
        [str(v) for v in fixes.in_view.sum(axis=1).tolist()],
        _col(fixes.hdop, "%.3f"),
        _col(fixes.vdop, "%.3f"),
        _col(fixes.pdop, "%.3f"),
        _col(fixes.speed_mps, "%.3f"),
        _col(fixes.course_deg, "%.2f"),
        used_prns,
        _col(fixes.truth_lat_deg, "%.9f"),
        _col(fixes.truth_lon_deg, "%.9f"),
        _col(fixes.truth_alt_hae_m, "%.3f"),
    ]
    return "".join(",".join(row) + "\n" for row in zip(*cols, strict=True))
