"""The ``virtualgps`` command (DESIGN section 3); the only module that prints.

Subcommands: ``run`` (the daemon), ``replay`` (batch), ``sky`` (what the antenna sees), ``gap``
(the sim-to-real diagnosis).
Errors are one line on stderr and a non-zero exit; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import re
import signal
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps import __version__
from virtualgps.exceptions import ConfigError, VirtualGPSError

log = logging.getLogger("virtualgps")

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a command stopped by Ctrl-C
NO_POSE_WARNING_S = 10.0  # a live run that has had no pose this long says so, once


def _common(p: argparse.ArgumentParser, start_time_help: str | None) -> None:
    p.add_argument(
        "--scene",
        help="scene folder or scene.toml, a bundled scene name, or 'none' "
        "for open sky (default: the bundled magdeburg-campus)",
    )
    p.add_argument(
        "--profile",
        help="receiver profile: holux-m1000 (default), usarsim, ideal, ublox-m8n, ublox-m9n, "
        "phone, or a profile TOML path",
    )
    p.add_argument(
        "--config", help="TOML file of settings (precedence: defaults < profile < config < flags)"
    )
    p.add_argument(
        "--tle",
        action="append",
        help="TLE file, RINEX 2/3 GPS navigation file (broadcast orbits) or satellite lookup "
        "table (default: of the scene's, the bundled and the fetched TLE sets, the one whose "
        "epoch lies nearest the start time); repeatable, one TLE file per group (gps-ops, "
        "glo-ops, galileo, ...); the receivers track the GPS satellites of them",
    )
    p.add_argument("--rate", type=float, help="output rate in Hz (default: the profile's, 1 Hz)")
    if start_time_help is not None:  # (sky has --time instead: one moment, taken literally)
        p.add_argument("--start-time", help=start_time_help)
    p.add_argument("--seed", type=int, help="random seed (default 0)")
    p.add_argument("--origin", help="LAT,LON,ALT_HAE of the scene origin (overrides the scene)")
    p.add_argument("--debug", action="store_true", help="show tracebacks and debug logging")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = argparse.ArgumentParser(
        prog="virtualgps",
        description="A virtual GPS receiver for robots: poses in, Holux M-1000 NMEA out.",
    )
    parser.add_argument("--version", action="version", version=f"virtualgps {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser(
        "run",
        help="the daemon: poses in, NMEA out on a pseudo-terminal",
        description="Create the device, print its path, emit one epoch per "
        "period until SIGINT/SIGTERM.",
    )
    _common(run, "simulated UTC start, ISO 8601 (default: now)")
    run.add_argument(
        "--poses",
        default="udp://127.0.0.1:5600",
        help="udp://HOST:PORT (default udp://127.0.0.1:5600), tcp://HOST:PORT "
        "(we listen), '-' (stdin), a pose log file (paced in real time), or demo",
    )
    run.add_argument(
        "--link",
        default="./virtualgps{id}",
        help="stable symlink to each receiver's pty; {id} is the receiver's number "
        "(default ./virtualgps{id}: ./virtualgps0 for one receiver)",
    )
    run.add_argument("--receivers", type=int,
                     help="run this many receivers, each on its own pty (ids 0..N-1, seed "
                     "--seed + id); poses carry \"id\" (default 1)")
    run.add_argument("--fleet", help="TOML file listing the receivers (profile, seed, link, "
                     "baud, antenna offset of each; see docs/fleets.md)")
    run.add_argument("--workers", type=int,
                     help="worker processes a fleet is spread over, each computing and serving "
                     "a share of its receivers (default: one per core, at most one per 500 "
                     "receivers)")
    run.add_argument("--ids", metavar="LO-HI",
                     help="run only the receivers with ids LO..HI: this host's share of a fleet "
                     "split across hosts (each host given the same fleet and pose stream)")
    run.add_argument("--serial", help="drive this real serial port instead of a pty")
    run.add_argument("--baud", type=int, help="baud rate (default: the profile's, 38400)")
    run.add_argument("--duration", type=float, help="stop after this many seconds")
    run.add_argument("--topic", help="the pose topic of a ROS bag given to --poses")

    rep = sub.add_parser(
        "replay",
        help="run the receiver over a pose log as fast as possible",
        description="Replay a pose log (JSONL, CSV, TUM, NMEA, ROS 1/2 bag) and write NMEA.",
    )
    _common(rep, "simulated UTC of the log's first pose, ISO 8601: the log is shifted to "
                 "start then (default: its own times)")
    rep.add_argument("poses", help="pose log file")
    rep.add_argument("--out", required=True, help="NMEA output file ('-' for stdout)")
    rep.add_argument("--fixes", help="also write one CSV row per epoch here")
    rep.add_argument("--topic", help="the pose topic, for a ROS bag with several")

    sky = sub.add_parser("sky", help="what the antenna sees at one place and time")
    _common(sky, None)
    where = sky.add_mutually_exclusive_group()
    where.add_argument("--at", help="X,Y,Z antenna position in scene ENU metres (default 0,0,1.5)")
    where.add_argument("--lla", help="LAT,LON,ALT_HAE antenna position")
    sky.add_argument("--time", help="UTC time, ISO 8601 (default: now); no sky-time mapping")
    sky.add_argument("--json", action="store_true", help="print a JSON list")
    sky.add_argument("--plot", help="draw a skyplot to this PNG file")
    sky.add_argument("--systems", help="the systems listed, comma-separated (GPS, GLONASS, "
                     "Galileo, BeiDou, QZSS, SBAS; default: every system of the --tle sets)")

    gap = sub.add_parser(
        "gap",
        help="the sim-to-real gap: where real logs differ from the simulation, which effect "
        "causes it, how far it shrinks on held-out data",
        description="Re-simulate real runs along their truth as an ensemble of seeds, locate "
        "where the real log lies outside the ensemble, fit each candidate effect on training "
        "data and measure the gap on held-out data. Writes DIR/report.json, DIR/report.html "
        "and DIR/calibrated.toml.",
    )
    gap.add_argument("--real", action="append", default=[], metavar="LOG",
                     help="a real receiver's NMEA log, gpsd's JSON of it (gpspipe -w), a u-blox "
                     "UBX log, or a ROS bag of its nmea_msgs/Sentence or sensor_msgs/NavSatFix "
                     "(BAG:TOPIC where it has several) (repeat: one per run)")
    gap.add_argument("--truth", action="append", default=[], metavar="TRUTH",
                     help="the run's true trajectory: a pose log (JSONL, CSV, TUM, NMEA, a ROS "
                     "bag: BAG:TOPIC where it has several pose topics), 'static' (stood still "
                     "at an unknown point) or static:LAT,LON,ALT_HAE (repeat, in the order of "
                     "--real)")
    gap.add_argument("--scene", help="scene folder or scene.toml, or 'none' (default: the "
                     "bundled magdeburg-campus; runs far from it are simulated in open sky)")
    gap.add_argument("--tle", action="append",
                     help="TLE file or RINEX GPS navigation file; repeat for one TLE set per "
                     "system's group (default: for GPS and each other system the profile "
                     "tracks or the logs list, of the scene's, the bundled and the fetched "
                     "sets the one whose epoch lies nearest the log's time)")
    gap.add_argument("--profile", default="holux-m1000",
                     help="the profile under test (default holux-m1000)")
    gap.add_argument("--out", required=True, metavar="DIR", help="output folder")
    gap.add_argument("--seeds", type=int, default=50, help="ensemble size (default 50)")
    gap.add_argument("--fit-seeds", type=int,
                     help="seeds per candidate parameter set while fitting (default min(seeds, "
                     "8))")
    gap.add_argument("--effects", help="candidate effects, comma-separated (default: every "
                     "effect the profile lacks or has switched off; none: locate the gaps only)")
    gap.add_argument("--jobs", type=int, help="local worker processes (default: all cores)")
    gap.add_argument("--dask", metavar="ADDRESS",
                     help="send the ensemble jobs to this Dask scheduler (tcp://HOST:8786)")
    gap.add_argument("--blocks", type=int, default=4,
                     help="held-out time blocks per run at most, with one or two runs "
                     "(default 4; blocks are guarded by the error's correlation time)")
    gap.add_argument("--selfcheck", action="store_true",
                     help="diagnose pseudo-real logs with known injected effects instead "
                     "(--effects then names trials: effects, pairs a+b, either injected into "
                     "another profile as a@PROFILE, nothing@PROFILE, real:gsdc:EFFECT; naming "
                     "none, all of them)")
    gap.add_argument("--trials", type=int, default=3,
                     help="self-check trials per effect (default 3)")
    gap.add_argument("--data", metavar="DIR",
                     help="self-check: the shared real logs (../shared/data) for the trials "
                     "that inject effects into a real log (default: ../shared/data where it "
                     "exists)")
    gap.add_argument("--debug", action="store_true", help="show tracebacks and debug logging")

    ephem = sub.add_parser("ephemeris", help="today's sky: fetch current TLE sets, list them",
                           description="'fetch' downloads the current TLE set of each group "
                           "(gps-ops, glo-ops, galileo, beidou) into the user cache; run, "
                           "replay, sky and gap then use the cached set nearest their time. "
                           "'list' shows the cached sets.")
    ephem.add_argument("action", choices=("fetch", "list"))
    ephem.add_argument("--groups", help="comma-separated groups (default: all four)")
    ephem.add_argument("--url", help="where to fetch one group's set from (default: CelesTrak's "
                       "GP query for the group)")
    ephem.add_argument("--debug", action="store_true", help="show tracebacks and debug logging")
    return parser


def _flags(args: argparse.Namespace) -> dict[str, Any]:
    keys = ("scene", "profile", "config", "tle", "rate", "start_time", "seed", "origin", "baud")
    return {k: getattr(args, k, None) for k in keys}


def _xyz(text: str, what: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.split(",")])
    except ValueError:
        v = np.array([])
    if v.shape != (3,) or not np.isfinite(v).all():
        raise VirtualGPSError(f"{what} must be three numbers separated by commas, got {text!r}")
    return v


class StatusLine:
    """A one-line live status on a terminal, rewritten each epoch."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self.active = stream.isatty()

    def show(self, text: str) -> None:
        if self.active:
            self.stream.write("\r\x1b[2K" + text)
            self.stream.flush()

    def end(self) -> None:
        if self.active:
            self.stream.write("\n")
            self.stream.flush()


def _status_text(fixes, stats, device) -> str:
    t = time.strftime("%H:%M:%S", time.gmtime(float(fixes.t_unix_s[0])))
    seen = int(fixes.in_view[0].sum())
    used = int(fixes.used[0].sum())
    if fixes.quality[0] > 0:
        where = (
            f"{abs(fixes.lat_deg[0]):.6f}{'N' if fixes.lat_deg[0] >= 0 else 'S'} "
            f"{abs(fixes.lon_deg[0]):.6f}{'E' if fixes.lon_deg[0] >= 0 else 'W'} "
            f"{fixes.alt_msl_m[0]:.1f} m  HDOP {fixes.hdop[0]:.1f}"
        )
        fix = "3D fix"
    else:
        where, fix = "", "no fix"
    from virtualgps.run.fleet.run import lost_epochs

    dropped = lost_epochs([device])
    extra = f"  ({dropped} unread epochs dropped)" if dropped else ""
    return f"{t}Z  {fix}  sats {used} used / {seen} in view  {where}{extra}"


def _fleet_status(p) -> str:
    """The status line of a fleet's :class:`~virtualgps.run.fleet.run.Progress`."""
    extra = f"  ({p.dropped} unread epochs dropped)" if p.dropped else ""
    return (f"{time.strftime('%H:%M:%S', time.gmtime(p.t_unix_s))}Z  {p.receivers} receivers, "
            f"{p.with_fix} with a fix  {p.epochs} epochs{extra}")


def cmd_run(args: argparse.Namespace) -> int:
    from virtualgps.poses import posesource
    from virtualgps.run import config, daemon
    from virtualgps.run.fleet import limits, workers
    from virtualgps.run.fleet.members import fleet_members, parse_ids, select_ids
    from virtualgps.run.fleet.run import RunSummary, build_fleet, log_links, progress

    if args.duration is not None and not args.duration > 0:  # (0 used to mean "for ever")
        raise VirtualGPSError(f"--duration must be positive seconds, got {args.duration:g}")
    if args.workers is not None and args.workers < 1:
        raise VirtualGPSError(f"--workers must be at least 1, not {args.workers}")
    # (Before the devices exist: a signal while a thousand are being made still removes them.)
    stop = daemon.StopEvent()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    flags = _flags(args)
    cfg = config.resolve(flags)
    everyone = fleet_members(args.receivers, args.fleet, cfg.seed, args.link)
    members = everyone if args.ids is None else select_ids(everyone, parse_ids(args.ids))
    fleet_ids = [m.receiver_id for m in everyone]
    n_workers = 1 if args.serial else min(
        len(members), args.workers or workers.default_workers(len(members)))
    status = StatusLine(sys.stdout)
    no_pose_by = time.monotonic() + NO_POSE_WARNING_S

    def poses_line(source) -> str | None:
        """Where live poses come from (logged once), or None for a log or the demo walk."""
        if source is None:
            return None
        where = "standard input" if source.describe() == "-" else source.describe()
        log.info('poses: %s, one JSON pose per message (e.g. {"t": UTC s, "x": .., "y": .., '
                 '"z": ..} in the scene\'s metres, or "lat", "lon", "alt"); no fix before the '
                 "first", where)
        return where

    def no_pose_yet(where: str | None, n_good: int) -> None:
        nonlocal no_pose_by
        if where is not None and time.monotonic() > no_pose_by:
            no_pose_by = math.inf
            if n_good == 0:
                log.warning("no pose has arrived on %s in %g s: the receiver has no fix until "
                            "one does (or try --poses demo)", where, NO_POSE_WARNING_S)

    if n_workers > 1:
        limits.check_ptys(len(members))
        source = posesource.open_pose_source(args.poses)
        where = poses_line(source)

        def on_status(progress) -> None:
            no_pose_yet(where, progress.n_good)
            status.show(_fleet_status(progress))

        try:
            summary = workers.run_workers(
                flags, args.poses, args.link, members, fleet_ids, args.topic, n_workers, stop,
                cfg.start_time_unix_s, args.duration,
                on_device=lambda slave, link: print(f"device: {slave} -> {link}", flush=True),
                on_status=on_status, live_source=source)
        finally:
            status.end()
            stop.close()
        summary.log()
        return 0

    fleet = build_fleet(flags, args.poses, args.link, serial_port=args.serial, topic=args.topic,
                        members=members, fleet_ids=fleet_ids)
    receivers = fleet.receivers
    for r, link in zip(receivers, fleet.links, strict=True):
        dev = r.device
        print(f"device: {dev.slave_path} -> {link}" if link else f"device: {dev.path}",
              flush=True)
    shown = [0.0]
    where = poses_line(getattr(fleet.provider, "source", None))  # a live stream

    def on_epoch(r, fixes, row) -> None:
        no_pose_yet(where, fleet.provider.n_good if where is not None else 0)
        if not status.active:
            return
        if len(receivers) == 1:
            status.show(_status_text(fixes, r.stats, r.device))
            return
        now = time.monotonic()
        if now - shown[0] >= 1.0:  # a fleet's line: once a second
            shown[0] = now
            status.show(_fleet_status(progress(fleet)))

    try:
        # --duration counts simulated seconds from the first epoch, not a wall-clock timer:
        # a timer races the epochs on whole seconds and sends 3 or 4 of them in 3 s.
        daemon.freeze_heap()
        daemon.run_receivers(receivers, fleet.provider, fleet.clock, stop, on_epoch,
                             waiter=fleet.waiter, duration_s=args.duration)
    finally:
        status.end()
        fleet.close()
        stop.close()
    log_links(receivers)
    RunSummary.of(fleet).log()
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from virtualgps.device import nmea
    from virtualgps.poses import logs as pose_logs
    from virtualgps.run import config, replay

    cfg = config.resolve(_flags(args))
    scene, georef, scene_tle = config.load_scene_for(cfg)
    track = pose_logs.read_pose_log(Path(args.poses), args.topic)
    t_first = cfg.start_time_unix_s if cfg.start_time_unix_s is not None else track.t_unix_s[0]
    ephemeris, _ = config.load_ephemeris(cfg, scene_tle, float(t_first))
    if georef is None:
        if track.frame != "geodetic":
            config.require_georef(None, "a geodetic pose log")
        georef = config.Georef(*(float(v) for v in track.xyz[0]))
    track = replay.track_in_scene(track, georef)
    grid = replay.epoch_grid(track.t_unix_s, cfg.profile.rate_hz, cfg.start_time_unix_s)
    if len(grid.t_unix_s) == 0:
        raise VirtualGPSError(f"{args.poses}: the pose log spans less than one output period")
    rx = config.make_receiver(cfg, scene, georef, ephemeris, float(grid.t_unix_s[0]))
    fmt = nmea.NmeaFormat.from_dict(cfg.profile.nmea)
    log.info(
        "replay %s: %d epochs, profile %s, seed %d",
        args.poses,
        len(grid.t_unix_s),
        cfg.profile.name,
        cfg.seed,
    )
    bar = _progress_bar(sys.stderr)
    written = [0]  # epochs written so far (what an interrupted replay leaves)

    def progress(done: int, total: int) -> None:
        written[0] = done
        if bar is not None:
            bar(done, total)

    if len(grid.t_unix_s) > replay.CHUNK_EPOCHS:
        replay.keep_freed_memory()  # (this process exits after the replay)
    out = sys.stdout.buffer if args.out == "-" else open(args.out, "wb")  # noqa: SIM115
    fixes_out = open(args.fixes, "w", newline="") if args.fixes else None  # noqa: SIM115
    t_start = time.perf_counter()
    try:
        n = replay.run_replay(rx, track, grid, fmt, out, cfg.seed, fixes_out, progress)
    except KeyboardInterrupt:
        # Whole epochs only were written (a chunk at a time): say how far it got, and exit
        # as an interrupted command does (128 + SIGINT), not as a finished one.
        if bar is not None:
            sys.stderr.write("\n")  # (below the progress bar's line)
        log.info("replay interrupted: %d of %d epochs written to %s", written[0],
                 len(grid.t_unix_s), args.out)
        return EXIT_INTERRUPTED
    finally:
        if out is not sys.stdout.buffer:
            out.close()
        if fixes_out is not None:
            fixes_out.close()
    dt = time.perf_counter() - t_start
    log.info("wrote %d epochs in %.2f s (%.0f epochs/s)", n, dt, n / max(dt, 1e-9))
    return 0


def _progress_bar(stream):
    if not stream.isatty():
        return None

    def show(done: int, total: int) -> None:
        width = 40
        k = int(width * done / max(total, 1))
        stream.write(f"\r[{'#' * k}{'.' * (width - k)}] {done}/{total} epochs")
        if done >= total:
            stream.write("\n")
        stream.flush()

    return show


def cmd_sky(args: argparse.Namespace) -> int:
    from virtualgps import geodesy
    from virtualgps.receiver.skyview import compute_sky
    from virtualgps.run import config
    from virtualgps.sky import systems

    try:
        kept = ("".join(systems.system_named(n).letter for n in args.systems.split(","))
                if args.systems else None)
    except ValueError as exc:
        raise ConfigError(f"--systems: {exc}") from None
    cfg = config.resolve(_flags(args))
    scene, georef, scene_tle = config.load_scene_for(cfg)
    t = config.parse_time(args.time) if args.time else time.time()
    ephemeris, _ = config.load_ephemeris(cfg, scene_tle, t, systems_kept=kept)
    if args.lla:
        lla = np.array(config.parse_origin(args.lla, "--lla"))
        if georef is None:
            georef = config.Georef(*lla)
        at = geodesy.ecef_to_enu(
            geodesy.geodetic_to_ecef(*lla), georef.lat0_deg, georef.lon0_deg, georef.alt0_hae_m
        )
    else:
        georef = config.require_georef(georef, "--lla")
        at = _xyz(args.at, "--at") if args.at else np.array([0.0, 0.0, 1.5])
    # --time is taken literally: no sky-time mapping here.
    note = config.coverage_note(ephemeris, t)
    if note:
        raise VirtualGPSError(f"{note} (give --time within it)")
    rx = config.make_receiver(cfg, scene, georef, ephemeris, t, apply_sky_policy=False)
    sky = compute_sky(rx, np.array([t]), at[None, :])
    rows = sky_rows(rx, sky)
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        print(f"{'system':<7} {'prn':>4} {'az_deg':>7} {'el_deg':>7}  state")
        for r in rows:
            print(
                f"{r['system']:<7} {r['prn']:>4} {r['az_deg']:7.2f} {r['el_deg']:7.2f}  "
                f"{r['state']}"
                + (f"  {r['cn0_dbhz']:.1f} dB-Hz" if r.get("cn0_dbhz") is not None else "")
            )
    if args.plot:
        from virtualgps.plot import skyplot

        skyplot(
            rows, Path(args.plot), title=f"{time.strftime('%Y-%m-%d %H:%M:%SZ', time.gmtime(t))}"
        )
        log.info("skyplot written to %s", args.plot)
    return 0


def sky_rows(rx, sky) -> list[dict[str, Any]]:
    """One row per satellite above the horizon: system, prn, az_deg, el_deg, state, cn0_dbhz.

    ``prn`` is the satellite's ID as its system's NMEA GSV writes it (GPS 1-32, GLONASS 65-96,
    Galileo 1-36, BeiDou 1-63, QZSS 1-10, SBAS 33-64), ``system`` the system's name.

    States: ``below_mask`` (above the horizon, below the mask), ``blocked`` (line of sight
    hits an occluder or a blocking bin of the profile's ``[sky_mask]``, no signal), ``nlos``
    (blocked, received off a wall: the ``nlos`` effect), ``attenuated`` (through foliage or a
    sky-mask bin: the ``foliage`` effect), ``visible``. ``cn0_dbhz`` is the
    arriving signal's C/N0 without fading (null where none).
    """
    from virtualgps.receiver.core import expected_cn0_dbhz
    from virtualgps.sky import systems

    cn0 = expected_cn0_dbhz(rx.profile, sky)
    rows = []
    for j, prn in enumerate(np.asarray(rx.ephemeris.prn).tolist()):
        system = systems.system_of(prn)
        el = float(sky.el_deg[0, j])
        if not np.isfinite(el) or el < 0.0:
            continue
        if not sky.above_mask[0, j]:
            state = "below_mask"
        elif sky.nlos[0, j]:
            state = "nlos"
        elif sky.blocked[0, j]:
            state = "blocked"
        elif sky.foliage_db[0, j] > 0.0:
            state = "attenuated"
        else:
            state = "visible"
        c = float(cn0[0, j])
        rows.append({"system": system.name if system is not None else "unknown",
                     "prn": int(prn) - (system.nmea_offset if system is not None else 0),
                     "az_deg": round(float(sky.az_deg[0, j]), 3),
                     "el_deg": round(el, 3), "state": state,
                     "cn0_dbhz": round(c, 1) if np.isfinite(c) and state != "below_mask"
                     else None})
    return sorted(rows, key=lambda r: -r["el_deg"])


def _gap_options(args: argparse.Namespace):
    from virtualgps.gap.diagnose import Options
    from virtualgps.gap.effects import EFFECT_NAMES

    effects = None
    if args.effects and args.effects.strip() == "none" and not args.selfcheck:
        effects = ()  # (locate the gaps and name the causes; offer no effect)
    elif args.effects:
        effects = tuple(e.strip() for e in args.effects.split(",") if e.strip())
        bad = [e for e in effects if not (e in EFFECT_NAMES or (args.selfcheck and (
            "+" in e or "@" in e or e.startswith(("nothing", "real:")))))]
        if bad:
            raise VirtualGPSError(f"--effects: unknown effect {', '.join(bad)}; known: "
                                  f"{', '.join(EFFECT_NAMES)}")
    for name in ("seeds", "fit_seeds", "jobs", "blocks", "trials"):
        v = getattr(args, name)
        if v is not None and v < (2 if name in ("seeds", "blocks") else 1):
            raise VirtualGPSError(f"--{name.replace('_', '-')} must be at least "
                                  f"{2 if name in ('seeds', 'blocks') else 1}, got {v}")
    return Options(seeds=args.seeds, fit_seeds=args.fit_seeds, effects=effects,
                   jobs=args.jobs, dask=args.dask, blocks=args.blocks)


class _GapStatus:
    """Where a long diagnosis or self-check is: on a terminal, one line kept up to date; on
    anything else (a log file, a pipe, CI) a plain line at most every ``every_s`` seconds, so a
    30-minute self-check logs where it is without flooding the log, and a run shorter than
    ``every_s`` writes nothing but its result."""

    def __init__(self, stream, every_s: float = 15.0) -> None:
        self.stream, self.every_s = stream, every_s
        self.tty = stream.isatty()
        self.last_s = time.monotonic()

    def __call__(self, text: str) -> None:
        if self.tty:
            self.stream.write("\r\x1b[K" + text[:120])
        else:
            now = time.monotonic()
            if now - self.last_s < self.every_s:
                return
            self.last_s = now
            self.stream.write(f"virtualgps: {text}\n")
        self.stream.flush()

    def clear(self) -> None:
        """Ends the display before the result is printed."""
        if self.tty:
            self.stream.write("\r\x1b[K")


def cmd_gap(args: argparse.Namespace) -> int:
    from virtualgps.gap import tool

    opts = _gap_options(args)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise VirtualGPSError(f"--out {out}: exists and is not a folder")
    progress = _GapStatus(sys.stderr)
    if args.selfcheck:
        from virtualgps.gap import selfcheck, selfcheck_real, synthetic

        data = Path(args.data) if args.data else Path("..") / "shared" / "data"
        if args.data and not data.is_dir():
            raise VirtualGPSError(f"--data {data}: no such folder")
        try:
            labels = selfcheck.default_labels(opts.effects)
            for label in labels:
                synthetic.spec_of(label)
            selfcheck_real.named_effects(opts.effects)
        except (KeyError, ValueError) as exc:
            raise VirtualGPSError(f"--effects: {exc}") from None
        result = selfcheck.run(opts, trials=args.trials, out_dir=out, progress=progress,
                               labels=labels, data=data if data.is_dir() else None)
        progress.clear()
        for line in selfcheck.summary_lines(result):
            print(line)
        print(f"wrote {out / 'selfcheck.json'} and {out / 'report.html'}")
        return 0
    inp = tool.GapInputs(real=tuple(args.real), truth=tuple(args.truth), scene=args.scene,
                         tle=tuple(args.tle) if args.tle else None, profile=args.profile)
    report, figures, calibrated = tool.diagnose(inp, opts, progress=progress)
    progress.clear()
    try:
        tool.write_outputs(report, figures, calibrated, report["profile"], out, opts.jobs,
                           opts.dask)
    except OSError as exc:
        raise VirtualGPSError(f"--out {out}: cannot write the report ({exc.strerror})") from None
    for line in tool.summary_lines(report):
        print(line)
    print(f"wrote {out / 'report.json'}, {out / 'report.html'} and {out / 'calibrated.toml'}")
    return 0


def cmd_ephemeris(args: argparse.Namespace) -> int:
    from virtualgps.sky import systems, tlecache

    groups = (args.groups.split(",") if args.groups
              else ["gps-ops"] if args.url else list(systems.GROUPS.values()))
    if args.action == "fetch":
        if args.url and len(groups) != 1:
            raise ConfigError("--url fetches one group: name it with --groups (e.g. "
                              "--groups galileo); the default is gps-ops")
        failed = []
        for group in groups:
            try:
                c = tlecache.fetch(args.url, group=group)
            except VirtualGPSError as exc:
                if len(groups) == 1:
                    raise
                log.warning("%s: not fetched: %s", group, exc)
                failed.append(group)
                continue
            print(f"{c.path}: {c.n_sat} satellites, epoch {_utc(c.epoch_center_unix_s)}, "
                  f"from {c.url}")
        # (the receivers track GPS: a fetch without its GPS set has failed)
        return 1 if "gps-ops" in failed else 0
    sets = [c for g in groups for c in tlecache.cached_sets(group=g)]
    if not sets:
        print(f"no fetched TLE sets in {tlecache.cache_dir()} ('virtualgps ephemeris fetch')")
    for c in sets:
        age_d = (time.time() - c.fetched_unix_s) / 86400.0
        print(f"{c.path}: {c.n_sat} satellites, epoch {_utc(c.epoch_center_unix_s)}, fetched "
              f"{age_d:.1f} days ago from {c.url}")
    return 0


def _utc(t_unix_s: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime(t_unix_s))


COMMANDS = {"run": cmd_run, "replay": cmd_replay, "sky": cmd_sky, "gap": cmd_gap,
            "ephemeris": cmd_ephemeris}


# Options whose value is a comma-separated triple that may start with a minus sign
# (``--lla -33.86,151.21,50``): argparse takes such a word for an option of its own.
TRIPLE_OPTIONS = ("--lla", "--at", "--origin")
NEGATIVE = re.compile(r"-\.?\d")


def join_triples(argv: list[str]) -> list[str]:
    """``--lla -33.9,151.2,50`` as ``--lla=-33.9,151.2,50``, so negative values parse as typed."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in TRIPLE_OPTIONS and i + 1 < len(argv) and NEGATIVE.match(argv[i + 1]):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``virtualgps`` command; returns the exit code."""
    args = build_parser().parse_args(join_triples(sys.argv[1:] if argv is None else list(argv)))
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.INFO,
        format="virtualgps: %(message)s",
        stream=sys.stderr,
    )
    try:
        return COMMANDS[args.command](args)
    except VirtualGPSError as exc:
        if args.debug:
            raise
        print(f"virtualgps: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        return 0
    except BrokenPipeError:
        # The reader left (``virtualgps sky | head``): nothing more to say, and nothing for
        # the interpreter to flush at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # a path that cannot be read or written: say which, in one line
        if args.debug:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"virtualgps: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_ERROR
