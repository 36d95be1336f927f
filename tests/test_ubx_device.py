"""The u-blox profiles as devices: ``virtualgps run --profile ublox-m8n`` (and ``ublox-m9n``) on a
pty, configured and read by real clients: gpsd's u-blox driver, and a client sending the UBX
configuration sequence a flight stack's driver sends, every byte read back by pyubx2.

These tests start real processes (the daemon, gpsd) and talk over the pty only.
"""

from __future__ import annotations

import io
import os
import select
import time
import tty
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e

pyubx2 = pytest.importorskip("pyubx2")

ORIGIN = "52.14,11.64,100"


def _open(link: Path) -> int:
    fd = os.open(link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    return fd


def _read_for(fd: int, seconds: float) -> bytes:
    """Everything the device writes within ``seconds``."""
    out = bytearray()
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        if select.select([fd], [], [], left)[0]:
            try:
                out += os.read(fd, 65536)
            except BlockingIOError:
                pass
    return bytes(out)


def _ubx_whole_at(data: bytes, k: int) -> int:
    """The end of a whole UBX frame with a good checksum at ``k`` (u-blox 8 protocol spec,
    §32.4: 8-bit Fletcher over class, id, length and payload), or -1."""
    if data[k:k + 2] != b"\xb5\x62" or k + 6 > len(data):
        return -1
    end = k + 8 + int.from_bytes(data[k + 4:k + 6], "little")
    if end > len(data):
        return -1
    a = b = 0
    for x in data[k + 2:end - 2]:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return end if data[end - 2:end] == bytes((a, b)) else -1


def _nmea_whole_at(data: bytes, k: int) -> int:
    """The end of a whole NMEA sentence with a good checksum at ``k``, or -1."""
    if data[k:k + 1] != b"$":
        return -1
    end = data.find(b"\r\n", k, k + 90)
    if end < 0 or data[end - 3:end - 2] != b"*":
        return -1
    x = 0
    for c in data[k + 1:end - 3]:
        x ^= c
    return end + 2 if data[end - 2:end] == b"%02X" % x else -1


def _parse_all(data: bytes) -> list:
    """Every message of a byte stream of UBX and NMEA, pyubx2 raising on any error. A read
    starts and ends anywhere in the stream: it is parsed from its first whole message (one
    with a good checksum; a UBX payload may hold a ``$``) to its last."""
    start = next((k for k in range(len(data))
                  if _ubx_whole_at(data, k) >= 0 or _nmea_whole_at(data, k) >= 0), len(data))
    end = start
    while (k := max(_ubx_whole_at(data, end), _nmea_whole_at(data, end))) >= 0:
        end = k
    rest = data[end:]
    cut = (rest[:2] in (b"\xb5", b"\xb5\x62") and (len(rest) < 6 or len(rest) < 8 + int.from_bytes(
        rest[4:6], "little"))) or (rest[:1] == b"$" and b"\r\n" not in rest)
    if cut:  # the read ended inside this message; anything else is handed on, to raise
        rest = b""
    reader = pyubx2.UBXReader(io.BytesIO(data[start:end] + rest),
                              protfilter=pyubx2.NMEA_PROTOCOL | pyubx2.UBX_PROTOCOL,
                              quitonerror=pyubx2.ERR_RAISE)
    return [msg for _, msg in reader]


def _answer(fd: int, wait_s: float, head: bytes) -> list:
    """What the device writes until a UBX frame starting with ``head`` is whole (at most
    ``wait_s``), parsed."""
    buf = bytearray()
    end = time.monotonic() + wait_s
    while time.monotonic() < end:
        buf += _read_for(fd, min(0.01, max(0.0, end - time.monotonic())))
        k = buf.find(head)
        if k >= 0 and len(buf) >= k + 6 and len(buf) >= k + 8 + int.from_bytes(
                buf[k + 4:k + 6], "little"):
            break
    return _parse_all(bytes(buf))


def _name(ack) -> str:
    """The command an ACK answers, as pyubx2 names it."""
    return pyubx2.UBX_MSGIDS[bytes((ack.clsID, ack.msgID))]


def _ubx(cls: str, name: str, mode: int, **fields) -> bytes:
    return pyubx2.UBXMessage(cls, name, mode, **fields).serialize()


def _daemon(tmp_path: Path, profile: str):
    from test_e2e import Daemon

    return Daemon(tmp_path, "--profile", profile, "--scene", "none", "--origin", ORIGIN,
                  "--poses", "demo")


def test_a_flight_stacks_configuration_brings_nav_pvt_at_its_rate_and_baud(tmp_path):
    """As PX4's and ArduPilot's u-blox drivers start (PX4-GPSDrivers ``ubx.cpp``, ArduPilot
    ``AP_GPS_UBLOX``): CFG-PRT to 115200 baud with UBX only out, CFG-RATE 200 ms, CFG-NAV5
    (airborne < 4 g), CFG-MSG NAV-PVT every solution, a MON-VER poll. Each is answered within
    250 ms; the port switches to 115200 after its ACK; then only UBX comes, NAV-PVT at 5 Hz,
    and every byte parses with pyubx2."""
    daemon = _daemon(tmp_path, "ublox-m8n")
    try:
        fd = _open(daemon.link)
        try:
            boot = _read_for(fd, 2.5)  # power-on: the $GNTXT notices and NMEA at 1 Hz
            assert b"$GNTXT,01,01,02,HW UBX-M8030 00080000*60\r\n" in boot
            assert b"$GNGGA," in boot and b"\xb5\x62" not in boot
            steps = [
                (_ubx("CFG", "CFG-PRT", pyubx2.SET, portID=1, charLen=3, parity=4,
                      baudRate=115200, inUBX=1, inNMEA=0, outUBX=1, outNMEA=0), "CFG-PRT"),
                (_ubx("CFG", "CFG-RATE", pyubx2.SET, measRate=200, navRate=1, timeRef=0),
                 "CFG-RATE"),
                (_ubx("CFG", "CFG-NAV5", pyubx2.SET, dyn=1, dynModel=8), "CFG-NAV5"),
                (_ubx("CFG", "CFG-MSG", pyubx2.SET, msgClass=0x01, msgID=0x07, rateUART1=1),
                 "CFG-MSG"),
            ]
            # The first ACK may wait behind the NMEA epoch on the line (at 9600 baud up to
            # ~0.8 s, as on the module); once NMEA is off each answer comes within 250 ms.
            for (frame, name), wait_s in zip(steps, (1.5, 0.25, 0.25, 0.25), strict=True):
                os.write(fd, frame)
                got = _answer(fd, wait_s, b"\xb5\x62\x05")
                acks = [m for m in got if m.identity == "ACK-ACK"]
                assert acks and _name(acks[-1]) == name, (name, got)
            os.write(fd, _ubx("MON", "MON-VER", pyubx2.POLL))
            got = _answer(fd, 0.25, b"\xb5\x62\x0a\x04")
            ver = [m for m in got if m.identity == "MON-VER"]
            assert ver and ver[0].hwVersion.rstrip(b"\x00") == b"00080000"
            stream = _read_for(fd, 3.0)
        finally:
            os.close(fd)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    assert "client set the baud rate to 115200" in err
    msgs = _parse_all(stream)
    kinds = {m.identity for m in msgs}
    assert kinds == {"NAV-PVT"}, kinds  # NMEA out switched off, NAV-PVT alone switched on
    pvt = [m for m in msgs if m.identity == "NAV-PVT"]
    assert 13 <= len(pvt) <= 16  # 5 Hz over 3 s
    itow = [m.iTOW for m in pvt]
    steps_ms = {b - a for a, b in zip(itow, itow[1:], strict=False)}
    assert steps_ms == {200}
    assert all(m.fixType == 3 and m.numSV >= 6 for m in pvt[-5:])
    lat = [m.lat for m in pvt[-5:]]
    assert all(abs(x - 52.14) < 0.01 for x in lat)


def _nav_sat(m) -> dict[tuple[int, int], tuple[int, int, int, int]]:
    """NAV-SAT's satellites: (gnssId, svId) -> (cno, elev, azim, svUsed)."""
    out = {}
    for k in range(1, m.numSvs + 1):
        key = (getattr(m, f"gnssId_{k:02d}"), getattr(m, f"svId_{k:02d}"))
        out[key] = tuple(getattr(m, f"{f}_{k:02d}") for f in ("cno", "elev", "azim", "svUsed"))
    return out


def _gsv(msgs: list) -> dict[tuple[int, int], tuple[int, int, int]]:
    """One epoch's GSV satellites: (gnssId, svId) -> (snr, elevation, azimuth); GPGSV GPS
    1-32, GLGSV GLONASS 65-96 (svId 1-24 in NAV-SAT)."""
    out = {}
    for g in msgs:
        gnss = {"GPGSV": 0, "GLGSV": 6}[g.identity]
        for k in range(1, 5):
            sv = getattr(g, f"svid_{k:02d}", "")
            if sv in ("", None):
                continue
            sv = int(sv)
            key = (6, sv - 64) if gnss == 6 else ((1, sv + 87) if sv > 32 else (0, sv))
            snr = getattr(g, f"cno_{k:02d}")
            out[key] = (int(snr) if snr != "" else 0, int(getattr(g, f"elv_{k:02d}")),
                        int(getattr(g, f"az_{k:02d}")))
    return out


def test_nav_pvt_and_nav_sat_agree_with_the_same_epochs_nmea(tmp_path):
    """With NMEA, NAV-PVT and NAV-SAT on, each epoch's NAV-PVT (written before the NMEA, as the
    module orders its output) names the GGA's time, position to the GGA's printed digits,
    satellites used and fix, and the RMC's speed; NAV-SAT lists GSV's satellites with the same
    C/N0, elevation and azimuth, and marks used those GSA names."""
    daemon = _daemon(tmp_path, "ublox-m8n")
    try:
        fd = _open(daemon.link)
        try:
            _read_for(fd, 1.5)
            # (NMEA, NAV-PVT and NAV-SAT of 20-odd satellites need ~1.2 kB an epoch: more than
            # 9600 baud carries, so first the baud, as a client would)
            os.write(fd, _ubx("CFG", "CFG-PRT", pyubx2.SET, portID=1, charLen=3, parity=4,
                              baudRate=115200, inUBX=1, inNMEA=1, outUBX=1, outNMEA=1))
            for mid in (0x07, 0x35):  # NAV-PVT, NAV-SAT
                os.write(fd, _ubx("CFG", "CFG-MSG", pyubx2.SET, msgClass=0x01, msgID=mid,
                                  rateUART1=1))
            _read_for(fd, 1.2)
            stream = _read_for(fd, 6.0)  # (each whole epoch is closed by the next NAV-PVT)
        finally:
            os.close(fd)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    msgs = _parse_all(stream)
    pvt_at = [k for k, m in enumerate(msgs) if m.identity == "NAV-PVT"]
    pairs = 0
    for k, nxt in zip(pvt_at, pvt_at[1:], strict=False):  # each whole epoch
        m, epoch = msgs[k], msgs[k + 1:nxt]
        gga = next((x for x in epoch if x.identity == "GNGGA"), None)
        rmc = next((x for x in epoch if x.identity == "GNRMC"), None)
        sat = next((x for x in epoch if x.identity == "NAV-SAT"), None)
        if gga is None or rmc is None or sat is None:
            continue
        pairs += 1
        assert (m.hour, m.min, m.second) == (gga.time.hour, gga.time.minute, gga.time.second)
        assert m.iTOW % 1000 == 0
        assert m.fixType == 3 and gga.quality == 1
        assert abs(m.lat - gga.lat) < 1e-5 / 60 * 1.01 + 1e-7
        assert abs(m.lon - gga.lon) < 1e-5 / 60 * 1.01 + 1e-7
        assert abs(m.hMSL / 1000.0 - gga.alt) <= 0.051
        assert m.numSV == int(gga.numSV)
        assert abs(m.gSpeed / 1000.0 - rmc.spd * 0.514444) < 0.001
        gsv = _gsv([x for x in epoch if x.identity in ("GPGSV", "GLGSV")])
        nav = _nav_sat(sat)
        assert set(gsv) == set(nav)
        for key, (snr, el, az) in gsv.items():
            assert nav[key][:3] == (snr, el, az), key
        used_gsa = {int(getattr(g, f"svid_{j:02d}")) for g in epoch if g.identity == "GNGSA"
                    for j in range(1, 13) if getattr(g, f"svid_{j:02d}", "") not in ("", None)}
        used_nav = {sv + 64 if gnss == 6 else sv for (gnss, sv), v in nav.items() if v[3]}
        assert used_gsa == used_nav and len(used_nav) == m.numSV
    assert pairs >= 3


def test_a_system_switched_off_is_neither_tracked_nor_listed(tmp_path):
    """An M9 client switching GLONASS off (CFG-VALSET CFG-SIGNAL-GLO_ENA = 0, as PX4 does for
    a GPS_1_GNSS mask without it): from the next epoch no GLONASS satellite is listed in NAV-SAT
    or GSV, none used, and the fix goes on with the others."""
    daemon = _daemon(tmp_path, "ublox-m9n")
    try:
        fd = _open(daemon.link)
        try:
            _read_for(fd, 2.2)
            os.write(fd, _ubx("CFG", "CFG-MSG", pyubx2.SET, msgClass=0x01, msgID=0x35,
                              rateUART1=1))
            before = _parse_all(_read_for(fd, 2.0))
            os.write(fd, pyubx2.UBXMessage.config_set(1, 0, [("CFG_SIGNAL_GLO_ENA", 0)])
                     .serialize())
            got = _answer(fd, 1.5, b"\xb5\x62\x05")
            assert [_name(m) for m in got if m.identity == "ACK-ACK"] == ["CFG-VALSET"]
            _read_for(fd, 1.1)
            # (from the first whole epoch on, each opening with its NAV-SAT: the read above
            # may have stopped mid-epoch)
            raw = _read_for(fd, 2.5)
            after = _parse_all(raw[raw.find(b"\xb5\x62\x01\x35"):])
        finally:
            os.close(fd)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    assert "client set the systems tracked: GPS, Galileo, BeiDou" in err

    def glonass(msgs: list) -> tuple[int, int]:
        sats = [_nav_sat(m) for m in msgs if m.identity == "NAV-SAT"]
        listed = sum(1 for m in msgs if m.identity == "GLGSV" for k in range(1, 5)
                     if getattr(m, f"svid_{k:02d}", "") not in ("", None))
        return sum(1 for s in sats for g, _ in s if g == 6), listed

    assert all(n > 0 for n in glonass(before))
    assert glonass(after) == (0, 0)
    gga = [m for m in after if m.identity == "GNGGA"]
    assert gga and all(m.quality == 1 for m in gga)


# (no BeiDou TLE set is bundled: the M9's BeiDou satellites are left out with a warning)
@pytest.mark.parametrize("profile, hw, systems", [("ublox-m8n", "00080000", {0, 6}),
                                                  ("ublox-m9n", "00190000", {0, 2, 6})])
def test_gpsd_identifies_the_u_blox_configures_it_and_reports_every_system(
        tmp_path, profile, hw, systems):
    """gpsd (probing allowed) takes the device for a u-blox with its MON-VER, switches it to
    UBX, and reports 3D fixes and every system's satellites by u-blox gnssId."""
    from test_e2e import GPSD, sky_after_fix, tpv3, watch_gpsd

    if GPSD is None and not os.environ.get("CI"):
        pytest.skip("gpsd not installed")
    assert GPSD, "gpsd must be installed in CI (the README's test command installs it)"

    def ublox(m):
        return [x for x in m if x.get("class") == "DEVICE" and x.get("driver") == "u-blox"]

    daemon = _daemon(tmp_path, profile)
    try:
        messages = watch_gpsd(tmp_path, daemon.link, 60.0,
                              lambda m: ublox(m) and len(tpv3(m)) >= 3
                              and sky_after_fix(m, systems) is not None)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    dev = ublox(messages)
    assert dev, f"gpsd did not identify a u-blox; daemon stderr: {err}"
    assert hw in dev[-1]["subtype"] and "PROTVER" in dev[-1].get("subtype1", "")
    assert len(tpv3(messages)) >= 3
    assert "u-blox command link" in err and "NAV-PVT/1" in err  # gpsd configured it
    if profile == "ublox-m9n":
        assert "BeiDou satellites left out (no beidou TLE set is at hand" in err
    sky = sky_after_fix(messages, systems)
    assert sky is not None, f"no SKY of {systems} after the fix"
    sats = sky["satellites"]
    assert any(s["used"] for s in sats if s["gnssid"] == 6)
