"""The live loop in-process: epochs on whole multiples of the period, no fix before the first pose
and after the pose timeout, malformed messages counted and skipped, the demo loop."""

from __future__ import annotations

import io
import json
import os
import select
import threading
from dataclasses import replace

import numpy as np
import pytest

from virtualgps.device import nmea
from virtualgps.receiver.definition import Georef
from virtualgps.receiver.profiles import load_profile
from virtualgps.run import daemon, live, poseproviders
from virtualgps.run.config import BUNDLED_SCENES_DIR, make_receiver, resolve
from virtualgps.sky.ephemeris import load_tle
from virtualgps.sky.scene import load_scene

START = 1490712768.0  # 2017-03-28T14:52:48Z


class FakeSource:
    """Pose messages handed out at chosen simulated times (a stand-in for UDP)."""

    def __init__(self, clock: poseproviders.SimClock, schedule: list[tuple[float, bytes]]) -> None:
        self.clock, self.schedule = clock, sorted(schedule)

    def fileno_list(self) -> list[int]:
        return []

    def poll(self):
        now = self.clock.now_unix_s()
        ready = [(m, now - self.clock.offset_s) for t, m in self.schedule if t <= now]
        self.schedule = [(t, m) for t, m in self.schedule if t > now]
        return ready

    def close(self) -> None:
        pass


class Sink:
    def __init__(self) -> None:
        self.epochs: list[bytes] = []

    def write_epoch(self, data: bytes) -> None:
        self.epochs.append(data)

    def read_available(self) -> bytes:
        return b""


@pytest.fixture(scope="module")
def receiver():
    cfg = resolve({"rate": 10.0, "scene": "none"})
    # The loop's pose rules are under test: a receiver with a fix as soon as a pose is there
    # (no start-up, no acquisition delay).
    quick = {"cold_start": {"enabled": False}, "cn0_tracking": {"enabled": False}}
    prof = load_profile(cfg.profile.name, quick, flag_overrides={"rate_hz": 10.0})
    cfg = replace(cfg, profile=prof)
    eph = load_tle(BUNDLED_SCENES_DIR.parent / "ephemeris" / "gps-ops-2017-03-28.tle")
    return cfg, make_receiver(cfg, None, Georef(52.14, 11.64, 100.0), eph, START)


def test_live_loop_fix_rules_and_epoch_times(receiver):
    cfg, rx = receiver
    clock = poseproviders.SimClock(START)
    t0 = clock.now_unix_s()
    good = json.dumps({"x": 0.0, "y": 0.0, "z": 1.5}).encode()  # t absent: arrival time
    schedule = [(t0 + 0.5, good), (t0 + 0.55, b"{not json"), (t0 + 0.6, b'{"x": 1}'),
                (t0 + 0.7, good)]
    provider = poseproviders.LiveProvider(FakeSource(clock, schedule), rx.georef, clock,
                                   cfg.profile.pose_timeout_s)
    sink = Sink()
    fixes_seen: list[tuple[float, int]] = []
    stop = threading.Event()
    stats = daemon.run_daemon(
        rx, provider, sink, nmea.NmeaFormat.from_dict(cfg.profile.nmea), clock,
        np.random.default_rng(0), stop,
        on_epoch=lambda f, s: fixes_seen.append((float(f.t_unix_s[0]), int(f.quality[0]))),
        max_epochs=35,
    )
    t = np.array([t for t, _ in fixes_seen])
    q = np.array([q for _, q in fixes_seen])
    np.testing.assert_allclose(t * 10, np.round(t * 10), atol=1e-6)  # multiples of 0.1 s
    np.testing.assert_allclose(np.diff(t), 0.1, atol=1e-6)
    age = t - (t0 + 0.7)  # the last pose
    assert (q[t < t0 + 0.5] == 0).all()  # no pose yet
    assert (q[(age > 0.05) & (age < 2.0 - 0.05)] == 1).all()  # held within the 2 s timeout
    assert (q[age > 2.0 + 0.05] == 0).all()  # older than the timeout: no fix
    assert dict(provider.bad) == {"not-json": 1, "no-position": 1}
    # holux-m1000 speaks MTK: its power-up message comes before the first epoch.
    assert sink.epochs[0] == b"$PMTK010,001*2E\r\n"
    assert stats.epochs == 35 and len(sink.epochs) == 36
    assert all(e.startswith(b"$GPGGA") and e.endswith(b"\r\n") for e in sink.epochs[1:])


def test_a_line_too_slow_for_the_epochs_is_warned_of_once(monkeypatch, caplog):
    monkeypatch.setattr(live, "_LINE_WARNED", set())
    sizes = [400] * 10  # 400 bytes at 10 Hz: 40,000 bits a second, 8N1
    with caplog.at_level("WARNING", logger="virtualgps.run.live"):
        assert live.warn_if_line_too_slow(sizes, 10.0, 38400)
        assert live.warn_if_line_too_slow(sizes, 10.0, 38400)  # too slow, but said already
        assert not live.warn_if_line_too_slow(sizes, 10.0, 57600)
        assert not live.warn_if_line_too_slow(sizes, 1.0, 9600)
        assert not live.warn_if_line_too_slow(sizes, 10.0, None)  # a file: no line
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1
    assert "needs 40000 baud" in warnings[0] and "carries 96 %" in warnings[0]


@pytest.mark.parametrize(("baud", "warned"), [(9600, True), (115200, False)])
def test_the_live_loop_warns_when_its_line_cannot_carry_the_rate(receiver, monkeypatch, caplog,
                                                                 baud, warned):
    cfg, rx = receiver  # 10 Hz
    monkeypatch.setattr(live, "_LINE_WARNED", set())
    clock = poseproviders.SimClock(START)
    good = json.dumps({"x": 0.0, "y": 0.0, "z": 1.5}).encode()
    provider = poseproviders.LiveProvider(FakeSource(clock, [(clock.now_unix_s(), good)]),
                                          rx.georef, clock, cfg.profile.pose_timeout_s)
    sink = Sink()
    sink.baud = baud
    with caplog.at_level("WARNING", logger="virtualgps.run.live"):
        daemon.run_daemon(rx, provider, sink, nmea.NmeaFormat.from_dict(cfg.profile.nmea),
                          clock, np.random.default_rng(0), threading.Event(), max_epochs=12)
    sizes = [len(e) for e in sink.epochs[1:]]
    assert min(sizes) * 10 * 10 > 9600 and max(sizes) * 10 * 10 < 115200
    assert any("baud" in r.getMessage() for r in caplog.records) is warned


def test_a_fix_interval_the_new_baud_cannot_carry_is_refused(receiver):
    """$PMTK251 to 9600 baud, then (in a later read) $PMTK220 for 100 ms epochs of ~400
    bytes: MTK firmware refuses the interval the line cannot carry (PMTK001,220,2); the line
    check that follows the baud change must not make the link forget the epochs' size."""
    from virtualgps.device import mtk

    cfg, rx = receiver
    clock = poseproviders.SimClock(START)
    sink = Sink()
    client = [nmea.format_sentence(c).encode() for c in ("PMTK251,9600", "PMTK220,100")]
    sink.read_available = lambda: client.pop(0) if client else b""
    member = live.LiveReceiver(rx, sink, nmea.NmeaFormat.from_dict(cfg.profile.nmea), clock,
                                 np.random.default_rng(0))
    lap = poseproviders.demo_lap(np.array([[0, 0, 1.5], [40, 0, 1.5]]), 1.4)
    walk = poseproviders.LoopProvider(lap, START, 2.0)
    for _ in range(3):
        (group, fixes, data), = daemon.tick([member], walk)
        member.sent(data[0], bool(fixes.quality[0] > 0))
    assert min(len(e) for e in sink.epochs[1:]) > 96  # 100 ms at 9600 baud
    member.service_client()
    member.service_client()
    assert sink.epochs[-2:] == [mtk.ack(251, 3).encode(), mtk.ack(220, 2).encode()]


def test_demo_lap_walks_the_loop_at_the_set_speed():
    scene = load_scene(BUNDLED_SCENES_DIR / "magdeburg-campus")
    lap = poseproviders.demo_lap(scene.demo_waypoints_enu_m, 1.4)
    walk = poseproviders.LoopProvider(lap, START, 2.0)
    t = START + np.arange(0.0, 3 * walk.lap_s, 7.3)
    pos, vel, ok = walk.pose_at(t)
    assert ok.all()
    np.testing.assert_allclose(np.linalg.norm(vel, axis=1), 1.4, rtol=1e-9)
    # Periodic, and starts at the first waypoint.
    p2, _, _ = walk.pose_at(t + walk.lap_s)
    np.testing.assert_allclose(p2, pos, atol=1e-6)
    p0, _, _ = walk.pose_at(np.array([START]))
    np.testing.assert_allclose(p0[0], scene.demo_waypoints_enu_m[0], atol=1e-9)


def test_link_settings_switch_the_sbas_and_static_hold_effects(receiver):
    from dataclasses import replace

    from virtualgps.device import mtk

    _, rx = receiver
    on = replace(mtk.default_settings(("GGA",), {}, 1.0, 38400), dgps_mode=2, sbas_enabled=True,
                 static_nav_mps=0.8)
    rx2 = live.apply_link_settings(rx, on)
    assert rx2.profile.sbas.enabled and rx2.profile.static_hold.enabled
    assert rx2.profile.static_hold.threshold_mps == 0.8
    assert rx2.ephemeris is rx.ephemeris and rx2.georef == rx.georef
    off = replace(on, sbas_enabled=False, static_nav_mps=0.0)
    rx3 = live.apply_link_settings(rx2, off)
    assert not rx3.profile.sbas.enabled and not rx3.profile.static_hold.enabled
    assert live.apply_link_settings(rx3, off) is rx3  # nothing to change


def test_a_u_blox_clients_masks_become_the_receivers():
    """CFG-NAV5 polled at power-on shows the profile's masks (ublox-m9n: pDop 25.0 and minElev
    5, the module's defaults); a client's CFG-VALSET of CFG-NAVSPG-OUTFIL_PDOP (the M9 way)
    and its CFG-NAV5 (the M8 way, which M9 firmware still takes) each become the receiver's
    ``sky.pdop_mask`` and ``sky.elevation_mask_deg``; what the client leaves alone stays."""
    pyubx2 = pytest.importorskip("pyubx2")
    cfg = resolve({"profile": "ublox-m9n", "scene": "none"})
    eph = load_tle(BUNDLED_SCENES_DIR.parent / "ephemeris" / "gps-ops-2017-03-28.tle")
    rx = make_receiver(cfg, None, Georef(52.14, 11.64, 100.0), eph, START)
    assert rx.profile.sky.pdop_mask == 25.0
    sink = Sink()
    nav5 = {"dyn": 1, "minEl": 1, "posFixMode": 1, "posMask": 1, "dynModel": 4, "fixMode": 3,
            "minElev": 10, "pDop": 12.5, "tDop": 25.0, "pAcc": 100, "tAcc": 350}
    client = [pyubx2.UBXMessage("CFG", "CFG-NAV5", pyubx2.POLL).serialize(),
              pyubx2.UBXMessage.config_set(1, 0, [("CFG_NAVSPG_OUTFIL_PDOP", 40)]).serialize(),
              pyubx2.UBXMessage("CFG", "CFG-NAV5", pyubx2.SET, **nav5).serialize()]
    sink.read_available = lambda: client.pop(0) if client else b""
    member = live.LiveReceiver(rx, sink, nmea.NmeaFormat.from_dict(cfg.profile.nmea),
                               poseproviders.SimClock(START), np.random.default_rng(0))

    def answer() -> list:
        sink.epochs.clear()
        member.service_client()
        reader = pyubx2.UBXReader(io.BytesIO(b"".join(sink.epochs)),
                                  quitonerror=pyubx2.ERR_RAISE)
        return [msg for _, msg in reader]

    polled = answer()
    assert [m.identity for m in polled] == ["CFG-NAV5", "ACK-ACK"]
    assert polled[0].pDop == pytest.approx(25.0) and polled[0].minElev == 5
    masks, elevations = [], []
    for _ in range(2):
        assert [m.identity for m in answer()] == ["ACK-ACK"]
        masks.append(member.rx.profile.sky.pdop_mask)
        elevations.append(member.rx.profile.sky.elevation_mask_deg)
    assert masks == [4.0, 12.5]
    assert elevations == [5.0, 10.0]
    before = member.rx.profile.sky
    assert live.sky_after_nav5(before, member.applied.nav5, member.applied.nav5) is before
    assert live.pdop_mask_of(0) == float("inf")


_HANDLER_INSIDE_SET = """
import os, signal, threading
from virtualgps.run import daemon

stop = daemon.StopEvent()
signal.signal(signal.SIGUSR1, lambda *_: stop.set())
raised = []

def raise_once():
    if not raised:
        raised.append(1)
        signal.raise_signal(signal.SIGUSR1)  # (its handler runs in the call below)

# The second signal's handler runs while the first handler's set is under way: where set holds
# a lock (threading.Event's Condition, while it notifies), or as it wakes the descriptor.
notify_all, eventfd_write = threading.Condition.notify_all, os.eventfd_write

def notify_then(self, *a):
    raise_once()
    notify_all(self, *a)

def write_then(fd, value):
    raise_once()
    eventfd_write(fd, value)

threading.Condition.notify_all = notify_then
os.eventfd_write = write_then
stop.set()
print("stopped", stop.is_set(), len(raised))
"""


def test_a_signal_inside_another_signals_stop_does_not_hang():
    """``timeout -s INT`` sends SIGINT to the daemon, then to its process group: the second
    handler may run inside the first's ``set``. The daemon hung for good there (SIGTERM too)
    while StopEvent was a threading.Event, whose ``set`` holds a lock."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _HANDLER_INSIDE_SET], capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["stopped", "True", "1"], r.stdout


def test_stop_event_wakes_a_select_and_never_writes_after_close():
    stop = daemon.StopEvent()
    fd = stop.fileno()
    assert select.select([fd], [], [], 0)[0] == []
    threading.Timer(0.05, stop.set).start()
    assert select.select([fd], [], [], 5.0)[0] == [fd]  # (woken by set, long before 5 s)
    assert stop.is_set()
    r, w = os.pipe()
    stop.close()
    # The closed number given to another file (here a pipe's write end): set must not write to it.
    try:
        os.dup2(w, fd)
        os.set_blocking(r, False)
        stop.set()
        with pytest.raises(BlockingIOError):
            os.read(r, 64)
    finally:
        for f in {r, w, fd}:
            os.close(f)
