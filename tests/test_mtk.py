"""The MTK command link: splitting client bytes, PMTK parsing and checksums, every command's reply
flag, and the live loop answering and applying commands (restart -> no fix for the TTFF)."""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

from virtualgps.device import mtk, nmea
from virtualgps.receiver.definition import Georef
from virtualgps.receiver.profiles import load_profile
from virtualgps.run import daemon, poseproviders
from virtualgps.run.config import BUNDLED_SCENES_DIR, make_receiver, resolve
from virtualgps.sky.ephemeris import load_tle

START = 1490712768.0  # 2017-03-28T14:52:48Z
FIRMWARE = "AXN_1.30,0000,HOLUX M-1000 (virtualgps),"
PROFILE_SENTENCES = ("GGA", "GSA", "GSV", "RMC", "VTG")


def cmd(body: str) -> bytes:
    """A command as a client writes it: ``$body*HH\\r\\n``."""
    return nmea.format_sentence(body).encode("ascii")


def fresh_link(rate_hz: float = 1.0, baud: int = 38400) -> mtk.MtkLink:
    return mtk.MtkLink(mtk.default_settings(PROFILE_SENTENCES, {}, rate_hz, baud), FIRMWARE)


def replies(link: mtk.MtkLink, data: bytes, epoch_bytes: int = 500) -> list[str]:
    return [r for resp in link.feed(data, epoch_bytes) for r in resp.replies]


def flag_of(link: mtk.MtkLink, body: str, epoch_bytes: int = 500) -> int:
    out = replies(link, cmd(body), epoch_bytes)
    assert len(out) >= 1 and out[0].startswith("$PMTK001,"), out
    fields = nmea.parse_sentence(out[0])
    assert fields is not None, out[0]  # our reply carries a valid checksum
    return int(fields[1][1])


# --- parsing ------------------------------------------------------------------------------------


def test_known_checksums_of_the_mtk_manuals():
    # Examples printed in MTK manuals and gpsd's logs (gpsd-mtk/*.log).
    assert mtk.STARTUP_MESSAGE == "$PMTK010,001*2E\r\n"
    assert cmd("PMTK103") == b"$PMTK103*30\r\n"
    assert cmd("PMTK605") == b"$PMTK605*31\r\n"
    assert cmd("PMTK220,1000") == b"$PMTK220,1000*1F\r\n"
    assert cmd("PMTK314,-1") == b"$PMTK314,-1*04\r\n"
    assert mtk.ack(320, 2) == "$PMTK001,320,2*30\r\n"  # quectel-L70.log
    assert mtk.ack(313, 3) == "$PMTK001,313,3*31\r\n"


def test_parse_pmtk_checksum_states():
    p = mtk.parse_pmtk(b"$PMTK220,1000*1F")
    assert p == mtk.PmtkPacket(220, ("1000",), "ok")
    assert mtk.parse_pmtk(b"$PMTK220,1000*1f").checksum == "ok"  # hex case does not matter
    assert mtk.parse_pmtk(b"$PMTK220,1000*1E").checksum == "wrong"
    assert mtk.parse_pmtk(b"$PMTK220,1000*1").checksum == "wrong"
    assert mtk.parse_pmtk(b"$PMTK220,1000").checksum == "absent"
    assert mtk.parse_pmtk(b"$GPGGA,1*00") is None  # another talker
    assert mtk.parse_pmtk(b"$PMTKX1,2*00") is None  # no 3-digit packet type
    assert mtk.parse_pmtk(b"$PMTK22*00") is None
    assert mtk.parse_pmtk(b"$PMTK220,\xff*00") is None  # not ASCII


def test_splitter_joins_pieces_and_drops_junk_and_binary():
    sp = mtk.PacketSplitter()
    whole = cmd("PMTK605") + cmd("PMTK103")
    got = []
    for i in range(len(whole)):  # one byte at a time
        got += sp.feed(whole[i : i + 1])
    assert got == [b"$PMTK605*31", b"$PMTK103*30"]
    # UBX and Evermore binary probes, noise, a broken line cut by the next '$', bare LF endings.
    junk = b"\xb5\x62\x0a\x04\x00\x00\x0e\x34\x10\x02\x04\x38\x10\x03noise$PMTK22"
    assert sp.feed(junk + b"$PMTK605*31\n\x00\x00$PGRMCE*0E\r\n") == [b"$PMTK605*31", b"$PGRMCE*0E"]


def test_splitter_is_bounded():
    sp = mtk.PacketSplitter()
    assert sp.feed(b"$" + b"A" * 10_000) == []
    assert sp.dropped_lines == 1
    assert len(sp._buf) <= mtk.MAX_PACKET_BYTES
    assert sp.feed(b"A" * 1000 + b"\r\n" + cmd("PMTK000")) == [b"$PMTK000*32"]


# --- commands -----------------------------------------------------------------------------------


def test_probe_is_answered_with_the_firmware_release_and_no_ack():
    link = fresh_link()
    assert replies(link, cmd("PMTK605")) == [nmea.format_sentence("PMTK705," + FIRMWARE)]


@pytest.mark.parametrize(
    ("body", "flag"),
    [
        ("PMTK000", 3),
        ("PMTK220,1000", 3),
        ("PMTK220,200", 3),
        ("PMTK220,50", 2),  # below MTK's 100 ms
        ("PMTK220,20000", 2),
        ("PMTK220,fast", 0),
        ("PMTK220", 0),
        ("PMTK300,1000,0,0,0.0,0.0", 3),  # gpsd's MTK-3301 configuration
        ("PMTK300,1000,0,0,x,0", 0),
        ("PMTK251,57600", 3),
        ("PMTK251,0", 3),
        ("PMTK251,12345", 2),
        ("PMTK251,", 0),
        ("PMTK301,2", 3),
        ("PMTK301,0", 3),
        ("PMTK301,7", 2),
        ("PMTK313,1", 3),
        ("PMTK313,0", 3),
        ("PMTK313,on", 0),
        ("PMTK320,0", 3),
        ("PMTK320,1", 3),
        ("PMTK314,0,1,0,1,1,5,1,1,0,0,0,0,0,0,0,0,0,1,0", 3),
        ("PMTK314,-1", 3),
        ("PMTK314,1,1,1", 0),
        ("PMTK314,0,1,0,1,1,9,1,1,0,0,0,0,0,0,0,0,0,1,0", 2),
        ("PMTK386,0.4", 3),
        ("PMTK386,2.5", 2),
        ("PMTK397,1.2", 3),
        ("PMTK397,", 0),
        ("PMTK161,0", 1),  # standby: not emulated
        ("PMTK424", 1),  # gpsd 3.22 asks for the PPS setting after configuring
        ("PMTK999,1,2", 1),
    ],
)
def test_reply_flags(body, flag):
    assert flag_of(fresh_link(), body) == flag


def test_ack_names_the_command_and_unchanged_settings_on_failure():
    link = fresh_link()
    before = link.settings
    assert replies(link, cmd("PMTK251,12345")) == [mtk.ack(251, 2)]
    assert link.settings is before


def test_command_without_checksum_is_invalid_and_wrong_checksum_is_ignored():
    link = fresh_link()
    assert replies(link, b"$PMTK220,200\r\n") == [mtk.ack(220, 0)]
    assert replies(link, b"$PMTK220,200*00\r\n") == []
    assert link.bad_checksum == 1
    assert link.settings.fix_interval_ms == 1000


@pytest.mark.parametrize(
    ("number", "kind"), [(101, "hot"), (102, "warm"), (103, "cold"), (104, "cold")]
)
def test_restarts(number, kind):
    link = fresh_link()
    replies(link, cmd("PMTK386,1.0") + cmd("PMTK220,500"))
    (resp,) = link.feed(cmd(f"PMTK{number}"), 500)
    assert resp.restart == kind
    assert resp.replies == (mtk.ack(number, 3), "$PMTK010,001*2E\r\n")
    assert link.settings.static_nav_mps == 0.0  # restarts reset static navigation
    # 104 (full cold start) restores every setting; the others keep the fix interval.
    assert link.settings.fix_interval_ms == (1000 if number == 104 else 500)


def test_fix_interval_too_fast_for_the_baud():
    # 38400 baud carries 3840 bytes/s: a 500-byte epoch needs 130 ms.
    link = fresh_link()
    assert flag_of(link, "PMTK220,100", epoch_bytes=500) == 2
    assert link.settings.fix_interval_ms == 1000
    assert flag_of(link, "PMTK220,200", epoch_bytes=500) == 3
    assert flag_of(link, "PMTK220,100", epoch_bytes=300) == 3
    # At 115200 baud (11520 bytes/s) the 500-byte epoch fits in 100 ms.
    link = fresh_link(baud=38400)
    assert flag_of(link, "PMTK251,115200") == 3
    assert flag_of(link, "PMTK300,100,0,0,0,0", epoch_bytes=500) == 3
    assert link.settings.rate_hz == 10.0


def test_sentence_rates_and_restore_defaults():
    link = fresh_link()
    defaults = link.settings
    assert mtk.sentence_order(PROFILE_SENTENCES, defaults) == PROFILE_SENTENCES
    # gpsd's MTK-3301 configuration: no VTG, GSV every 5th fix, GRS/GST (we lack) and ZDA on.
    replies(link, cmd("PMTK314,0,1,0,1,1,5,1,1,0,0,0,0,0,0,0,0,0,1,0"))
    assert link.settings.sentence_every() == {"RMC": 1, "GGA": 1, "GSA": 1, "GSV": 5, "ZDA": 1}
    assert mtk.sentence_order(PROFILE_SENTENCES, link.settings) == (
        "GGA",
        "GSA",
        "GSV",
        "RMC",
        "ZDA",
    )
    # Queried back as set.
    assert replies(link, cmd("PMTK414")) == [
        nmea.format_sentence("PMTK514,0,1,0,1,1,5,1,1,0,0,0,0,0,0,0,0,0,1,0")
    ]
    replies(link, cmd("PMTK314,-1"))
    assert link.settings.rates == defaults.rates


def test_sbas_and_static_navigation_are_stored():
    link = fresh_link()
    assert link.settings.sbas_active
    replies(link, cmd("PMTK313,0"))
    assert not link.settings.sbas_enabled and not link.settings.sbas_active
    replies(link, cmd("PMTK313,1") + cmd("PMTK301,1"))
    assert link.settings.sbas_enabled and link.settings.dgps_mode == 1
    assert not link.settings.sbas_active  # DGPS source RTCM, not SBAS
    replies(link, cmd("PMTK397,0.8"))
    assert link.settings.static_nav_mps == pytest.approx(0.8)
    assert replies(link, cmd("PMTK447")) == [nmea.format_sentence("PMTK527,0.80")]


def test_junk_between_commands_changes_nothing():
    link = fresh_link()
    before = link.settings
    noise = bytes(range(256)) + b"$PSRF100,0,38400,8,1,0*3C\r\n$PFEC,GPint\r\n$PMTK$$$\r\n\r\n"
    assert replies(link, noise) == []
    assert link.settings is before
    assert replies(link, noise + cmd("PMTK605") + noise) == [
        nmea.format_sentence("PMTK705," + FIRMWARE)
    ]


# --- in the live loop ---------------------------------------------------------------------------


class ScriptedDevice:
    """A device whose client writes scripted bytes at chosen simulated times; records output."""

    def __init__(self, clock: poseproviders.SimClock, script: list[tuple[float, bytes]]) -> None:
        self.clock, self.script = clock, sorted(script)
        self.writes: list[tuple[float, bytes]] = []
        self.bauds: list[int] = []

    def write_epoch(self, data: bytes) -> None:
        self.writes.append((self.clock.now_unix_s(), data))

    def read_available(self) -> bytes:
        now = self.clock.now_unix_s()
        ready = b"".join(m for t, m in self.script if t <= now)
        self.script = [(t, m) for t, m in self.script if t > now]
        return ready

    def set_baud(self, baud: int) -> None:
        self.bauds.append(baud)


@pytest.fixture(scope="module")
def mtk_receiver():
    cfg = resolve({"rate": 10.0, "scene": "none"})
    prof = load_profile(
        "holux-m1000",
        {
            "command_link": "mtk",
            "rate_hz": 10.0,
            # a fix from the first epoch (no power-on start, no acquisition delay): the
            # restarts the client commands are what is under test
            "cold_start": {"power_on": "none", "ttff_cold_s": 1.0, "ttff_warm_s": 0.5,
                           "ttff_sd_frac": 0.0},
            "cn0_tracking": {"enabled": False},
        },
    )
    cfg = dataclasses.replace(cfg, profile=prof)
    eph = load_tle(BUNDLED_SCENES_DIR.parent / "ephemeris" / "gps-ops-2017-03-28.tle")
    return cfg, make_receiver(cfg, None, Georef(52.14, 11.64, 100.0), eph, START)


def run_scripted(rx, script_rel, n_epochs):
    clock = poseproviders.SimClock(START)
    t0 = clock.now_unix_s()
    dev = ScriptedDevice(clock, [(t0 + dt, data) for dt, data in script_rel])
    lap = poseproviders.demo_lap(np.array([[0, 0, 1.5], [40, 0, 1.5], [40, 40, 1.5]], float), 1.4)
    provider = poseproviders.LoopProvider(lap, t0, 2.0)
    epochs: list[tuple[float, int]] = []
    stats = daemon.run_daemon(
        rx,
        provider,
        dev,
        nmea.NmeaFormat.from_dict(rx.profile.nmea),
        clock,
        np.random.default_rng(0),
        threading.Event(),
        on_epoch=lambda f, s: epochs.append((float(f.t_unix_s[0]), int(f.quality[0]))),
        max_epochs=n_epochs,
    )
    return t0, dev, epochs, stats


def test_live_loop_answers_probe_and_cold_start_withholds_the_fix(mtk_receiver):
    _, rx = mtk_receiver
    t0, dev, epochs, stats = run_scripted(
        rx, [(0.35, b"\xb5\x62junk" + cmd("PMTK605")), (1.05, cmd("PMTK103"))], 32
    )
    texts = [d for _, d in dev.writes]
    assert texts[0] == b"$PMTK010,001*2E\r\n"  # at start-up, before the first epoch
    i705 = texts.index(nmea.format_sentence("PMTK705," + FIRMWARE).encode())
    i103 = texts.index((mtk.ack(103, 3) + mtk.STARTUP_MESSAGE).encode())
    assert i705 < i103
    # Replies are written on their own, never inside an epoch, and promptly.
    t_705 = dev.writes[i705][0]
    t_103 = dev.writes[i103][0]
    assert t0 + 0.35 <= t_705 < t0 + 0.35 + 0.15
    assert t0 + 1.05 <= t_103 < t0 + 1.05 + 0.15
    assert all(d.startswith(b"$GPGGA") for d in texts[1:] if not d.startswith(b"$PMTK"))
    t = np.array([e[0] for e in epochs])
    q = np.array([e[1] for e in epochs])
    assert (q[t < t0 + 1.05] > 0).all()  # fixes before the restart was sent
    withheld = (t > t_103) & (t < t_103 + 1.0)  # the cold TTFF, 1.0 s with no spread
    assert withheld.sum() >= 8 and (q[withheld] == 0).all()
    assert (q[t > t_103 + 1.0 + 1e-6] > 0).all()  # and back
    assert stats.link is not None and stats.link.commands == 2


def test_live_loop_applies_fix_interval_and_sentence_rates(mtk_receiver):
    _, rx = mtk_receiver
    gpsd_rates = "PMTK314,0,1,0,1,1,5,1,1,0,0,0,0,0,0,0,0,0,1,0"
    t0, dev, epochs, stats = run_scripted(
        rx,
        [
            (0.32, cmd("PMTK220,100")),  # 10 Hz at 38400 baud: too fast for ~500-byte epochs
            (0.52, cmd("PMTK220,200")),
            (1.52, cmd(gpsd_rates)),
            (2.92, cmd("PMTK314,-1") + cmd("PMTK251,115200")),
        ],
        20,
    )
    texts = [d for _, d in dev.writes]
    assert mtk.ack(220, 2).encode() in texts
    assert mtk.ack(220, 3).encode() in texts
    assert dev.bauds == [115200]
    t = np.array([e[0] for e in epochs])
    # 10 Hz until the 200 ms interval, then multiples of 0.2 s with no epoch repeated.
    assert np.all(np.diff(t) > 0)
    after = t[t > t0 + 0.6]
    np.testing.assert_allclose(after * 5, np.round(after * 5), atol=1e-6)
    np.testing.assert_allclose(np.diff(after), 0.2, atol=1e-6)
    # gpsd's rates: no VTG, ZDA added, GSV on every 5th fix only; -1 brings the profile's back.
    ep = [(w_t, d) for w_t, d in dev.writes if d.startswith(b"$GPGGA")]
    mid = [d for w_t, d in ep if t0 + 1.7 < w_t < t0 + 2.9]
    assert mid and all(b"$GPVTG" not in d and b"$GPZDA" in d for d in mid)
    assert 0 < sum(b"$GPGSV" in d for d in mid) < len(mid)
    late = [d for w_t, d in ep if w_t > t0 + 3.1]
    assert late and all(b"$GPVTG" in d and b"$GPZDA" not in d and b"$GPGSV" in d for d in late)
    assert stats.link.settings.baud == 115200


def test_without_link_client_bytes_are_read_and_dropped(mtk_receiver):
    cfg, rx = mtk_receiver
    rx = dataclasses.replace(rx, profile=dataclasses.replace(rx.profile, command_link="none"))
    _, dev, epochs, stats = run_scripted(rx, [(0.15, cmd("PMTK605") + cmd("PMTK103"))], 6)
    assert stats.link is None
    assert all(d.startswith(b"$GPGGA") for _, d in dev.writes)
    assert dev.script == []  # read
    assert all(q > 0 for _, q in epochs)


def test_devices_change_baud_at_run_time():
    from virtualgps.device.pty import PtyDevice
    from virtualgps.device.serialport import SerialDevice

    with PtyDevice(None, baud=38400) as pty:
        pty.set_baud(115200)
        assert pty.baud == 115200 and pty.termios_baud() == 115200
        assert pty.max_backlog_bytes == int(2.0 * 11520)
        pty.set_baud(14400)  # not a termios rate: pacing only
        assert pty.baud == 14400 and pty.termios_baud() == 115200
    with SerialDevice("loop://", 38400) as port:
        port.write_epoch(mtk.ack(251, 3).encode())  # leaves at the old rate, then the switch
        port.set_baud(9600)
        deadline = time.monotonic() + 2.0
        while port.baud != 9600 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert port.baud == 9600 and port._serial.baudrate == 9600
        assert port.written_bytes == len(mtk.ack(251, 3))
