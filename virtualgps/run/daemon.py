"""The live loop: one epoch per period on absolute ticks of the simulated clock, for one
receiver or a fleet.

Epochs fall on whole multiples of 1/rate of simulated UTC. Each epoch interpolates the poses to
the epoch time, runs :func:`virtualgps.receiver.core.simulate` on that one epoch of every receiver
due (the receivers as rows; the code replay runs on thousands of epochs), renders NMEA and
hands it to the devices, which never block. Pose messages and the clients' commands are read
whenever they arrive, between epochs (each receiver's own part: :mod:`virtualgps.run.live`).
"""

from __future__ import annotations

import contextlib
import gc
import logging
import math
import os
import select
import threading
import time
from collections.abc import Callable

import numpy as np

from virtualgps.device import mtk, nmea
from virtualgps.device.ubx import messages as ubx_messages
from virtualgps.device.ubx.link import UbxLink
from virtualgps.receiver.core import simulate
from virtualgps.receiver.definition import Receiver
from virtualgps.receiver.records import Fixes
from virtualgps.receiver.skyview import compute_sky
from virtualgps.receiver.state import ReceiverRows
from virtualgps.run.live import DaemonStats, LiveReceiver
from virtualgps.run.poseproviders import PoseProvider, SimClock

log = logging.getLogger(__name__)


def poses_at(
    provider: PoseProvider, t_unix_s: float, receiver_ids: list[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The poses of several receivers at one simulated time: the provider's ``poses_at`` where
    it has one, else its ``pose_at`` receiver by receiver.

    Returns
    -------
    pos : (n, 3) scene ENU m; vel : (n, 3) ENU m/s; valid : (n,) bool
    """
    batch = getattr(provider, "poses_at", None)
    if batch is not None:
        return batch(t_unix_s, receiver_ids)
    t = np.array([t_unix_s])
    got = [provider.pose_at(t, rid) for rid in receiver_ids]
    return (np.concatenate([p for p, _, _ in got]), np.concatenate([v for _, v, _ in got]),
            np.concatenate([ok for _, _, ok in got]))


def tick(
    members: list[LiveReceiver], provider: PoseProvider
) -> list[tuple[list[LiveReceiver], Fixes, list[bytes | None]]]:
    """Simulate the epoch of receivers due together and render their NMEA (sent by
    :meth:`LiveReceiver.sent`).

    Receivers that share a :class:`~virtualgps.receiver.definition.Receiver` and an epoch time are
    one batch: one :func:`compute_sky` for all their antennas (SGP4 once, every ray in one Embree
    call), one :func:`simulate` with the receivers as rows (:class:`ReceiverRows`: each row computed
    as that receiver alone would compute its one epoch), and their sentences rendered in one pass
    per output format.

    Parameters
    ----------
    members : receivers whose next epoch is due
    provider : the pose source (``pose_at(t, receiver_id)``)

    Returns
    -------
    batches : (receivers, their Fixes (one row each, in that order), their epochs' bytes
        (None: every sentence off)) per batch
    """
    groups: dict[tuple[int, float], list[LiveReceiver]] = {}
    for m in members:
        groups.setdefault((id(m.rx), m.t_next_unix_s), []).append(m)
    out = []
    for (_, t_epoch), group in groups.items():
        rx = group[0].rx
        n = len(group)
        t = np.array([t_epoch])
        pos, vel, valid = poses_at(provider, t_epoch, [m.receiver_id for m in group])
        pos = pos + np.array([m.offset_enu_m for m in group])
        ant = np.where(valid[:, None], pos, 0.0)
        sky = compute_sky(rx, t, ant[:, None, :]).rows()
        last = group[0]._row
        if last is not None and len(last[0].n_epochs) == n and all(
                m._row is not None and m._row[0] is last[0] and m._row[1] == b
                for b, m in enumerate(group)):
            rows = last[0]  # (the same batch as last tick, its states untouched since)
        else:
            rows = ReceiverRows.stack([m.state for m in group], [m.rng for m in group],
                                      rx.profile, group[0].n_sat)
        fixes, rows = simulate(rx, np.full(n, t_epoch), pos, vel, valid, rows, None, sky=sky)
        # (one pass over the receivers: a fleet's per-receiver Python is a cost of its own)
        by_fmt: dict[int, tuple[nmea.NmeaFormat, list[int]]] = {}  # (by the format object)
        ubx: list[int] = []
        prof = rx.profile
        for b, m in enumerate(group):
            m._row = (rows, b, prof)
            fmt = m.out_fmt
            if fmt is not None:
                entry = by_fmt.get(id(fmt))
                if entry is None:
                    by_fmt[id(fmt)] = entry = (fmt, [])
                entry[1].append(b)
            if isinstance(m.link, UbxLink):
                ubx.append(b)
        data: list[bytes | None] = [None] * n
        for fmt, idx in by_fmt.values():
            if len(idx) == n:
                data = list(nmea.render_batch(fixes, fmt))
            else:
                for b in idx:
                    data[b] = nmea.epoch_sentences(fixes, b, fmt)
        sol = None
        for b in ubx:  # (its UBX around the NMEA, at the link's rates)
            m = group[b]
            if sol is None:
                sol = ubx_messages.solution(fixes, m.link.uere_m)
            data[b] = m.link.output(fixes, b, m.stats.epochs, data[b] or b"", sol) or None
        out.append((group, fixes, data))
    return out


class StopEvent:
    """The flag the signal handlers set to stop the live loop, with a descriptor that turns
    readable once it is set, so a loop waiting in ``select``/``epoll`` wakes at once (a
    signal handler's ``set`` would otherwise wait for the loop's next timeout: an idle 1 Hz
    daemon then had to wake ten times a second just to look at the flag).

    :meth:`set` takes no lock, so a handler may run inside another's ``set``. It was a
    :class:`threading.Event`, whose ``set`` holds a lock: ``timeout -s INT`` sends SIGINT to
    the daemon and then to its process group, the second handler ran while the first held
    that lock, and the daemon hung for good (SIGTERM too; found with the README's demo in a
    script, 2026-11-28)."""

    def __init__(self) -> None:
        self._flag = False
        self._fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)

    def set(self) -> None:
        """Set the flag and wake the descriptor's waiters (safe in a signal handler)."""
        self._flag = True
        fd = self._fd
        if fd >= 0:  # (after close the number may belong to another file: never write to it)
            with contextlib.suppress(OSError):
                os.eventfd_write(fd, 1)

    def is_set(self) -> bool:
        """Whether :meth:`set` was called."""
        return self._flag

    def fileno(self) -> int:
        """Return the descriptor, readable once set."""
        return self._fd

    def close(self) -> None:
        """Close the descriptor (a later :meth:`set` still sets the flag)."""
        fd, self._fd = self._fd, -1
        if fd >= 0:
            os.close(fd)


class _SelectWaiter:
    """Waits with ``select`` on the pose source and the devices' client-byte events (devices
    with writer threads of their own: a single receiver's pty, a serial port)."""

    def __init__(self, devices: list) -> None:
        self.devices = devices

    def wait(self, deadline_s: float, fds: list[int]) -> None:
        fds = list(fds)
        blind = False  # a device without a descriptor (pyserial's loop://): look every 0.1 s
        for dev in self.devices:
            get_fd = getattr(dev, "fileno", None)
            fd = get_fd() if get_fd is not None else None
            if fd is not None:
                fds.append(fd)
            else:
                blind = True
        timeout = max(0.0, deadline_s - time.monotonic())
        if blind:
            timeout = min(timeout, 0.1)
        if fds:
            select.select(fds, [], [], timeout)
        else:
            time.sleep(timeout)

    def take_client_ready(self) -> list | None:
        return None  # unknown: read every device

    def serve(self) -> None:
        pass  # (the devices' own threads write)


def run_daemon(
    rx: Receiver,
    provider: PoseProvider,
    device,
    fmt: nmea.NmeaFormat,
    clock: SimClock,
    rng: np.random.Generator,
    stop: threading.Event | StopEvent,
    on_epoch: Callable[[Fixes, DaemonStats], None] | None = None,
    max_epochs: int | None = None,
    link: mtk.MtkLink | UbxLink | None | str = "profile",
) -> DaemonStats:
    """Emit one epoch per period until ``stop`` is set (or ``max_epochs`` epochs): one
    receiver, :func:`run_receivers` with one member (see :class:`LiveReceiver` for the
    command link).

    Parameters
    ----------
    rx : the receiver
    provider : pose source
    device : output device (``write_epoch``, ``read_available``; optional ``fileno`` and
        ``set_baud``), never blocking
    fmt : NMEA format
    clock : the simulated clock
    rng : random generator
    stop : set by the signal handlers to end the loop
    on_epoch : called after each epoch with its Fixes and the counters
    max_epochs : stop after this many epochs (tests)
    link : the command link; ``"profile"`` (default) makes the profile's (see
        :func:`make_link`), None for none

    Returns
    -------
    stats : DaemonStats
    """
    member = LiveReceiver(rx, device, fmt, clock, rng, link)
    cb = None if on_epoch is None else (lambda m, fixes, _: on_epoch(fixes, m.stats))
    run_receivers([member], provider, clock, stop, cb, max_epochs)
    return member.stats


# A fleet's due receivers are simulated in chunks of about CHUNK_S of work each, a power of two
# of receivers between the bounds (Thinning.chunk): large enough that a tick's per-batch cost
# (~3 ms) is small against its per-receiver cost (~0.05 ms in open sky, ~0.1 ms in the campus;
# a chunk of 32 costs 0.19 ms a receiver, one of 1024 0.05 ms), small enough that the devices'
# writers, run between chunks, are never held back long by the compute.
CHUNK_S = 0.04
CHUNK_RECEIVERS = 512  # (to start with)
CHUNK_BOUNDS = (64, 4096)
# Of each period at most this share goes to computing epochs ahead of their time, and an epoch
# may be computed up to LATE_SHARE of a period after it; the rest is the devices' and clients'.
LEAD_SHARE = 0.7
LATE_SHARE = 0.15
# Thinning is reported once it drops more than this share of the epochs asked over a window.
THIN_WARN_SHARE = 0.01
THIN_WINDOW_S = 5.0


def chunks_due(due: list[LiveReceiver], size: int = CHUNK_RECEIVERS) -> list[list[LiveReceiver]]:
    """Split the receivers due into the batches one :func:`tick` simulates: those sharing a
    :class:`~virtualgps.receiver.definition.Receiver` and an epoch time, in the fleet's order,
    cut into pieces of at most ``size``. The pieces are the same from one epoch to the next
    while the receivers due are, so each goes on from its last rows.

    Returns
    -------
    chunks : lists of receivers, the longest-waiting first (the oldest last epoch: a chunk
        thinned out at one epoch comes first at the next), and among those that waited as
        long, the one thinned out most often (without it, the first chunks of the fleet won
        every tie and the last were thinned twice as often)
    """
    groups: dict[tuple[int, float], list[LiveReceiver]] = {}
    for m in due:
        groups.setdefault((id(m.rx), m.t_next_unix_s), []).append(m)
    chunks = [g[i:i + size] for g in groups.values() for i in range(0, len(g), size)]
    never = -math.inf
    chunks.sort(key=lambda c: (never if c[0].t_last is None else c[0].t_last,
                               -c[0].stats.thinned_epochs))
    return chunks


class Thinning:
    """What the loop can compute per period, and the one warning when it cannot keep up.

    Attributes
    ----------
    s_per_receiver : the recent cost of one receiver's epoch, seconds (a moving average)
    chunk : receivers per chunk now (see CHUNK_S)
    asked, thinned : receiver-epochs due and left out since the window began
    warned : whether the overload was reported
    """

    def __init__(self, n_receivers: int) -> None:
        self.n_receivers = n_receivers
        self.s_per_receiver = 0.0
        self.asked = self.thinned = 0
        self.window_start_s = time.monotonic()
        self.warned = False
        self.chunk = CHUNK_RECEIVERS

    def measured(self, n: int, spent_s: float) -> None:
        """A chunk of ``n`` receivers took ``spent_s`` seconds: the cost per receiver, and the
        chunk size that takes about CHUNK_S (halved or doubled only when 1.5 times off, so the
        chunks, and the rows each goes on from, stay the same from one epoch to the next)."""
        per = spent_s / max(n, 1)
        self.s_per_receiver = per if self.s_per_receiver == 0.0 else (
            0.8 * self.s_per_receiver + 0.2 * per)
        if n < self.chunk:
            return  # (a short chunk, the last of its group, says little about the size)
        ideal = CHUNK_S / max(self.s_per_receiver, 1e-9)
        if ideal > 1.5 * self.chunk and self.chunk < CHUNK_BOUNDS[1]:
            self.chunk *= 2
        elif ideal < self.chunk / 1.5 and self.chunk > CHUNK_BOUNDS[0]:
            self.chunk //= 2

    def fits(self, n: int, left_s: float) -> bool:
        """Whether a chunk of ``n`` receivers is likely done within ``left_s`` seconds."""
        return n * self.s_per_receiver <= left_s

    def count(self, asked: int, thinned: int, rate_hz: float) -> None:
        """One epoch's receivers due and left out; warns once when the window's share left out
        is past THIN_WARN_SHARE."""
        self.asked += asked
        self.thinned += thinned
        now = time.monotonic()
        if now - self.window_start_s < THIN_WINDOW_S:
            return
        if not self.warned and self.thinned > THIN_WARN_SHARE * self.asked:
            self.warned = True
            share = 1.0 - self.thinned / self.asked
            n = self.n_receivers
            what = "the receiver" if n == 1 else f"{n} receivers"
            advice = ("lower --rate, or use a lighter scene or profile (one receiver's epochs "
                      "are computed in one process)" if n == 1 else
                      "use more worker processes (--workers, this process may use "
                      f"{len(os.sched_getaffinity(0))} cores), split the fleet across hosts "
                      "(--ids), or lower --rate")
            log.warning(
                "%s at %g Hz need%s %.2f ms each per epoch, %.0f %% more than this process "
                "has: epochs are thinned evenly, each receiver gets ~%.1f Hz (%.0f %% of its "
                "epochs); %s", what, rate_hz, "s" if n == 1 else "", 1e3 * self.s_per_receiver,
                100.0 * (1.0 / share - 1.0), share * rate_hz, 100.0 * share, advice)
        self.asked = self.thinned = 0
        self.window_start_s = now


def freeze_heap() -> None:
    """Leave what a daemon built before its loop (scene, ephemeris, receivers, devices) out of
    the garbage collector's passes (``gc.freeze``; the objects are still freed when their last
    reference goes).

    A full collection walks every object tracked: over a fleet worker's heap one paused the
    loop for up to 37 ms (five in 8 s, 2,000 receivers over two workers, seen through
    ``gc.callbacks``), longer than a 10 Hz epoch's first bytes may wait.
    """
    gc.collect()
    gc.freeze()


def run_receivers(
    members: list[LiveReceiver],
    provider: PoseProvider,
    clock: SimClock,
    stop: threading.Event | StopEvent,
    on_epoch: Callable[[LiveReceiver, Fixes, int], None] | None = None,
    max_epochs: int | None = None,
    waiter=None,
    duration_s: float | None = None,
) -> None:
    """The live loop of one or many receivers: each emits its epochs on whole multiples of its
    period; receivers due at once are simulated together, in chunks (:func:`chunks_due`).

    Between epochs the loop reads poses and the clients' commands as they arrive; between
    chunks the devices' writers run. An epoch is computed ahead of its time (by what the last
    ones took, at most LEAD_SHARE of a period) and sent at its time. When the receivers due
    cannot all be computed by LATE_SHARE of a period after it, the chunks left are *thinned*
    out of that epoch (they go first at the next): under overload every receiver still gets
    fresh epochs, at a lower rate, and every device is served (:class:`Thinning` warns once).

    Parameters
    ----------
    members : the receivers
    provider : pose source, ``pose_at(t, receiver_id)``
    clock : the simulated clock
    stop : set by the signal handlers to end the loop (one with a ``fileno``, as
        :class:`StopEvent`, wakes the loop's waits at once)
    on_epoch : called after each receiver's epoch with the receiver, the Fixes of its batch
        and its row there
    max_epochs : stop once every receiver has emitted this many epochs (tests)
    waiter : what the loop waits in: ``wait(deadline_s, fds)``, ``take_client_ready()`` and
        ``serve()`` (a :class:`virtualgps.run.fleet.ptyloop.PtyLoop` serving the devices;
        default: ``select`` on the pose source and the devices' own descriptors)
    duration_s : simulated seconds, counted from the first epoch due: the loop ends before the
        first epoch due at or after then, so ``--duration S`` sends the S × rate epochs of
        [first, first + S) whatever the phase of the start within a second, and however long
        the set-up took after the receivers' clock started
    """
    # (Counted from the clock's reading just before the loop, an epoch already due when a
    # slow set-up crossed a whole second made S × rate + 1.)
    until_unix_s = (None if duration_s is None
                    else min(m.t_next_unix_s for m in members) + duration_s)
    if waiter is None:
        waiter = _SelectWaiter([m.device for m in members])
    by_device = {id(m.device): m for m in members}
    # A stop with a descriptor to wait on (StopEvent) lets the loop sleep until the next epoch;
    # a plain Event is looked at every 0.1 s.
    stop_fileno = getattr(stop, "fileno", None)
    stop_fds = [stop_fileno()] if stop_fileno is not None else []
    max_wait_s = math.inf if stop_fds else 0.1
    thin = Thinning(len(members))
    lead_s = 0.0  # how long before its time an epoch's computing starts

    def send(batches, deadline: float) -> None:
        lateness = time.monotonic() - deadline
        for group, fixes, data in batches:
            for b, m in enumerate(group):
                if lateness > 0.5 / m.rate:
                    m.stats.late_epochs += 1
                m.stats.max_lateness_s = max(m.stats.max_lateness_s, lateness)
                m.sent(data[b], bool(fixes.quality[b] > 0))
                if on_epoch is not None:
                    on_epoch(m, fixes, b)

    while not stop.is_set():
        # Wait for the next epoch due, reading poses and the clients' commands as they come.
        while not stop.is_set():
            provider.pump()
            ready = waiter.take_client_ready()
            for m in members if ready is None else [by_device[id(d)] for d in ready]:
                m.service_client()  # (may change a receiver's rate and next epoch)
            t_due = min(m.t_next_unix_s for m in members)
            if until_unix_s is not None and t_due > until_unix_s - 1e-6:
                return
            deadline = clock.monotonic_at(t_due)
            if deadline - lead_s <= time.monotonic():
                break
            waiter.wait(min(deadline - lead_s, time.monotonic() + max_wait_s),
                        [*provider.fileno_list(), *stop_fds])
        if stop.is_set():
            break
        due = [m for m in members if m.t_next_unix_s <= t_due + 1e-9]
        period_s = 1.0 / max(m.rate for m in due)
        give_up_unix_s = t_due + LATE_SHARE * period_s  # (on the simulated clock)
        held, n_done = [], 0
        for i, chunk in enumerate(chunks_due(due, thin.chunk)):
            if i > 0 and not thin.fits(len(chunk), give_up_unix_s - clock.now_unix_s()):
                for m in chunk:
                    m.skip()
                continue
            t0 = time.monotonic()
            batches = tick(chunk, provider)
            thin.measured(len(chunk), time.monotonic() - t0)
            n_done += len(chunk)
            if time.monotonic() >= deadline:  # (late: out at once, after any held)
                send(held + batches, deadline)
                held = []
            else:
                held += batches
            waiter.serve()  # (the devices' writers, between chunks)
        thin.count(len(due), len(due) - n_done, 1.0 / period_s)
        lead_s = min(1.25 * thin.s_per_receiver * len(due) + 0.002, LEAD_SHARE * period_s)
        if held:
            while time.monotonic() < deadline and not stop.is_set():
                waiter.wait(deadline, stop_fds)  # (the devices' writers are served meanwhile)
            send(held, deadline)
        if max_epochs is not None and all(m.stats.epochs >= max_epochs for m in members):
            break
