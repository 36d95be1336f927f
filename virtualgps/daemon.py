"""The live loop: one epoch per period on absolute ticks of the simulated clock.

Epochs fall on whole multiples of 1/rate of simulated UTC. Each epoch interpolates the pose to
the epoch time, runs :func:`virtualgps.receiver.simulate` on that one epoch (the code replay runs
on thousands), renders NMEA and hands it to the device, which never blocks. Pose messages are
read whenever they arrive, between epochs.
"""

from __future__ import annotations

import logging
import math
import select
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from virtualgps import mtk, nmea, pose
from virtualgps.exceptions import PoseError
from virtualgps.receiver import Georef, Receiver, initial_state, restart, simulate
from virtualgps.records import Fixes

log = logging.getLogger(__name__)

LIVE_POSE_HISTORY = 64  # poses kept for interpolation; a few seconds at typical robot rates
MAX_MESSAGES_PER_PUMP = 20_000  # bound the work between two epochs under a message flood


@dataclass
class SimClock:
    """Simulated UTC running at wall-clock speed from ``start_unix_s`` (or the wall clock itself).

    offset_s : simulated minus wall-clock time; poses stamped by the robot's (wall) clock are
        moved by it onto the simulated clock
    """

    start_unix_s: float | None = None
    _mono0: float = field(default_factory=time.monotonic)
    _wall0: float = field(default_factory=time.time)

    @property
    def offset_s(self) -> float:
        return 0.0 if self.start_unix_s is None else self.start_unix_s - self._wall0

    def now_unix_s(self) -> float:
        """Simulated UTC now, seconds."""
        base = self._wall0 if self.start_unix_s is None else self.start_unix_s
        return base + (time.monotonic() - self._mono0)

    def monotonic_at(self, t_unix_s: float) -> float:
        """The monotonic-clock time at which the simulated clock reads ``t_unix_s``."""
        base = self._wall0 if self.start_unix_s is None else self.start_unix_s
        return self._mono0 + (t_unix_s - base)


class PoseProvider(Protocol):
    """Where the daemon gets the antenna pose at an epoch."""

    def fileno_list(self) -> list[int]:
        """File descriptors to wait on for incoming poses (may be empty)."""
        ...

    def pump(self) -> None:
        """Read whatever has arrived (never blocks)."""
        ...

    def pose_at(self, t_unix_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pos (n, 3) scene ENU m, vel (n, 3) ENU m/s, valid (n,) bool) at simulated times."""
        ...

    def close(self) -> None: ...


class TrackProvider:
    """A pose log (or any PoseTrack in scene ENU) replayed in real time from ``t0_unix_s``."""

    def __init__(self, track: pose.PoseTrack, t0_unix_s: float, max_gap_s: float) -> None:
        self.track = track
        self.shift_s = t0_unix_s - float(track.t_unix_s[0]) if len(track) else 0.0
        self.max_gap_s = max_gap_s

    def fileno_list(self) -> list[int]:
        return []

    def pump(self) -> None:
        return None

    def pose_at(self, t_unix_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return pose.interpolate(self.track, np.asarray(t_unix_s) - self.shift_s, self.max_gap_s)

    def close(self) -> None:
        return None


def demo_lap(waypoints_enu_m: np.ndarray, speed_mps: float, step_s: float = 0.5) -> pose.PoseTrack:
    """One lap of a scripted walk: the closed waypoint loop at constant speed, sampled densely.

    Parameters
    ----------
    waypoints_enu_m : (n, 3) metres, scene ENU (antenna positions)
    speed_mps : walking speed
    step_s : sampling interval of the returned track

    Returns
    -------
    lap : PoseTrack in the scene ENU frame, times from 0 to the lap time; velocities are left
        to finite differences, which are exact since every corner is a sample
    """
    pts = np.asarray(waypoints_enu_m, dtype=float)
    loop = np.vstack([pts, pts[:1]])
    seg_m = np.linalg.norm(np.diff(loop, axis=0), axis=1)
    leg_t = np.concatenate([[0.0], np.cumsum(seg_m) / speed_mps])  # (n + 1,) arrival times
    t = np.union1d(np.arange(0.0, leg_t[-1], step_s), leg_t)
    k = np.clip(np.searchsorted(leg_t, t, side="right") - 1, 0, len(seg_m) - 1)
    w = ((t - leg_t[k]) / (leg_t[k + 1] - leg_t[k]))[:, None]
    xyz = loop[k] + w * (loop[k + 1] - loop[k])
    return pose.PoseTrack(t_unix_s=t, frame="enu", xyz=xyz, vel_enu_mps=np.full_like(xyz, np.nan))


class LoopProvider(TrackProvider):
    """A lap (times from 0) walked again and again from ``t0_unix_s``: the ``demo`` source."""

    def __init__(self, lap: pose.PoseTrack, t0_unix_s: float, max_gap_s: float) -> None:
        super().__init__(lap, 0.0, max_gap_s)
        self.t0_unix_s = t0_unix_s
        self.lap_s = float(lap.t_unix_s[-1])

    def pose_at(self, t_unix_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t_lap = (np.asarray(t_unix_s, dtype=float) - self.t0_unix_s) % self.lap_s
        return pose.interpolate(self.track, t_lap, self.max_gap_s)


class LiveProvider:
    """Poses from a message source (UDP, TCP, stdin): parsed, counted, kept for interpolation.

    Malformed messages are counted per kind and logged once per kind; they never stop the daemon.
    """

    def __init__(self, source, georef: Georef, clock: SimClock, max_gap_s: float) -> None:
        self.source = source
        self.georef = georef
        self.clock = clock
        self.max_gap_s = max_gap_s
        self.history: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=LIVE_POSE_HISTORY)
        self.bad: Counter[str] = Counter()
        self.n_good = 0
        self._track: pose.PoseTrack | None = None

    def fileno_list(self) -> list[int]:
        return list(self.source.fileno_list())

    def _to_enu(self, p: pose.Pose) -> np.ndarray:
        if p.frame == "enu":
            return np.asarray(p.xyz, dtype=float)
        track = pose.PoseTrack(
            np.array([p.t_unix_s]),
            "geodetic",
            np.asarray([p.xyz], float),
            np.asarray([p.vel_enu_mps], float),
        )
        g = self.georef
        return pose.to_enu(track, g.lat0_deg, g.lon0_deg, g.alt0_hae_m).xyz[0]

    def pump(self) -> None:
        messages = self.source.poll()[:MAX_MESSAGES_PER_PUMP]
        for data, arrival_wall_s in messages:
            try:
                p = pose.parse_pose_message(data, arrival_wall_s)
                enu = self._to_enu(p)
            except PoseError as exc:
                if self.bad[exc.kind] == 0:
                    log.warning(
                        "skipping malformed pose message (%s): %s "
                        "(further ones of this kind are counted, not logged)",
                        exc.kind,
                        exc,
                    )
                self.bad[exc.kind] += 1
                continue
            t_sim = p.t_unix_s + self.clock.offset_s
            if self.history and t_sim <= self.history[-1][0]:
                if t_sim == self.history[-1][0]:
                    continue
                # Out-of-order message: keep the history sorted (rare; UDP may reorder).
                items = sorted(
                    [*self.history, (t_sim, enu, np.asarray(p.vel_enu_mps, float))],
                    key=lambda item: item[0],
                )
                self.history = deque(items, maxlen=LIVE_POSE_HISTORY)
            else:
                self.history.append((t_sim, enu, np.asarray(p.vel_enu_mps, float)))
            self.n_good += 1
            self._track = None

    def pose_at(self, t_unix_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t_unix_s, dtype=float)
        if not self.history:
            n = t.shape[0]
            return np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.zeros(n, bool)
        if self._track is None:
            ts, xyz, vel = zip(*self.history, strict=True)
            self._track = pose.PoseTrack(np.array(ts), "enu", np.array(xyz), np.array(vel))
        return pose.interpolate(self._track, t, self.max_gap_s)

    def close(self) -> None:
        self.source.close()


@dataclass
class DaemonStats:
    """Counters the status line and the exit summary show.

    link : the MTK command link (its ``settings`` are what the client set: fix interval, baud,
        sentence rates, SBAS, static-navigation threshold), or None without one
    """

    epochs: int = 0
    fixes: int = 0
    late_epochs: int = 0
    skipped_epochs: int = 0
    max_lateness_s: float = 0.0
    link: mtk.MtkLink | None = None


def make_link(profile, fmt: nmea.NmeaFormat) -> mtk.MtkLink | None:
    """The profile's command link: an :class:`~virtualgps.mtk.MtkLink` for ``mtk``, else None.

    Parameters
    ----------
    profile : the receiver profile (``command_link``, ``firmware``, ``rate_hz``, ``baud``)
    fmt : its output format (the sentences and their rates at power-on)

    Returns
    -------
    link : MtkLink or None
    """
    if getattr(profile, "command_link", "none") != "mtk":
        return None
    sbas = profile.sbas.enabled
    hold = profile.static_hold
    defaults = mtk.default_settings(
        fmt.sentences, dict(fmt.every), profile.rate_hz, profile.baud,
        dgps_mode=2 if sbas else 0, sbas_enabled=sbas,
        static_nav_mps=hold.threshold_mps if hold.enabled else 0.0,
    )
    return mtk.MtkLink(defaults, profile.firmware)


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


def run_daemon(
    rx: Receiver,
    provider: PoseProvider,
    device,
    fmt: nmea.NmeaFormat,
    clock: SimClock,
    rng: np.random.Generator,
    stop: threading.Event,
    on_epoch: Callable[[Fixes, DaemonStats], None] | None = None,
    max_epochs: int | None = None,
    link: mtk.MtkLink | None | str = "profile",
) -> DaemonStats:
    """Emit one epoch per period until ``stop`` is set (or ``max_epochs`` epochs).

    With an MTK command link, ``$PMTK010,001`` goes out before the first epoch; what the client
    writes is read as soon as it arrives (the device's descriptor is in the ``select``), answered
    at once between epochs (a reply is queued whole, after any epoch already queued, so it never
    splits an epoch), and applied: restarts (no fix until the start's TTFF), fix interval
    (epochs on multiples of the new interval), baud (the device's pacing or port speed),
    sentence rates. SBAS and the static-navigation threshold are kept in ``stats.link.settings``.
    Without a link the client's bytes are read and discarded.

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
    prof = rx.profile
    if isinstance(link, str):
        link = make_link(prof, fmt)
    base_fmt = fmt
    rate = prof.rate_hz
    stats = DaemonStats(link=link)
    n_sat = len(rx.ephemeris.prn)
    state = initial_state(prof, clock.now_unix_s(), rng, n_sat)
    if link is not None:
        device.write_epoch(link.startup().encode("ascii"))
    get_fd = getattr(device, "fileno", None)
    recent_sizes: deque[int] = deque(maxlen=10)  # bytes of the last epochs (too-fast check)
    out_fmt: nmea.NmeaFormat | None = fmt
    t_last: float | None = None
    applied = link.settings if link is not None else None  # the settings in effect

    def next_k(r: float) -> int:
        """Index of the next epoch at rate ``r``: after the last one, not in the past."""
        k_now = math.ceil(clock.now_unix_s() * r - 1e-9)
        if t_last is None:
            return k_now
        return max(math.floor(t_last * r + 1e-6) + 1, k_now)

    def service_client() -> None:
        """Read what the client wrote; with a link answer and apply it."""
        nonlocal state, rate, out_fmt, k, applied, rx
        data = device.read_available()
        if link is None or applied is None or not data:
            return
        for resp in link.feed(data, max(recent_sizes, default=0)):
            old = applied
            if resp.replies:
                device.write_epoch("".join(resp.replies).encode("ascii"))
            if resp.restart is not None:
                state = restart(state, resp.restart, clock.now_unix_s(), prof, rng, n_sat)
                log.info("client commanded a %s start", resp.restart)
            new = applied = resp.settings
            if new is old:
                continue
            if new.baud != old.baud:
                set_baud = getattr(device, "set_baud", None)
                if set_baud is not None:
                    set_baud(new.baud)
                log.info("client set the baud rate to %d", new.baud)
            if new.fix_interval_ms != old.fix_interval_ms:
                rate = (
                    prof.rate_hz
                    if new.fix_interval_ms == link.defaults.fix_interval_ms
                    else new.rate_hz
                )
                k = next_k(rate)
                log.info("client set the fix interval to %d ms", new.fix_interval_ms)
            if new.rates != old.rates or new.fix_interval_ms != old.fix_interval_ms:
                out_fmt = _format_for(base_fmt, new, link.defaults, rate)
            if (new.sbas_active, new.static_nav_mps) != (old.sbas_active, old.static_nav_mps):
                rx = apply_link_settings(rx, new)
                log.info("client set SBAS %s, static navigation %.2f m/s",
                         "on" if new.sbas_active else "off", new.static_nav_mps)

    k = next_k(rate)
    while not stop.is_set():
        # Wait for the epoch, reading poses and the client's commands as they come.
        while not stop.is_set():
            provider.pump()
            service_client()
            deadline = clock.monotonic_at(k / rate)  # k and rate may change in service_client
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            timeout = min(remaining, 0.1)
            fds = provider.fileno_list()  # stdin drops out at end of input
            dev_fd = get_fd() if get_fd is not None else None
            if dev_fd is not None:
                fds = [*fds, dev_fd]
            if fds:
                select.select(fds, [], [], timeout)
            else:
                stop.wait(timeout)
        if stop.is_set():
            break
        t_epoch = k / rate
        lateness = time.monotonic() - deadline
        if lateness > 0.5 / rate:
            stats.late_epochs += 1
        stats.max_lateness_s = max(stats.max_lateness_s, lateness)
        pos, vel, valid = provider.pose_at(np.array([t_epoch]))
        fixes, state = simulate(rx, np.array([t_epoch]), pos, vel, valid, state, rng)
        if out_fmt is not None:
            data = nmea.epoch_sentences(fixes, 0, out_fmt)
            device.write_epoch(data)
            recent_sizes.append(len(data))
        t_last = t_epoch
        stats.epochs += 1
        stats.fixes += int(fixes.quality[0] > 0)
        if on_epoch is not None:
            on_epoch(fixes, stats)
        if max_epochs is not None and stats.epochs >= max_epochs:
            break
        k += 1
        # Fell behind by more than one period (machine suspended, debugger): skip to now rather
        # than emit a burst of old epochs.
        k_now = math.floor(clock.now_unix_s() * rate)
        if k_now > k:
            stats.skipped_epochs += k_now - k
            k = k_now
    return stats
