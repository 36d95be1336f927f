"""The device's NMEA output as a flight controller's UART receives it, for the driver models of
``test_nmea_px4.py`` and ``test_nmea_ardupilot.py``.

Each epoch's bytes leave from the epoch's time on (or once the line is free) at baud / 10 bytes
per second (8N1), handed over at the end of each of the pty's 16 ms slices; where the baud
cannot carry the rate, the device's bounded queue drops the oldest whole epochs not yet started
(docs/device.md, "The pty and the serial port"; virtualgps/device/output.py, ``_EpochQueue``).
"""

from __future__ import annotations

import math
import os
import select
import time
from collections import deque

import numpy as np

PTY_SLICE_S = 0.016  # virtualgps/device/pty.py: the pty's output slices
#: virtualgps/device/output.py (QueuedLine, max_backlog_s): at most 2 s of line time waits, and
#: no epoch older than that
DEVICE_MAX_BACKLOG_S = 2.0


def epoch_starts_s(sizes: list[int], t_s: np.ndarray, baud: int,
                   max_backlog_s: float = DEVICE_MAX_BACKLOG_S) -> list[float | None]:
    """When each epoch's first byte goes out on a line of ``baud`` (8N1), or None where the
    device's queue drops it: epochs are sent whole and in order; at each new epoch and whenever
    the line frees, the oldest unstarted epochs go while more than ``max_backlog_s`` of line
    time is queued or while they are older than that (the newest is kept: _EpochQueue.trim).

    sizes : bytes of each epoch; t_s : (n,) each epoch's time, seconds, non-decreasing
    """
    s_per_byte = 10.0 / baud
    max_bytes = int(max_backlog_s * baud / 10)
    start: list[float | None] = [None] * len(sizes)
    queue: deque[int] = deque()  # epochs waiting, none of their bytes sent
    busy_until = -math.inf  # when the line has sent the epoch it is sending

    def trim(now: float) -> None:
        while queue:
            too_old = now - t_s[queue[0]] > max_backlog_s
            backlog = max(0.0, (busy_until - now) / s_per_byte) + sum(sizes[j] for j in queue)
            if not too_old and (backlog <= max_bytes or len(queue) == 1):
                return
            queue.popleft()

    def advance(now: float) -> None:
        nonlocal busy_until
        while queue and busy_until <= now:
            t = max(busy_until, float(t_s[queue[0]]))
            trim(t)
            if not queue:
                return
            i = queue.popleft()
            start[i] = t
            busy_until = t + sizes[i] * s_per_byte

    for i, t in enumerate(t_s):
        advance(float(t))
        queue.append(i)
        trim(float(t))
        advance(float(t))
    advance(math.inf)
    return start


def byte_times_s(start_s: float, n_bytes: int, baud: int,
                 slice_s: float = PTY_SLICE_S) -> np.ndarray:
    """(n_bytes,) when each byte of an epoch that starts at ``start_s`` can be read: the end of
    its stop bit, handed over at the end of its ``slice_s`` slice (0: at once)."""
    t = start_s + np.arange(1, n_bytes + 1) * (10.0 / baud)
    return np.ceil(t / slice_s - 1e-9) * slice_s if slice_s else t


def read_timed(fd: int, seconds: float) -> list[tuple[float, bytes]]:
    """What the real device writes on its pty ``fd`` within ``seconds``: each read with the
    seconds since this call began (the driver models take them as the bytes' arrival)."""
    out = []
    t0 = time.monotonic()
    while (left := t0 + seconds - time.monotonic()) > 0:
        if select.select([fd], [], [], left)[0]:
            try:
                data = os.read(fd, 65536)
            except BlockingIOError:
                continue
            out.append((time.monotonic() - t0, data))
    return out
