"""The u-blox emulation against PX4's u-blox driver's configuration sequences.

PX4 cannot be installed here, so its driver's u-blox logic is re-written below as a small model
(our code, not theirs) that writes the bytes the driver writes, in its order, at its baud rates,
and judges every answer the way the driver does: an ACK within the driver's timeout where it waits
for one, the MON-VER fields it parses, the NAV/MON messages it needs at the rate it asked for with
the fields it reads, its "configured" test, its timeouts and resets. The model drives the pure
:class:`~virtualgps.device.ubx.link.UbxLink` through the simulated UART of ``ubx_uart.py``. One
test drives the real daemon on a pty with PX4's M9 CFG-VALSET sequence.

Sources read (through the project's source index; every step below cites file and function):
PX4/PX4-GPSDrivers ``src/ubx.cpp`` at 00b9e7b71ca191a22cd9e9c7310609f3cf06ffb0 (2023: the M10
release, ``GPSDriverUBX(..., uart2_baudrate, mode)``), ``src/ubx.h`` (03a52f6: timeouts, key IDs,
payload layouts) and the ``src/ubx.cpp`` revision that merged PX4-GPSDrivers PR #189 (2025-10:
minimum C/N0 and elevation, DGNSS timeout, CFG-CFG wipe, SEC-JAMDET; the index's copy of it names
no commit). PX4/PX4-Autopilot ``src/drivers/gps/gps.cpp`` (TIMEOUT_5HZ, TIMEOUT_INIT_5HZ) and
``params.c`` (GPS_UBX_CFG_INTF default 0).
"""

from __future__ import annotations

import os
import select
import struct
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np
import pytest
from nmea_line import read_timed
from pyubx2 import UBXReader
from pyubx2.ubxtypes_configdb import UBX_CONFIG_DATABASE
from ubx_uart import (
    ACK_ACK,
    ALT0_M,
    CFG_CFG,
    CFG_GNSS,
    CFG_MSG,
    CFG_NAV5,
    CFG_PRT,
    CFG_RATE,
    CFG_RST,
    CFG_VALSET,
    CLS_ACK,
    CLS_CFG,
    CLS_MON,
    CLS_NAV,
    CLS_RXM,
    COURSE_DEG,
    MON_HW,
    MON_RF,
    MON_VER,
    N_USED,
    NAV_DOP,
    NAV_PVT,
    NAV_SAT,
    NAV_STATUS,
    NAV_SVINFO,
    RXM_RTCM,
    SPEED_MPS,
    T0_UNIX_S,
    Module,
    Scanner,
    fix_at,
    ubx,
)


def key_size(key_id: int) -> int:
    """Bytes of a configuration value from its key ID (size field, bits 28-30)."""
    return {1: 1, 2: 1, 3: 2, 4: 4, 5: 8}[(key_id >> 28) & 7]


def valset(items: list[tuple[int, int]], layers: int = 0x01) -> bytes:
    """A CFG-VALSET payload as PX4 builds it (GPSDriverUBX::initCfgValset / cfgValset): version
    0, the RAM layer, two reserved bytes, then each key and its little-endian value."""
    out = bytearray((0, layers, 0, 0))
    for key, value in items:
        out += struct.pack("<I", key) + int(value).to_bytes(key_size(key), "little")
    return bytes(out)


# --- PX4: PX4-GPSDrivers GPSDriverUBX ----------------------------------------------------------

#: GPSDriverUBX::configure: the baud rates tried, in this order.
PX4_BAUDS = (38400, 57600, 9600, 115200, 230400, 460800, 921600)
PX4_UBX_CONFIG_TIMEOUT_S = 0.250  # ubx.h UBX_CONFIG_TIMEOUT: every waitForAck but one
PX4_VALSET_PROBE_TIMEOUT_S = 2.0  # configure(): the first CFG-VALSET ("M10 ... at 9600")
PX4_TIMEOUT_5HZ_S = 0.5  # PX4-Autopilot gps.cpp TIMEOUT_5HZ: 200 ms + 300 ms
PX4_TIMEOUT_INIT_5HZ_S = 1.5  # gps.cpp TIMEOUT_INIT_5HZ, until the receiver is healthy
PX4_TX_CFG_PRT_MODE = 0x000008D0  # ubx.h UBX_TX_CFG_PRT_MODE: 8N1
PX4_TX_CFG_PRT_BAUDRATE = 38400  # ubx.h: the first baud the legacy path switches to
PX4_BAUDRATE_M8_AND_NEWER = 115200  # ubx.h UBX_BAUDRATE_M8_AND_NEWER
PROTO_UBX, PROTO_RTCM3 = 0x01, 0x20  # ubx.h UBX_TX_CFG_PRT_PROTO_UBX / _RTCM
GNSS_GPS, GNSS_SBAS, GNSS_GALILEO, GNSS_BEIDOU, GNSS_GLONASS = 1, 2, 4, 8, 16  # GNSSSystemsMask
STEP_S = 0.005  # the models' read step (PX4 reads in pieces; ArduPilot's loop runs faster)

#: Configuration keys PX4 sends, as src/ubx.h defines them (checked against pyubx2's database,
#: which transcribes u-blox's tables, in test_px4_key_ids_are_u_blox_s).
PX4_KEYS = {
    "UART1_BAUDRATE": 0x40520001, "UART1_STOPBITS": 0x20520002, "UART1_DATABITS": 0x20520003,
    "UART1_PARITY": 0x20520004, "UART1INPROT_UBX": 0x10730001, "UART1INPROT_NMEA": 0x10730002,
    "UART1INPROT_RTCM3X": 0x10730004, "UART1OUTPROT_UBX": 0x10740001,
    "UART1OUTPROT_NMEA": 0x10740002, "USBINPROT_UBX": 0x10770001, "USBINPROT_NMEA": 0x10770002,
    "USBINPROT_RTCM3X": 0x10770004, "USBOUTPROT_UBX": 0x10780001, "USBOUTPROT_NMEA": 0x10780002,
    "I2CINPROT_UBX": 0x10710001, "I2CINPROT_NMEA": 0x10710002, "I2CINPROT_RTCM3X": 0x10710004,
    "I2COUTPROT_UBX": 0x10720001, "I2COUTPROT_NMEA": 0x10720002,
    "NAVHPG_DGNSSMODE": 0x20140011, "NAVSPG_FIXMODE": 0x20110011,
    "NAVSPG_UTCSTANDARD": 0x2011001C, "NAVSPG_DYNMODEL": 0x20110021,
    "NAVSPG_INFIL_MINCNO": 0x201100A3, "NAVSPG_INFIL_MINELEV": 0x201100A4,
    "NAVSPG_CONSTR_DGNSSTO": 0x201100C4, "ODO_USE_ODO": 0x10220001, "ODO_USE_COG": 0x10220002,
    "ODO_OUTLPVEL": 0x10220003, "ODO_OUTLPCOG": 0x10220004, "ITFM_ENABLE": 0x1041000D,
    "SEC_JAMDET_SENSITIVITY_HI": 0x10F60051, "RATE_MEAS": 0x30210001, "RATE_NAV": 0x30210002,
    "RATE_TIMEREF": 0x20210003, "MSGOUT_UBX_MON_RF_I2C": 0x20910359,
    "MSGOUT_UBX_NAV_SAT_I2C": 0x20910015, "MSGOUT_UBX_NAV_STATUS_I2C": 0x2091001A,
    "MSGOUT_UBX_NAV_DOP_I2C": 0x20910038, "MSGOUT_UBX_NAV_PVT_I2C": 0x20910006,
    "MSGOUT_UBX_RXM_RTCM_I2C": 0x20910268, "SIGNAL_GPS_ENA": 0x1031001F,
    "SIGNAL_SBAS_ENA": 0x10310020, "SIGNAL_SBAS_L1CA_ENA": 0x10310005,
    "SIGNAL_GAL_ENA": 0x10310021, "SIGNAL_BDS_ENA": 0x10310022, "SIGNAL_QZSS_ENA": 0x10310024,
    "SIGNAL_QZSS_L1CA_ENA": 0x10310012, "SIGNAL_QZSS_L1S_ENA": 0x10310014,
    "SIGNAL_GLO_ENA": 0x10310025, "SIGNAL_GLO_L1_ENA": 0x10310018,
}
K = PX4_KEYS


def cfg_prt_pair(baud: int) -> bytes:
    """PX4's two CFG-PRT blocks in one message (GPSDriverUBX::configure, ``cfg_prt[2]``): UART1
    and USB, mode 8N1, the baud, UBX + RTCM3 in, UBX out (OutputMode::GPS)."""
    return b"".join(struct.pack("<BBHIIHHHH", port, 0, 0, PX4_TX_CFG_PRT_MODE, baud,
                                PROTO_UBX | PROTO_RTCM3, PROTO_UBX, 0, 0) for port in (1, 3))


@dataclass
class Px4Ubx:
    """GPSDriverUBX (PX4-GPSDrivers src/ubx.cpp) on a UART with automatic baud rate, output
    mode GPS, mode Normal, as PX4's gps driver starts it.

    revision : "2023" (00b9e7b) or "2025" (PR #189 merged: ``min_cno``, ``min_elev``,
        ``dgnss_timeout``, the separate ITFM and SEC-JAMDET messages, QZSS L1C/A + L1S and
        GLONASS L1 keys, CFG-CFG wipe)
    dyn_model : GPS_UBX_DYNMODEL (default 7, airborne < 2 g); gnss_systems : GPS_1_GNSS mask
        (default 0: leave the receiver's); sat_info : GPS_SAT_INFO (NAV-SAT / NAV-SVINFO on)
    """

    module: Module
    revision: str = "2023"
    dyn_model: int = 7
    gnss_systems: int = 0
    sat_info: bool = False
    min_cno: int = 0
    min_elev: int = 0
    dgnss_timeout: int = 0
    cfg_wipe: bool = False
    t: float = 0.0
    baud: int = 0
    configured: bool = False
    proto27: bool = False
    board: str = ""
    use_nav_pvt: bool = False
    log: list[tuple[str, str, float]] = field(default_factory=list)  # (what, outcome, latency s)
    mon_ver: dict = field(default_factory=dict)
    reports: list[dict] = field(default_factory=list)  # one per NAV-PVT handled (a gps report)
    seen: list[tuple[float, int, int, int]] = field(default_factory=list)  # (t, cls, id, len)
    unexpected: list[tuple[int, int]] = field(default_factory=list)  # would be disabled
    state: dict = field(default_factory=dict)  # the other fields of sensor_gps / satellite_info

    def __post_init__(self) -> None:
        self.scanner = Scanner()

    # -- the UART --

    def set_baudrate(self, baud: int) -> None:
        """GPSHelper::setBaudrate, then decodeInit + receive(20) + decodeInit: flush."""
        self.baud = baud
        self.t += 0.020
        self.module.read(self.baud, self.t)
        self.scanner = Scanner()

    def send(self, cls: int, mid: int, payload: bytes = b"") -> None:
        """GPSDriverUBX::sendMessage."""
        self.module.write(ubx(cls, mid, payload), self.baud, self.t)

    def frames(self) -> list[tuple[int, int, bytes]]:
        return self.scanner.feed(self.module.read(self.baud, self.t))

    def wait_for_ack(self, cls: int, mid: int, timeout_s: float, what: str) -> int:
        """GPSDriverUBX::waitForAck: 0 on an ACK-ACK for (cls, id) (or, for MON-VER, on MON-VER
        itself: payloadRxDone sets the ack state), -1 on its NAK or on the timeout."""
        t0, outcome = self.t, "timeout"
        while self.t < t0 + timeout_s - 1e-9 and outcome == "timeout":
            self.t = min(self.t + STEP_S, t0 + timeout_s)
            for c, i, p in self.frames():
                if c == CLS_ACK and len(p) == 2 and (p[0], p[1]) == (cls, mid):
                    outcome = "ACK" if i == ACK_ACK else "NAK"
                    break
                if (c, i) == (CLS_MON, MON_VER):
                    self.handle_mon_ver(p)
                    if (cls, mid) == (CLS_MON, MON_VER):
                        outcome = "ACK"
                        break
                # (not _configured: NAV/MON output is ignored, payloadRxInit)
        self.log.append((what, outcome, self.t - t0))
        return 0 if outcome == "ACK" else -1

    def handle_mon_ver(self, p: bytes) -> None:
        """GPSDriverUBX::payloadRxAddMonVer: the board from hwVersion (strncmp over its 10
        bytes: the string must be NUL-terminated there), F9P from "MOD=", FWVER / PROTVER
        printed."""
        sw, hw = p[:30], p[30:40]
        boards = {b"00040005": "u_blox5", b"00040007": "u_blox6", b"00070000": "u_blox7",
                  b"00080000": "u_blox8", b"00190000": "u_blox9", b"000A0000": "u_blox10"}
        self.board = next((name for ver, name in boards.items()
                           if hw == ver + bytes(10 - len(ver))), "unknown")
        exts = [p[j:j + 30].split(b"\0")[0].decode() for j in range(40, len(p), 30)]
        mod = next((e[4:] for e in exts if e.startswith("MOD=")), "")
        if self.board == "u_blox9" and "F9P" in mod:
            self.board = "u_blox9_F9P"
        self.mon_ver = {"sw": sw.split(b"\0")[0].decode(), "hw": hw.split(b"\0")[0].decode(),
                        "FWVER": next((e[6:] for e in exts if e.startswith("FWVER=")), None),
                        "PROTVER": next((e[8:] for e in exts if e.startswith("PROTVER=")), None),
                        "MOD": mod}

    # -- GPSDriverUBX::configure --

    def configure(self) -> int:
        """GPSDriverUBX::configure for Interface::UART, baudrate 0 (auto), OutputMode::GPS."""
        self.configured = False
        desired = PX4_BAUDRATE_M8_AND_NEWER
        for test_baud in PX4_BAUDS:
            self.set_baudrate(test_baud)
            if self.cfg_wipe and self.revision == "2025":
                # (2025) CFG-CFG clear all, load all, waited for 2 s
                self.send(CLS_CFG, CFG_CFG, struct.pack("<IIIB", 0xFFFFFFFF, 0, 0xFFFFFFFF, 0))
                if self.wait_for_ack(CLS_CFG, CFG_CFG, 2.0, "CFG-CFG wipe") < 0:
                    continue
            # try CFG-VALSET: an ACK means protocol 27+
            self.send(CLS_CFG, CFG_VALSET, valset([
                (K["UART1_STOPBITS"], 1), (K["UART1_DATABITS"], 0), (K["UART1_PARITY"], 0),
                (K["UART1INPROT_UBX"], 1), (K["UART1INPROT_NMEA"], 0),
                (K["UART1OUTPROT_UBX"], 1), (K["UART1OUTPROT_NMEA"], 0)]))
            if self.wait_for_ack(CLS_CFG, CFG_VALSET, PX4_VALSET_PROBE_TIMEOUT_S,
                                 f"VALSET probe @{test_baud}") == 0:
                self.proto27 = True
                self.send(CLS_CFG, CFG_VALSET, valset([(K["UART1_BAUDRATE"], desired)]))
                self.wait_for_ack(CLS_CFG, CFG_VALSET, PX4_UBX_CONFIG_TIMEOUT_S,
                                  "VALSET UART1 baud (no ACK expected)")
            else:
                self.proto27 = False
                self.send(CLS_CFG, CFG_PRT, cfg_prt_pair(test_baud))
                if self.wait_for_ack(CLS_CFG, CFG_PRT, PX4_UBX_CONFIG_TIMEOUT_S,
                                     f"CFG-PRT @{test_baud}") < 0:
                    continue  # try the next baud rate
                desired = PX4_TX_CFG_PRT_BAUDRATE
                self.send(CLS_CFG, CFG_PRT, cfg_prt_pair(desired))
                self.wait_for_ack(CLS_CFG, CFG_PRT, PX4_UBX_CONFIG_TIMEOUT_S,
                                  f"CFG-PRT to {desired} (no ACK expected)")
            if desired != test_baud:
                self.set_baudrate(desired)
            break
        else:
            return -1  # connection and/or baud rate detection failed
        self.send(CLS_MON, MON_VER)
        if self.wait_for_ack(CLS_MON, MON_VER, PX4_UBX_CONFIG_TIMEOUT_S, "MON-VER") < 0:
            return -1
        if self.board == "u_blox8":  # now that the board is known: M8 to 115200
            self.send(CLS_CFG, CFG_PRT, cfg_prt_pair(PX4_BAUDRATE_M8_AND_NEWER))
            self.wait_for_ack(CLS_CFG, CFG_PRT, PX4_UBX_CONFIG_TIMEOUT_S,
                              "CFG-PRT to 115200 (no ACK expected)")
            self.baud = PX4_BAUDRATE_M8_AND_NEWER
            self.scanner = Scanner()
        ret = self.configure_device() if self.proto27 else self.configure_device_pre_v27()
        if ret != 0:
            return ret
        self.configured = True
        return 0

    def required(self, cls: int, mid: int, payload: bytes, what: str) -> bool:
        """Send, and waitForAck(..., UBX_CONFIG_TIMEOUT, true) must return 0."""
        self.send(cls, mid, payload)
        return self.wait_for_ack(cls, mid, PX4_UBX_CONFIG_TIMEOUT_S, what) == 0

    def configure_device_pre_v27(self) -> int:
        """GPSDriverUBX::configureDevicePreV27: CFG-RATE, CFG-NAV5, CFG-GNSS, then CFG-MSG for
        each message (the 3-byte form: this port's rate)."""
        if not self.required(CLS_CFG, CFG_RATE, struct.pack("<HHH", 200, 1, 0), "CFG-RATE"):
            return -1
        nav5 = struct.pack("<HBB", 0x0005, self.dyn_model, 2) + bytes(32)  # mask dyn+posFix
        if not self.required(CLS_CFG, CFG_NAV5, nav5, "CFG-NAV5"):
            return -1
        if self.gnss_systems:
            gps_on = self.gnss_systems & GNSS_GPS
            blocks = [(0, 8, 16, 0x00010001) if gps_on else (0, 0, 0, 0),
                      (5, 0, 3, 0x00010001) if gps_on else (5, 0, 0, 0),
                      (1, 1, 3, 0x00010001) if self.gnss_systems & GNSS_SBAS else (1, 0, 0, 0),
                      (2, 4, 8, 0x00010001) if self.gnss_systems & GNSS_GALILEO else (2, 0, 0, 0),
                      (3, 8, 16, 0x00010001) if self.gnss_systems & GNSS_BEIDOU else (3, 0, 0, 0),
                      (6, 8, 14, 0x00010001) if self.gnss_systems & GNSS_GLONASS
                      else (6, 0, 0, 0),
                      (4, 0, 0, 0)]  # IMES always disabled
            gnss = struct.pack("<BBBB", 0, 0, 0xFF, 7) + b"".join(
                struct.pack("<BBBxI", *b) for b in blocks)
            if not self.required(CLS_CFG, CFG_GNSS, gnss, "CFG-GNSS"):
                return -1
        self.send(CLS_CFG, CFG_MSG, bytes((CLS_NAV, NAV_PVT, 1)))
        self.use_nav_pvt = self.wait_for_ack(CLS_CFG, CFG_MSG, PX4_UBX_CONFIG_TIMEOUT_S,
                                             "CFG-MSG NAV-PVT 1") == 0
        if not self.use_nav_pvt:  # (u-blox 6: NAV-TIMEUTC, POSLLH, SOL, VELNED instead)
            return -1
        for (cls, mid), rate, what in (((CLS_NAV, NAV_STATUS), 1, "NAV-STATUS"),
                                       ((CLS_NAV, NAV_DOP), 1, "NAV-DOP"),
                                       ((CLS_NAV, NAV_SVINFO), 5 if self.sat_info else 0,
                                        "NAV-SVINFO"),
                                       ((CLS_MON, MON_HW), 1, "MON-HW")):
            if not self.required(CLS_CFG, CFG_MSG, bytes((cls, mid, rate)),
                                 f"CFG-MSG {what} {rate}"):
                return -1
        return 0

    def port_keys(self, i2c_key: int, value: int) -> list[tuple[int, int]]:
        """GPSDriverUBX::cfgValsetPort: a message's rate on UART1 (+1) and USB (+3)."""
        return [(i2c_key + 1, value), (i2c_key + 3, value)]

    def configure_device(self) -> int:
        """GPSDriverUBX::configureDevice (protocol 27+), board u_blox9, mode Normal."""
        new = self.revision == "2025"
        if not self.required(CLS_CFG, CFG_VALSET, valset([
                (K["UART1INPROT_RTCM3X"], 1), (K["USBINPROT_UBX"], 1),
                (K["USBINPROT_RTCM3X"], 1), (K["USBINPROT_NMEA"], 0),
                (K["USBOUTPROT_UBX"], 1), (K["USBOUTPROT_NMEA"], 0)]), "VALSET ports"):
            return -1
        items = [(K["NAVSPG_FIXMODE"], 3), (K["NAVSPG_UTCSTANDARD"], 3),
                 (K["NAVSPG_DYNMODEL"], self.dyn_model)]
        if new:
            if self.min_cno:
                items.append((K["NAVSPG_INFIL_MINCNO"], self.min_cno))
            if self.min_elev:
                items.append((K["NAVSPG_INFIL_MINELEV"], self.min_elev))
            if self.dgnss_timeout:
                items.append((K["NAVSPG_CONSTR_DGNSSTO"], self.dgnss_timeout))
        items += [(K["ODO_USE_ODO"], 0), (K["ODO_USE_COG"], 0), (K["ODO_OUTLPVEL"], 0),
                  (K["ODO_OUTLPCOG"], 0)]
        if not new:
            items.append((K["ITFM_ENABLE"], 1))
        rate_meas = 100 if self.board == "u_blox9_F9P" else 125  # 8 Hz on the M9
        items += [(K["RATE_MEAS"], rate_meas), (K["RATE_NAV"], 1), (K["RATE_TIMEREF"], 0)]
        if not self.required(CLS_CFG, CFG_VALSET, valset(items), "VALSET navigation + rate"):
            return -1
        # RTK (only RTK devices know it): the answer is read and ignored
        self.send(CLS_CFG, CFG_VALSET, valset([(K["NAVHPG_DGNSSMODE"], 3)]))
        self.wait_for_ack(CLS_CFG, CFG_VALSET, PX4_UBX_CONFIG_TIMEOUT_S,
                          "VALSET DGNSSMODE (optional)")
        if new:  # the jamming monitor, then the JAMDET sensitivity: both optional
            self.send(CLS_CFG, CFG_VALSET, valset([(K["ITFM_ENABLE"], 1)]))
            self.wait_for_ack(CLS_CFG, CFG_VALSET, PX4_UBX_CONFIG_TIMEOUT_S,
                              "VALSET ITFM (optional)")
            self.send(CLS_CFG, CFG_VALSET, valset([(K["SEC_JAMDET_SENSITIVITY_HI"], 0)]))
            self.wait_for_ack(CLS_CFG, CFG_VALSET, PX4_UBX_CONFIG_TIMEOUT_S,
                              "VALSET SEC-JAMDET (optional)")
        if self.gnss_systems:
            g = self.gnss_systems
            items = [(K["SIGNAL_GPS_ENA"], int(bool(g & GNSS_GPS))),
                     (K["SIGNAL_QZSS_ENA"], int(bool(g & GNSS_GPS)))]
            if new and g & GNSS_GPS:
                items += [(K["SIGNAL_QZSS_L1CA_ENA"], 1), (K["SIGNAL_QZSS_L1S_ENA"], 1)]
            items += [(K["SIGNAL_GAL_ENA"], int(bool(g & GNSS_GALILEO))),
                      (K["SIGNAL_BDS_ENA"], int(bool(g & GNSS_BEIDOU))),
                      (K["SIGNAL_GLO_ENA"], int(bool(g & GNSS_GLONASS)))]
            if new and g & GNSS_GLONASS:
                items.append((K["SIGNAL_GLO_L1_ENA"], 1))
            if not self.required(CLS_CFG, CFG_VALSET, valset(items), "VALSET GNSS"):
                return -1
            sbas = ([(K["SIGNAL_SBAS_ENA"], 1), (K["SIGNAL_SBAS_L1CA_ENA"], 1)]
                    if g & GNSS_SBAS else [(K["SIGNAL_SBAS_ENA"], 0)])
            self.send(CLS_CFG, CFG_VALSET, valset(sbas))  # sent alone; the answer is ignored
            self.wait_for_ack(CLS_CFG, CFG_VALSET, PX4_UBX_CONFIG_TIMEOUT_S, "VALSET SBAS")
        items = (self.port_keys(K["MSGOUT_UBX_NAV_PVT_I2C"], 1)
                 + self.port_keys(K["MSGOUT_UBX_NAV_DOP_I2C"], 1)
                 + self.port_keys(K["MSGOUT_UBX_NAV_SAT_I2C"], 10 if self.sat_info else 0)
                 + self.port_keys(K["MSGOUT_UBX_NAV_STATUS_I2C"], 1)
                 + self.port_keys(K["MSGOUT_UBX_MON_RF_I2C"], 1)
                 + self.port_keys(K["MSGOUT_UBX_RXM_RTCM_I2C"], 1))  # (u_blox9 / F9P)
        self.use_nav_pvt = True
        if not self.required(CLS_CFG, CFG_VALSET, valset(items), "VALSET message rates"):
            return -1
        # I2C protocols from GPS_UBX_CFG_INTF (default 0: all off); each value is the mask
        # bit itself (InterfaceProtocolsMask & bit), 0 with the default.
        intf = 0
        items = [(K["I2CINPROT_UBX"], intf & 1), (K["I2CINPROT_NMEA"], intf & 2),
                 (K["I2CINPROT_RTCM3X"], intf & 4), (K["I2COUTPROT_UBX"], intf & 8),
                 (K["I2COUTPROT_NMEA"], intf & 16)]
        if not self.required(CLS_CFG, CFG_VALSET, valset(items), "VALSET I2C protocols"):
            return -1
        return 0

    # -- after configure: GPSDriverUBX::receive / payloadRxInit / payloadRxDone --

    def run(self, seconds: float) -> str:
        """PX4's gps driver loop after configure: receive() until a NAV-PVT (it sets
        _got_posllh and _got_velned) or the timeout; "timeout" makes the driver reset and
        configure again (gps.cpp). Returns "ok" or "timeout"."""
        t_end = self.t + seconds
        last = self.t
        timeout = PX4_TIMEOUT_INIT_5HZ_S if not self.reports else PX4_TIMEOUT_5HZ_S
        while self.t < t_end:
            self.t += STEP_S
            for c, i, p in self.frames():
                self.seen.append((self.t, c, i, len(p)))
                if self.handle(c, i, p):
                    last = self.t
                    timeout = PX4_TIMEOUT_5HZ_S
            if self.t - last > timeout:
                return "timeout"
        return "ok"

    def handle(self, c: int, i: int, p: bytes) -> bool:
        """payloadRxInit's length checks and payloadRxDone's decoding; True for a NAV-PVT."""
        n = len(p)
        if (c, i) == (CLS_NAV, NAV_PVT):
            assert n in (84, 92), f"NAV-PVT of {n} bytes: invalid len"
            (itow, year, month, day, hour, minute, sec, valid, _tacc, nano, fix_type, flags, _,
             num_sv, lon, lat, height, hmsl, hacc, vacc, vn, ve, vd, gspeed, head, sacc,
             headacc, pdop) = struct.unpack_from("<IHBBBBBBIiBBBBiiiiIIiiiiiIIH", p)
            fix_ok = flags & 0x01 == 1
            fix = fix_type if fix_ok else 0
            if fix_ok and flags & 0x02:
                fix = 4  # DGPS
            carr = flags >> 6
            fix = {1: 5, 2: 6}.get(carr, fix) if fix_ok else fix
            report = {"t": self.t, "iTOW": itow, "fix_type": fix, "vel_ned_valid": fix_ok,
                      "satellites_used": num_sv, "lat": lat * 1e-7, "lon": lon * 1e-7,
                      "alt": hmsl * 1e-3, "alt_ellipsoid": height * 1e-3, "eph": hacc * 1e-3,
                      "epv": vacc * 1e-3, "s_variance": sacc * 1e-3, "vel_m_s": gspeed * 1e-3,
                      "vel_n": vn * 1e-3, "vel_e": ve * 1e-3, "vel_d": vd * 1e-3,
                      "cog_deg": head * 1e-5, "c_variance_deg": headacc * 1e-5,
                      "time_utc": None}
            if valid & 0x07 == 0x07:  # validDate, validTime, fullyResolved
                report["time_utc"] = datetime(year, month, day, hour, minute, sec,
                                              tzinfo=UTC).timestamp() + nano * 1e-9
            report.update(self.state)
            self.reports.append(report)
            return True
        if (c, i) == (CLS_NAV, NAV_DOP):
            assert n == 18, "NAV-DOP invalid len"
            _, _, _, _, vdop, hdop, _, _ = struct.unpack("<I7H", p)
            self.state.update(hdop=hdop * 0.01, vdop=vdop * 0.01)
        elif (c, i) == (CLS_NAV, NAV_STATUS):
            assert n == 16, "NAV-STATUS invalid len"
            self.state["spoofing_state"] = (p[7] & 0x18) >> 3  # flags2 spoofDetState
        elif (c, i) in ((CLS_NAV, NAV_SAT), (CLS_NAV, NAV_SVINFO)):
            assert self.sat_info, "NAV-SAT/SVINFO without sat info: would be disabled"
            count = p[5] if i == NAV_SAT else p[4]
            assert n == 8 + 12 * count
            sats = []
            for j in range(count):
                r = p[8 + 12 * j: 20 + 12 * j]
                if i == NAV_SAT:
                    gnss, sv, cno, elev, azim, _, flags = struct.unpack("<BBBbhhI", r)
                    svid = {0: sv, 1: sv, 2: sv + 210, 5: sv + 192, 6: sv + 64}.get(gnss, 255)
                    # PX4 takes "used" from flags bit 0, which is qualityInd's low bit, not
                    # svUsed (bit 3): it comes out right where used satellites have quality 7
                    # (code and carrier locked) and tracked ones 4, as ours have.
                    used = flags & 0x01 != 0
                else:
                    _, svid, flags, _, cno, elev, azim, _ = struct.unpack("<BBBBBbhi", r)
                    used = flags & 0x01 != 0
                sats.append((svid, used, elev, azim, cno))
            self.state["satellites"] = sats
        elif (c, i) == (CLS_MON, MON_HW):
            assert n in (60, 68), "MON-HW invalid len"
            noise, agc = struct.unpack_from("<HH", p, 16)
            self.state.update(noise_per_ms=noise, agc=agc, jamming_indicator=p[45 if n == 60
                                                                               else 53])
        elif (c, i) == (CLS_MON, MON_RF):
            assert n >= 28 and (n - 4) % 24 == 0, "MON-RF invalid len"
            self.state.update(noise_per_ms=struct.unpack_from("<H", p, 16)[0],
                              jamming_indicator=p[20], jamming_state=p[5])
        elif (c, i) == (CLS_RXM, RXM_RTCM):
            assert n >= 8
        elif c == CLS_ACK or (c, i) == (CLS_MON, MON_VER):
            pass  # ACKs are ignored once configured; MON-VER is handled unconditionally
        else:
            # payloadRxInit: UBX_RXMSG_DISABLE (protocol < 27 sends CFG-MSG rate 0 for it)
            self.unexpected.append((c, i))
        return False

    def reset(self, navbbr: int) -> None:
        """GPSDriverUBX::reset: CFG-RST, software reset, no ACK awaited."""
        self.send(CLS_CFG, CFG_RST, struct.pack("<HBB", navbbr, 1, 0))


def px4_outcomes(drv: Px4Ubx) -> list[tuple[str, str]]:
    return [(what, outcome) for what, outcome, _ in drv.log]


def check_px4_reports(drv: Px4Ubx, period_ms: int) -> None:
    """What PX4 reads from NAV-PVT is the fix record's, and NAV-PVT comes every period."""
    reps = drv.reports
    assert len(reps) >= 5
    assert {b["iTOW"] - a["iTOW"] for a, b in zip(reps, reps[1:], strict=False)} == {period_ms}
    for r in reps:
        t_s = r["time_utc"] - T0_UNIX_S
        assert abs(t_s * 1000 - round(t_s * 1000)) < 1e-3  # whole ms, from the fix's time
        want = fix_at(t_s)
        assert r["fix_type"] == 3 and r["vel_ned_valid"] and r["satellites_used"] == N_USED
        assert abs(r["lat"] - want.lat_deg[0]) < 1.5e-7
        assert abs(r["lon"] - want.lon_deg[0]) < 1.5e-7
        assert abs(r["alt"] - ALT0_M) <= 1e-3 and abs(r["alt_ellipsoid"] - 141.0) <= 1e-3
        assert r["eph"] == pytest.approx(np.hypot(1.1, 1.3), abs=1e-3)
        assert r["epv"] == pytest.approx(2.0, abs=1e-3)
        assert r["vel_m_s"] == pytest.approx(SPEED_MPS, abs=1e-3)
        assert r["vel_n"] == pytest.approx(r["vel_e"], abs=2e-3) and r["vel_d"] == 0
        assert r["cog_deg"] == pytest.approx(COURSE_DEG, abs=1e-5)
        assert 0 < r["s_variance"] < 1 and 0 < r["c_variance_deg"] < 180
        assert r["hdop"] == pytest.approx(0.8) and r["vdop"] == pytest.approx(1.2)
    assert 0 < drv.state["noise_per_ms"] and drv.state["jamming_indicator"] < 255


# --- PX4 tests -------------------------------------------------------------------------------


def test_px4_key_ids_are_u_blox_s():
    """The key IDs the PX4 model sends (PX4-GPSDrivers src/ubx.h) are u-blox's, by name."""
    for name, key in PX4_KEYS.items():
        assert UBX_CONFIG_DATABASE["CFG_" + name][0] == key, name


@pytest.mark.parametrize("gnss_systems, sat_info", [
    (0, False),  # PX4's defaults: GPS_1_GNSS 0 (receiver's systems), GPS_SAT_INFO 0
    (GNSS_GPS | GNSS_SBAS | GNSS_GALILEO | GNSS_GLONASS, True),
])
def test_px4_configures_an_m8_on_the_legacy_path(gnss_systems, sat_info):
    """PX4-GPSDrivers GPSDriverUBX::configure + configureDevicePreV27 against a NEO-M8N at its
    power-on 9600 baud: the CFG-VALSET probe is NAKed (protocol 18), 38400 and 57600 time out
    (noise on the line), CFG-PRT at 9600 is ACKed, the port goes to 38400, MON-VER names a
    u-blox 8, the port goes to 115200, and every CFG it must have ACKed is ACKed."""
    mod = Module("M8")
    drv = Px4Ubx(mod, gnss_systems=gnss_systems, sat_info=sat_info)
    assert drv.configure() == 0
    want = [("VALSET probe @38400", "timeout"), ("CFG-PRT @38400", "timeout"),
            ("VALSET probe @57600", "timeout"), ("CFG-PRT @57600", "timeout"),
            ("VALSET probe @9600", "NAK"), ("CFG-PRT @9600", "ACK"),
            ("CFG-PRT to 38400 (no ACK expected)", "ACK"), ("MON-VER", "ACK"),
            ("CFG-PRT to 115200 (no ACK expected)", "ACK"),
            ("CFG-RATE", "ACK"), ("CFG-NAV5", "ACK")]
    want += [("CFG-GNSS", "ACK")] if gnss_systems else []
    want += [("CFG-MSG NAV-PVT 1", "ACK"), ("CFG-MSG NAV-STATUS 1", "ACK"),
             ("CFG-MSG NAV-DOP 1", "ACK"), (f"CFG-MSG NAV-SVINFO {5 if sat_info else 0}", "ACK"),
             ("CFG-MSG MON-HW 1", "ACK")]
    assert px4_outcomes(drv) == want
    # each awaited answer came within waitForAck's timeout (here: the first read step)
    assert all(dt <= PX4_UBX_CONFIG_TIMEOUT_S for _, o, dt in drv.log if o != "timeout")
    assert mod.noise_bytes > 0 and mod.link.internal_errors == 0
    assert drv.board == "u_blox8" and not drv.proto27 and drv.use_nav_pvt
    assert drv.mon_ver == {"sw": "ROM CORE 3.01 (107888)", "hw": "00080000",
                           "FWVER": "SPG 3.01", "PROTVER": "18.00", "MOD": ""}
    s = mod.link.settings
    assert (s.baud, s.meas_rate_ms, s.nav_rate, s.time_ref, s.dyn_model) == (115200, 200, 1, 0, 7)
    assert s.nav5.fix_mode == 2 and s.ports[1].out_proto == PROTO_UBX
    assert s.ports[3].in_proto == PROTO_UBX | PROTO_RTCM3  # USB too
    if gnss_systems:
        assert s.enabled_gnss == {"GPS", "QZSS", "SBAS", "Galileo", "GLONASS"}
    # configured: NAV-PVT every 200 ms with the fields PX4 reads; NAV-DOP, NAV-STATUS and
    # MON-HW every epoch; NAV-SVINFO every 5th; nothing it would disable; no NMEA
    assert drv.run(3.0) == "ok"
    check_px4_reports(drv, 200)
    kinds = {(c, i) for _, c, i, _ in drv.seen}
    want_kinds = {(CLS_NAV, NAV_PVT), (CLS_NAV, NAV_DOP), (CLS_NAV, NAV_STATUS), (CLS_MON, MON_HW)}
    assert kinds == want_kinds | ({(CLS_NAV, NAV_SVINFO)} if sat_info else set())
    assert not drv.unexpected
    per_epoch = [sum(1 for _, c, i, _ in drv.seen if (c, i) == k) for k in sorted(want_kinds)]
    assert max(per_epoch) - min(per_epoch) <= 1
    if sat_info:
        n_pvt = len(drv.reports)
        n_svinfo = sum(1 for _, c, i, _ in drv.seen if (c, i) == (CLS_NAV, NAV_SVINFO))
        assert abs(n_svinfo - n_pvt / 5) <= 1
        svids = {s[0] for s in drv.state["satellites"]}
        assert svids == {2, 5, 12, 15, 24, 29, 66, 70, 75, 213, 221, 131}
        assert sum(s[1] for s in drv.state["satellites"]) == N_USED


@pytest.mark.parametrize("revision, gnss_systems, extra", [
    ("2023", 0, {}),
    ("2023", GNSS_GPS | GNSS_SBAS | GNSS_GALILEO | GNSS_BEIDOU | GNSS_GLONASS,
     {"sat_info": True}),
    # PR #189's parameters set (GPS_UBX_MIN_CNO, _MIN_ELEV, _DGNSS_TO) and GPS_CFG_WIPE: the
    # batch carrying them must be ACKed, or PX4 gives up (it was NAKed before the fix)
    ("2025", GNSS_GPS | GNSS_SBAS | GNSS_GALILEO | GNSS_GLONASS,
     {"min_cno": 35, "min_elev": 15, "dgnss_timeout": 3, "cfg_wipe": True}),
])
def test_px4_configures_an_m9_with_cfg_valset(revision, gnss_systems, extra):
    """PX4-GPSDrivers GPSDriverUBX::configure + configureDevice against a NEO-M9N at its
    power-on 38400 baud: the CFG-VALSET probe is ACKed at the first baud tried, the port goes to
    115200 by CFG-VALSET, MON-VER names a u-blox 9 (not an F9P), and every batch PX4 needs ACKed
    is ACKed (the RTK key and SEC-JAMDET are NAKed, as an M9 does, which PX4 tolerates)."""
    mod = Module("M9")
    drv = Px4Ubx(mod, revision=revision, gnss_systems=gnss_systems, **extra)
    assert drv.configure() == 0
    new = revision == "2025"
    want = ([("CFG-CFG wipe", "ACK")] if extra.get("cfg_wipe") else [])
    want += [("VALSET probe @38400", "ACK"), ("VALSET UART1 baud (no ACK expected)", "ACK"),
             ("MON-VER", "ACK"), ("VALSET ports", "ACK"), ("VALSET navigation + rate", "ACK"),
             ("VALSET DGNSSMODE (optional)", "NAK")]
    want += ([("VALSET ITFM (optional)", "ACK"), ("VALSET SEC-JAMDET (optional)", "NAK")]
             if new else [])
    want += ([("VALSET GNSS", "ACK"), ("VALSET SBAS", "ACK")] if gnss_systems else [])
    want += [("VALSET message rates", "ACK"), ("VALSET I2C protocols", "ACK")]
    assert px4_outcomes(drv) == want
    assert all(dt <= PX4_UBX_CONFIG_TIMEOUT_S for _, _, dt in drv.log)
    assert drv.board == "u_blox9" and drv.proto27 and drv.configured
    assert drv.mon_ver == {"sw": "EXT CORE 4.04 (7f89f7)", "hw": "00190000",
                           "FWVER": "SPG 4.04", "PROTVER": "32.01", "MOD": "NEO-M9N"}
    s = mod.link.settings
    assert (s.baud, s.meas_rate_ms, s.nav_rate, s.time_ref) == (115200, 125, 1, 0)
    assert (s.dyn_model, s.nav5.fix_mode, s.nav5.utc_standard) == (7, 3, 3)
    assert s.ports[1].in_proto & 0x03 == PROTO_UBX and s.ports[1].out_proto == PROTO_UBX
    assert s.ports[0].in_proto & 0x07 == 0 and s.ports[0].out_proto == 0  # I2C: all off
    if extra.get("dgnss_timeout"):
        assert s.nav5.dgnss_timeout_s == 3 and s.nav5.min_elev_deg == 15
        assert dict(s.extra)[K["NAVSPG_INFIL_MINCNO"]] == 35
    if gnss_systems:
        want_gnss = {"GPS", "QZSS", "SBAS", "Galileo", "GLONASS"}
        assert s.enabled_gnss == want_gnss | ({"BeiDou"} if gnss_systems & GNSS_BEIDOU else set())
    assert drv.run(2.5) == "ok"
    check_px4_reports(drv, 125)  # 8 Hz
    kinds = {(c, i) for _, c, i, _ in drv.seen}
    want_kinds = {(CLS_NAV, NAV_PVT), (CLS_NAV, NAV_DOP), (CLS_NAV, NAV_STATUS), (CLS_MON, MON_RF)}
    # (RXM-RTCM comes only with RTCM input, as on the module)
    assert kinds == want_kinds | ({(CLS_NAV, NAV_SAT)} if extra.get("sat_info") else set())
    assert not drv.unexpected
    if extra.get("sat_info"):
        n_sat = sum(1 for _, c, i, _ in drv.seen if (c, i) == (CLS_NAV, NAV_SAT))
        assert abs(n_sat - len(drv.reports) / 10) <= 1
        assert sum(s[1] for s in drv.state["satellites"]) == N_USED
    assert drv.state["jamming_state"] == 1  # MON-RF flags: jammingState "ok"


def test_px4_m9_cold_reset_times_out_and_is_configured_again():
    """PX4's reset (GPSDriverUBX::reset: CFG-RST, software reset, no ACK) reloads the module's
    stored configuration (38400 baud, NMEA): NAV-PVT stops at 115200, the driver's receive times
    out after 500 ms (gps.cpp TIMEOUT_5HZ) and configure runs again from the baud probing, and
    succeeds. A no-fix stretch is reported as PX4 reads it: gnssFixOK 0, fix_type 0."""
    mod = Module("M9", no_fix=(4.0, 5.0))
    drv = Px4Ubx(mod)
    assert drv.configure() == 0 and drv.run(1.0) == "ok"
    drv.reset(0xFFFF)  # cold
    assert mod.baud == 38400 and mod.link.nmea_enabled()
    assert drv.run(2.0) == "timeout"
    drv.log.clear()
    assert drv.configure() == 0
    assert [w for w, o in px4_outcomes(drv) if o != "ACK"] == ["VALSET DGNSSMODE (optional)"]
    n = len(drv.reports)
    assert drv.run(3.0) == "ok"
    fixes = [r["fix_type"] for r in drv.reports[n:]]
    assert 0 in fixes and 3 in fixes
    assert all(r["eph"] > 4e6 for r in drv.reports[n:] if r["fix_type"] == 0)  # hAcc unknown


# --- PX4's M9 sequence through the real daemon on a pty --------------------------------------


def _await(fd: int, scanner: Scanner, want: tuple[int, int], timeout_s: float,
           frames: list | None = None) -> tuple[str, float]:
    """Read until an ACK/NAK for ``want`` (or, for MON-VER, MON-VER itself) or the timeout:
    (outcome, seconds). Frames read are appended to ``frames``."""
    t0 = time.monotonic()
    while (left := t0 + timeout_s - time.monotonic()) > 0:
        if not select.select([fd], [], [], left)[0]:
            continue
        try:
            data = os.read(fd, 65536)
        except BlockingIOError:
            continue
        for c, i, p in scanner.feed(data):
            if frames is not None:
                frames.append((c, i, p))
            if c == CLS_ACK and len(p) == 2 and (p[0], p[1]) == want:
                return ("ACK" if i == ACK_ACK else "NAK"), time.monotonic() - t0
            if (c, i) == want == (CLS_MON, MON_VER):
                return "ACK", time.monotonic() - t0
    return "timeout", timeout_s


@pytest.mark.e2e
def test_px4_m9_valset_sequence_on_the_daemon(tmp_path):
    """``virtualgps run --profile ublox-m9n`` on a pty answers PX4-GPSDrivers' M9 sequence
    (GPSDriverUBX::configure + configureDevice, 2023 revision, GPS_1_GNSS 0, GPS_SAT_INFO 0) in
    real time: each answer within PX4's waitForAck timeout (2 s for the first CFG-VALSET, 250 ms
    after), the port at 115200 after the baud CFG-VALSET, then only UBX: NAV-PVT every 125 ms
    (never more than gps.cpp's 500 ms apart), NAV-DOP, NAV-STATUS and MON-RF with it."""
    from test_ubx_device import _daemon, _open, _read_for

    daemon = _daemon(tmp_path, "ublox-m9n")
    try:
        fd = _open(daemon.link)
        try:
            _read_for(fd, 1.0)  # (the boot notices and NMEA; PX4 flushes with receive(20))
            scanner = Scanner()
            steps = [
                ("probe", (CLS_CFG, CFG_VALSET), PX4_VALSET_PROBE_TIMEOUT_S, valset([
                    (K["UART1_STOPBITS"], 1), (K["UART1_DATABITS"], 0), (K["UART1_PARITY"], 0),
                    (K["UART1INPROT_UBX"], 1), (K["UART1INPROT_NMEA"], 0),
                    (K["UART1OUTPROT_UBX"], 1), (K["UART1OUTPROT_NMEA"], 0)]), "ACK"),
                ("baud", (CLS_CFG, CFG_VALSET), PX4_UBX_CONFIG_TIMEOUT_S,
                 valset([(K["UART1_BAUDRATE"], 115200)]), None),
                ("MON-VER", (CLS_MON, MON_VER), PX4_UBX_CONFIG_TIMEOUT_S, None, "ACK"),
                ("ports", (CLS_CFG, CFG_VALSET), PX4_UBX_CONFIG_TIMEOUT_S, valset([
                    (K["UART1INPROT_RTCM3X"], 1), (K["USBINPROT_UBX"], 1),
                    (K["USBINPROT_RTCM3X"], 1), (K["USBINPROT_NMEA"], 0),
                    (K["USBOUTPROT_UBX"], 1), (K["USBOUTPROT_NMEA"], 0)]), "ACK"),
                ("navigation", (CLS_CFG, CFG_VALSET), PX4_UBX_CONFIG_TIMEOUT_S, valset([
                    (K["NAVSPG_FIXMODE"], 3), (K["NAVSPG_UTCSTANDARD"], 3),
                    (K["NAVSPG_DYNMODEL"], 7), (K["ODO_USE_ODO"], 0), (K["ODO_USE_COG"], 0),
                    (K["ODO_OUTLPVEL"], 0), (K["ODO_OUTLPCOG"], 0), (K["ITFM_ENABLE"], 1),
                    (K["RATE_MEAS"], 125), (K["RATE_NAV"], 1), (K["RATE_TIMEREF"], 0)]), "ACK"),
                ("DGNSSMODE", (CLS_CFG, CFG_VALSET), PX4_UBX_CONFIG_TIMEOUT_S,
                 valset([(K["NAVHPG_DGNSSMODE"], 3)]), "NAK"),
                ("rates", (CLS_CFG, CFG_VALSET), PX4_UBX_CONFIG_TIMEOUT_S, valset(
                    [(K[f"MSGOUT_UBX_{m}_I2C"] + d, r) for m, r in (
                        ("NAV_PVT", 1), ("NAV_DOP", 1), ("NAV_SAT", 0), ("NAV_STATUS", 1),
                        ("MON_RF", 1), ("RXM_RTCM", 1)) for d in (1, 3)]), "ACK"),
                ("I2C", (CLS_CFG, CFG_VALSET), PX4_UBX_CONFIG_TIMEOUT_S, valset(
                    [(K[k], 0) for k in ("I2CINPROT_UBX", "I2CINPROT_NMEA", "I2CINPROT_RTCM3X",
                                         "I2COUTPROT_UBX", "I2COUTPROT_NMEA")]), "ACK"),
            ]
            got, frames = [], []
            for name, want, timeout_s, payload, expect in steps:
                os.write(fd, ubx(*want, payload or b""))
                outcome, dt = _await(fd, scanner, want, timeout_s, frames)
                got.append((name, outcome, dt))
                if expect is not None:
                    assert outcome == expect, (name, outcome, got)
            ver = next(p for c, i, p in frames if (c, i) == (CLS_MON, MON_VER))
            assert ver[30:40] == b"00190000\0\0" and b"MOD=NEO-M9N" in ver[40:]
            # receive: NAV-PVT with its arrival time, for 3 s
            arrivals, stream = [], []
            for now, data in read_timed(fd, 3.0):
                for c, i, p in scanner.feed(data):
                    stream.append((c, i, p))
                    if (c, i) == (CLS_NAV, NAV_PVT):
                        arrivals.append((now, p))
        finally:
            os.close(fd)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    assert "client set the baud rate to 115200" in err
    assert "client set the navigation period to 125 ms" in err
    kinds = {(c, i) for c, i, _ in stream}
    assert kinds <= {(CLS_NAV, NAV_PVT), (CLS_NAV, NAV_DOP), (CLS_NAV, NAV_STATUS),
                     (CLS_MON, MON_RF)}, kinds
    assert {(CLS_NAV, NAV_PVT), (CLS_NAV, NAV_DOP), (CLS_NAV, NAV_STATUS),
            (CLS_MON, MON_RF)} <= kinds
    assert 18 <= len(arrivals) <= 26  # 8 Hz over 3 s
    assert all(len(p) == 92 for _, p in arrivals)
    itows = [struct.unpack_from("<I", p)[0] for _, p in arrivals]
    assert {b - a for a, b in zip(itows, itows[1:], strict=False)} == {125}
    gaps = [b - a for (a, _), (b, _) in zip(arrivals, arrivals[1:], strict=False)]
    assert max(gaps) < PX4_TIMEOUT_5HZ_S, gaps
    # every frame also parses with pyubx2 (an independent reader)
    for c, i, p in stream:
        UBXReader.parse(ubx(c, i, p))
