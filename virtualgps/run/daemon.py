"""The live loop: one epoch per period on absolute ticks of the simulated clock, for one
receiver or a fleet.

Epochs fall on whole multiples of 1/rate of simulated UTC. Each epoch interpolates the poses to
the epoch time, runs :func:`virtualgps.receiver.core.simulate` on that one epoch of every receiver
due (the receivers as rows; the code replay runs on thousands of epochs), renders NMEA and
hands it to the devices, which never block. Pose messages and the clients' commands are read
whenever they arrive, between epochs.
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
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from virtualgps.device import mtk, nmea
from virtualgps.device.ubx import messages as ubx_messages
from virtualgps.device.ubx.link import UbxLink
from virtualgps.device.ubx.settings import default_settings as ubx_defaults
from virtualgps.receiver.core import simulate
from virtualgps.receiver.definition import Receiver
from virtualgps.receiver.profiles import Profile
from virtualgps.receiver.records import Fixes
from virtualgps.receiver.skyview import compute_sky
from virtualgps.receiver.state import ReceiverRows, ReceiverState, initial_state, restart
from virtualgps.run.poseproviders import PoseProvider, SimClock
from virtualgps.sky import systems as sky_systems

log = logging.getLogger(__name__)


@dataclass
class DaemonStats:
    """Counters the status line and the exit summary show.

    link : the command link (its ``settings`` are what the client set: with MTK fix interval,
        baud, sentence rates, SBAS, static-navigation threshold; with u-blox baud, protocols,
        message rates, navigation rate, GNSS, dynamic model), or None without one
    """

    epochs: int = 0
    fixes: int = 0
    last_fix: bool = False  # whether the last epoch sent had a fix
    # (late: sent over half a period after their time; skipped: the loop fell behind by over a
    # period, e.g. a suspended machine; thinned: left out to keep up, see Thinning)
    late_epochs: int = 0
    skipped_epochs: int = 0
    thinned_epochs: int = 0
    max_lateness_s: float = 0.0
    link: mtk.MtkLink | UbxLink | None = None


def make_link(profile, fmt: nmea.NmeaFormat) -> mtk.MtkLink | UbxLink | None:
    """The profile's command link: a :class:`~virtualgps.device.mtk.MtkLink` for ``mtk``, a
    :class:`~virtualgps.device.ubx.link.UbxLink` for ``ubx``, else None.

    Parameters
    ----------
    profile : the receiver profile (``command_link``, ``firmware``, ``rate_hz``, ``baud``)
    fmt : its output format (the sentences and their rates at power-on)

    Returns
    -------
    link : MtkLink, UbxLink or None
    """
    kind = getattr(profile, "command_link", "none")
    if kind == "ubx":
        return make_ubx_link(profile)
    if kind != "mtk":
        return None
    sbas = profile.sbas.enabled
    hold = profile.static_hold
    defaults = mtk.default_settings(
        fmt.sentences, dict(fmt.every), profile.rate_hz, profile.baud,
        dgps_mode=2 if sbas else 0, sbas_enabled=sbas,
        static_nav_mps=hold.threshold_mps if hold.enabled else 0.0,
    )
    return mtk.MtkLink(defaults, profile.firmware)


def make_ubx_link(profile) -> UbxLink:
    """A u-blox link at the profile's power-on: its generation (``[ubx]``), baud, rate, and the
    systems it tracks enabled (SBAS where ``[sbas]`` is on).

    profile : the receiver profile; returns the UbxLink
    """
    systems = list(profile.constellations.systems if profile.constellations.enabled
                   else ("GPS",))
    if profile.sbas.enabled:
        systems.append("SBAS")
    defaults = ubx_defaults(profile.ubx.generation, baud=profile.baud, rate_hz=profile.rate_hz,
                            gnss=tuple(systems))
    return UbxLink(defaults)


def tracking_systems(rx: Receiver, profile: Profile, enabled: frozenset[str]) -> Receiver:
    """The receiver tracking the systems of its profile that a u-blox client left enabled
    (CFG-GNSS, CFG-SIGNAL-*_ENA): a system switched off is neither tracked nor listed; one
    switched on that the profile's ephemeris does not hold stays absent.

    rx : the receiver now; profile : its profile at power-on; enabled : the names enabled
    (``UbxSettings.enabled_gnss``: "GPS", "GLONASS", "Galileo", "BeiDou", "QZSS", ...)
    """
    cs = profile.constellations
    systems = cs.systems if cs.enabled else ("GPS",)
    keep = tuple(s for s in systems if sky_systems.system_named(s).name in enabled)
    prof = rx.profile
    return replace(rx, profile=replace(prof, constellations=replace(
        prof.constellations, enabled=True, systems=keep)))


def ubx_format(base: nmea.NmeaFormat, link: UbxLink, rate_hz: float) -> nmea.NmeaFormat | None:
    """The NMEA a u-blox link writes: the profile's sentences the link has on for its port
    (CFG-MSG class F0, CFG-PRT's NMEA output), at their rates (every n-th solution, counted
    on the epoch grid as ``every`` does); None when no sentence is on.

    base : the profile's format; link : the link; rate_hz : solutions per second
    """
    every = link.nmea_every() if link.nmea_enabled() else {}
    sentences = tuple(s for s in base.sentences if s in every)
    if not sentences:
        return None
    slow = tuple(sorted((s, n) for s, n in every.items() if s in sentences and n > 1))
    return replace(base, sentences=sentences, every=slow, fix_rate_hz=rate_hz)


def apply_link_settings(rx: Receiver, settings: mtk.MtkSettings) -> Receiver:
    """The receiver with the link's SBAS and static-navigation settings in its effects.

    Parameters
    ----------
    rx : the receiver
    settings : the command link's settings (``sbas_active``, ``static_nav_mps``)

    Returns
    -------
    rx : a receiver whose profile has ``sbas.enabled`` and ``static_hold`` set accordingly
    """
    prof = rx.profile
    hold = replace(prof.static_hold, enabled=settings.static_nav_mps > 0.0,
                   threshold_mps=settings.static_nav_mps or prof.static_hold.threshold_mps)
    new = replace(prof, sbas=replace(prof.sbas, enabled=settings.sbas_active), static_hold=hold)
    return rx if new == prof else replace(rx, profile=new)


def _format_for(
    base: nmea.NmeaFormat, settings: mtk.MtkSettings, defaults: mtk.MtkSettings, rate_hz: float
) -> nmea.NmeaFormat | None:
    """The output format under the link's sentence rates (None: every sentence switched off)."""
    if settings.rates == defaults.rates:
        return replace(base, fix_rate_hz=rate_hz)
    sentences = mtk.sentence_order(base.sentences, settings)
    if not sentences:
        return None
    enabled = settings.sentence_every()
    every = dict(base.every)
    every.update({s: n for s, n in enabled.items() if s in sentences})
    every = {s: n for s, n in every.items() if s in sentences and n > 1}
    return replace(
        base, sentences=sentences, every=tuple(sorted(every.items())), fix_rate_hz=rate_hz
    )


class LiveReceiver:
    """One receiver of the live loop: its state and random streams, command link, rate, output
    format and device.

    With an MTK command link, ``$PMTK010,001`` goes out at once (before the first epoch); what
    the client writes is answered by :meth:`service_client` between epochs (a reply is queued
    whole, after any epoch already queued, so it never splits an epoch) and applied: restarts
    (no fix until the start's TTFF), fix interval (epochs on multiples of the new interval),
    baud (the device's pacing or port speed), sentence rates; SBAS and the static-navigation
    threshold switch those effects. With a u-blox link its boot notices go out at once, each
    epoch carries the UBX messages the client switched on around the NMEA, and UBX commands
    are answered and applied the same way (:meth:`_service_ubx`). Without a link the client's
    bytes are read and discarded.

    Parameters
    ----------
    rx : the receiver
    device : output device (``write_epoch``, ``read_available``; optional ``fileno``,
        ``set_baud``), never blocking
    fmt : NMEA format
    clock : the simulated clock
    rng : this receiver's random generator
    link : the command link; ``"profile"`` (default) makes the profile's (:func:`make_link`),
        None for none
    receiver_id : the receiver's number (the ``"id"`` of its pose messages)
    antenna_offset_enu_m : (3,) metres, scene ENU, added to every pose (antenna lever arm)
    t_first_unix_s : simulated UTC from which the first epoch is the next on the grid (default:
        now; a fleet gives all its receivers one)

    Attributes
    ----------
    stats : DaemonStats, this receiver's counters
    k : index of the next epoch at ``rate`` (the epoch is at ``k / rate`` simulated UTC)
    """

    def __init__(
        self,
        rx: Receiver,
        device,
        fmt: nmea.NmeaFormat,
        clock: SimClock,
        rng: np.random.Generator,
        link: mtk.MtkLink | UbxLink | None | str = "profile",
        receiver_id: int = 0,
        antenna_offset_enu_m: np.ndarray | None = None,
        t_first_unix_s: float | None = None,
    ) -> None:
        prof = rx.profile
        if isinstance(link, str):
            link = make_link(prof, fmt)
        self.rx, self.prof, self.device, self.clock, self.rng = rx, prof, device, clock, rng
        self.link = link
        self.receiver_id = receiver_id
        self.offset_enu_m = (np.zeros(3) if antenna_offset_enu_m is None
                             else np.asarray(antenna_offset_enu_m, float).reshape(3))
        self.base_fmt = fmt
        self.out_fmt: nmea.NmeaFormat | None = fmt
        self.rate = prof.rate_hz
        self.stats = DaemonStats(link=link)
        self.n_sat = len(rx.ephemeris.prn)
        self.recent_sizes: deque[int] = deque(maxlen=10)  # bytes of the last epochs
        # Whether the line carries the output is looked at every few epochs, from the last
        # epochs' sizes (afresh after a client changes the rate, the baud or the sentences).
        self._line_check_at = self.recent_sizes.maxlen
        self.t_last: float | None = None
        self.applied = link.settings if link is not None else None  # the settings in effect
        t_from = clock.now_unix_s() if t_first_unix_s is None else t_first_unix_s
        self.k = math.ceil(t_from * self.rate - 1e-9)
        # Its row in the batch it was last simulated in, while nothing else touched its state:
        # the next tick of the same batch goes on from the rows as they are.
        self._row: tuple[ReceiverRows, int, Profile] | None = None
        # Power-on at the first epoch's time, as replay does: a run with --start-time starts
        # the same whatever its set-up took (a fleet's receiver as the same receiver alone).
        self.state = initial_state(prof, self.t_next_unix_s, rng, self.n_sat)
        if isinstance(link, UbxLink):
            self.out_fmt = ubx_format(fmt, link, self.rate)
            if boot := link.startup():
                device.write_epoch(boot)
        elif link is not None:
            device.write_epoch(link.startup().encode("ascii"))

    @property
    def state(self) -> ReceiverState:
        """The receiver state after its last epoch."""
        if self._row is not None:
            rows, i, prof = self._row
            self._state = rows.row_state(i, prof)
            self._row = None
        return self._state

    @state.setter
    def state(self, state: ReceiverState) -> None:
        self._state = state
        self._row = None

    def next_k(self, r: float) -> int:
        """Index of the next epoch at rate ``r``: after the last one, not in the past."""
        k_now = math.ceil(self.clock.now_unix_s() * r - 1e-9)
        if self.t_last is None:
            return k_now
        return max(math.floor(self.t_last * r + 1e-6) + 1, k_now)

    @property
    def t_next_unix_s(self) -> float:
        """Simulated UTC of the next epoch, seconds."""
        return self.k / self.rate

    def service_client(self) -> None:
        """Read what the client wrote; with a link answer and apply it."""
        data = self.device.read_available()
        link, prof = self.link, self.prof
        if link is None or self.applied is None or not data:
            return
        if isinstance(link, UbxLink):
            self._service_ubx(link, data)
            return
        for resp in link.feed(data, max(self.recent_sizes, default=0)):
            old = self.applied
            if resp.replies:
                self.device.write_epoch("".join(resp.replies).encode("ascii"))
            if resp.restart is not None:
                self.state = restart(self.state, resp.restart, self.clock.now_unix_s(), prof,
                                     self.rng, self.n_sat)
                log.info("client commanded a %s start", resp.restart)
            new = self.applied = resp.settings
            if new is old:
                continue
            if new.baud != old.baud:
                self._set_baud(new.baud)
            if new.fix_interval_ms != old.fix_interval_ms:
                self.rate = (
                    prof.rate_hz
                    if new.fix_interval_ms == link.defaults.fix_interval_ms
                    else new.rate_hz
                )
                self.k = self.next_k(self.rate)
                log.info("client set the fix interval to %d ms", new.fix_interval_ms)
            if new.rates != old.rates or new.fix_interval_ms != old.fix_interval_ms:
                self.out_fmt = _format_for(self.base_fmt, new, link.defaults, self.rate)
            if (new.baud, new.rates, new.fix_interval_ms) != (old.baud, old.rates,
                                                              old.fix_interval_ms):
                # (recent_sizes is kept: the link's too-fast check of $PMTK220 needs it; by
                # the next check it holds only epochs made after the change)
                self._line_check_at = self.stats.epochs + self.recent_sizes.maxlen
            if (new.sbas_active, new.static_nav_mps) != (old.sbas_active, old.static_nav_mps):
                self.rx = apply_link_settings(self.rx, new)
                log.info("client set SBAS %s, static navigation %.2f m/s",
                         "on" if new.sbas_active else "off", new.static_nav_mps)

    def _set_baud(self, baud: int) -> None:
        """The line's new speed (the device's pacing or the port's), as a client set it."""
        set_baud = getattr(self.device, "set_baud", None)
        if set_baud is not None:
            set_baud(baud)
        log.info("client set the baud rate to %d", baud)

    def _service_ubx(self, link: UbxLink, data: bytes) -> None:
        """Answer a u-blox client and apply what it set: each reply is queued whole, then its
        settings applied (a baud change after the ACK has gone out at the old baud, as the
        module does); CFG-RST restarts the receiver; the navigation rate, the NMEA sentences,
        SBAS and the systems tracked (:func:`tracking_systems`) follow the link's settings."""
        for resp in link.feed(data):
            if resp.reply:
                self.device.write_epoch(resp.reply)
            if resp.restart is not None:
                self.state = restart(self.state, resp.restart, self.clock.now_unix_s(),
                                     self.prof, self.rng, self.n_sat)
                log.info("client commanded a %s start (%s)", resp.restart, resp.command)
            old, new = self.applied, resp.settings
            if new is None or new == old:
                continue
            self.applied = new
            if new.baud != old.baud:
                self._set_baud(new.baud)
            if new.nav_period_ms != old.nav_period_ms:
                self.rate = 1000.0 / new.nav_period_ms
                self.k = self.next_k(self.rate)
                log.info("client set the navigation period to %d ms", new.nav_period_ms)
            self.out_fmt = ubx_format(self.base_fmt, link, self.rate)
            self._line_check_at = self.stats.epochs + self.recent_sizes.maxlen
            if new.sbas_enabled != old.sbas_enabled:
                prof = self.rx.profile
                self.rx = replace(self.rx, profile=replace(
                    prof, sbas=replace(prof.sbas, enabled=new.sbas_enabled)))
                log.info("client set SBAS %s", "on" if new.sbas_enabled else "off")
            if new.enabled_gnss != old.enabled_gnss:
                self.rx = tracking_systems(self.rx, self.prof, new.enabled_gnss)
                log.info("client set the systems tracked: %s",
                         ", ".join(self.rx.profile.constellations.systems) or "none")

    def sent(self, data: bytes | None, has_fix: bool) -> None:
        """Queue the epoch's NMEA (None: every sentence switched off) and move to the next
        epoch."""
        if data is not None:
            self.device.write_epoch(data)
            self.recent_sizes.append(len(data))
        if self.stats.epochs >= self._line_check_at:  # (every few epochs: a fix lengthens them)
            self._line_check_at = self.stats.epochs + self.recent_sizes.maxlen
            warn_if_line_too_slow(self.recent_sizes, self.rate, getattr(self.device, "baud", None))
        self.t_last = self.t_next_unix_s
        self.stats.epochs += 1
        self.stats.fixes += int(has_fix)
        self.stats.last_fix = has_fix
        self._advance()

    def skip(self) -> None:
        """Leave this epoch out (the loop cannot compute every receiver's: see
        :class:`Thinning`) and move to the next."""
        self.stats.thinned_epochs += 1
        self._advance()

    def _advance(self) -> None:
        self.k += 1
        # Fell behind by more than one period (machine suspended, debugger): skip to now rather
        # than emit a burst of old epochs.
        k_now = math.floor(self.clock.now_unix_s() * self.rate)
        if k_now > self.k:
            self.stats.skipped_epochs += k_now - self.k
            self.k = k_now


_LINE_WARNED: set[tuple[float, int]] = set()  # (rate, baud) already warned of, once a process


def warn_if_line_too_slow(sizes: Sequence[int], rate_hz: float, baud: int | None) -> bool:
    """Warn (once per rate and baud in a process) when the epochs need more than the serial
    line carries: the device then drops the oldest whole epochs to keep its output fresh, and
    a client sees fewer epochs than the rate, as behind a real receiver set to a rate its baud
    cannot carry (MTK's PMTK220 notes: 10 Hz wants 115200 baud or fewer sentences).

    Parameters
    ----------
    sizes : bytes of the last epochs
    rate_hz : epochs per second
    baud : the line's bits per second (8N1: 10 bits a byte); None for a device without a line

    Returns
    -------
    bool : whether the line is too slow
    """
    if baud is None or not sizes:
        return False
    need_baud = 10.0 * rate_hz * sum(sizes) / len(sizes)
    if need_baud <= baud:
        return False
    if (rate_hz, baud) not in _LINE_WARNED:
        _LINE_WARNED.add((rate_hz, baud))
        log.warning(
            "at %g Hz an epoch of ~%d bytes needs %d baud: the %d-baud line carries %.0f %% of "
            "the epochs, the rest are dropped (raise the baud rate, e.g. --baud 115200 or "
            "$PMTK251, lower the rate, or switch sentences off with $PMTK314)",
            rate_hz, round(sum(sizes) / len(sizes)), math.ceil(need_baud), baud,
            100.0 * baud / need_baud)
    return True


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
