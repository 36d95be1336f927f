"""Many pseudo-terminals served from one thread: an epoll loop over their writers.

A fleet of a thousand receivers cannot afford a writer thread per device (a thread's stack, and
a context switch per slice of output). :class:`PtyLoop` drives :class:`~virtualgps.device.pty.
PtyDevice` writers built with ``threaded=False``: each device's :meth:`~virtualgps.device.pty.
PtyDevice.step` runs when its next slice is due (a heap of wake times), when a new epoch is
queued for it, or when its master reports client bytes or a hang-up (epoll, level-triggered,
watched only while a reader is attached). One stalled reader only ever delays its own device:
a step never blocks, and a device whose client stopped reading is looked at again on its own
schedule, apart from the rest. Devices nobody has open are not stepped one by one: one
``poll`` over all of them every ``_IDLE_POLL_S`` finds those a client opened (their queues
trim themselves as epochs arrive), so ten thousand unopened devices cost one system call, not
ten thousand, per look.

The loop also waits on the caller's descriptors (the pose source), so the daemon's thread does
all its waiting in one ``epoll_wait``.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import logging
import select
import time

from virtualgps.device.output import _IDLE_POLL_S
from virtualgps.device.pty import PtyDevice

log = logging.getLogger(__name__)


class PtyLoop:
    """Serve many non-threaded :class:`PtyDevice` writers from the calling thread.

    Attributes
    ----------
    devices : the devices added, in order
    client_ready : devices whose client bytes wait for ``read_available`` (filled by
        :meth:`wait`; :meth:`take_client_ready` empties it)
    """

    def __init__(self) -> None:
        self._ep = select.epoll()
        self.devices: list[PtyDevice] = []
        self._by_fd: dict[int, PtyDevice] = {}
        self._watching: dict[int, bool] = {}
        self._due_s: dict[int, float] = {}  # master fd -> monotonic time of its next step
        self._heap: list[tuple[float, int, int]] = []  # (due, tie-break, master fd), lazily
        self._tie = itertools.count()
        self._kicked: set[int] = set()
        self._events: set[int] = set()  # masters epoll reported since their last step
        self._extra: set[int] = set()
        self.client_ready: set[PtyDevice] = set()
        self.steps = 0
        # Devices without a reader: watched together (POLLHUP holds while nobody has the slave
        # open, and no event says it cleared), not stepped until one shows a reader.
        self._idle: set[int] = set()
        self._idle_poll = select.poll()
        self._idle_check_s = 0.0

    def add(self, device: PtyDevice) -> None:
        """Take over ``device``'s writer (built with ``threaded=False``); it steps at once."""
        fd = device.master_fd
        device.on_wake = self._kick
        self.devices.append(device)
        self._by_fd[fd] = device
        self._watching[fd] = False
        self._kicked.add(fd)

    def _kick(self, device: PtyDevice) -> None:
        fd = device.master_fd
        if fd not in self._idle:  # (an idle device's new epoch waits in its queue)
            self._kicked.add(fd)

    def _sync_extra(self, fds: list[int]) -> None:
        want = set(fds)
        for fd in self._extra - want:
            with contextlib.suppress(OSError):  # (closed already: epoll forgot it)
                self._ep.unregister(fd)
        for fd in want - self._extra:
            self._ep.register(fd, select.EPOLLIN)
        self._extra = want

    def _step(self, fd: int, now_s: float, master_quiet: bool = False) -> None:
        dev = self._by_fd.get(fd)
        if dev is None or not dev.alive:
            if fd in self._idle:
                self._idle.discard(fd)
                with contextlib.suppress(KeyError, ValueError):
                    self._idle_poll.unregister(fd)
            return
        timeout_s = dev.step(master_quiet and self._watching[fd])
        self.steps += 1
        if dev.client_bytes_waiting:
            self.client_ready.add(dev)
        if dev.watch_master != self._watching[fd]:
            if dev.watch_master:
                self._ep.register(fd, select.EPOLLIN)
            else:
                self._ep.unregister(fd)
            self._watching[fd] = dev.watch_master
        if not dev.reader_attached and dev.alive:
            if fd not in self._idle:
                self._idle.add(fd)
                self._idle_poll.register(fd, select.POLLIN)
            self._due_s.pop(fd, None)
            return
        if fd in self._idle:
            self._idle.discard(fd)
            self._idle_poll.unregister(fd)
        due = now_s + timeout_s
        self._due_s[fd] = due
        heapq.heappush(self._heap, (due, next(self._tie), fd))

    def run_due(self) -> None:
        """Step every device that is due now or was woken (new output, master events)."""
        now_s = time.monotonic()
        fds = self._kicked
        self._kicked = set()
        while self._heap and self._heap[0][0] <= now_s:
            due, _, fd = heapq.heappop(self._heap)
            if self._due_s.get(fd) == due:  # (else a stale entry: the device stepped since)
                fds.add(fd)
        if self._idle and now_s >= self._idle_check_s:
            self._idle_check_s = now_s + _IDLE_POLL_S
            gone = select.POLLHUP | select.POLLNVAL
            hung_up = {fd for fd, ev in self._idle_poll.poll(0) if ev & gone}
            fds |= self._idle - hung_up  # (a reader came: step it)
        events, self._events = self._events, set()
        for fd in fds:
            self._step(fd, now_s, fd not in events)

    def serve(self) -> None:
        """Step the devices due now or whose masters have events (client bytes, a hang-up),
        without waiting (between a fleet's chunks of work).

        The events are polled here too: an overloaded fleet seldom reaches :meth:`wait`, and a
        step without them leaves the master unread, so a client's command waited for the load
        to ease (3,500 receivers in one process: a ``$PMTK000`` answered after 0.5–1.8 s).
        """
        self._poll(0.0)
        self.run_due()

    def _poll(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for epoll; mark the devices it reports (their next step
        reads the master). Returns whether one of the caller's descriptors is readable."""
        extra = False
        for fd, _ in self._ep.poll(timeout_s):
            if fd in self._by_fd:
                self._kicked.add(fd)
                self._events.add(fd)
            else:
                extra = True
        return extra

    def take_client_ready(self) -> list[PtyDevice]:
        """Return (and forget) the devices whose client bytes wait for ``read_available``."""
        ready = list(self.client_ready)
        self.client_ready.clear()
        return ready

    def wait(self, deadline_s: float, fds: list[int] = ()) -> bool:
        """Serve the devices until ``deadline_s`` (monotonic), until one of ``fds`` is readable
        or until a client's bytes arrive.

        Parameters
        ----------
        deadline_s : monotonic seconds
        fds : the caller's descriptors (e.g. the pose source's sockets)

        Returns
        -------
        bool
            True if one of ``fds`` became readable, or a device's client bytes arrived (see
            :meth:`take_client_ready`; only when none were waiting already), before the
            deadline.
        """
        self._sync_extra(list(fds))
        had_client_bytes = bool(self.client_ready)
        while True:
            self.run_due()
            if self.client_ready and not had_client_bytes:
                return True  # (a command to answer now, not at the next epoch)
            now_s = time.monotonic()
            if now_s >= deadline_s:
                return False
            next_s = self._heap[0][0] if self._heap else deadline_s
            if self._idle:
                next_s = min(next_s, self._idle_check_s)
            timeout_s = max(0.0, min(deadline_s, next_s) - now_s)
            if self._kicked:
                timeout_s = 0.0
            if self._poll(timeout_s):
                self.run_due()
                return True

    def close(self) -> None:
        """Close every device (removing its link) and the loop."""
        for dev in self.devices:
            dev.close()
        self._ep.close()
