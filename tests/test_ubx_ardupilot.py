"""The u-blox emulation against ArduPilot's u-blox driver's detection and configuration.

ArduPilot cannot be installed here, so its driver's u-blox logic is re-written below as a small
model (our code, not theirs) that writes the bytes the driver writes, in its order, at its baud
rates, and judges every answer the way the driver does: the baud it finds the module at, the
messages it polls and sets until every item of its configuration is right, the MON-VER fields it
parses, the navigation messages it needs, its timeouts. The model drives the pure
:class:`~virtualgps.device.ubx.link.UbxLink` through the simulated UART of ``ubx_uart.py``.

Sources read (through the project's source index; every step below cites file and function):
ArduPilot/ardupilot ``libraries/AP_GPS/AP_GPS_UBLOX.cpp`` and ``.h`` (the 4.5-era revision with
STEP_M10 / STEP_L5, in which only F9 and M10 take CFG-VALGET/VALSET: an M9 is configured with the
legacy CFG messages, told from an M8 by MON-VER) and ``AP_GPS.cpp`` (``_detect_instance``, the
1.2 s baud probing with the UBLOX_SET_BINARY_230400 blob, the 4 s timeout).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from datetime import UTC, datetime

import pytest
from ubx_uart import (
    ACK_ACK,
    ACK_NAK,
    CFG_CFG,
    CFG_GNSS,
    CFG_MSG,
    CFG_NAV5,
    CFG_PRT,
    CFG_RATE,
    CFG_SBAS,
    CLS_ACK,
    CLS_CFG,
    CLS_MON,
    CLS_NAV,
    CLS_TIM,
    COURSE_DEG,
    GEOID_M,
    MON_HW,
    MON_HW2,
    MON_VER,
    N_USED,
    NAV_DOP,
    NAV_POSLLH,
    NAV_PVT,
    NAV_SOL,
    NAV_STATUS,
    NAV_SVINFO,
    NAV_TIMEGPS,
    NAV_VELNED,
    SPEED_MPS,
    T0_UNIX_S,
    TIM_TM2,
    Module,
    Scanner,
    acks_and_naks,
    ubx,
)

from virtualgps.device.nmea import nmea_checksum

# --- ArduPilot: AP_GPS / AP_GPS_UBLOX ---------------------------------------------------------

#: AP_GPS.cpp: the baud rates _detect_instance cycles through, 1.2 s each (GPS_BAUD_TIME_MS)
AP_BAUDS = (9600, 115200, 4800, 19200, 38400, 57600, 230400, 460800)
AP_BAUD_TIME_S = 1.2
AP_GPS_TIMEOUT_S = 4.0  # AP_GPS.cpp GPS_TIMEOUT_MS: no position for 4 s, detect again
AP_LOOP_S = 0.02  # AP_GPS::update's rate (50 Hz); read() runs each time
#: AP_GPS.h UBLOX_SET_BINARY_230400: CFG-MSG NAV-SOL rate 1, then $PUBX,41 (UBX + NMEA + RTCM3
#: in, UBX out, 230400 baud), the blob AP_GPS::send_blob_start writes at every probed baud
AP_INIT_BLOB = (b"\xb5\x62\x06\x01\x03\x00\x01\x06\x01\x12\x4f"
                b"$PUBX,41,1,0023,0001,230400,0*1E\r\n")
#: AP_GPS_UBLOX.h: the largest payload read (the _buffer union: RXM-RAWX of 32 satellites)
AP_BUFFER_BYTES = 16 + 32 * 32
# AP_GPS_UBLOX.h configuration bits and the rates it wants
CONFIG_RATE_NAV, CONFIG_RATE_POSLLH, CONFIG_RATE_STATUS, CONFIG_RATE_SOL = 1, 2, 4, 8
CONFIG_RATE_VELNED, CONFIG_RATE_DOP, CONFIG_RATE_MON_HW, CONFIG_RATE_MON_HW2 = 16, 32, 64, 128
CONFIG_RATE_RAW, CONFIG_VERSION, CONFIG_NAV_SETTINGS, CONFIG_GNSS = 256, 512, 1024, 2048
CONFIG_SBAS, CONFIG_RATE_PVT, CONFIG_RATE_TIMEGPS, CONFIG_TIM_TM2 = 4096, 8192, 1 << 15, 1 << 18
CONFIG_REQUIRED_INITIAL = (CONFIG_RATE_NAV | CONFIG_RATE_POSLLH | CONFIG_RATE_STATUS
                           | CONFIG_RATE_VELNED)
CONFIG_ALL = (CONFIG_RATE_NAV | CONFIG_RATE_POSLLH | CONFIG_RATE_STATUS | CONFIG_RATE_SOL
              | CONFIG_RATE_VELNED | CONFIG_RATE_DOP | CONFIG_RATE_MON_HW | CONFIG_RATE_MON_HW2
              | CONFIG_RATE_RAW | CONFIG_VERSION | CONFIG_NAV_SETTINGS | CONFIG_GNSS
              | CONFIG_SBAS)
SAVE_CFG_ALL = 0x1 | 0x2 | 0x4 | 0x8 | 0x10 | 0x200 | 0x400
UBLOX_M8, UBLOX_M9, UNKNOWN_GENERATION = 4, 0x81, 0xFF
#: AP_GPS_UBLOX.h enum config_step, in order (the revision with STEP_M10 and STEP_L5)
AP_STEPS = ("PVT", "NAV_RATE", "SOL", "PORT", "STATUS", "POSLLH", "VELNED", "TIMEGPS",
            "POLL_SVINFO", "POLL_SBAS", "POLL_NAV", "POLL_GNSS", "POLL_TP5", "TMODE", "DOP",
            "MON_HW", "MON_HW2", "RAW", "RAWX", "VERSION", "RTK_MOVBASE", "TIM_TM2", "M10", "L5",
            "LAST")
GNSS_ID_GALILEO, GNSS_ID_SBAS = 2, 1


@dataclass
class ArduPilotUblox:
    """AP_GPS's detection and the AP_GPS_UBLOX backend's configuration state machine with its
    defaults: GPS_AUTO_CONFIG 1, GPS_RATE_MS 200, GPS_NAVFILTER 8 (airborne < 4 g),
    GPS_MIN_ELEV -100 (leave), GPS_SBAS_MODE 2 (leave), GPS_GNSS_MODE 0 (leave),
    GPS_SAVE_CFG 2 (save when changed), GPS_RAW_DATA 0, TIM-TM2 logging built in (boards with
    more than 1 MB flash)."""

    module: Module
    gnss_mode: int = 0
    sbas_mode: int = 2
    navfilter: int = 8
    min_elevation: int = -100
    rate_ms: int = 200
    port_baud: int = 115200  # SERIALn_BAUD: the first probe is at the port's own rate
    t: float = 0.0
    baud: int = 0
    detected_at: float | None = None
    detected_baud: int = 0
    configured_at: float | None = None
    timeouts: int = 0
    unconfigured: int = CONFIG_ALL
    next_step: int = 0
    ublox_port: int = 255
    generation: int = UNKNOWN_GENERATION
    have_version: bool = False
    have_pvt: bool = False
    last_config_time: float = 0.0
    delay_time: float = 0.0
    cfg_needs_save: bool = False
    cfg_saved: bool = False
    save_tries: int = 0
    last_save_time: float = -10.0
    sent: list[tuple[float, int, int, bytes]] = field(default_factory=list)
    naks: list[tuple[int, int]] = field(default_factory=list)
    unexpected: list[tuple[int, int]] = field(default_factory=list)
    pvt: list[dict] = field(default_factory=list)
    seen: list[tuple[float, int, int]] = field(default_factory=list)
    state: dict = field(default_factory=dict)
    version: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.scanner = Scanner(AP_BUFFER_BYTES)
        self.new_position = self.new_speed = False
        self.last_pos_itow = self.last_vel_itow = -1
        self.last_message_time = 0.0

    def send(self, cls: int, mid: int, payload: bytes = b"") -> None:
        """AP_GPS_UBLOX::_send_message."""
        self.sent.append((self.t, cls, mid, payload))
        self.module.write(ubx(cls, mid, payload), self.baud, self.t)

    # -- AP_GPS::_detect_instance --

    def detect(self, limit_s: float) -> bool:
        """Probe baud rates every 1.2 s, writing the init blob at each; a u-blox is taken once
        any valid UBX frame arrives while probing at 230400 (with GPS_AUTO_CONFIG on and
        GPS_DRV_OPTIONS 0, detection needs 230400). Frames after it go to the backend."""
        probe, current, last_change = 0, 0, -1e9
        while self.t < limit_s:
            if self.t - last_change > AP_BAUD_TIME_S:
                if probe == 0:
                    probe = self.port_baud
                else:
                    current = (current + 1) % len(AP_BAUDS)
                    probe = AP_BAUDS[current]
                self.baud, last_change = probe, self.t
                self.scanner = Scanner(AP_BUFFER_BYTES)
                self.module.write(AP_INIT_BLOB, self.baud, self.t)
            frames = self.scanner.feed(self.module.read(self.baud, self.t))
            if frames and AP_BAUDS[current] == 230400:
                self.detected_at, self.detected_baud = self.t, self.baud
                self.last_message_time = self.t
                self.request_next_config()  # (the constructor starts the configuration)
                for f in frames[1:]:
                    self.parse(*f)
                return True
            self.t += AP_LOOP_S
        return False

    # -- AP_GPS_UBLOX::read --

    def run(self, seconds: float) -> None:
        """AP_GPS::update_instance at 50 Hz: the backend's read(), the 4 s timeout, and the
        configuration save once everything is configured."""
        t_end = self.t + seconds
        while self.t < t_end:
            self.t += AP_LOOP_S
            if self.t - self.last_config_time >= self.delay_time:
                self.request_next_config()
                self.last_config_time = self.t
                if self.unconfigured:
                    self.delay_time = (0.3 if not self.have_pvt
                                       and self.unconfigured & CONFIG_REQUIRED_INITIAL else 0.75)
                else:
                    self.delay_time = 2.0
            if (not self.unconfigured and not self.cfg_saved and self.save_tries < 5
                    and self.t - self.last_save_time > 5.0 and self.cfg_needs_save):
                self.send(CLS_CFG, CFG_CFG, struct.pack("<III", 0, SAVE_CFG_ALL, 0))  # _save_cfg
                self.last_save_time = self.t
                self.save_tries += 1
            result = False
            for f in self.scanner.feed(self.module.read(self.baud, self.t)):
                result |= self.parse(*f)
            if not self.unconfigured and self.configured_at is None:
                self.configured_at = self.t
            if result:
                self.last_message_time = self.t
            elif self.t - self.last_message_time > AP_GPS_TIMEOUT_S:
                self.timeouts += 1  # (the driver would be deleted and detection run again)
                self.last_message_time = self.t

    # -- AP_GPS_UBLOX::_request_next_config --

    def request_rate(self, cls: int, mid: int) -> bool:
        """_request_message_rate: poll CFG-MSG (2 bytes), once the port is known."""
        if self.ublox_port >= 6:
            self.send(CLS_CFG, CFG_PRT)  # _request_port
            return False
        self.send(CLS_CFG, CFG_MSG, bytes((cls, mid)))
        return True

    def request_next_config(self) -> None:
        if self.unconfigured == CONFIG_RATE_SOL and self.have_pvt:
            self.unconfigured &= ~CONFIG_RATE_SOL  # (PVT and TIMEGPS make SOL unnecessary)
        step = AP_STEPS[self.next_step]
        self.next_step += 1
        rates = {"PVT": (CLS_NAV, NAV_PVT), "SOL": (CLS_NAV, NAV_SOL),
                 "STATUS": (CLS_NAV, NAV_STATUS), "POSLLH": (CLS_NAV, NAV_POSLLH),
                 "VELNED": (CLS_NAV, NAV_VELNED), "TIMEGPS": (CLS_NAV, NAV_TIMEGPS),
                 "DOP": (CLS_NAV, NAV_DOP), "MON_HW": (CLS_MON, MON_HW),
                 "MON_HW2": (CLS_MON, MON_HW2), "TIM_TM2": (CLS_TIM, TIM_TM2)}
        if step in rates:
            if not self.request_rate(*rates[step]):
                self.next_step -= 1
        elif step == "NAV_RATE":
            self.send(CLS_CFG, CFG_RATE)
        elif step == "PORT":
            self.send(CLS_CFG, CFG_PRT)
        elif step == "POLL_SVINFO":
            if self.generation == UNKNOWN_GENERATION:
                self.send(CLS_NAV, NAV_SVINFO)
        elif step == "POLL_SBAS":
            if self.sbas_mode != 2:
                self.send(CLS_CFG, CFG_SBAS)
            else:
                self.unconfigured &= ~CONFIG_SBAS
        elif step == "POLL_NAV":
            self.send(CLS_CFG, CFG_NAV5)
        elif step == "POLL_GNSS":
            self.send(CLS_CFG, CFG_GNSS)
        elif step in ("RAW", "RAWX"):
            self.unconfigured &= ~CONFIG_RATE_RAW  # GPS_RAW_DATA 0
        elif step == "VERSION":
            if not self.have_version:
                self.send(CLS_MON, MON_VER)  # _request_version
            else:
                self.unconfigured &= ~CONFIG_VERSION
        elif step == "LAST":
            self.next_step = 0
        # POLL_TP5 (PPS pin not configured), TMODE and RTK_MOVBASE (F9 only), M10, L5: nothing

    # -- AP_GPS_UBLOX::_verify_rate --

    def verify_rate(self, cls: int, mid: int, rate: int) -> None:
        off = 0 if self.have_pvt else 1
        want = {(CLS_NAV, NAV_POSLLH): (off, CONFIG_RATE_POSLLH),
                (CLS_NAV, NAV_STATUS): (off, CONFIG_RATE_STATUS),
                (CLS_NAV, NAV_SOL): (off, CONFIG_RATE_SOL),
                (CLS_NAV, NAV_PVT): (1, CONFIG_RATE_PVT),
                (CLS_NAV, NAV_TIMEGPS): (5, CONFIG_RATE_TIMEGPS),
                (CLS_NAV, NAV_VELNED): (off, CONFIG_RATE_VELNED),
                (CLS_NAV, NAV_DOP): (1, CONFIG_RATE_DOP),
                (CLS_MON, MON_HW): (5, CONFIG_RATE_MON_HW),
                (CLS_MON, MON_HW2): (5, CONFIG_RATE_MON_HW2),
                (CLS_TIM, TIM_TM2): (1, CONFIG_TIM_TM2)}.get((cls, mid))
        if want is None:
            return
        desired, bit = want
        if rate == desired:
            self.unconfigured &= ~bit
            return
        self.send(CLS_CFG, CFG_MSG, bytes((cls, mid, desired)))  # _configure_message_rate
        self.unconfigured |= bit
        self.cfg_needs_save = True

    # -- AP_GPS_UBLOX::_parse_gps --

    def parse(self, c: int, i: int, p: bytes) -> bool:
        """One message; True when a new position and velocity of one epoch are complete."""
        self.seen.append((self.t, c, i))
        if c == CLS_ACK:
            if i == ACK_ACK and p[0] == CLS_CFG:
                self.unconfigured &= ~{CFG_GNSS: CONFIG_GNSS, CFG_NAV5: CONFIG_NAV_SETTINGS,
                                       CFG_SBAS: CONFIG_SBAS}.get(p[1], 0)
                if p[1] == CFG_CFG:
                    self.cfg_saved, self.cfg_needs_save = True, False
            if i == ACK_NAK:
                self.naks.append((p[0], p[1]))
            return False
        if c == CLS_CFG:
            self.parse_cfg(i, p)
            return False
        if c == CLS_MON:
            if i == MON_VER:
                self.have_version = True
                sw = p[:30].split(b"\0")[0].decode()
                hw = p[30:40].split(b"\0")[0].decode()
                self.version = {"sw": sw, "hw": hw}
                if hw[:8] == "00190000" and sw[:10] == "EXT CORE 4":
                    self.generation = UBLOX_M9  # (an F9 says "EXT CORE 1")
                assert b"L1L5" not in p[40:]  # (would ask for the L5 override config)
            elif i == MON_HW:
                assert len(p) in (60, 68)  # log_mon_hw
                self.state["noise_per_ms"] = struct.unpack_from("<H", p, 16)[0]
            elif i == MON_HW2:
                assert len(p) == 28
            else:
                self.unexpected.append((c, i))
            return False
        if c != CLS_NAV:
            self.unexpected.append((c, i))
            return False
        if i == NAV_PVT:
            (itow, _, _, _, _, _, _, _, _, _, fix_type, flags, _, num_sv, lon, lat, height, hmsl,
             hacc, vacc, vn, ve, vd, gspeed, head, sacc, _, pdop) = struct.unpack_from(
                "<IHBBBBBBIiBBBBiiiiIIiiiiiIIH", p)
            self.have_pvt = True
            status = {2: 2, 3: 3, 4: 3}.get(fix_type, 1)  # NO_FIX 1, 2D 2, 3D 3
            if fix_type == 3 and flags & 0x02:
                status = 4  # GPS_OK_FIX_3D_DGPS
            self.state.update(status=status, lat=lat * 1e-7, lng=lon * 1e-7, alt_msl=hmsl * 1e-3,
                              undulation=(hmsl - height) * 1e-3, h_acc=hacc * 1e-3,
                              v_acc=vacc * 1e-3, num_sats=num_sv, ground_speed=gspeed * 1e-3,
                              ground_course=(head * 1e-5) % 360, vel=(vn, ve, vd),
                              speed_accuracy=sacc * 1e-3, time_week_ms=itow)
            self.state.setdefault("hdop", pdop)
            self.last_pos_itow = self.last_vel_itow = itow
            self.new_position = self.new_speed = True
            self.pvt.append({"t": self.t, "iTOW": itow, **self.state})
        elif i == NAV_TIMEGPS:
            _, _, week, _, valid, _ = struct.unpack("<IihbBI", p)
            if valid & 0x02:  # UBX_TIMEGPS_VALID_WEEK_MASK
                self.state["time_week"] = week
        elif i == NAV_DOP:
            _, _, _, _, vdop, hdop, _, _ = struct.unpack("<I7H", p)
            self.state.update(hdop=hdop, vdop=vdop)
        elif i in (NAV_POSLLH, NAV_STATUS, NAV_VELNED):
            if self.have_pvt:  # wanted off once NAV-PVT comes: configure it again
                self.unconfigured |= {NAV_POSLLH: CONFIG_RATE_POSLLH,
                                      NAV_STATUS: CONFIG_RATE_STATUS,
                                      NAV_VELNED: CONFIG_RATE_VELNED}[i]
        elif i == NAV_SOL:
            if self.have_pvt:
                self.state["time_week"] = struct.unpack_from("<h", p, 8)[0]
        elif i == NAV_SVINFO:
            self.generation = p[5] & 0x07  # globalFlags: the chip generation
            assert self.generation == UBLOX_M8
            self.unconfigured &= ~CONFIG_VERSION
            self.send(CLS_CFG, CFG_MSG, bytes((CLS_NAV, NAV_SVINFO, 0)))
        else:
            self.unexpected.append((c, i))
            return False
        if self.new_position and self.new_speed and self.last_vel_itow == self.last_pos_itow:
            self.new_position = self.new_speed = False
            return True
        return False

    def parse_cfg(self, i: int, p: bytes) -> None:
        if i == CFG_NAV5:
            nav = bytearray(p)
            nav[0:2] = b"\0\0"
            mask = 0
            if self.navfilter != 0 and nav[2] != self.navfilter:
                nav[2], mask = self.navfilter, mask | 1
            if self.min_elevation != -100 and struct.unpack_from("<b", nav, 12)[0] != \
                    self.min_elevation:
                struct.pack_into("<b", nav, 12, self.min_elevation)
                mask |= 2
            if mask:
                nav[0:2] = struct.pack("<H", mask)
                self.send(CLS_CFG, CFG_NAV5, bytes(nav))
                self.unconfigured |= CONFIG_NAV_SETTINGS
                self.cfg_needs_save = True
            else:
                self.unconfigured &= ~CONFIG_NAV_SETTINGS
        elif i == CFG_GNSS:
            if self.gnss_mode == 0:
                self.unconfigured &= ~CONFIG_GNSS
                return
            g = bytearray(p)
            hw, n_blocks = g[1], g[3]
            count = sum(1 for k in range(7) if self.gnss_mode & (1 << k) and k != GNSS_ID_SBAS)
            for j in range(4, 4 + 8 * n_blocks, 8):
                gid = g[j]
                flags = struct.unpack_from("<I", g, j + 4)[0]
                if self.gnss_mode & (1 << gid):
                    if gid == GNSS_ID_SBAS:
                        g[j + 1], g[j + 2] = 1, 3
                    else:
                        g[j + 1] = (hw - 3) // (count * 2)
                        g[j + 2] = (8 if gid == GNSS_ID_GALILEO
                                    and self.generation <= UBLOX_M8 else hw)
                    flags |= 1
                else:
                    g[j + 1], g[j + 2], flags = 0, 0, flags & 0xFFFFFFFE
                struct.pack_into("<I", g, j + 4, flags)
            if bytes(g) != p:
                self.send(CLS_CFG, CFG_GNSS, bytes(g))
                self.unconfigured |= CONFIG_GNSS
                self.cfg_needs_save = True
            else:
                self.unconfigured &= ~CONFIG_GNSS
        elif i == CFG_SBAS:
            if self.sbas_mode == 2:
                self.unconfigured &= ~CONFIG_SBAS
            elif p[0] != self.sbas_mode:
                self.send(CLS_CFG, CFG_SBAS, bytes((self.sbas_mode,)) + p[1:8])
                self.unconfigured |= CONFIG_SBAS
                self.cfg_needs_save = True
            else:
                self.unconfigured &= ~CONFIG_SBAS
        elif i == CFG_MSG:
            if len(p) == 8:  # ubx_cfg_msg_rate_6: the rate on every port
                if self.ublox_port >= 6:
                    self.send(CLS_CFG, CFG_PRT)
                    return
                self.verify_rate(p[0], p[1], p[2 + self.ublox_port])
            else:
                self.verify_rate(p[0], p[1], p[2])
        elif i == CFG_PRT:
            self.ublox_port = p[0]
        elif i == CFG_RATE:
            meas, nav, ref = struct.unpack("<HHH", p)
            if (meas, nav, ref) != (self.rate_ms, 1, 0):
                self.send(CLS_CFG, CFG_RATE, struct.pack("<HHH", self.rate_ms, 1, 0))
                self.unconfigured |= CONFIG_RATE_NAV
                self.cfg_needs_save = True
            else:
                self.unconfigured &= ~CONFIG_RATE_NAV


def check_ardupilot(drv: ArduPilotUblox, mod: Module, generation: int) -> None:
    """ArduPilot reports the GPS configured and healthy, as its driver judges it."""
    assert drv.detected_at is not None and drv.detected_baud == 230400 == mod.baud
    assert drv.configured_at is not None, f"unconfigured 0x{drv.unconfigured:x}"
    assert drv.unconfigured == 0 and drv.generation == generation and drv.timeouts == 0
    assert not drv.naks and not drv.unexpected
    assert mod.link.internal_errors == 0 and mod.noise_bytes > 0
    # every set it wrote was ACKed (the driver verifies by polling again: done above)
    sets = [(c, i) for _, c, i, p in drv.sent if c == CLS_CFG and (
        (i == CFG_MSG and len(p) == 3) or (i in (CFG_RATE, CFG_SBAS) and p)
        or (i in (CFG_NAV5, CFG_GNSS, CFG_CFG) and p))]
    acks = [(c, i) for kind, c, i in acks_and_naks(mod) if kind == "ACK"]
    assert all(s in acks for s in sets) and "NAK" not in {k for k, _, _ in acks_and_naks(mod)}
    assert drv.cfg_saved and mod.link.saved == mod.link.settings  # GPS_SAVE_CFG 2
    s = mod.link.settings
    assert (s.baud, s.meas_rate_ms, s.nav_rate, s.time_ref, s.dyn_model) == (230400, 200, 1, 0, 8)
    # configured: NAV-PVT every 200 ms (AP_GPS's health wants <= 245 ms), TIMEGPS every 5th
    # epoch, DOP every epoch, MON-HW every 5th; POSLLH, STATUS, SOL, VELNED off
    t_conf = drv.configured_at
    after = [(c, i) for t, c, i in drv.seen if t > t_conf + 1.0]
    kinds = set(after)
    assert kinds <= {(CLS_NAV, NAV_PVT), (CLS_NAV, NAV_TIMEGPS), (CLS_NAV, NAV_DOP),
                     (CLS_MON, MON_HW), (CLS_ACK, ACK_ACK), (CLS_CFG, CFG_MSG),
                     (CLS_CFG, CFG_PRT), (CLS_CFG, CFG_RATE), (CLS_CFG, CFG_NAV5),
                     (CLS_CFG, CFG_GNSS), (CLS_CFG, CFG_SBAS), (CLS_MON, MON_VER)}
    n_pvt = after.count((CLS_NAV, NAV_PVT))
    assert n_pvt >= 20
    assert abs(after.count((CLS_NAV, NAV_TIMEGPS)) - n_pvt / 5) <= 1
    assert abs(after.count((CLS_MON, MON_HW)) - n_pvt / 5) <= 1
    assert abs(after.count((CLS_NAV, NAV_DOP)) - n_pvt) <= 1
    pvt = [r for r in drv.pvt if r["t"] > t_conf]
    assert {b["iTOW"] - a["iTOW"] for a, b in zip(pvt, pvt[1:], strict=False)} == {200}
    last = pvt[-1]
    assert last["status"] == 3 and last["num_sats"] == N_USED
    assert abs(last["undulation"] + GEOID_M) < 1e-3 and last["hdop"] == 80
    assert last["ground_speed"] == pytest.approx(SPEED_MPS, abs=1e-3)
    assert last["ground_course"] == pytest.approx(COURSE_DEG, abs=1e-5)
    gps_epoch = datetime(1980, 1, 6, tzinfo=UTC).timestamp()
    assert last["time_week"] == int((T0_UNIX_S - gps_epoch + 18) // 604800)


@pytest.mark.parametrize("gnss_mode, sbas_mode", [(0, 2), (1 | 2 | 64, 1)])
def test_ardupilot_configures_an_m8(gnss_mode, sbas_mode):
    """ArduPilot against a NEO-M8N at 9600: the blob at 9600 switches it to 230400 (its ACK at
    9600 is not taken: detection needs 230400), the blob at 230400 is answered and the u-blox
    detected; NAV-SVINFO tells an M8; the state machine polls and sets every rate, CFG-RATE,
    CFG-NAV5 (and CFG-GNSS / CFG-SBAS when asked) until every bit of its configuration mask is
    clear, then saves the configuration."""
    mod = Module("M8")
    drv = ArduPilotUblox(mod, gnss_mode=gnss_mode, sbas_mode=sbas_mode)
    assert drv.detect(40.0)
    assert drv.detected_at > 9 * AP_BAUD_TIME_S  # (9600 is the ninth rate probed)
    drv.run(55.0)
    check_ardupilot(drv, mod, UBLOX_M8)
    # two passes of the step cycle at 750 ms: the first finds each rate wrong and sets it, the
    # second reads it back
    assert drv.configured_at - drv.detected_at < 2 * len(AP_STEPS) * 0.75 + 2.0
    if gnss_mode:
        gnss = {b.gnss_id: b for b in mod.link.settings.gnss}
        assert mod.link.settings.enabled_gnss == {"GPS", "SBAS", "GLONASS"}
        assert (gnss[0].res_trk_ch, gnss[0].max_trk_ch) == ((32 - 3) // 4, 32)
        assert (gnss[1].res_trk_ch, gnss[1].max_trk_ch) == (1, 3)
        assert any(i == CFG_GNSS and p for _, c, i, p in drv.sent if c == CLS_CFG)


def test_ardupilot_configures_an_m9():
    """ArduPilot against a NEO-M9N at 38400: detected at 230400; the M9 does not answer the
    NAV-SVINFO poll (not in its firmware), MON-VER ("00190000", "EXT CORE 4...") tells an M9, and
    the legacy CFG messages ArduPilot uses on it are all ACKed until it is configured."""
    mod = Module("M9")
    drv = ArduPilotUblox(mod)
    assert drv.detect(20.0)
    drv.run(50.0)
    check_ardupilot(drv, mod, UBLOX_M9)
    assert drv.configured_at - drv.detected_at < 2 * len(AP_STEPS) * 0.75 + 2.0
    assert drv.version == {"sw": "EXT CORE 4.04 (7f89f7)", "hw": "00190000"}
    assert (CLS_NAV, NAV_SVINFO) not in {(c, i) for _, c, i in drv.seen}


def test_ardupilot_init_blob_is_what_the_header_spells():
    """AP_GPS.h's blob is a valid CFG-MSG (NAV-SOL rate 1) and a $PUBX,41 with its checksum."""
    assert AP_INIT_BLOB[:11] == ubx(CLS_CFG, CFG_MSG, bytes((CLS_NAV, NAV_SOL, 1)))
    line = AP_INIT_BLOB[11:].decode().strip()
    body, star, ck = line[1:].partition("*")
    assert star and nmea_checksum(body) == ck
