"""``virtualgps run`` for one receiver or many: assemble the receivers, their devices and the
pose source, then run :func:`virtualgps.run.daemon.run_receivers`.

One receiver and a fleet take the same path: a fleet of one is ``virtualgps run`` as it always
was (device ``./virtualgps0``, seed ``--seed``). Receivers that share a profile share one
:class:`~virtualgps.receiver.definition.Receiver` (scene, walls, ephemeris), so they are simulated
together.
"""

from __future__ import annotations

import errno
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from virtualgps.device import nmea
from virtualgps.device.pty import PtyDevice
from virtualgps.device.serialport import SerialDevice
from virtualgps.exceptions import ConfigError
from virtualgps.poses import logs as pose_logs
from virtualgps.poses import posesource
from virtualgps.run import config, live, poseproviders
from virtualgps.run.fleet.limits import check_limits, pty_error
from virtualgps.run.fleet.members import Member, fleet_members
from virtualgps.run.fleet.ptyloop import PtyLoop

log = logging.getLogger(__name__)

# A fleet's ptys get up to 100 ms of line time per write (1 KiB at most): one wake-up per
# epoch and device at 10 Hz instead of a USB adapter's 16 ms slices, which a thousand devices
# could not afford. A single receiver keeps the 16 ms slices.
FLEET_CHUNK_S = 0.1
# A fleet larger than this logs its clients' coming and going at debug level only.
QUIET_CLIENTS_ABOVE = 16


@dataclass
class Fleet:
    """A run's receivers, ready to start.

    receivers : the live receivers, in the fleet's order
    provider : the pose source (``pose_at(t, receiver_id)``)
    waiter : the loop the daemon waits in (a PtyLoop serving the ptys, or None: select)
    devices : the output devices (closed by :meth:`close`)
    clock : the simulated clock
    tle_path : the ephemeris file used
    links : each receiver's link as given (None on a serial port)
    """

    receivers: list[live.LiveReceiver]
    provider: poseproviders.PoseProvider
    waiter: PtyLoop | None
    devices: list
    clock: poseproviders.SimClock
    tle_path: str
    links: list[str | None]

    def close(self) -> None:
        """Close every device (removing its link) and the pose source."""
        try:
            if self.waiter is not None:
                self.waiter.close()
            for dev in self.devices:
                dev.close()
        finally:
            self.provider.close()


def build_fleet(
    flags: dict,
    poses_spec: str,
    link_pattern: str,
    n_receivers: int | None = None,
    fleet_file: str | None = None,
    serial_port: str | None = None,
    topic: str | None = None,
    *,
    members: list[Member] | None = None,
    fleet_ids: list[int] | None = None,
    pose_source=None,
    start_clock: Callable[[list, float | None], poseproviders.SimClock] | None = None,
) -> Fleet:
    """Make the receivers, their devices and the pose source of ``virtualgps run`` (or of
    one worker process's share of a fleet: ``members``).

    Parameters
    ----------
    flags : the run's command-line settings (see :func:`virtualgps.run.config.resolve`)
    poses_spec : ``--poses``: ``udp://``, ``tcp://``, ``-``, a pose log, or ``demo``
    link_pattern : ``--link`` (``{id}`` is the receiver's number)
    n_receivers : ``--receivers``
    fleet_file : ``--fleet``
    serial_port : ``--serial`` (one receiver only)
    topic : ``--topic`` for a ROS bag
    members : the receivers to make (default: from ``n_receivers`` and ``fleet_file``)
    fleet_ids : the ids of the whole fleet (default: the members'), where the demo walk
        spreads them out, so a receiver walks the same in any share of its fleet
    pose_source : the live pose source to read (default: ``--poses`` opened here; a worker
        reads what its parent forwards)
    start_clock : called with the devices once they exist and ``--start-time`` (or None),
        returns the simulated clock (default: started there; a worker's starts when its parent
        says, with all the others')

    Returns
    -------
    fleet : Fleet (its devices exist; nothing has been emitted)

    Raises
    ------
    VirtualGPSError
        with one line for bad settings or inputs.
    """
    cfg = config.resolve(flags)
    if members is None:
        members = fleet_members(n_receivers, fleet_file, cfg.seed, link_pattern)
    check_limits(len(members), serial_port is None)
    if serial_port and len(members) > 1:
        raise ConfigError("--serial drives one receiver; a fleet gets ptys (--link PATTERN)")
    scene, georef, scene_tle = config.load_scene_for(cfg)
    t_start = cfg.start_time_unix_s
    ephemeris, tle_path = config.load_ephemeris(
        cfg, scene_tle, poseproviders.SimClock(t_start).now_unix_s())
    prof = cfg.profile
    share = ("" if fleet_ids is None or len(fleet_ids) == len(members)
             else f" (this process's share of {len(fleet_ids)})")
    log.info("profile %s (%s), scene %s, seed %d, rate %g Hz, baud %d, %d receiver%s%s",
             prof.name, prof.source, cfg.scene or config.DEFAULT_SCENE, cfg.seed,
             prof.rate_hz, prof.baud, len(members), "s" if len(members) > 1 else "", share)

    spec = poses_spec
    ids = [m.receiver_id for m in members]
    is_log = spec != "demo" and not spec.startswith(("udp://", "tcp://")) and spec != "-"
    tracks = pose_logs.read_pose_logs_by_id(Path(spec), topic) if is_log else None
    if georef is None and tracks is not None:
        first = next(iter(tracks.values()))
        if first.frame != "geodetic":
            config.require_georef(None, "geodetic poses")
        georef = config.Georef(*(float(v) for v in first.xyz[0]))
    elif georef is None:
        # Open sky, live geodetic poses, no --origin. With exact WGS-84 geodesy the ENU frame's
        # origin is arbitrary (the ECEF<->ENU round trip is exact), so any origin will do; the
        # paper's flat earth needs a real one.
        if prof.georef == "flat_earth":
            config.require_georef(None, "a scene")
        georef = config.Georef(0.0, 0.0, 0.0)

    # One Receiver per distinct (profile, baud): receivers that share it are simulated together.
    cfgs: dict[tuple, config.RunConfig] = {}
    for m in members:
        key = (m.profile, m.baud)
        if key not in cfgs:
            cfgs[key] = cfg if key == (None, None) else config.resolve(
                {**flags, "profile": m.profile or flags.get("profile"),
                 "baud": m.baud or flags.get("baud")})
    t_guess = poseproviders.SimClock(t_start).now_unix_s()  # (for the sky-time policy)
    rxs = {key: config.make_receiver(c, scene, georef, ephemeris, t_guess)
           for key, c in cfgs.items()}
    fmts = {key: nmea.NmeaFormat.from_dict(c.profile.nmea) for key, c in cfgs.items()}
    unknown = sorted(set(tracks or ()) - set(ids if fleet_ids is None else fleet_ids))
    if unknown:
        log.warning("%s has poses for receivers %s, which this run does not have: ignored",
                    spec, ", ".join(map(str, unknown[:10])) + (" ..." if len(unknown) > 10 else ""))

    devices: list = []
    waiter = None if serial_port else PtyLoop()
    provider = None
    receivers = []
    try:
        for m in members:
            p = cfgs[(m.profile, m.baud)].profile
            if serial_port:
                devices.append(SerialDevice(serial_port, p.baud))
            else:
                # (by the whole fleet: a receiver is paced alike in any share of it)
                fleet_size = len(fleet_ids or members)
                pacing = {"chunk_s": FLEET_CHUNK_S} if fleet_size > 1 else {}
                try:
                    dev = PtyDevice(Path(m.link), baud=p.baud, threaded=False, **pacing)
                except OSError as exc:
                    if exc.errno not in (errno.EMFILE, errno.ENFILE, errno.ENOSPC):
                        raise
                    raise pty_error(exc, len(waiter.devices), len(members)) from exc
                if fleet_size > QUIET_CLIENTS_ABOVE:
                    dev.client_log_level = logging.DEBUG
                waiter.add(dev)
        # The simulated clock starts once everything is loaded and made: with --start-time,
        # the first epoch is the first on the grid after it, however long the set-up took.
        made = devices if serial_port else waiter.devices
        clock = (poseproviders.SimClock(t_start) if start_clock is None
                 else start_clock(made, t_start))
        t0 = clock.now_unix_s()
        # Logs and the demo walk start at --start-time exactly (else now): a receiver's poses
        # are then the same in every run that starts there, to the bit.
        provider = _provider(spec, tracks, ids, ids if fleet_ids is None else fleet_ids,
                             scene, georef, prof.pose_timeout_s, clock,
                             t0 if t_start is None else t_start, pose_source)
        for m, dev in zip(members, devices if serial_port else waiter.devices, strict=True):
            key = (m.profile, m.baud)
            receivers.append(live.LiveReceiver(
                rxs[key], dev, fmts[key], clock,
                np.random.default_rng(m.seed), receiver_id=m.receiver_id,
                antenna_offset_enu_m=np.array(m.antenna_offset_enu_m), t_first_unix_s=t0))
    except BaseException:
        if waiter is not None:
            waiter.close()
        for dev in devices:
            dev.close()
        if provider is not None:
            provider.close()
        raise
    links = [None if serial_port else m.link for m in members]
    return Fleet(receivers, provider, waiter, devices, clock, str(tle_path), links)


def _provider(spec: str, tracks, ids: list[int], fleet_ids: list[int], scene, georef,
              max_gap_s: float, clock: poseproviders.SimClock, t0: float,
              pose_source=None) -> poseproviders.PoseProvider:
    """The pose source of ``--poses`` for receivers ``ids`` of a fleet of ``fleet_ids`` (the
    demo walk spreads the whole fleet, a log keeps the whole fleet's timing: a receiver's
    poses do not depend on which share of the fleet it runs in)."""
    if spec == "demo":
        waypoints = getattr(scene, "demo_waypoints_enu_m", None) if scene is not None else None
        speed = getattr(scene, "demo_speed_mps", 1.4) if scene is not None else 1.4
        if waypoints is None or len(waypoints) < 2:
            # Open sky or a scene without [demo]: a 40 m square around the origin, 1.5 m up.
            waypoints = np.array([[0, 0, 1.5], [40, 0, 1.5], [40, 40, 1.5], [0, 40, 1.5]], float)
        lap = poseproviders.demo_lap(np.asarray(waypoints, float), float(speed))
        lap_s = float(lap.t_unix_s[-1])
        # A fleet spreads out along the loop: receiver j of n starts j / n of a lap ahead.
        mine = set(ids)
        return poseproviders.ReceiverPoses({
            rid: poseproviders.LoopProvider(lap, t0 - j * lap_s / len(fleet_ids), max_gap_s)
            for j, rid in enumerate(fleet_ids) if rid in mine})
    if spec.startswith(("udp://", "tcp://")) or spec == "-":
        source = posesource.open_pose_source(spec) if pose_source is None else pose_source
        return poseproviders.LiveProvider(source, georef, clock, max_gap_s, receiver_ids=ids,
                                          elsewhere_ids=set(fleet_ids) - set(ids))
    from virtualgps.run.replay import track_in_scene

    # A fleet's log keeps its receivers' timing: all are replayed from the earliest pose.
    in_fleet = set(fleet_ids)
    t_first = min((float(tr.t_unix_s[0]) for rid, tr in tracks.items() if rid in in_fleet),
                  default=0.0)
    mine = set(ids)
    return poseproviders.ReceiverPoses({
        rid: poseproviders.TrackProvider(track_in_scene(tr, georef), t0, max_gap_s, t_first)
        for rid, tr in tracks.items() if rid in mine})


def lost_epochs(devices) -> int:
    """Epochs the devices dropped that a client or a port should have had. (A pty nobody
    opened drops what nobody reads, as it should: only devices that wrote, to a client or a
    port, count, where a slow line or client lost epochs.)"""
    return sum(getattr(d, "dropped_epochs", 0) for d in devices if getattr(d, "written_bytes", 0))


@dataclass
class RunSummary:
    """What a run (or one worker's share of it) did: the counts of its exit line.

    epochs, fixes, late, skipped, thinned : receiver-epochs sent, with a fix, sent late,
        skipped (fell behind), thinned out (see :class:`virtualgps.run.daemon.Thinning`)
    dropped : epochs dropped unread on devices a client read
    bad : malformed pose messages by kind; unknown : pose messages by unknown receiver id
    n_good : good pose messages; elsewhere : messages for receivers other hosts run (--ids)
    """

    epochs: int = 0
    fixes: int = 0
    late: int = 0
    skipped: int = 0
    thinned: int = 0
    dropped: int = 0
    bad: dict | None = None
    unknown: dict | None = None
    n_good: int = 0
    elsewhere: int = 0

    @classmethod
    def of(cls, fleet: Fleet) -> RunSummary:
        """The counts of a fleet's receivers, devices and pose source now."""
        s = [r.stats for r in fleet.receivers]
        provider = fleet.provider
        return cls(
            epochs=sum(x.epochs for x in s), fixes=sum(x.fixes for x in s),
            late=sum(x.late_epochs for x in s), skipped=sum(x.skipped_epochs for x in s),
            thinned=sum(x.thinned_epochs for x in s),
            dropped=lost_epochs([r.device for r in fleet.receivers]),
            bad=dict(getattr(provider, "bad", None) or {}),
            unknown=dict(getattr(provider, "unknown_ids", None) or {}),
            n_good=getattr(provider, "n_good", 0), elsewhere=getattr(provider, "elsewhere", 0))

    def __add__(self, other: RunSummary) -> RunSummary:
        def merged(a, b):
            out = dict(a or {})
            for k, v in (b or {}).items():
                out[k] = out.get(k, 0) + v
            return out

        return RunSummary(
            self.epochs + other.epochs, self.fixes + other.fixes, self.late + other.late,
            self.skipped + other.skipped, self.thinned + other.thinned,
            self.dropped + other.dropped, merged(self.bad, other.bad),
            merged(self.unknown, other.unknown), self.n_good + other.n_good,
            self.elsewhere + other.elsewhere)

    def log(self) -> None:
        """The run's exit line."""
        unknown = self.unknown or {}
        log.info(
            "stopped after %d epochs (%d with a fix, %d late, %d skipped%s%s)%s%s%s",
            self.epochs, self.fixes, self.late, self.skipped,
            f", {self.thinned} thinned out to keep up" if self.thinned else "",
            f", {self.dropped} dropped unread" if self.dropped else "",
            f"; malformed pose messages: {self.bad}" if self.bad else "",
            f"; pose messages for unknown receivers: {sum(unknown.values())} "
            f"(ids {sorted(unknown)[:10]})" if unknown else "",
            f"; pose messages for other hosts' receivers (--ids): {self.elsewhere}, skipped"
            if self.elsewhere else "",
        )


def log_links(receivers: list[live.LiveReceiver]) -> None:
    """One line per receiver whose client used its command link: what it set."""
    for r in receivers:
        link = r.stats.link
        if link is not None and (link.commands or link.bad_checksum):
            log.info(
                "receiver %d: %s command link: %d commands answered, %d with a wrong checksum "
                "ignored; settings at exit: %s",
                r.receiver_id, link.protocol, link.commands, link.bad_checksum, link.summary(),
            )


@dataclass
class Progress:
    """A fleet's state for its status line: receivers with a fix at their last epoch, epochs
    sent, epochs dropped unread, the newest epoch's time, good pose messages.

    Parts of one fleet (its workers') add up (``+``).
    """

    receivers: int = 0
    with_fix: int = 0
    epochs: int = 0
    dropped: int = 0
    t_unix_s: float = 0.0
    n_good: int = 0

    def __add__(self, other: Progress) -> Progress:
        return Progress(self.receivers + other.receivers, self.with_fix + other.with_fix,
                        self.epochs + other.epochs, self.dropped + other.dropped,
                        max(self.t_unix_s, other.t_unix_s), self.n_good + other.n_good)


def progress(fleet: Fleet) -> Progress:
    """A fleet's :class:`Progress` now (from its receivers' counters: nothing is followed per
    epoch, which a fleet of thousands would pay for)."""
    rs = fleet.receivers
    return Progress(
        len(rs), sum(1 for r in rs if r.stats.last_fix), sum(r.stats.epochs for r in rs),
        lost_epochs([r.device for r in rs]), max((r.t_last or 0.0 for r in rs), default=0.0),
        getattr(fleet.provider, "n_good", 0))
