"""A fleet at scale: spread over worker processes with each receiver's bytes unchanged, split
across hosts by id, thinned evenly (never collapsing) past what the machine computes, live
poses forwarded to the worker of their receiver, and the system's limits named in one line."""

from __future__ import annotations

import json
import os
import resource
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_fleet import START_ISO, ListSource, Reader, epochs_by_time, start_fleet, stop

from virtualgps.exceptions import ConfigError
from virtualgps.poses.pose import MAX_RECEIVER_ID
from virtualgps.run.fleet import limits
from virtualgps.run.fleet.members import fleet_members, parse_ids, select_ids
from virtualgps.run.fleet.workers import shares

# --- pure parts -----------------------------------------------------------------------------


def test_shares_are_contiguous_and_even():
    members = fleet_members(10, None, 0, "gps{id}")
    parts = shares(members, 3)
    assert [len(p) for p in parts] == [3, 4, 3]
    assert [m for p in parts for m in p] == members
    assert len(shares(members[:2], 4)) == 2  # (never an empty worker)


def test_default_workers_one_per_core_and_per_500_receivers(monkeypatch):
    from virtualgps.run.fleet import workers

    monkeypatch.setattr(workers.os, "sched_getaffinity", lambda _: set(range(16)))
    assert [workers.default_workers(n) for n in (1, 10, 500, 501, 1200, 10_000)] == [
        1, 1, 1, 2, 3, 16]
    monkeypatch.setattr(workers.os, "sched_getaffinity", lambda _: {0, 1})
    assert workers.default_workers(10_000) == 2


def test_ids_select_this_hosts_share():
    members = fleet_members(10, None, 0, "gps{id}")
    assert [m.receiver_id for m in select_ids(members, parse_ids("3-5"))] == [3, 4, 5]
    assert [m.receiver_id for m in select_ids(members, parse_ids("7"))] == [7]
    for bad in ("5-3", "a-b", "-1", "1-2-3", ""):
        with pytest.raises(ConfigError, match="--ids"):
            parse_ids(bad)
    with pytest.raises(ConfigError, match="selects none"):
        select_ids(members, (20, 30))


def test_no_fixed_cap_on_the_count():
    assert len(fleet_members(10_000, None, 0, "gps{id}")) == 10_000
    with pytest.raises(ConfigError, match="--receivers"):
        fleet_members(0, None, 0, "gps{id}")


def _run_cli(*args: str, limit_nofile: tuple[int, int] | None = None, timeout: float = 120):
    def pre() -> None:
        if limit_nofile is not None:
            resource.setrlimit(resource.RLIMIT_NOFILE, limit_nofile)

    return subprocess.run([sys.executable, "-m", "virtualgps", "run", *args],
                          capture_output=True, text=True, timeout=timeout, preexec_fn=pre)


def test_past_the_systems_ptys_is_one_line_naming_the_limit(tmp_path):
    got = limits.ptys_free()
    if got is None:
        pytest.skip("no /proc/sys/kernel/pty here")
    n = got[0] - got[1] + 1
    if n > MAX_RECEIVER_ID + 1:
        pytest.skip(f"the system allows more ptys ({got[0]}) than a fleet has receiver ids")
    res = _run_cli("--receivers", str(n), "--poses", "demo", "--scene", "none",
                   "--link", str(tmp_path / "gps{id}"))
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert "pseudo-terminals" in lines[-1] and "kernel.pty.max" in lines[-1], lines
    assert "Traceback" not in res.stderr
    assert not list(tmp_path.iterdir())  # (stopped before making any)


def test_open_file_limit_is_raised_within_the_hard_limit_and_named_past_it(tmp_path):
    args = ["--receivers", "300", "--workers", "1", "--poses", "demo", "--scene", "none",
            "--link", str(tmp_path / "gps{id}"), "--duration", "1"]
    # Soft 128, hard 4096: raised to what 300 devices need, and the run works.
    res = _run_cli(*args, limit_nofile=(128, 4096))
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.count("device: ") == 300
    # Hard 200: one line naming the limit and how to raise it, no device made.
    res = _run_cli(*args, limit_nofile=(128, 200))
    assert res.returncode == 2
    last = res.stderr.strip().splitlines()[-1]
    assert "open files" in last and "ulimit -Hn" in last and "--workers" in last, last
    assert not list(tmp_path.iterdir())


# --- the daemon as users run it ---------------------------------------------------------------


class ManyReader(threading.Thread):
    """Reads many devices through one epoll, noting (arrival wall time, GGA time tag) of each
    epoch's GGA on each device."""

    def __init__(self, paths: list[str]) -> None:
        super().__init__(daemon=True)
        self.ep = select.epoll()
        self.fds = {}
        for i, p in enumerate(paths):
            fd = os.open(p, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
            self.fds[fd] = i
            self.ep.register(fd, select.EPOLLIN)
        self.tail = [b""] * len(paths)
        self.got: list[list[tuple[float, float]]] = [[] for _ in paths]
        self.alive = True

    def run(self) -> None:
        while self.alive:
            for fd, _ in self.ep.poll(0.05):
                try:
                    chunk = os.read(fd, 65536)
                except OSError:
                    continue
                now = time.time()
                i = self.fds[fd]
                buf = self.tail[i] + chunk
                k = buf.find(b"$GPGGA,")
                while k >= 0 and len(buf) >= k + 17:
                    if k >= len(self.tail[i]):
                        f = buf[k + 7:k + 17].decode()
                        tag = int(f[:2]) * 3600 + int(f[2:4]) * 60 + float(f[4:])
                        self.got[i].append((now, tag))
                    k = buf.find(b"$GPGGA,", k + 1)
                self.tail[i] = buf[-32:]

    def close(self) -> None:
        self.alive = False
        self.join(5)
        for fd in self.fds:
            os.close(fd)
        self.ep.close()


@pytest.mark.e2e
def test_a_fleet_past_its_capacity_thins_evenly_and_keeps_every_device_fresh(tmp_path):
    # One process, 3,500 receivers at 10 Hz in the campus scene: about 2.5 times what one
    # core computes here (2,500 got 57 % of their epochs, 2026-11-27), so past capacity on a
    # machine twice as fast too, and below Linux's default 4,096 ptys. Before, such a fleet
    # delivered nothing (the loop never reached its devices' writers); now every device keeps
    # getting fresh epochs, the load spread evenly, and the run says so once.
    n = 3500
    proc, links = start_fleet(tmp_path, "--receivers", str(n), "--workers", "1", "--poses",
                              "demo", "--rate", "10", "--baud", "115200", "--link",
                              str(tmp_path / "gps{id}"), n_lines=n)
    try:
        time.sleep(3.0)
        reader = ManyReader(links)
        reader.start()
        time.sleep(10.0)
        t_end = time.time()
        reader.close()
        alive = proc.poll() is None
        # A client's command is still answered at once under the load.
        fd = os.open(links[7], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        os.write(fd, b"$PMTK000*32\r\n")
        t0, reply = time.monotonic(), b""
        while b"$PMTK001,0,3" not in reply and time.monotonic() - t0 < 2.0:
            select.select([fd], [], [], 0.05)
            try:
                reply += os.read(fd, 65536)
            except BlockingIOError:
                pass
        answer_s = time.monotonic() - t0
        os.close(fd)
    finally:
        code, err = stop(proc)
    assert alive and code == 0, err[-3000:]
    assert b"$PMTK001,0,3" in reply and answer_s < 0.5, (answer_s, reply[-200:])
    window = (t_end - 8.0, t_end)  # (the reader's first seconds: queued before it came)
    counts, lags = [], []
    for arrivals in reader.got:
        fresh = [(a, t) for a, t in arrivals if window[0] <= a <= window[1]]
        counts.append(len(fresh))
        lags += [(a % 86400.0) - t for a, t in fresh]
    counts = np.array(counts)
    asked = 8.0 * 10
    assert counts.min() >= 1, f"{(counts == 0).sum()} devices got no epoch in 8 s"
    assert counts.mean() < 0.9 * asked, "not past capacity: the test proves nothing"
    # Thinned evenly: no device gets much less than the others.
    assert counts.min() >= 0.75 * np.median(counts), (counts.min(), np.median(counts))
    lags = np.array(lags)
    assert np.percentile(lags, 99) < 0.5, np.percentile(lags, [50, 99])  # fresh, not aged
    assert err.count("are thinned evenly") == 1, err[-3000:]
    assert "thinned out to keep up" in err.strip().splitlines()[-1]


def _record(tmp_path: Path, args: list[str], n: int, seconds: float = 5.0):
    """Run ``virtualgps run ARGS`` with ``n`` devices, read each for ``seconds``, stop it:
    (links, each device's bytes, stderr)."""
    proc, links = start_fleet(tmp_path, *args, n_lines=n)
    try:
        readers = [Reader(Path(ln)) for ln in links]
        for r in readers:
            r.start()
        time.sleep(seconds)
    finally:
        code, err = stop(proc)
    assert code == 0, err
    return links, [r.close() for r in readers], err


@pytest.mark.e2e
def test_split_across_hosts_by_id_gives_each_receiver_its_bytes(tmp_path):
    # The same fleet of 6 on the demo walk, whole, and as host B's share (--ids 3-5): the
    # receivers of the share are those of the whole fleet, byte for byte.
    common = ["--receivers", "6", "--poses", "demo", "--rate", "5", "--start-time", START_ISO,
              "--scene", "none", "--workers", "2"]
    _, whole_out, _ = _record(tmp_path, [*common, "--link", str(tmp_path / "all{id}")], 6)
    links, part, err = _record(tmp_path, [*common, "--ids", "3-5", "--link",
                                          str(tmp_path / "b{id}")], 3)
    assert [Path(ln).name for ln in links] == ["b3", "b4", "b5"]
    assert "this process's share of 6" in err
    for rid, data in zip((3, 4, 5), part, strict=True):
        mine, theirs = epochs_by_time(data), epochs_by_time(whole_out[rid])
        common_t = sorted(set(mine) & set(theirs))
        assert len(common_t) >= 10, (rid, len(mine), len(theirs))
        for t in common_t:
            assert mine[t] == theirs[t], f"receiver {rid} differs at {t!r}"


@pytest.mark.e2e
def test_live_poses_reach_the_worker_of_their_receiver(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc, links = start_fleet(tmp_path, "--receivers", "4", "--workers", "2", "--poses",
                              f"udp://127.0.0.1:{port}", "--rate", "5", "--link",
                              str(tmp_path / "gps{id}"), "--scene", "none", "--origin",
                              "52.14,11.64,60", n_lines=4)
    readers = [Reader(Path(ln)) for ln in links]
    try:
        for r in readers:
            r.start()
        out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        t_end = time.time() + 6.0
        while time.time() < t_end:
            now = time.time()
            for rid in range(4):  # each robot 1 km further north
                msg = {"id": rid, "t": now, "x": 0.0, "y": 1000.0 * rid, "z": 1.5}
                out.sendto(json.dumps(msg).encode(), ("127.0.0.1", port))
            out.sendto(b"{not json", ("127.0.0.1", port))
            out.sendto(json.dumps({"id": 9, "t": now, "x": 0, "y": 0, "z": 0}).encode(),
                       ("127.0.0.1", port))
            time.sleep(0.1)
        out.close()
    finally:
        code, err = stop(proc)
    assert code == 0, err
    lats = []
    for r in readers:
        ggas = [ln.split(b",") for ln in r.close().split(b"\r\n") if ln.startswith(b"$GPGGA")]
        fixed = [g for g in ggas if len(g) > 6 and g[6] != b"0"]
        assert len(fixed) >= 10, len(fixed)
        lat = [int(g[2][:2]) + float(g[2][2:]) / 60.0 for g in fixed[-5:]]
        lats.append(np.median(lat))
    # Each device is at its own robot: ~1 km (0.009°) apart, in id order.
    np.testing.assert_allclose(np.diff(lats), 1000.0 / 111_250.0, rtol=0.02)
    last = err.strip().splitlines()[-1]
    assert "malformed pose messages" in last and "unknown receivers" in last, last


@pytest.mark.e2e
def test_a_killed_worker_stops_the_run_with_one_line_and_no_links_left(tmp_path):
    proc, links = start_fleet(tmp_path, "--receivers", "4", "--workers", "2", "--poses",
                              "demo", "--scene", "none", "--link", str(tmp_path / "gps{id}"),
                              n_lines=4)
    time.sleep(1.0)
    kids = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True)
    workers = [int(x) for x in kids.stdout.split()  # (not multiprocessing's resource tracker)
               if b"spawn_main" in Path(f"/proc/{x}/cmdline").read_bytes()]
    assert len(workers) == 2, kids
    os.kill(workers[0], signal.SIGKILL)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    assert proc.returncode == 2, err
    assert "worker process" in err.strip().splitlines()[-1], err[-2000:]
    assert not any(os.path.lexists(ln) for ln in links), "links left"


def test_poses_of_other_hosts_receivers_are_skipped_not_unknown():
    from virtualgps.run import poseproviders
    from virtualgps.run.config import Georef

    msgs = [(json.dumps({"id": rid, "t": 100.0 + k, "x": 1.0, "y": 2.0, "z": 0.0}).encode(),
             0.0) for k in range(3) for rid in (3, 4, 7, 9)]
    lp = poseproviders.LiveProvider(ListSource(msgs), Georef(52.0, 11.0, 50.0),
                                    poseproviders.SimClock(), 2.0, receiver_ids=[3, 4],
                                    elsewhere_ids=[0, 1, 2, 5, 6, 7])
    lp.pump()
    assert lp.n_good == 6 and lp.elsewhere == 3 and dict(lp.unknown_ids) == {9: 3}


@pytest.mark.e2e
def test_a_fleets_status_line_adds_up_its_workers(tmp_path):
    # On a terminal the fleet's one status line, once a second, counts every worker's
    # receivers and epochs.
    import pty

    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "virtualgps", "run", "--receivers", "4", "--workers", "2",
         "--poses", "demo", "--scene", "none", "--rate", "5", "--duration", "4", "--link",
         str(tmp_path / "gps{id}")], stdout=slave, stderr=subprocess.PIPE, text=True)
    os.close(slave)
    out = bytearray()
    while True:
        r, _, _ = select.select([master], [], [], 15)
        if not r:
            break
        try:
            chunk = os.read(master, 65536)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    proc.wait(30)
    os.close(master)
    err = proc.stderr.read()
    assert proc.returncode == 0, err
    # each worker counts --duration from its receivers' first epoch: 4 s at 5 Hz, each
    assert "stopped after 80 epochs" in err, err[-500:]
    lines = [ln for ln in out.decode().replace("\r", "\n").split("\n") if "receivers, " in ln]
    assert lines, out[-500:]
    last = lines[-1]
    assert "4 receivers, 4 with a fix" in last, last
    epochs = int(last.split("with a fix")[1].split()[0])
    assert 4 * 5 * 2 <= epochs <= 4 * 5 * 4, last
