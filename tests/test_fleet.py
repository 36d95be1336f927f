"""A fleet of receivers in one daemon: who is in it, each receiver's bytes equal to the same
receiver run alone, devices that stall or reconnect while the others keep time, a flood of bad
and unknown-id pose messages, and SIGTERM removing every link."""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from virtualgps.device import nmea
from virtualgps.exceptions import ConfigError
from virtualgps.poses import posesource
from virtualgps.run import daemon, live, poseproviders
from virtualgps.run.config import BUNDLED_SCENES_DIR, load_scene_for, make_receiver, resolve
from virtualgps.run.fleet.members import fleet_members
from virtualgps.sky.ephemeris import load_tle

START = 1490712768.0  # 2017-03-28T14:52:48Z, the day of the bundled TLE set
START_ISO = "2017-03-28T14:52:48Z"


# --- who is in the fleet ------------------------------------------------------------------


def test_receivers_n_get_ids_seeds_and_links_from_the_pattern():
    ms = fleet_members(3, None, 10, "/tmp/gps{id}")
    assert [m.receiver_id for m in ms] == [0, 1, 2]
    assert [m.seed for m in ms] == [10, 11, 12]
    assert [m.link for m in ms] == ["/tmp/gps0", "/tmp/gps1", "/tmp/gps2"]
    one = fleet_members(None, None, 5, "./virtualgps{id}")
    assert [(m.receiver_id, m.seed, m.link) for m in one] == [(0, 5, "./virtualgps0")]


def test_fleet_file_sets_each_receiver(tmp_path):
    f = tmp_path / "fleet.toml"
    f.write_text(
        '[defaults]\nbaud = 115200\n\n[[receiver]]\n\n[[receiver]]\nid = 7\nprofile = "usarsim"'
        '\nseed = 42\nlink = "/tmp/rover"\nantenna_offset_m = [0.5, 0, 1.25]\n'
    )
    a, b = fleet_members(None, str(f), 3, "gps{id}")
    assert (a.receiver_id, a.seed, a.link, a.baud, a.profile) == (0, 3, "gps0", 115200, None)
    assert (b.receiver_id, b.seed, b.link, b.profile) == (7, 42, "/tmp/rover", "usarsim")
    assert b.antenna_offset_enu_m == (0.5, 0.0, 1.25) and b.baud == 115200


@pytest.mark.parametrize(
    "text, n, pattern, message",
    [
        ("[[receiver]]\nid = 1\n[[receiver]]\nid = 1\n", None, "g{id}", "id 1 appears twice"),
        ("[[receiver]]\nspeed = 3\n", None, "g{id}", "unknown key 'speed'"),
        ("[[receiver]]\nid = -2\n", None, "g{id}", "id must be an integer"),
        ("[[receiver]]\nseed = 1.5\n", None, "g{id}", "seed must be"),
        ("[[receiver]]\nantenna_offset_m = [1, 2]\n", None, "g{id}", "antenna_offset_m"),
        ("[[receiver]]\n[[receiver]]\n", 3, "g{id}", "--receivers 3 but"),
        ("[[receiver]]\n[[receiver]]\n", None, "gps", "put {id} in it"),
        ("[defaults]\nseed = 3\n[[receiver]]\n", None, "g{id}", "[defaults] may set"),
        ("title = 'x'\n", None, "g{id}", "unknown table or key 'title'"),
        ("", None, "g{id}", "no [[receiver]] entries"),
    ],
)
def test_fleet_file_errors_name_the_problem(tmp_path, text, n, pattern, message):
    f = tmp_path / "fleet.toml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        fleet_members(n, str(f), 0, pattern)


def test_receivers_count_is_checked():
    with pytest.raises(ConfigError, match="--receivers must be"):
        fleet_members(0, None, 0, "g{id}")


# --- the vectorised tick: a receiver of a fleet is the same receiver alone -----------------


class Sink:
    def __init__(self) -> None:
        self.data = bytearray()

    def write_epoch(self, data: bytes) -> None:
        self.data += data

    def read_available(self) -> bytes:
        return b""


def walk(rid: int) -> poseproviders.TrackProvider:
    """A different straight walk through the campus for each receiver, from START."""
    from virtualgps.poses.pose import PoseTrack

    t = START + np.arange(0.0, 60.0, 0.5)
    start = np.array([[-40.0 + 25.0 * rid, -30.0 + 10.0 * rid, 1.5]])
    xyz = start + np.outer(t - START, [1.2, 0.9 - 0.4 * rid, 0.0])
    track = PoseTrack(t, "enu", xyz, np.full_like(xyz, np.nan))
    return poseproviders.TrackProvider(track, START, 2.0)


@pytest.fixture(scope="module")
def campus():
    cfg = resolve({"rate": 10.0})
    scene, georef, _ = load_scene_for(cfg)
    eph = load_tle(BUNDLED_SCENES_DIR.parent / "ephemeris" / "gps-ops-2017-03-28.tle")
    return cfg, scene, georef, eph


class FlatOut(poseproviders.SimClock):
    """A clock for which every epoch is due at once: the loop runs flat out, never skipping."""

    def now_unix_s(self) -> float:
        return START

    def monotonic_at(self, t_unix_s: float) -> float:
        return 0.0


def run_members(campus, specs, n_epochs):
    """run_receivers over receivers given as (id, seed, profile overrides); their bytes."""
    cfg, scene, georef, eph = campus
    rxs, members = {}, []
    clock = FlatOut(START)
    for rid, seed, over in specs:
        key = json.dumps(over, sort_keys=True)
        if key not in rxs:  # receivers alike share one Receiver, as the CLI's fleet does
            from virtualgps.receiver.profiles import load_profile

            prof = load_profile(cfg.profile.name, over, flag_overrides={"rate_hz": 10.0})
            rxs[key] = make_receiver(replace(cfg, profile=prof), scene, georef, eph, START)
        rx = rxs[key]
        members.append(live.LiveReceiver(
            rx, Sink(), nmea.NmeaFormat.from_dict(rx.profile.nmea), clock,
            np.random.default_rng(seed), receiver_id=rid, t_first_unix_s=START))
    provider = poseproviders.ReceiverPoses({rid: walk(rid) for rid, _, _ in specs})
    daemon.run_receivers(members, provider, clock, threading.Event(), max_epochs=n_epochs)
    return {m.receiver_id: bytes(m.device.data) for m in members}


def test_each_receiver_of_a_fleet_emits_what_it_emits_alone(campus):
    # Every effect of holux-m1000 on (nlos with scattering, foliage, cold start...), plus a
    # receiver with another profile (simulated in a group of its own).
    other = {"correlated_error": {"enabled": False}, "nlos": {"scattering": False}}
    specs = [(0, 11, {}), (1, 12, {}), (2, 13, other), (5, 14, {})]
    fleet = run_members(campus, specs, 400)
    for spec in specs:
        alone = run_members(campus, [spec], 400)
        assert alone[spec[0]] == fleet[spec[0]], f"receiver {spec[0]} differs"
    # ... and the receivers are not all the same (different walks, seeds and profiles).
    assert len({fleet[r] for r, _, _ in specs}) == len(specs)
    for rid, _, _ in specs:  # 40 s from power-on: fixes (and no fix before the first)
        ggas = [ln for ln in fleet[rid].split(b"\r\n") if ln.startswith(b"$GPGGA")]
        assert len(ggas) == 400 and ggas[-1].split(b",")[6] == b"1"


def test_rows_give_the_bytes_of_one_receiver_simulated_epoch_by_epoch(campus):
    # The live loop simulates receivers as rows (ReceiverRows); one receiver's rows must be
    # what simulate() gives for its epochs one at a time (the code path of replay's batches).
    from virtualgps.receiver.core import simulate
    from virtualgps.receiver.state import initial_state

    cfg, scene, georef, eph = campus
    fleet = run_members(campus, [(3, 21, {}), (4, 22, {})], 300)
    from virtualgps.receiver.profiles import load_profile

    prof = load_profile(cfg.profile.name, {}, flag_overrides={"rate_hz": 10.0})
    rx = make_receiver(replace(cfg, profile=prof), scene, georef, eph, START)
    fmt = nmea.NmeaFormat.from_dict(prof.nmea)
    rng = np.random.default_rng(21)
    state = initial_state(prof, START, rng, len(eph.prn))
    out = bytearray(b"$PMTK010,001*2E\r\n")
    poses = walk(3)
    for k in range(300):
        t = np.array([START + k / 10.0])
        p, v, ok = poses.pose_at(t)
        fixes, state = simulate(rx, t, p, v, ok, state, rng)
        out += nmea.epoch_sentences(fixes, 0, fmt)
    assert bytes(out) == fleet[3]


def test_rows_drawn_ahead_give_back_what_a_row_taken_out_did_not_use():
    # A fleet's rows draw their uniforms several epochs at once; a row taken out between
    # (a restart, another batch) must leave its generators where epoch-by-epoch draws leave
    # them, and the rows must go on from where every generator then stands.
    from virtualgps.receiver.profiles import load_profile
    from virtualgps.receiver.state import (
        DRAW_AHEAD,
        ReceiverRows,
        ReceiverState,
        draw_layout,
        draw_plan,
        draw_uniforms,
        model_streams,
    )

    prof = load_profile("holux-m1000")
    layout = draw_layout(prof, 32)
    plan = draw_plan(tuple(layout.items()))
    assert len(plan) >= 3  # (several streams: the paper's, white, correlated, fading...)

    def gens(seed):
        rng = np.random.default_rng(seed)
        return rng, model_streams(rng)

    seeds = (1, 2, 3)
    live = [gens(s) for s in seeds]
    rows = ReceiverRows.stack([ReceiverState(streams=st) for _, st in live],
                              [r for r, _ in live], prof, 32)
    n = DRAW_AHEAD + 3  # (mid-way through the second draw ahead)
    got = np.array([rows.uniforms(plan) for _ in range(n + 1)])
    want = [draw_uniforms(*gens(s), layout, n + 4) for s in seeds]  # (epoch by epoch's)
    for i in range(len(seeds)):
        assert np.array_equal(got[:, i], want[i][:n + 1])
    rows.row_state(1, prof)  # row 1 out after n + 1 epochs: its next draws are epoch n + 2's
    assert np.array_equal(draw_uniforms(*live[1], layout, 1)[0], want[1][n + 1])
    rows.row_state(1, prof)  # (given back once only)
    nxt = rows.uniforms(plan)  # (the others give back theirs too, and all draw again)
    assert np.array_equal(nxt[0], want[0][n + 1]) and np.array_equal(nxt[2], want[2][n + 1])
    assert np.array_equal(nxt[1], want[1][n + 2])


class CommandSink(Sink):
    """A device whose client writes ``command`` once ``after`` epochs have been written."""

    def __init__(self, after: int, command: bytes) -> None:
        super().__init__()
        self.after, self.command = after, command

    def read_available(self) -> bytes:
        if self.command and self.data.count(b"$GPGGA") >= self.after:
            out, self.command = self.command, b""
            return out
        return b""


def test_a_restart_of_one_receiver_leaves_the_others_as_they_were(campus):
    # A cold start (PMTK103) on receiver 1 mid-run: it loses its fix for the start's TTFF,
    # while receivers 0 and 2, simulated in the same batch, emit what they emit alone.
    cfg, scene, georef, eph = campus
    rx = make_receiver(cfg, scene, georef, eph, START)
    fmt = nmea.NmeaFormat.from_dict(rx.profile.nmea)
    clock = FlatOut(START)
    cold = nmea.format_sentence("PMTK103").encode("ascii")

    def members(ids):
        return [live.LiveReceiver(
            rx, CommandSink(150, cold) if rid == 1 else Sink(), fmt, clock,
            np.random.default_rng(30 + rid), receiver_id=rid, t_first_unix_s=START)
            for rid in ids]

    provider = poseproviders.ReceiverPoses({rid: walk(rid) for rid in range(3)})
    fleet = members([0, 1, 2])
    daemon.run_receivers(fleet, provider, clock, threading.Event(), max_epochs=300)
    for rid in (0, 2):
        alone = members([rid])
        daemon.run_receivers(alone, provider, clock, threading.Event(), max_epochs=300)
        assert bytes(alone[0].device.data) == bytes(fleet[rid].device.data)
    quality = [ln.split(b",")[6] for ln in bytes(fleet[1].device.data).split(b"\r\n")
               if ln.startswith(b"$GPGGA")]
    assert quality[140:150] == [b"1"] * 10  # fixed before the command
    assert b"1" not in quality[152:200]  # no fix through the cold start's first seconds
    assert b"$PMTK010,001" in bytes(fleet[1].device.data)[40:]  # restarted: power-up again


# --- the pose source: ids, a flood of bad messages -------------------------------------------


def test_flood_of_bad_and_unknown_id_messages_is_counted_and_poses_still_arrive(campus):
    cfg, _, georef, _ = campus
    src = posesource.open_pose_source("udp://127.0.0.1:0")
    port = src.address[1]
    clock = poseproviders.SimClock(START)
    provider = poseproviders.LiveProvider(src, georef, clock, 2.0, receiver_ids=[0, 1, 2])
    bad = [b"{not json", b'{"x": 1}', b'{"id": 9, "x": 0, "y": 0, "z": 1}',
           b'{"id": "a", "x": 0, "y": 0, "z": 1}', b"\xff\xfe", b'{"id": -1, "x": 0}']
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
            for i in range(10_000):
                s.sendto(bad[i % len(bad)], ("127.0.0.1", port))
                if i % 100 == 0:
                    provider.pump()  # (keep the socket's buffer from overflowing)
                if i % 500 == 0:
                    for rid in (1, 2):
                        msg = {"id": rid, "t": time.time(), "x": float(rid), "y": 0.0, "z": 1.5}
                        s.sendto(json.dumps(msg).encode(), ("127.0.0.1", port))
            time.sleep(0.2)
        for _ in range(50):
            provider.pump()
        counted = sum(provider.bad.values()) + sum(provider.unknown_ids.values())
        assert counted == 10_000
        assert provider.unknown_ids == {9: len(range(2, 10_000, len(bad)))}
        assert set(provider.bad) == {"not-json", "no-position", "bad-id"}
        assert provider.n_good == 2 * 20 and len(provider.histories[0]) == 0
        pos, _, ok = provider.pose_at(np.array([provider.histories[2][-1][0]]), 2)
        assert ok[0] and pos[0, 0] == 2.0
    finally:
        provider.close()


class ListSource:
    """A pose source handing out a list of (message, arrival time) at its first poll."""

    def __init__(self, msgs):
        self.msgs = msgs

    def poll(self):
        m, self.msgs = self.msgs, []
        return m

    def fileno_list(self):
        return []

    def close(self):
        pass


def test_live_poses_of_many_receivers_at_once_are_each_receivers_own(campus):
    # LiveProvider.poses_at (all receivers at one epoch) against pose_at one by one: before the
    # first pose, between poses, after the last (own velocity, finite difference, one pose
    # held), and beyond the pose timeout.
    _, _, georef, _ = campus
    clock = poseproviders.SimClock(START)
    off = clock.offset_s
    msgs = []
    for rid in range(6):
        for k in range(1 if rid == 3 else 5):
            m = {"id": rid, "t": START - off + 0.3 * k - 0.25 * rid, "x": 1.5 * k + rid,
                 "y": -0.7 * k, "z": 1.5 + 0.01 * rid}
            if rid == 2:
                m.update(vx=0.4, vy=-0.1, vz=0.0)
            msgs.append((json.dumps(m).encode(), 0.0))
    lp = poseproviders.LiveProvider(ListSource(msgs), georef, clock, 1.0, receiver_ids=range(8))
    lp.pump()
    ids = list(range(8))  # (6 and 7 never sent a pose)
    n_valid = []
    for t in START + np.array([-2.0, 0.05, 0.7, 1.2, 1.31, 1.9, 2.5]):
        pos, vel, ok = lp.poses_at(float(t), ids)
        for b, rid in enumerate(ids):
            p1, v1, ok1 = lp.pose_at(np.array([t]), rid)
            np.testing.assert_array_equal(pos[b], p1[0])
            np.testing.assert_array_equal(vel[b], v1[0])
            assert ok[b] == ok1[0]
        n_valid.append(int(ok.sum()))
    assert n_valid[0] == 0 and n_valid[-1] == 0 and max(n_valid) == 6, n_valid


# --- the daemon as users run it ----------------------------------------------------------------


def start_fleet(tmp_path: Path, *args: str, n_lines: int) -> tuple[subprocess.Popen, list[str]]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "virtualgps", "run", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    lines = [proc.stdout.readline() for _ in range(n_lines)]
    if not all(ln.startswith("device: ") for ln in lines):
        proc.kill()
        raise AssertionError(f"device lines {lines!r}; stderr: {proc.communicate()[1]}")
    return proc, [ln.split()[3] for ln in lines]


def stop(proc: subprocess.Popen) -> tuple[int, str]:
    proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return proc.returncode, err


class Reader(threading.Thread):
    """Reads a device as it comes, noting when each GGA line arrived."""

    def __init__(self, path: Path) -> None:
        super().__init__(daemon=True)
        self.fd = os.open(path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        self.data = bytearray()
        self.arrivals: list[tuple[float, bytes]] = []
        self.alive = True

    def run(self) -> None:
        while self.alive:
            r, _, _ = select.select([self.fd], [], [], 0.05)
            if not r:
                continue
            try:
                chunk = os.read(self.fd, 65536)
            except OSError:
                break
            now = time.time()
            start = len(self.data)
            self.data += chunk
            i = self.data.find(b"$GPGGA", max(0, start - 6))
            while i >= 0:
                self.arrivals.append((now, bytes(self.data[i + 7:i + 17])))
                i = self.data.find(b"$GPGGA", i + 1)

    def close(self) -> bytes:
        self.alive = False
        self.join(5)
        os.close(self.fd)
        return bytes(self.data)


def epochs_by_time(data: bytes) -> dict[bytes, bytes]:
    """Each epoch's bytes (GGA to the next GGA), keyed by its GGA time field."""
    parts = data.split(b"$GPGGA,")[1:]
    whole = parts[:-1]  # (the last may be cut off)
    return {p[:10]: b"$GPGGA," + p for p in whole}


@pytest.mark.e2e
def test_fleet_devices_match_single_runs_and_sigterm_removes_links(tmp_path):
    # Three receivers walking apart (one JSONL log with ids), receiver 2 with a profile and a
    # seed of its own from the fleet file; each compared with the same receiver run alone.
    rows = []
    for rid in range(3):
        for k in range(0, 200):
            t = START + 0.25 * k
            rows.append({"id": rid, "t": t, "x": -30.0 + 20 * rid + 0.3 * k, "y": 5.0 * rid,
                         "z": 1.5})
    rows.sort(key=lambda r: (r["t"], r["id"]))
    log = tmp_path / "fleet.jsonl"
    log.write_text("".join(json.dumps(r) + "\n" for r in rows))
    fleet_file = tmp_path / "fleet.toml"
    fleet_file.write_text('[[receiver]]\n[[receiver]]\n[[receiver]]\nprofile = "usarsim"\n'
                          "seed = 99\n")
    common = ["--start-time", START_ISO, "--rate", "10", "--seed", "4"]
    # (over two worker processes: a receiver's bytes do not depend on its share)
    proc, links = start_fleet(tmp_path, "--fleet", str(fleet_file), "--poses", str(log),
                              "--link", str(tmp_path / "gps{id}"), "--workers", "2", *common,
                              n_lines=3)
    try:
        readers = [Reader(Path(ln)) for ln in links]
        for r in readers:
            r.start()
        time.sleep(4.0)
    finally:
        code, err = stop(proc)
    fleet_out = [r.close() for r in readers]
    assert code == 0, err
    assert not any(Path(ln).is_symlink() or Path(ln).exists() for ln in links), "links left"

    for rid, (seed, extra) in enumerate([(4, []), (5, []), (99, ["--profile", "usarsim"])]):
        own = tmp_path / f"alone{rid}.jsonl"
        own.write_text("".join(json.dumps({k: v for k, v in r.items() if k != "id"}) + "\n"
                               for r in rows if r["id"] == rid))
        args = [*common[:-1], str(seed), *extra]
        p, (link,) = start_fleet(tmp_path, "--poses", str(own), "--link",
                                 str(tmp_path / f"alone{rid}"), *args, n_lines=1)
        try:
            reader = Reader(Path(link))
            reader.start()
            time.sleep(3.0)
        finally:
            stop(p)
        alone = epochs_by_time(reader.close())
        mine = epochs_by_time(fleet_out[rid])
        common_t = sorted(set(alone) & set(mine))
        assert len(common_t) >= 20, (rid, len(alone), len(mine))
        assert min(alone) in mine  # from the first epoch on
        for t in common_t:
            assert mine[t] == alone[t], f"receiver {rid} differs at {t!r}"
    assert epochs_by_time(fleet_out[0]) != epochs_by_time(fleet_out[1])


@pytest.mark.e2e
def test_stalled_and_reconnecting_devices_do_not_delay_the_others(tmp_path):
    proc, links = start_fleet(tmp_path, "--receivers", "4", "--poses", "demo", "--rate", "10",
                              "--baud", "115200", "--link", str(tmp_path / "gps{id}"),
                              "--scene", "none", n_lines=4)
    try:
        steady = Reader(Path(links[0]))
        steady.start()
        stalled = os.open(links[1], os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)  # never read
        t_end = time.monotonic() + 6.0
        reconnects = 0
        while time.monotonic() < t_end:  # device 2: open, read a little, close, again
            r = Reader(Path(links[2]))
            r.start()
            time.sleep(0.4)
            r.close()
            reconnects += 1
            time.sleep(0.2)
        got = steady.close()
        os.close(stalled)
        alive = proc.poll() is None
    finally:
        code, err = stop(proc)
    assert alive and code == 0, err
    assert reconnects >= 5
    # Device 0 got every epoch, each within 50 ms of its time tag's second... of wall time:
    # the tags are the simulated clock (here the wall clock) at the epoch.
    ts = sorted({float(t[:2]) * 3600 + float(t[2:4]) * 60 + float(t[4:])
                 for t in epochs_by_time(got)})
    assert len(ts) >= 55
    np.testing.assert_allclose(np.diff(ts), 0.1, atol=1e-6)  # none missing
    lag = [(now % 86400.0) - (float(t[:2]) * 3600 + float(t[2:4]) * 60 + float(t[4:]))
           for now, t in steady.arrivals]
    lag = np.array(lag[1:])  # (the first: queued before the reader came)
    assert np.percentile(lag, 99) < 0.05, np.percentile(lag, [50, 99, 100])


@pytest.mark.e2e
def test_a_command_on_one_device_changes_that_receiver_alone(tmp_path):
    # Each receiver has its own MTK command link: GSV switched off on device 1 (PMTK314) and
    # its fix interval set to 1 s (PMTK220) leave device 0 at 5 Hz with GSV; only device 1
    # answers.
    proc, links = start_fleet(tmp_path, "--receivers", "2", "--poses", "demo", "--rate", "5",
                              "--scene", "none", "--link", str(tmp_path / "gps{id}"), n_lines=2)
    try:
        quiet = Reader(Path(links[0]))
        quiet.start()
        fd = os.open(links[1], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        talker = Reader(Path(links[1]))
        talker.start()
        time.sleep(1.0)
        os.write(fd, nmea.format_sentence("PMTK314," + ",".join(
            ["0", "1", "1", "1", "1", "0"] + ["0"] * 13)).encode("ascii"))
        os.write(fd, nmea.format_sentence("PMTK220,1000").encode("ascii"))  # 5 Hz -> 1 Hz
        time.sleep(2.5)
        mark0, mark1 = len(quiet.data), len(talker.data)
        time.sleep(2.0)
        dev0, dev1 = quiet.close(), talker.close()
        os.close(fd)
    finally:
        code, err = stop(proc)
    assert code == 0, err
    assert b"$PMTK001,314,3*36" in dev1 and b"$PMTK001,220,3" in dev1
    assert b"$PMTK001" not in dev0
    assert b"$GPGSV" not in dev1[mark1:] and 1 <= dev1[mark1:].count(b"$GPGGA") <= 3
    assert dev0[mark0:].count(b"$GPGSV") >= 8 and dev0[mark0:].count(b"$GPGGA") >= 8


@pytest.mark.e2e
def test_an_idle_daemon_answers_at_once_and_stops_without_waiting_for_its_epoch(tmp_path):
    # At 1 Hz the loop sleeps until its next epoch (not in 0.1 s naps): a client's command and
    # SIGTERM must still end that sleep at once, not at the next epoch up to 1 s later.
    proc, links = start_fleet(tmp_path, "--poses", "demo", "--rate", "1", "--scene", "none",
                              "--link", str(tmp_path / "gps{id}"), n_lines=1)
    try:
        fd = os.open(links[0], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        reader = Reader(Path(links[0]))
        reader.start()
        delays = []
        for k in range(5):  # at different phases of the second
            time.sleep(0.27 + 0.11 * k)
            mark, t0 = len(reader.data), time.monotonic()
            os.write(fd, nmea.format_sentence("PMTK000").encode("ascii"))
            while b"$PMTK001,0,3" not in reader.data[mark:] and time.monotonic() - t0 < 3.0:
                time.sleep(0.002)
            delays.append(time.monotonic() - t0)
        time.sleep(0.3)  # mid-period
        t0 = time.monotonic()
        code, err = stop(proc)
        stop_s = time.monotonic() - t0
        reader.close()
        os.close(fd)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert code == 0, err
    assert max(delays) < 0.25, delays
    assert stop_s < 0.5, stop_s


@pytest.mark.e2e
def test_serial_port_runs_one_receiver_and_a_fleet_gets_ptys(tmp_path):
    run = [sys.executable, "-m", "virtualgps", "run", "--serial", "loop://", "--poses", "demo",
           "--scene", "none", "--duration", "2"]
    one = subprocess.run(run, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert one.returncode == 0, one.stderr
    assert one.stdout.splitlines()[0] == "device: loop://"
    assert "stopped after 2 epochs" in one.stderr  # (the epochs of 2 s from the first)
    two = subprocess.run([*run, "--receivers", "2"], capture_output=True, text=True, timeout=60,
                         cwd=tmp_path)
    assert two.returncode == 2 and two.stderr.strip().endswith(
        "--serial drives one receiver; a fleet gets ptys (--link PATTERN)")
