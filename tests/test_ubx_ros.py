"""The u-blox emulation against the ROS ``ublox`` driver (``ublox_gps``, KumarRobotics/ublox).

ROS is not installed here, so the driver's start-up and its NAV-PVT handling are re-written below
as a small model (our code, not theirs) that writes the bytes it writes, in its order, and judges
every answer as it does, driving the pure :class:`~virtualgps.device.ubx.link.UbxLink` through
the simulated UART of ``ubx_uart.py``; one test sends its M9 sequence to the real daemon's pty.

Sources read (through the project's source index; every step below cites file and function):
``ublox_gps/src/gps.cpp`` (ROS 1; the index's copy names no commit: ``Gps::initializeSerial``,
``resetSerial``, ``configUart1``, ``configRate``, ``configSbas``, ``setPpp``, ``configGnss``,
``configReset``), ``ublox_gps/include/ublox_gps/gps.h`` and ``node.h`` at fc9fb4f0
(``kDefaultAckTimeout``, ``kBaudrates``, ``kSetBaudrateSleepMs``,
``UbloxFirmware7Plus::callbackNavPvt``), ``ublox_gps/src/node.cpp`` (ROS 1:
``UbloxNode::initialize``, ``processMonVer``, ``configureUblox``, ``configureInf``),
``ublox_gps/src/ublox_firmware8.cpp`` at 1deaf66e (ROS 2; the GNSS comparison is ROS 1's) and
``ublox_firmware9.cpp`` at 0b5da36a (ROS 2's M9 path: CFG-VALSET), ``ublox_msgs/msg/CfgNAVX5.msg``
at 0b8e122a (40 bytes, version 0). ROS 1's ``UbloxFirmware9`` is ``UbloxFirmware8`` unchanged.
"""

from __future__ import annotations

import os
import struct
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np
import pytest
from nmea_line import read_timed
from ubx_uart import (
    ACK_ACK,
    ALT0_M,
    CFG_GNSS,
    CFG_MSG,
    CFG_NAV5,
    CFG_PRT,
    CFG_RATE,
    CFG_RST,
    CFG_SBAS,
    CFG_VALSET,
    CLS_ACK,
    CLS_CFG,
    CLS_MON,
    CLS_NAV,
    GEOID_M,
    MON_VER,
    NAV_PVT,
    T0_UNIX_S,
    Module,
    Scanner,
    fix_at,
    ubx,
)

CFG_INF, CFG_NAVX5 = 0x02, 0x23
ROS_ACK_TIMEOUT_S = 1.0  # gps.h kDefaultAckTimeout: every configure() and poll(), no retry
ROS_BAUDS = (4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800)  # gps.h kBaudrates
ROS_BAUD_STEP_S = 0.5  # gps.h kSetBaudrateSleepMs
ROS_GNSS_RESET_WAIT_S = 1.0 + 15.0  # configGnss: 1 s after CFG-RST, then reset(15 s)
ROS_UART1_IN, ROS_UART1_OUT = 0x07, 0x01  # node.cpp defaults uart1/in (UBX NMEA RTCM), /out
ROS_PRT_MODE = 0x8D0  # CfgPRT MODE_RESERVED1 | CHAR_LEN_8BIT | PARITY_NO | STOP_BITS_1
ROS_FIX_DELAY_TOL = 1.15  # node.h FixDiagnostic: a stamp up to 1.15 measurement periods old
ROS_FREQ_TOL = 0.15  # ... and the rate within 15 %
STEP_S = 0.005  # the model's read step
#: CfgVALSETCfgdata.msg keys ROS 2's UbloxFirmware9 sets, and the parameter each follows
#: (SBAS follows gnss.gps there; QZSS needs both)
ROS2_SIGNAL_KEYS = (("gps", 0x1031001F), ("gps", 0x10310001), ("gps", 0x10310020),
                    ("gps", 0x10310005), ("galileo", 0x10310021), ("galileo", 0x10310007),
                    ("beidou", 0x10310022), ("beidou", 0x1031000D), ("qzss", 0x10310024),
                    ("qzss", 0x10310012), ("glonass", 0x10310025), ("glonass", 0x10310018))
GNSS_IDS = {0: "gps", 1: "sbas", 2: "galileo", 3: "beidou", 4: "imes", 5: "qzss", 6: "glonass"}


class DriverDied(Exception):
    """What ends ublox_gps: ROS_FATAL and shutdown (ROS 1), a runtime_error (ROS 2)."""


@dataclass
class RosUblox:
    """ublox_gps on a serial port: ``device``, ``uart1/baudrate`` = ``baud``, ``rate``,
    ``nav_rate`` 1, ``dynamic_model`` portable, ``fix_mode`` auto, ``gnss/*`` as ``gnss``
    (default: GPS alone, the driver's defaults), no product-specific part (an SPG module).

    ros2 : the ROS 2 branch (its M9 path sets the signals with CFG-VALSET and no cold reset)
    tty_baud : the host port's baud before the driver sets it (a fresh pty's)
    """

    module: Module
    baud: int
    rate_hz: float = 4.0
    gnss: dict = field(default_factory=lambda: {"gps": True})
    ros2: bool = False
    tty_baud: int = 9600
    t: float = 0.0
    log: list[tuple[str, str]] = field(default_factory=list)  # (step, ACK / NAK / timeout)
    protocol: float = 0.0
    firmware: int = 0
    supported: set[str] = field(default_factory=set)
    pvt_subscribed: bool = False
    fixes: list[dict] = field(default_factory=list)  # one NavSatFix per NAV-PVT

    def __post_init__(self) -> None:
        self.scanner = Scanner()
        self.host_baud = self.tty_baud

    @property
    def meas_rate_ms(self) -> int:
        return int(1000 / self.rate_hz)  # node.cpp getRosParams: meas_rate = 1000 / rate

    def send(self, cls: int, mid: int, payload: bytes = b"") -> None:
        self.module.write(ubx(cls, mid, payload), self.host_baud, self.t)

    def wait(self, want: tuple[int, int], what: str, answer: bool = False
             ) -> tuple[str, bytes | None]:
        """``Gps::waitForAcknowledge`` (an ACK / NAK of ``want``) or, with ``answer``, a poll's
        ``read`` (the message ``want`` itself), for ROS_ACK_TIMEOUT_S."""
        t0, got = self.t, ("timeout", None)
        while self.t < t0 + ROS_ACK_TIMEOUT_S - 1e-9 and got[0] == "timeout":
            self.t += STEP_S
            for c, i, p in self.scanner.feed(self.module.read(self.host_baud, self.t)):
                if answer and (c, i) == want:
                    got = ("ACK", p)
                    break
                if not answer and c == CLS_ACK and len(p) == 2 and (p[0], p[1]) == want:
                    got = ("ACK" if i == ACK_ACK else "NAK", None)
                    break
        self.log.append((what, got[0]))
        return got

    def configure(self, cls: int, mid: int, payload: bytes, what: str) -> bool:
        """``Gps::configure``: send, then wait for the ACK."""
        self.send(cls, mid, payload)
        return self.wait((cls, mid), what)[0] == "ACK"

    def poll(self, cls: int, mid: int, payload: bytes, what: str) -> bytes | None:
        self.send(cls, mid, payload)
        return self.wait((cls, mid), what, answer=True)[1]

    # -- UbloxNode::initialize --

    def start(self) -> None:
        """initializeIo, processMonVer, configureUblox, subscribe, configureInf."""
        self.initialize_serial()
        self.process_mon_ver()
        self.configure_ublox()
        self.subscribe()

    def initialize_serial(self) -> None:
        """Gps::initializeSerial: step the host port up (or down) to ``uart1/baudrate``, half
        a second a step, sending nothing; then configUart1 at that baud, fatal unless ACKed."""
        for b in ROS_BAUDS:
            if self.host_baud == self.baud:
                break
            if self.host_baud > b and self.baud > b:
                continue
            self.host_baud = b
            self.t += ROS_BAUD_STEP_S
        self.module.read(self.host_baud, self.t)  # (the worker starts reading now)
        prt = struct.pack("<BBHIIHHHH", 1, 0, 0, ROS_PRT_MODE, self.baud, ROS_UART1_IN,
                          ROS_UART1_OUT, 0, 0)
        if not self.configure(CLS_CFG, CFG_PRT, prt, "CFG-PRT") or self.host_baud != self.baud:
            raise DriverDied("Could not configure serial baud rate")

    def process_mon_ver(self) -> None:
        """UbloxNode::processMonVer: PROTVER gives the firmware class (< 14: 6, < 16: 7, <= 23:
        8, else 9); the last extensions list the GNSS (SBAS, QZSS, ...)."""
        p = self.poll(CLS_MON, MON_VER, b"", "MON-VER")
        if p is None:
            raise DriverDied("Failed to poll MonVER & set relevant settings")
        ext = [p[j:j + 30].split(b"\0")[0].decode() for j in range(40, len(p), 30)]
        for e in ext:
            if e.startswith("PROTVER"):
                self.protocol = float(e[8:])
        self.firmware = (6 if self.protocol < 14 else 7 if self.protocol < 16
                         else 8 if self.protocol <= 23 else 9)
        for e in ext[-2:]:
            self.supported |= set(e.split(";"))

    def configure_ublox(self) -> None:
        """UbloxNode::configureUblox with config_on_startup (each step fatal unless ACKed),
        then the firmware's own (UbloxFirmware8::configureUblox / ROS 2 UbloxFirmware9)."""
        steps = [(CFG_RATE, struct.pack("<HHH", self.meas_rate_ms, 1, 1), "CFG-RATE")]
        if "SBAS" in self.supported:
            steps.append((CFG_SBAS, struct.pack("<BBBBI", 0, 0, 0, 0, 0), "CFG-SBAS"))
        # setPpp(false): CFG-NAVX5, version 0, mask1 PPP, 40 bytes
        steps.append((CFG_NAVX5, struct.pack("<HHI", 0, 0x2000, 0) + bytes(32), "CFG-NAVX5"))
        for mask, off, value, what in ((0x01, 2, 0, "dynModel"), (0x04, 3, 3, "fixMode"),
                                       (0x08, 13, 0, "drLimit")):
            nav5 = bytearray(36)
            nav5[0:2] = struct.pack("<H", mask)
            nav5[off] = value
            steps.append((CFG_NAV5, bytes(nav5), f"CFG-NAV5 {what}"))
        for mid, payload, what in steps:
            if not self.configure(CLS_CFG, mid, payload, what):
                raise DriverDied(f"Failed to configure: {what}")
        blocks = self.poll(CLS_CFG, CFG_GNSS, b"", "CFG-GNSS poll")
        if blocks is None:
            raise DriverDied("Failed to read the GNSS config.")
        if self.ros2 and self.firmware >= 9:
            want = {k: self.gnss.get(p, False) and (p != "qzss" or self.gnss.get("gps", False))
                    for p, k in ROS2_SIGNAL_KEYS}
            self.send(CLS_CFG, CFG_VALSET, bytes((0, 0x01, 0, 0)) + b"".join(
                struct.pack("<IB", k, v) for k, v in want.items()))  # (no ACK awaited)
            self.log.append(("CFG-VALSET signals", "sent"))
            return
        out, changed = bytearray(blocks), False
        for j in range(4, len(blocks), 8):
            name = GNSS_IDS.get(blocks[j])
            flags = struct.unpack_from("<I", blocks, j + 4)[0]
            want = bool(self.gnss.get(name, False))
            if name is not None and bool(flags & 1) != want:
                changed = True
                struct.pack_into("<I", out, j + 4, (flags & ~1) | want)
        if changed:  # Gps::configGnss: CFG-GNSS, CFG-RST cold GNSS-only, then reset(15 s)
            if not self.configure(CLS_CFG, CFG_GNSS, bytes(out), "CFG-GNSS"):
                raise DriverDied("Failed to cold reset device after configuring GNSS")
            self.send(CLS_CFG, CFG_RST, struct.pack("<HBB", 0xFFFF, 2, 0))
            self.log.append(("CFG-RST", "sent"))
            self.t += ROS_GNSS_RESET_WAIT_S
            self.module.read(self.host_baud, self.t)  # (a new worker: what came is gone)
            self.scanner = Scanner()
            prt = self.poll(CLS_CFG, CFG_PRT, bytes((1,)), "CFG-PRT poll")  # resetSerial
            if prt is None:
                raise DriverDied("Failed to cold reset device after configuring GNSS")
            self.host_baud = struct.unpack_from("<I", prt, 8)[0]

    def subscribe(self) -> None:
        """UbloxFirmware8::subscribe: NAV-PVT every solution (a NAK leaves it unsubscribed,
        only logged); configureInf: CFG-INF for UBX and NMEA (a NAK is a warning)."""
        self.pvt_subscribed = self.configure(CLS_CFG, CFG_MSG, bytes((CLS_NAV, NAV_PVT, 1)),
                                             "CFG-MSG NAV-PVT")
        inf = b"".join(bytes((proto, 0, 0, 0)) + bytes((0x0F,) * 6) for proto in (0, 1))
        self.configure(CLS_CFG, CFG_INF, inf, "CFG-INF")

    # -- UbloxFirmware7Plus::callbackNavPvt --

    def run(self, seconds: float) -> None:
        """Read for ``seconds``, publishing a NavSatFix for each NAV-PVT."""
        end = self.t + seconds
        while self.t < end:
            self.t += STEP_S
            for c, i, p in self.scanner.feed(self.module.read(self.host_baud, self.t)):
                if (c, i) == (CLS_NAV, NAV_PVT) and self.pvt_subscribed:
                    self.fixes.append(self.nav_sat_fix(p))

    def nav_sat_fix(self, p: bytes) -> dict:
        """The NavSatFix of one NAV-PVT: the stamp its UTC where valid date, time and fully
        resolved (0x07) and flags2's confirmedAvailable (0x20) are set, else the host's clock;
        height above the ellipsoid; FIX where gnssFixOK and fixType >= 2; variances hAcc²,
        vAcc²."""
        assert len(p) == 92, "NavPVT (firmware 8) is 92 bytes"
        (_, year, month, day, hour, minute, sec, valid, _, nano, fix_type, flags, flags2,
         num_sv, lon, lat, height, _, hacc, vacc) = struct.unpack_from(
            "<IHBBBBBBIiBBBBiiiiII", p)
        utc = valid & 0x07 == 0x07 and flags2 & 0x20
        stamp = (datetime(year, month, day, hour, minute, sec, tzinfo=UTC).timestamp()
                 + nano * 1e-9 if utc else T0_UNIX_S + self.t)
        return {"stamp": stamp, "utc_stamp": bool(utc), "arrival": T0_UNIX_S + self.t,
                "lat": lat * 1e-7, "lon": lon * 1e-7, "alt": height * 1e-3,
                "fix": bool(flags & 0x01) and fix_type >= 2, "num_sv": num_sv,
                "var_h": (hacc / 1000.0) ** 2, "var_v": (vacc / 1000.0) ** 2}


def check_fixes(drv: RosUblox, no_fix: tuple[float, float] | None = None) -> None:
    """Every NavSatFix against the epoch it reports (``ubx_uart.fix_at``), and the driver's
    fix diagnostic: the rate within 15 % of ``rate``, each stamp at most 1.15 periods old."""
    period_s = drv.meas_rate_ms / 1000.0
    assert drv.fixes
    rate = (len(drv.fixes) - 1) / (drv.fixes[-1]["arrival"] - drv.fixes[0]["arrival"])
    assert abs(rate - drv.rate_hz) <= ROS_FREQ_TOL * drv.rate_hz, rate
    for f in drv.fixes:
        # the epoch: the last one due before its arrival, on the module's grid (0.5 s + k T)
        te = 0.5 + period_s * np.floor((f["arrival"] - T0_UNIX_S - 0.5) / period_s + 1e-9)
        if f["utc_stamp"]:
            assert f["stamp"] == pytest.approx(T0_UNIX_S + te, abs=1e-6)
        assert 0.0 <= f["arrival"] - f["stamp"] <= ROS_FIX_DELAY_TOL * period_s
        fix = not (no_fix and no_fix[0] <= te < no_fix[1])
        assert f["fix"] == fix
        if fix:
            ref = fix_at(te)
            assert abs(f["lat"] - ref.lat_deg[0]) <= 0.6e-7
            assert abs(f["lon"] - ref.lon_deg[0]) <= 0.6e-7
            assert f["alt"] == pytest.approx(ALT0_M + GEOID_M, abs=1e-3)  # above the ellipsoid
            assert 0.0 < f["var_h"] < 25.0 and 0.0 < f["var_v"] < 100.0


@pytest.mark.parametrize("generation, baud", [("M8", 9600), ("M9", 38400)])
def test_ublox_gps_configures_the_module_and_publishes_its_fixes(generation, baud):
    """ublox_gps with its defaults (GPS alone) against a NEO-M8N at 9600 and a NEO-M9N at
    38400 (each profile's power-on baud, given as ``uart1/baudrate``): every configuration it
    must have ACKed is ACKed within its 1 s; MON-VER gives protocol 18 (firmware class 8) and
    32.01 (9, which ROS 1 treats as 8); the module's GNSS differ from GPS alone, so it sets
    CFG-GNSS, cold-starts the GNSS, waits 16 s and finds the port again at its baud; then a
    NavSatFix per NAV-PVT at 4 Hz, the M9's stamped with its own UTC (confirmedAvailable, a
    protocol 19+ flag), the M8's with the host's clock, as a real NEO-M8N's are; two seconds
    without a fix published as NO_FIX."""
    mod = Module(generation, no_fix=(30.0, 32.0))
    drv = RosUblox(mod, baud=baud)
    drv.start()
    assert drv.log == [
        ("CFG-PRT", "ACK"), ("MON-VER", "ACK"), ("CFG-RATE", "ACK"), ("CFG-SBAS", "ACK"),
        ("CFG-NAVX5", "ACK"), ("CFG-NAV5 dynModel", "ACK"), ("CFG-NAV5 fixMode", "ACK"),
        ("CFG-NAV5 drLimit", "ACK"), ("CFG-GNSS poll", "ACK"), ("CFG-GNSS", "ACK"),
        ("CFG-RST", "sent"), ("CFG-PRT poll", "ACK"), ("CFG-MSG NAV-PVT", "ACK"),
        ("CFG-INF", "ACK")]
    assert (drv.protocol, drv.firmware) == ((18.0, 8) if generation == "M8" else (32.01, 9))
    assert drv.host_baud == baud and "SBAS" in drv.supported
    s = mod.link.settings
    assert {GNSS_IDS[b.gnss_id] for b in s.gnss if b.enabled} == {"gps"}
    assert (s.meas_rate_ms, s.nav_rate, s.time_ref, s.dyn_model, s.nav5.fix_mode) == (
        250, 1, 1, 0, 3)
    assert s.ports[1].out_proto == 0x01  # UBX alone: NMEA off
    drv.run(20.0)
    check_fixes(drv, no_fix=(30.0, 32.0))
    # (without a fix NAV-PVT's time is not fully resolved: the driver takes the host's clock)
    assert all(f["utc_stamp"] == (generation == "M9" and f["fix"]) for f in drv.fixes)
    assert sum(not f["fix"] for f in drv.fixes) == 8  # the two seconds without a fix
    assert mod.link.internal_errors == 0


def test_ublox_gps_leaves_a_module_whose_gnss_it_wants_alone():
    """With ``gnss/*`` as the module has them (the M8's GPS, SBAS, QZSS and GLONASS), no
    CFG-GNSS is set and no cold start asked: the fixes come from the first second."""
    mod = Module("M8")
    drv = RosUblox(mod, baud=9600, rate_hz=1.0,
                   gnss={"gps": True, "sbas": True, "qzss": True, "glonass": True})
    drv.start()
    assert ("CFG-RST", "sent") not in drv.log and ("CFG-GNSS", "ACK") not in drv.log
    assert all(outcome == "ACK" for _, outcome in drv.log)
    drv.run(5.0)
    check_fixes(drv)
    assert len(drv.fixes) == 5


def test_ros2_m9_sets_its_signals_with_cfg_valset():
    """ROS 2's firmware-9 path polls CFG-GNSS, then sets the signals with CFG-VALSET without
    awaiting its ACK: the module must take every key (a NAK would leave the systems as they
    were, unnoticed). GPS and its SBAS stay, Galileo, BeiDou, QZSS and GLONASS go."""
    mod = Module("M9")
    drv = RosUblox(mod, baud=38400, ros2=True)
    drv.start()
    assert ("CFG-VALSET signals", "sent") in drv.log
    naks = [r for _, r in mod.replies if r[2:4] == bytes((CLS_ACK, 0x00))]
    assert not naks
    enabled = {GNSS_IDS[b.gnss_id] for b in mod.link.settings.gnss if b.enabled}
    assert enabled == {"gps", "sbas"}
    drv.run(5.0)
    check_fixes(drv)


def test_a_wrong_uart1_baudrate_is_fatal_as_on_a_real_module():
    """ublox_gps does not search for the module's baud: ``uart1/baudrate`` 38400 against a
    NEO-M8N at its power-on 9600 sends CFG-PRT at 38400 (noise to the module), gets no ACK and
    dies ("Could not configure serial baud rate"). docs/device.md says to give the profile's
    baud."""
    mod = Module("M8")
    drv = RosUblox(mod, baud=38400)
    with pytest.raises(DriverDied, match="Could not configure serial baud rate"):
        drv.start()
    assert drv.log == [("CFG-PRT", "timeout")] and mod.noise_bytes > 0


@pytest.mark.e2e
def test_ublox_gps_m9_sequence_on_the_daemon(tmp_path):
    """``virtualgps run --profile ublox-m9n`` on a pty answers ublox_gps's start-up (ROS 1,
    ``gnss/*`` as the profile tracks them, so no cold start) in real time, each answer within
    its 1 s; then, once the receiver has started, NAV-PVT at 4 Hz (within the fix diagnostic's
    15 %) whose UTC stamps are at most 1.15 periods older than their arrival on the host's
    clock (the daemon's clock is the host's): the driver's fix diagnostic stays OK."""
    from test_ubx_device import _daemon, _open, _read_for
    from test_ubx_px4 import _await

    daemon = _daemon(tmp_path, "ublox-m9n")
    try:
        fd = _open(daemon.link)
        try:
            _read_for(fd, 1.0)
            scanner, frames, got = Scanner(), [], []
            nav5 = [bytearray(36) for _ in range(3)]
            for buf, (mask, off, value) in zip(nav5, ((1, 2, 0), (4, 3, 3), (8, 13, 0)),
                                               strict=True):
                buf[0:2] = struct.pack("<H", mask)
                buf[off] = value
            steps = [
                ((CLS_CFG, CFG_PRT), struct.pack("<BBHIIHHHH", 1, 0, 0, ROS_PRT_MODE, 38400,
                                                 ROS_UART1_IN, ROS_UART1_OUT, 0, 0)),
                ((CLS_MON, MON_VER), b""),
                ((CLS_CFG, CFG_RATE), struct.pack("<HHH", 250, 1, 1)),
                ((CLS_CFG, CFG_SBAS), bytes(8)),
                ((CLS_CFG, CFG_NAVX5), struct.pack("<HHI", 0, 0x2000, 0) + bytes(32)),
                *(((CLS_CFG, CFG_NAV5), bytes(b)) for b in nav5),
                ((CLS_CFG, CFG_GNSS), b""),
                ((CLS_CFG, CFG_MSG), bytes((CLS_NAV, NAV_PVT, 1))),
                ((CLS_CFG, CFG_INF), b"".join(bytes((proto, 0, 0, 0)) + bytes((0x0F,) * 6)
                                              for proto in (0, 1))),
            ]
            for want, payload in steps:
                os.write(fd, ubx(*want, payload))
                poll = want in ((CLS_MON, MON_VER), (CLS_CFG, CFG_GNSS))
                outcome, dt = _await(fd, scanner, want, ROS_ACK_TIMEOUT_S, frames)
                if poll and want != (CLS_MON, MON_VER):  # the answer comes before its ACK
                    outcome = "ACK" if any((c, i) == want for c, i, _ in frames) else "timeout"
                got.append((want, outcome, dt))
                assert outcome == "ACK", got
            blocks = next(p for c, i, p in frames if (c, i) == (CLS_CFG, CFG_GNSS))
            enabled = {GNSS_IDS[blocks[j]] for j in range(4, len(blocks), 8)
                       if blocks[j + 4] & 1}
            # the systems the profile tracks (docs/device.md: gnss/* set so, the driver
            # leaves them alone)
            assert enabled == {"gps", "glonass", "galileo", "beidou"}
            drv = RosUblox(Module("M9"), baud=38400)
            wall0 = time.time()
            for rel_s, data in read_timed(fd, 8.0):  # (the receiver's start-up, then fixes)
                for c, i, p in scanner.feed(data):
                    if (c, i) == (CLS_NAV, NAV_PVT):
                        drv.t = wall0 + rel_s - T0_UNIX_S
                        drv.fixes.append(drv.nav_sat_fix(p))
        finally:
            os.close(fd)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    # the receiver's start-up (the profile's TTFF) may take the first; then every one a fix
    first = next(k for k, f in enumerate(drv.fixes) if f["fix"])
    fixed = drv.fixes[first:]
    assert len(fixed) >= 12 and all(f["fix"] for f in fixed)  # 3 s or more of them
    rate_hz = (len(fixed) - 1) / (fixed[-1]["arrival"] - fixed[0]["arrival"])
    assert abs(rate_hz - 4.0) <= ROS_FREQ_TOL * 4.0, rate_hz
    assert all(f["utc_stamp"] == f["fix"] for f in drv.fixes)
    delays = np.array([f["arrival"] - f["stamp"] for f in drv.fixes if f["utc_stamp"]])
    # (a real-time check on a shared machine: a scheduling hiccup may delay one read)
    assert (delays >= 0.0).all() and np.median(delays) < 0.1, delays
    assert np.mean(delays <= ROS_FIX_DELAY_TOL * 0.25) >= 0.9, delays
