"""Benchmark: a fleet of receivers in one daemon, every device read by epoll reader processes.

Usage:

    python tools/bench_fleet.py [--receivers 1,10,100,1000] [--seconds 20] [--rate 10]
        [--scene none|default] [--config FILE] [--poses demo|udp] [--workers 1,2]
        [--readers K] [--json FILE]

For each fleet size: ``virtualgps run --receivers N --poses demo`` at ``--rate`` Hz and 115200
baud, and reader processes (one per 2,500 devices unless ``--readers`` says) that each open a
contiguous share of the devices and read them all through one epoll. After a warm-up the
daemon's CPU (all its processes and threads, from /proc) is measured over ``--seconds``; the
reader notes when the first byte of each epoch arrived on each device: when epoll reported the
device readable (the byte was there by then), and when the reader had read it (later by its
reads of the devices before it in the same batch: a thousand devices readable at once take one
reader several milliseconds). The report, one line per size: the daemon's CPU in cores and per
receiver-epoch delivered, the share of the epochs due in the window (tags up to a second before
its end) that arrived (mean and worst device), and the first byte's delay after its time tag
(median and 99th percentile over all devices and epochs; the p99 also as read).

The time tag is the epoch's simulated UTC, here the wall clock (no --start-time): the delay is
what a client sees between the epoch's instant and its first byte.

``--poses udp``: instead of the scripted walk, a sender process sends every receiver's pose
over UDP at the output rate (``{"id": i, "t": now, "x": ..., "y": ..., "z": ...}``, each robot
on a circle of its own), as a simulator would.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

READER = r'''
import json, os, resource, select, sys, time
paths, seconds = json.loads(sys.stdin.readline()), float(sys.argv[1])
soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
if soft < len(paths) + 64:
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, len(paths) + 64), hard))
ep = select.epoll()
fds = {}
for i, p in enumerate(paths):
    fd = os.open(p, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    fds[fd] = i
    ep.register(fd, select.EPOLLIN)
tail = [b""] * len(paths)
# (readable, read: wall times; GGA time field) of each epoch's first byte. "Readable" is when
# epoll reported the device (the byte was there by then); "read" is after this process read it,
# later by the reads of the devices before it in the same batch: this reader's own time.
first = [[] for _ in paths]
t_end = time.time() + seconds
while time.time() < t_end:
    ready = ep.poll(0.05)
    t_ready = time.time()
    for fd, _ in ready:
        try:
            chunk = os.read(fd, 65536)
        except OSError:
            continue
        now = time.time()
        i = fds[fd]
        buf = tail[i] + chunk
        start = 0
        while True:
            k = buf.find(b"$GPGGA,", start)
            if k < 0 or len(buf) < k + 17:
                break
            if k >= len(tail[i]):  # (a GGA that arrived in this read: its first byte now)
                first[i].append((t_ready, now, buf[k + 7:k + 17].decode("ascii", "replace")))
            start = k + 1
        tail[i] = buf[-32:]
print(json.dumps(first))
'''


SENDER = r'''
import json, math, socket, sys, time
port, n, rate = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
k = 0
t0 = time.time()
while True:
    now = time.time()
    for i in range(n):
        a = 0.05 * now + i
        msg = {"id": i, "t": now, "x": 30.0 * math.cos(a) + (i % 40) - 20.0,
               "y": 30.0 * math.sin(a) + (i // 40) - 12.0, "z": 1.5}
        s.sendto(json.dumps(msg).encode(), ("127.0.0.1", port))
    k += 1
    time.sleep(max(0.0, t0 + k / rate - time.time()))
'''


# Devices one reader process takes: a reader is one Python epoll loop, and its own time must
# stay small beside the daemon's (at 2,000 devices at 10 Hz one takes 0.15 cores here).
READERS_EVERY = 2500


def free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stat(pid: int) -> list[str]:
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()


def cpu_s(pid: int) -> float:
    """User + system CPU seconds so far of a process (all threads) and of its worker
    processes (its children, while they run)."""
    total = 0.0
    for pids in (pid, *children(pid)):
        try:
            fields = _stat(pids)
        except (FileNotFoundError, ProcessLookupError):
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def children(pid: int) -> list[int]:
    """The running processes whose parent is ``pid``."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if int(_stat(int(d.name))[1]) == pid:
                    out.append(int(d.name))
            except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
                continue
    return out


def tag_s(field: str) -> float:
    return int(field[:2]) * 3600 + int(field[2:4]) * 60 + float(field[4:])


def bench(n: int, seconds: float, rate: float, scene: str, cfg: str | None,
          poses: str = "demo", workers: int | None = None, readers: int = 0) -> dict:
    """One fleet size; returns its figures."""
    sender = None
    spec = "demo"
    if poses == "udp":
        port = free_udp_port()
        spec = f"udp://127.0.0.1:{port}"
        sender = subprocess.Popen([sys.executable, "-c", SENDER, str(port), str(n), str(rate)])
    with tempfile.TemporaryDirectory() as tmp:
        args = [sys.executable, "-m", "virtualgps", "run", "--receivers", str(n), "--poses",
                spec, "--rate", str(rate), "--baud", "115200", "--link",
                str(Path(tmp) / "gps{id}"), "--duration", str(seconds + 30)]
        if scene != "default":
            args += ["--scene", scene]
        if cfg:
            args += ["--config", cfg]
        if workers is not None:
            args += ["--workers", str(workers)]
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                text=True)
        rd: list[subprocess.Popen] = []
        try:
            links = [proc.stdout.readline().split()[3] for _ in range(n)]
            warm_s = 5.0
            # (the paths go on stdin: 10,000 of them are past one argument's 128 kB limit)
            k = readers or -(-n // READERS_EVERY)
            shares_of = np.array_split(np.arange(n), k)
            rd = [subprocess.Popen([sys.executable, "-c", READER, str(seconds + warm_s)],
                                   stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
                  for _ in shares_of]
            for r, ids in zip(rd, shares_of, strict=True):
                r.stdin.write(json.dumps([links[i] for i in ids]) + "\n")
                r.stdin.close()
            time.sleep(warm_s)
            c0, w0 = cpu_s(proc.pid), time.time()
            r0 = sum(cpu_s(r.pid) for r in rd)
            time.sleep(seconds)
            c1, w1 = cpu_s(proc.pid), time.time()
            r1 = sum(cpu_s(r.pid) for r in rd)
            first = [dev for r in rd for dev in json.loads(r.stdout.read())]
        finally:
            for r in rd:
                r.kill()
                r.wait()
            proc.terminate()
            proc.wait(30)
            if sender is not None:
                sender.kill()
                sender.wait()
    day = np.floor(w0 / 86400.0) * 86400.0
    # The epochs due in the window (tags from its start to a second before its end, that second
    # left for them to arrive): each device's share is how many of those it received.
    k_lo, k_hi = math.ceil(w0 * rate - 1e-6), math.floor((w1 - 1.0) * rate + 1e-6)
    delays, read_delays, shares = [], [], []
    for dev in first:
        arr = np.array([(t, t_read, tag_s(f)) for t, t_read, f in dev]).reshape(-1, 3)
        tags = arr[:, 2] + day
        tags = np.where(tags - arr[:, 0] > 43200, tags - 86400, tags)  # (midnight)
        k = np.round(tags * rate)
        sel = (k >= k_lo) & (k <= k_hi)
        delays.extend(arr[sel, 0] - tags[sel])
        read_delays.extend(arr[sel, 1] - tags[sel])
        shares.append(len(set(k[sel].tolist())) / (k_hi - k_lo + 1))
    d, d_read = np.array(delays), np.array(read_delays)
    cores = (c1 - c0) / (w1 - w0)
    delivered = float(np.mean(shares))
    # (the CPU per receiver-epoch *delivered*: an overloaded daemon thins its epochs)
    return {
        "receivers": n, "cores": cores,
        "ms_per_receiver_epoch": 1e3 * cores / (n * rate * max(delivered, 1e-9)),
        "worst_device_share": min(shares), "mean_share": delivered,
        "devices_without_epochs": sum(1 for x in shares if x == 0.0),
        "delay_median_ms": 1e3 * float(np.median(d)) if d.size else float("nan"),
        "delay_p99_ms": 1e3 * float(np.percentile(d, 99)) if d.size else float("nan"),
        "read_delay_p99_ms": (1e3 * float(np.percentile(d_read, 99)) if d_read.size
                              else float("nan")),
        "reader_cores": (r1 - r0) / (w1 - w0),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--receivers", default="1,10,100,1000")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--scene", default="none", help="'none' (open sky), 'default' (Magdeburg) "
                    "or a scene path")
    ap.add_argument("--config", help="a config file of profile overrides (e.g. every effect)")
    ap.add_argument("--poses", choices=("demo", "udp"), default="demo",
                    help="the scripted walk, or every receiver's pose sent over UDP")
    ap.add_argument("--workers", default="",
                    help="comma-separated --workers values to run each size with (default: "
                    "the daemon's default, the cores)")
    ap.add_argument("--readers", type=int, default=0,
                    help=f"reader processes (default: one per {READERS_EVERY:,} devices)")
    ap.add_argument("--json", help="also write every result to this JSON file")
    args = ap.parse_args()
    results = []
    for w in [int(x) for x in args.workers.split(",") if x] or [None]:
        for n in (int(x) for x in args.receivers.split(",")):
            r = bench(n, args.seconds, args.rate, args.scene, args.config, args.poses, w,
                      args.readers)
            r["workers"] = w
            results.append(r)
            print(f"{n:5d} receivers at {args.rate:g} Hz (scene {args.scene}, poses "
                  f"{args.poses}, workers {w or 'default'}): daemon {r['cores']:.2f} cores "
                  f"({r['ms_per_receiver_epoch']:.3f} ms per receiver-epoch delivered); "
                  f"devices got {100 * r['mean_share']:.1f} % of epochs (worst "
                  f"{100 * r['worst_device_share']:.1f} %, {r['devices_without_epochs']} none); "
                  f"first byte {r['delay_median_ms']:.1f} ms after the tag (p99 "
                  f"{r['delay_p99_ms']:.1f} ms; read by the reader p99 "
                  f"{r['read_delay_p99_ms']:.1f} ms); reader {r['reader_cores']:.2f} cores",
                  flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
