"""A fleet spread over worker processes: ``virtualgps run --workers N``.

One process computes at most one core's worth of epochs, so a fleet is cut into ``N``
contiguous shares of its receivers, each run by a worker process of its own with the same
loop a lone daemon runs (:func:`virtualgps.run.daemon.run_receivers`): it loads the scene and
ephemeris, makes its receivers' ptys, serves them from its own epoll loop and computes their
epochs with the same vectorised tick. A receiver's bytes are those of the same receiver run
alone, in whichever share it falls (each row of a tick is computed as that receiver alone).

The parent process only coordinates: it prints the device lines in the fleet's order, starts
every worker's simulated clock at one instant (so all receivers keep one time), forwards live
pose messages (UDP, TCP, stdin) to the worker that holds each message's receiver (a framed
batch per worker and read, over a local stream socket), adds up the status line and the exit
line, and stops the workers on SIGINT/SIGTERM. A worker dies with its parent (a killed parent
leaves no orphan holding ptys), and a worker that fails stops the run with its error.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import multiprocessing
import os
import pickle
import select
import signal
import socket
import sys
import time
from dataclasses import dataclass

from virtualgps.exceptions import VirtualGPSError
from virtualgps.poses.posesource import PoseSource
from virtualgps.run import daemon, poseproviders
from virtualgps.run.fleet.members import Member
from virtualgps.run.fleet.run import Progress, RunSummary, build_fleet, log_links, progress
from virtualgps.run.processes import die_with_parent

log = logging.getLogger(__name__)

STATUS_EVERY_S = 1.0  # how often a worker reports its progress
STOP_WAIT_S = 30.0  # how long a stopped run waits for its workers' counts before ending them
_MAX_PENDING_BYTES = 16 << 20  # forwarded poses a worker has yet to take (~100,000 messages)
_FORWARD_BUF_BYTES = 4 << 20


# A worker per this many receivers at most, by default: each worker pays a tick's fixed cost
# (~3 ms an epoch) of its own, which a small fleet does not win back (tools/bench_fleet.py, 10
# receivers at 10 Hz: 0.04 cores in one process, 0.08 over two).
RECEIVERS_PER_WORKER = 500


def default_workers(n_receivers: int) -> int:
    """Worker processes for a fleet of ``n_receivers`` when ``--workers`` is not given: one per
    core this process may run on, and one per RECEIVERS_PER_WORKER receivers at most (a fleet
    of up to 500 runs in the one process, as a single receiver does).
    """
    per_load = -(-n_receivers // RECEIVERS_PER_WORKER)
    return max(1, min(per_load, len(os.sched_getaffinity(0))))


def shares(members: list[Member], n_workers: int) -> list[list[Member]]:
    """Cut the fleet into ``n_workers`` contiguous shares, their sizes differing by one at most.
    """
    n = len(members)
    bounds = [round(i * n / n_workers) for i in range(n_workers + 1)]
    return [members[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]


@dataclass(frozen=True)
class WorkerJob:
    """What one worker runs.

    index : its number; flags : the run's settings; poses_spec : ``--poses``;
    link_pattern : ``--link``; members : its receivers; fleet_ids : every receiver's id of the
    fleet; topic : ``--topic``; forward_address : the abstract AF_UNIX address it reads
    forwarded pose messages on (None: it reads ``--poses`` itself: a log or the demo walk);
    log_level : the parent's logging level; duration_s : ``--duration`` (None: until stopped),
    counted from its receivers' first epoch as one process counts it
    """

    index: int
    flags: dict
    poses_spec: str
    link_pattern: str
    members: list[Member]
    fleet_ids: list[int]
    topic: str | None
    forward_address: str | None
    log_level: int
    duration_s: float | None = None


class ForwardedPoses(PoseSource):
    """The pose messages a parent forwards to one worker, over a local stream socket: frames
    of a 4-byte length and a pickled list of ``(message bytes, arrival time)`` as the parent's
    source read them. (A stream, not datagrams: an AF_UNIX datagram queue holds only
    ``net.unix.max_dgram_qlen`` datagrams, 10 by default, fewer than a busy epoch's.)

    address : the abstract AF_UNIX address to listen on; spec : the parent's ``--poses``
    """

    def __init__(self, address: str, spec: str) -> None:
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        self._listener.bind("\0" + address)
        self._listener.listen(1)
        self._sock: socket.socket | None = None
        self._buf = bytearray()
        self._spec = spec
        self.received_messages = 0
        self.dropped_messages = 0

    def accept(self) -> None:
        """Take the parent's connection (it connects once the clocks start)."""
        self._sock, _ = self._listener.accept()
        self._listener.close()
        with contextlib.suppress(OSError):
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _FORWARD_BUF_BYTES)
        self._sock.setblocking(False)

    def poll(self) -> list[tuple[bytes, float]]:
        """Return the messages forwarded since the last call, oldest first."""
        out: list[tuple[bytes, float]] = []
        if self._sock is None:
            return out
        while True:
            try:
                data = self._sock.recv(1 << 20)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break
            if not data:
                break
            self._buf += data
        buf, k = self._buf, 0
        while len(buf) - k >= 4:
            size = int.from_bytes(buf[k:k + 4], "little")
            if len(buf) - k - 4 < size:
                break
            out.extend(pickle.loads(buf[k + 4:k + 4 + size]))
            k += 4 + size
        del buf[:k]
        self.received_messages += len(out)
        return out

    def fileno(self) -> int:
        return (self._sock if self._sock is not None else self._listener).fileno()

    def describe(self) -> str:
        return self._spec

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
        self._listener.close()


class Forwarder:
    """The parent's side: reads ``--poses`` and sends each message to the worker holding its
    receiver (by its ``"id"``, default 0; a message that names no receiver of the fleet, or
    does not parse, goes to the first worker, which counts it as its own would; one for a
    receiver other hosts run, ``--ids``, is skipped and counted in ``elsewhere``).

    source : the opened pose source; addresses : each worker's address (it listens there);
    owner : receiver id -> worker index; fleet_ids : every id of the fleet
    """

    def __init__(self, source: PoseSource, addresses: list[str],
                 owner: dict[int, int], fleet_ids: list[int]) -> None:
        self.source = source
        self.owner = owner
        self.other_hosts = frozenset(fleet_ids) - set(owner)
        self.elsewhere = 0
        self.dropped = 0
        self._socks: list[socket.socket] = []
        for a in addresses:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
            sock.connect("\0" + a)
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, _FORWARD_BUF_BYTES)
            sock.setblocking(False)
            self._socks.append(sock)
        self._out = [bytearray() for _ in addresses]  # (what a worker has yet to take)

    def fileno_list(self) -> list[int]:
        return self.source.fileno_list()

    @property
    def pending(self) -> bool:
        """Whether some worker has yet to take what was forwarded to it."""
        return any(self._out)

    def pump(self) -> None:
        """Forward what has arrived, and what a worker had yet to take; never waits. A worker
        with more than _MAX_PENDING_BYTES untaken loses new messages, as a full UDP buffer
        would, and the loss is counted."""
        batches: dict[int, list[tuple[bytes, float]]] = {}
        for data, t in self.source.poll():
            w = self._owner_of(data)
            if w is None:
                self.elsewhere += 1
                continue
            batches.setdefault(w, []).append((data, t))
        for w, msgs in batches.items():
            if len(self._out[w]) > _MAX_PENDING_BYTES:
                if not self.dropped:
                    log.warning("worker %d is not taking its pose messages: dropping them "
                                "(counted in the exit line)", w)
                self.dropped += len(msgs)
                continue
            frame = pickle.dumps(msgs)
            self._out[w] += len(frame).to_bytes(4, "little") + frame
        for w, out in enumerate(self._out):
            while out:
                try:
                    n = self._socks[w].send(out)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:  # (the worker is gone: its end is reported by the loop)
                    out.clear()
                    break
                del out[:n]

    def _owner_of(self, data: bytes) -> int | None:
        """The worker of a message's receiver (None: another host's)."""
        try:
            rid = json.loads(data).get("id", 0)
        except (ValueError, AttributeError):
            return 0
        if type(rid) is not int:
            return 0
        w = self.owner.get(rid)
        if w is None:
            return None if rid in self.other_hosts else 0
        return w

    def close(self) -> None:
        for sock in self._socks:
            sock.close()
        self.source.close()


# --- the worker ------------------------------------------------------------------------------


class _Stopped(Exception):
    """The parent stopped the run before the clocks started."""


def worker_main(job: WorkerJob, conn) -> None:
    """A worker process: make its share of the fleet, report its devices, start its clock when
    the parent says, run the live loop until stopped, report the counts.

    Messages to the parent (``conn``): ``("devices", [(slave, link), ...])``, ``("status",
    Progress)`` once a second, ``("done", RunSummary)``, or ``("error", line)``.
    """
    # The set-up lines (ephemeris, profile, warnings about them) are the same in every worker:
    # the first says them, the others only their errors until the clocks start.
    logging.basicConfig(level=job.log_level if job.index == 0 else logging.ERROR,
                        format="virtualgps: %(message)s", stream=sys.stderr)
    die_with_parent()
    stop = daemon.StopEvent()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    def start_clock(devices, start_unix_s):
        conn.send(("devices", [(str(d.slave_path), str(d.link_path)) for d in devices]))
        msg = conn.recv()
        if msg[0] != "go":
            raise _Stopped
        _, mono0, wall0 = msg
        logging.getLogger().setLevel(job.log_level)
        if source is not None:
            source.accept()  # (the parent connects right after the go)
        return poseproviders.SimClock(start_unix_s, mono0, wall0)

    source = (None if job.forward_address is None
              else ForwardedPoses(job.forward_address, job.poses_spec))
    try:
        fleet = build_fleet(job.flags, job.poses_spec, job.link_pattern, topic=job.topic,
                            members=job.members, fleet_ids=job.fleet_ids,
                            pose_source=source, start_clock=start_clock)
    except _Stopped:
        return
    except VirtualGPSError as exc:
        conn.send(("error", str(exc)))
        return
    except (EOFError, OSError):  # (the parent went away)
        return
    next_status = [time.monotonic() + STATUS_EVERY_S]

    def on_epoch(r, fixes, row) -> None:
        now = time.monotonic()
        if now >= next_status[0]:
            next_status[0] = now + STATUS_EVERY_S
            with contextlib.suppress(OSError):
                conn.send(("status", progress(fleet)))

    daemon.freeze_heap()
    try:
        daemon.run_receivers(fleet.receivers, fleet.provider, fleet.clock, stop, on_epoch,
                             waiter=fleet.waiter, duration_s=job.duration_s)
    finally:
        fleet.close()
        stop.close()
    log_links(fleet.receivers)
    with contextlib.suppress(OSError):
        conn.send(("done", RunSummary.of(fleet)))


# --- the parent ------------------------------------------------------------------------------


def run_workers(
    flags: dict,
    poses_spec: str,
    link_pattern: str,
    members: list[Member],
    fleet_ids: list[int],
    topic: str | None,
    n_workers: int,
    stop: daemon.StopEvent,
    start_unix_s: float | None,
    duration_s: float | None = None,
    on_device=None,
    on_status=None,
    live_source: PoseSource | None = None,
) -> RunSummary:
    """Run a fleet over ``n_workers`` worker processes until ``stop`` (or ``duration_s``).

    Parameters
    ----------
    flags, poses_spec, link_pattern, topic : the run's settings (as :func:`build_fleet`)
    members : the receivers; fleet_ids : every id of the fleet (with --ids, beyond these)
    n_workers : worker processes (each gets a contiguous share)
    stop : set to end the run
    start_unix_s : ``--start-time`` (None: the wall clock)
    duration_s : ``--duration``: simulated seconds from the first epoch
    on_device : called with (slave path, link) of each device, in the fleet's order, before
        the first epoch
    on_status : called with the fleet's :class:`Progress` about once a second
    live_source : the opened live pose source (UDP, TCP, stdin), forwarded to the workers

    Returns
    -------
    summary : the fleet's counts (the forwarder's drops in ``bad["forward-dropped"]``)

    Raises
    ------
    VirtualGPSError
        a worker's one-line error (bad settings, a limit), or a worker that died.
    """
    parts = shares(members, n_workers)
    ctx = multiprocessing.get_context("spawn")  # (a fresh interpreter: no forked threads)
    token = f"virtualgps-{os.getpid()}-{time.monotonic_ns()}"
    addresses = [f"{token}-{i}" for i in range(len(parts))] if live_source else []
    level = logging.getLogger().getEffectiveLevel()
    procs, conns = [], []
    # (BLAS pools: one thread per worker; the workers are the parallelism)
    env = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    saved = {k: os.environ.get(k) for k in env}
    forwarder = None
    summary = RunSummary()
    devices: list[list | None] = [None] * len(parts)
    try:
        try:
            for k in env:
                os.environ.setdefault(k, env[k])
            for i, part in enumerate(parts):
                job = WorkerJob(i, flags, poses_spec, link_pattern, part, fleet_ids, topic,
                                addresses[i] if addresses else None, level, duration_s)
                parent_end, child_end = ctx.Pipe()
                p = ctx.Process(target=worker_main, args=(job, child_end),
                                name=f"virtualgps-worker-{i}")
                p.start()
                child_end.close()
                procs.append(p)
                conns.append(parent_end)
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        printed = 0
        while printed < len(parts):
            for i, msg in _messages(conns, procs, stop, 0.5):
                if msg[0] == "error":
                    raise VirtualGPSError(msg[1])
                if msg[0] == "devices":
                    devices[i] = msg[1]
            while printed < len(parts) and devices[printed] is not None:
                for slave, link in devices[printed]:
                    if on_device is not None:
                        on_device(slave, link)
                printed += 1
            if stop.is_set():
                return summary
        log.info("%d receivers over %d worker processes (%s receivers each)", len(members),
                 len(parts), "-".join(sorted({str(len(p)) for p in parts}, key=int)))
        clock = poseproviders.SimClock(start_unix_s)
        for c in conns:
            c.send(("go", *clock.anchor))
        if live_source is not None:
            owner = {m.receiver_id: i for i, part in enumerate(parts) for m in part}
            forwarder = Forwarder(live_source, addresses, owner, fleet_ids)
        progress: list[Progress] = [Progress() for _ in parts]
        done: dict[int, RunSummary] = {}
        told, give_up = False, math.inf
        while len(done) < len(parts) and time.monotonic() < give_up:
            if stop.is_set() and not told:
                told, give_up = True, time.monotonic() + STOP_WAIT_S
                for p in procs:
                    if p.is_alive():
                        with contextlib.suppress(OSError):
                            os.kill(p.pid, signal.SIGTERM)
            fds = forwarder.fileno_list() if forwarder is not None else []
            wait_s = 0.01 if forwarder is not None and forwarder.pending else 0.5
            # (once told, the stop's descriptor stays readable: wait on the workers alone)
            for i, msg in _messages(conns, procs, None if told else stop, wait_s, fds, done):
                if msg[0] == "status":
                    progress[i] = msg[1]
                    if on_status is not None:
                        on_status(sum(progress, Progress()))
                elif msg[0] == "done":
                    done[i] = msg[1]
            if forwarder is not None:
                forwarder.pump()
        summary = sum(done.values(), RunSummary())
        if forwarder is not None:
            summary.elsewhere += forwarder.elsewhere
            if forwarder.dropped:
                summary.bad = {**(summary.bad or {}), "forward-dropped": forwarder.dropped}
        return summary
    finally:
        if forwarder is not None:
            forwarder.close()
        elif live_source is not None:
            live_source.close()
        _end(procs, conns, devices)


def _messages(conns, procs, stop, timeout_s: float, fds=(), done=()):
    """Wait up to ``timeout_s`` for the workers' messages (or ``fds``, or ``stop``); return
    [(worker index, message)]. Raises VirtualGPSError for a worker that died without one."""
    waits = [c for i, c in enumerate(conns) if i not in done]
    sentinels = {p.sentinel: i for i, p in enumerate(procs) if i not in done}
    stops = [] if stop is None else [stop.fileno()]
    ready, _, _ = select.select([*waits, *sentinels, *fds, *stops], [], [], timeout_s)
    out = []
    for i, c in enumerate(conns):
        if i in done:
            continue
        with contextlib.suppress(EOFError, OSError):
            while c.poll():
                out.append((i, c.recv()))
    got = {i for i, m in out if m[0] in ("done", "error")}
    for s, i in sentinels.items():
        if s in ready and i not in got and not procs[i].is_alive():
            raise VirtualGPSError(
                f"worker process {i} stopped (exit code {procs[i].exitcode}) before its "
                "receivers did: the run is stopped (see the lines above)")
    return out


def _end(procs, conns, devices) -> None:
    """Stop the workers left (a worker still starting is told to stop; a running one gets
    SIGTERM, then SIGKILL) and remove the links a killed one left behind."""
    for c in conns:
        with contextlib.suppress(OSError):
            c.send(("stop",))
    for p in procs:
        if p.is_alive():
            with contextlib.suppress(OSError):
                os.kill(p.pid, signal.SIGTERM)
    deadline = time.monotonic() + 10.0
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(5.0)
    for c in conns:
        c.close()
    for made in devices:
        for slave, link in made or ():
            with contextlib.suppress(OSError):
                if os.readlink(link) == slave:  # (left by a killed worker: it points nowhere)
                    os.unlink(link)
