"""Benchmark: replay throughput and live CPU per epoch on the Magdeburg scene.

Usage (pinned to one core, as the figures in docs/performance.md were measured; whole processes also
on both, where a long replay computes the next chunk's sky in a second thread):

    taskset -c 0 python tools/bench_replay.py [--profile NAME] [--hours 1] [--live-epochs 2000]
        [--repeat 5]
    python tools/bench_replay.py --whole-process [--repeat 5]     # and with taskset -c 0
    python tools/bench_replay.py --daemon [--seconds 30]
    taskset -c 0 python tools/bench_replay.py --breakdown

``--whole-process`` times whole ``virtualgps replay`` processes (interpreter start-up, imports
and all): a 20-epoch replay, and the 1 h walk at 10 Hz (36,000 epochs) paired, run by run,
with nmeasim's ``Simulator().generate`` of as many epochs (no physics: a reference for what
writing NMEA alone costs in Python; ``pip install nmeasim``). ``--daemon`` measures whole
``virtualgps run --poses demo`` processes at 1 Hz and 10 Hz, a client reading the device: CPU
time (all threads, from /proc) per epoch and as a share of a core, and their wake-ups per epoch,
after probes of what the machine adds: to work that follows idle time (a fixed workload,
:func:`idle_penalty`, and the daemon's own per-epoch work after 90 ms of sleep) and to every
wake-up (:func:`wake_cost_s`). ``--breakdown`` replays the
hour at 10 Hz in-process and times (CPU of the calling thread) the seed-independent sky
(``sky.compute_sky``, in the replay's second thread) and its parts inside it -- what any
receiver model on this sky costs before its first random draw -- then the rest of the receiver
and the NMEA rendering in the main thread.

Replay: a 1 h, 1 Hz walk (the scene's demo loop) written as a JSONL pose log, replayed through
``virtualgps replay`` (the CLI's code path, in-process), NMEA to a file: epochs per second of
wall time overall; then the same replay's start-up (loading) and epochs timed apart in one
process: epochs per second of ``replay.run_replay``, best and median of ``--repeat`` runs.

Live: the daemon's per-epoch work (interpolate the pose, simulate one epoch, render its NMEA) for
``--repeat`` blocks of ``--live-epochs`` consecutive epochs, measured as process CPU time per
epoch, best and median block. (This project's machine is a VM whose neighbours make single runs
vary by +-20 %: the best of several runs is the code's speed.)
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from virtualgps.cli import main as cli_main
from virtualgps.device import nmea
from virtualgps.poses import logs as pose_logs
from virtualgps.receiver.core import simulate
from virtualgps.receiver.state import ReceiverState
from virtualgps.run import config, replay
from virtualgps.run.poseproviders import LoopProvider, demo_lap

START_UNIX_S = 1490712768.0  # 2017-03-28T14:52:48Z, the day of the Magdeburg waypoint logs


def write_walk(path: Path, hours: float, rate_hz: float = 1.0) -> None:
    """The scene's demo loop for ``hours`` at ``rate_hz`` poses per second, as JSONL."""
    scene, _, _ = config.load_scene_for(config.resolve({}))
    walk = LoopProvider(demo_lap(scene.demo_waypoints_enu_m, scene.demo_speed_mps),
                        START_UNIX_S, 2.0)
    n = int(round(hours * 3600 * rate_hz))
    t = START_UNIX_S + np.arange(n + (rate_hz == 1.0)) / rate_hz
    pos, _, _ = walk.pose_at(t)
    with open(path, "w") as f:
        for ti, p in zip(t.tolist(), pos.tolist(), strict=True):
            f.write(
                json.dumps(
                    {
                        "t": round(ti, 3),
                        "x": round(p[0], 3),
                        "y": round(p[1], 3),
                        "z": round(p[2], 3),
                    }
                )
                + "\n"
            )


def bench_replay(poses: Path, out: Path, profile: str, cfg: str | None) -> tuple[float, int]:
    """Wall time of the whole ``virtualgps replay`` command, in-process, and its epoch count."""
    t0 = time.perf_counter()
    extra = ["--config", cfg] if cfg else []
    code = cli_main(["replay", str(poses), "--out", str(out), "--profile", profile, "--seed", "1",
                     *extra])
    assert code == 0
    n = sum(1 for line in open(out, "rb") if line.startswith(b"$GPGGA"))
    return time.perf_counter() - t0, n


def bench_core(
    poses: Path, profile: str, cfg_file: str | None, repeat: int
) -> tuple[float, list[float], int]:
    """The replay's two parts timed apart in one process: start-up (profile, scene with its
    Embree scenes, TLEs, receiver and its reflecting walls, the pose log) and the epochs
    (``replay.run_replay``: simulate + NMEA, output discarded), the epochs ``repeat`` times
    with a fresh receiver each (the same work: the host's noise is what varies)."""
    import io

    t0 = time.perf_counter()
    cfg = config.resolve({"profile": profile, "config": cfg_file})
    scene, georef, tle = config.load_scene_for(cfg)
    walk = pose_logs.read_pose_log(poses)
    eph, _ = config.load_ephemeris(cfg, tle, float(walk.t_unix_s[0]))  # (the set replay takes)
    track = replay.track_in_scene(walk, georef)
    grid = replay.epoch_grid(track.t_unix_s, cfg.profile.rate_hz, None)
    rx = config.make_receiver(cfg, scene, georef, eph, float(grid.t_unix_s[0]))
    fmt = nmea.NmeaFormat.from_dict(cfg.profile.nmea)
    startup_s = time.perf_counter() - t0
    runs_s = []
    for k in range(repeat):
        if k:
            rx = config.make_receiver(cfg, scene, georef, eph, float(grid.t_unix_s[0]))
        t1 = time.perf_counter()
        n = replay.run_replay(rx, track, grid, fmt, io.BytesIO(), 1)
        runs_s.append(time.perf_counter() - t1)
    return startup_s, runs_s, n


def bench_live(profile: str, cfg_file: str | None, n_epochs: int, repeat: int,
               pause_s: float = 0.0) -> list[float]:
    """CPU seconds per epoch of the daemon's per-epoch work, for each of ``repeat`` consecutive
    blocks of ``n_epochs`` epochs: back to back, or each epoch after ``pause_s`` of sleep (as a
    daemon runs them; the sleeps not counted)."""
    cfg = config.resolve({"profile": profile, "config": cfg_file})
    scene, georef, tle = config.load_scene_for(cfg)
    eph, _ = config.load_ephemeris(cfg, tle, START_UNIX_S)
    rx = config.make_receiver(cfg, scene, georef, eph, START_UNIX_S)
    fmt = nmea.NmeaFormat.from_dict(cfg.profile.nmea)
    walk = LoopProvider(demo_lap(scene.demo_waypoints_enu_m, scene.demo_speed_mps),
                        START_UNIX_S, 2.0)
    rng = np.random.default_rng(0)
    state = ReceiverState()
    sink = bytearray()

    def epoch(k: int) -> None:
        nonlocal state
        t = np.array([START_UNIX_S + k])
        p, v, ok = walk.pose_at(t)
        fixes, state = simulate(rx, t, p, v, ok, state, rng)
        sink.extend(nmea.epoch_sentences(fixes, 0, fmt))

    for k in range(-20, 0):  # warm up: lazy imports and caches, as a long-running daemon has
        epoch(k)
    per_epoch_s = []
    for block in range(repeat):
        spent_s = 0.0
        c0 = time.process_time()
        for k in range(block * n_epochs, (block + 1) * n_epochs):
            if pause_s:
                time.sleep(pause_s)
                c0 = time.process_time()
            epoch(k)
            if pause_s:
                spent_s += time.process_time() - c0
        if not pause_s:
            spent_s = time.process_time() - c0
        per_epoch_s.append(spent_s / n_epochs)
    return per_epoch_s


def _process_s(cmd: list[str], cpu: list[float] | None = None) -> float:
    """Wall seconds of one whole process (its CPU seconds, user + system, appended to
    ``cpu``)."""
    import resource
    import subprocess

    # With bytecode caches, as users run: pip compiles an installed wheel's modules, and a
    # checkout writes __pycache__ on its first run, unless PYTHONDONTWRITEBYTECODE is set (this
    # project's machine sets it; every run then compiles our modules again, ~0.07 s).
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if cpu is not None:
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return wall


NMEASIM = """import io, sys
from nmeasim.simulator import Simulator
Simulator().generate(float(sys.argv[1]), output=io.StringIO())
"""


def bench_whole_process(repeat: int, profile: str) -> None:
    """Whole replay processes: 20 epochs, and an hour at 10 Hz against nmeasim (paired)."""
    import importlib.util

    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        short, long_ = Path(tmp) / "short.jsonl", Path(tmp) / "walk10.jsonl"
        write_walk(short, 19 / 3600)
        write_walk(long_, 1.0, rate_hz=10.0)
        rep = [py, "-m", "virtualgps", "replay", "--profile", profile, "--out",
               str(Path(tmp) / "o.nmea")]
        _process_s([*rep, str(short)])  # the mesh cache and bytecode, as a second run has them
        t20 = [_process_s([*rep, str(short)]) for _ in range(repeat)]
        print(f"20-epoch replay, whole process: best {min(t20):.2f} s, median "
              f"{np.median(t20):.2f} s (target <= 0.4 s)")
        have_nmeasim = importlib.util.find_spec("nmeasim") is not None
        ours, theirs, ours_cpu = [], [], []
        for _ in range(repeat):
            ours.append(_process_s([*rep, "--rate", "10", str(long_)], ours_cpu))
            if have_nmeasim:
                theirs.append(_process_s([py, "-c", NMEASIM, "36000"]))
        # (A replay of several chunks computes the next chunk's sky in a second thread: wall
        # time is what a user waits for, CPU time what the cores spent.)
        print(f"1 h walk at 10 Hz (36,000 epochs), whole process: best {min(ours):.2f} s, "
              f"median {np.median(ours):.2f} s (CPU {np.median(ours_cpu):.2f} s on "
              f"{len(os.sched_getaffinity(0))} core(s))")
        if have_nmeasim:
            ratio = np.array(theirs) / np.array(ours)
            print(f"nmeasim generate of 36,000 epochs: best {min(theirs):.2f} s, median "
                  f"{np.median(theirs):.2f} s; speed-up (paired) median {np.median(ratio):.2f}x, "
                  f"range {ratio.min():.2f}-{ratio.max():.2f}x (target >= 3x)")
        else:
            print("nmeasim not installed (pip install nmeasim): no comparison")


def bench_breakdown() -> None:
    """The hour at 10 Hz replayed in-process (``virtualgps replay``), with the sky's parts
    timed where they are called: CPU seconds of the calling thread (the skies run in a second
    thread beside the main one, which on one core interleave), summed over the run's chunks."""
    from virtualgps.receiver import signals
    from virtualgps.run import replay
    from virtualgps.sky import satnodes, scene

    spent: dict[str, float] = {}  # in the order registered

    def timed(owner: object, name: str, label: str) -> None:
        inner = getattr(owner, name)

        def wrapper(*args: object, **kwargs: object) -> object:
            t0 = time.thread_time()
            try:
                return inner(*args, **kwargs)
            finally:
                spent[label] = spent.get(label, 0.0) + time.thread_time() - t0

        setattr(owner, name, wrapper)
        spent[label] = 0.0

    timed(replay, "compute_sky", "sky (compute_sky), all of it")
    timed(satnodes.SatNodes, "sat_ecef_m", "  satellite positions (SGP4 nodes, interpolated)")
    timed(scene.Scene, "blocked", "  Embree any-hit rays (direct paths, scattering's 2nd leg)")
    timed(scene.Scene, "hit_distance_m",
          "  Embree nearest-hit rays (foliage, scattering's 1st leg)")
    timed(signals, "scattered_paths", "  scattering search (its rays included)")
    timed(replay, "simulate", "the rest of the receiver (simulate, given the sky)")
    timed(replay.nmea, "render_batch", "NMEA (render_batch)")
    with tempfile.TemporaryDirectory() as tmp:
        poses = Path(tmp) / "walk10.jsonl"
        write_walk(poses, 1.0, rate_hz=10.0)
        t0 = time.perf_counter()
        code = cli_main(["replay", str(poses), "--rate", "10", "--out", str(Path(tmp) / "o.nmea")])
        total = time.perf_counter() - t0
    assert code == 0
    print(f"1 h walk at 10 Hz in-process: {total:.2f} s wall (imports before it not counted); "
          "CPU seconds of the calling thread:")
    for label, sec in spent.items():
        print(f"{label}: {sec:.2f} s")


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (all its threads), from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _sleeps(pid: int) -> int:
    """Times the threads of a process have gone to sleep so far (voluntary context switches:
    each is a wake-up later), from /proc."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):  # (a thread that ended meanwhile)
            for line in (task / "status").read_text().splitlines():
                if line.startswith("voluntary_ctxt_switches:"):
                    total += int(line.split()[1])
    return total


def bench_daemon(rate_hz: float, seconds: float, profile: str) -> tuple[float, float]:
    """CPU seconds per epoch of a whole ``virtualgps run --poses demo`` process (simulation,
    NMEA, the pty writer's pacing, pose input) at ``rate_hz``, 115200 baud, with a client
    reading the device, over ``seconds`` after a 5 s warm-up, and its wake-ups per epoch."""
    import subprocess
    import threading

    with tempfile.TemporaryDirectory() as tmp:
        link = Path(tmp) / "gps"
        proc = subprocess.Popen(
            [sys.executable, "-m", "virtualgps", "run", "--poses", "demo", "--profile", profile,
             "--rate", str(rate_hz), "--baud", "115200", "--link", str(link), "--duration",
             str(seconds + 8)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            for _ in range(200):
                if link.exists():
                    break
                time.sleep(0.05)
            fd = os.open(link, os.O_RDONLY | os.O_NOCTTY)

            def drain() -> None:
                try:
                    while os.read(fd, 4096):
                        pass
                except OSError:
                    pass

            threading.Thread(target=drain, daemon=True).start()
            time.sleep(5.0)
            c0, w0 = _cpu_s(proc.pid), _sleeps(proc.pid)
            time.sleep(seconds)
            c1, w1 = _cpu_s(proc.pid), _sleeps(proc.pid)
        finally:
            proc.terminate()
            proc.wait()
    return (c1 - c0) / (seconds * rate_hz), (w1 - w0) / (seconds * rate_hz)


def wake_cost_s(sleep_s: float = 0.016, n: int = 300) -> float:
    """CPU seconds a thread is charged for each wake-up from an ``epoll`` wait of ``sleep_s``
    with no work in between: what the machine charges a daemon per wake-up (an epoch, a slice of
    output), before any of our code runs (this project's VM: 60-85 us; a poll that does not
    sleep, 0.5 us). Median of ``n`` waits."""
    import select

    ep = select.epoll()
    spent = []
    try:
        for _ in range(n):
            c0 = time.thread_time()
            ep.poll(sleep_s)
            spent.append(time.thread_time() - c0)
    finally:
        ep.close()
    return float(np.median(spent))


def idle_penalty(pauses_s: tuple[float, ...] = (0.0, 0.09, 1.0), n: int = 14) -> list[float]:
    """CPU time of a fixed small-numpy workload (~2 ms, like one live epoch) run after each of
    ``pauses_s`` of sleep (0: back to back), as a daemon at 10 Hz or 1 Hz runs its epochs: what
    the machine itself adds to work that follows idle time (a VM's vCPU descheduled, caches and
    clock speed lost), independent of our code. Median of the last ``n`` of ``n + 2`` runs for
    each pause, seconds."""
    a = np.random.default_rng(0).random(64)

    def work() -> None:
        for i in range(200):
            float(np.sum(a * i))

    out = []
    for pause in pauses_s:
        spent = []
        for _ in range(n + 2):
            if pause:
                time.sleep(pause)
            c0 = time.process_time()
            work()
            spent.append(time.process_time() - c0)
        out.append(float(np.median(spent[2:])))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="holux-m1000")
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--live-epochs", type=int, default=2000)
    ap.add_argument("--config", help="a config file of profile overrides (e.g. effects on)")
    ap.add_argument("--repeat", type=int, default=5,
                    help="time the replay epochs and the live blocks this many times: the best "
                    "is the code's speed, the median what a busy host gives")
    ap.add_argument("--whole-process", action="store_true",
                    help="time whole replay processes (20 epochs; 1 h at 10 Hz vs nmeasim)")
    ap.add_argument("--daemon", action="store_true",
                    help="CPU of whole 'virtualgps run' processes at 1 Hz and 10 Hz")
    ap.add_argument("--seconds", type=float, default=30.0, help="--daemon: measured seconds")
    ap.add_argument("--breakdown", action="store_true",
                    help="time the sky and its parts inside a replay of the hour at 10 Hz")
    args = ap.parse_args()
    if args.breakdown:
        bench_breakdown()
        return
    if args.daemon:
        tight_s, after_90ms_s, after_1s_s = idle_penalty()
        print(f"machine: a fixed workload takes {tight_s * 1e3:.2f} ms of CPU back to back, "
              f"{after_90ms_s * 1e3:.2f} ms after 90 ms of sleep ({after_90ms_s / tight_s:.1f}x), "
              f"{after_1s_s * 1e3:.2f} ms after 1 s ({after_1s_s / tight_s:.1f}x)")
        wake_s = wake_cost_s()
        print(f"machine: each wake-up from a 16 ms epoll wait costs {wake_s * 1e6:.0f} us of CPU")
        tight = np.median(bench_live(args.profile, args.config, 200, 3))
        after = np.median(bench_live(args.profile, args.config, 100, 3, pause_s=0.09))
        print(f"the daemon's per-epoch work ({args.profile}, in-process): {tight * 1e3:.2f} ms "
              f"of CPU back to back, {after * 1e3:.2f} ms after 90 ms of sleep "
              f"({after / tight:.1f}x)")
        for rate in (1.0, 10.0):
            per, wakes = bench_daemon(rate, args.seconds, args.profile)
            print(f"daemon at {rate:g} Hz ({args.profile}, 115200 baud, a client reading): "
                  f"{per * 1e3:.2f} ms CPU per epoch, {100 * per * rate:.2f} % of a core; "
                  f"{wakes:.1f} wake-ups per epoch (~{wakes * wake_s * 1e3:.2f} ms of it)")
        return
    if args.whole_process:
        bench_whole_process(args.repeat, args.profile)
        return
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        poses = Path(tmp) / "walk.jsonl"
        write_walk(poses, args.hours)
        wall_s, n = bench_replay(poses, Path(tmp) / "out.nmea", args.profile, args.config)
        startup_s, core_s, n_core = bench_core(poses, args.profile, args.config, args.repeat)
    live_s = bench_live(args.profile, args.config, args.live_epochs, args.repeat)
    print(f"profile {args.profile}{' + ' + args.config if args.config else ''}, {cores} core(s) "
          "available to the process")
    print(f"replay command: {n} epochs in {wall_s:.2f} s -> {n / wall_s:,.0f} epochs/s overall")
    best, median = min(core_s), float(np.median(core_s))
    print(f"replay epochs: {n_core} after a {startup_s:.2f} s start-up, best of {args.repeat} "
          f"{best:.3f} s -> {n_core / best:,.0f} epochs/s (median {n_core / median:,.0f})")
    print(f"live: {min(live_s) * 1e3:.3f} ms CPU per epoch, best of {args.repeat} blocks of "
          f"{args.live_epochs} epochs (median {np.median(live_s) * 1e3:.3f} ms)")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
