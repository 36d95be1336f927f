"""A model of PX4's NMEA GPS driver, for test_nmea_px4.py (``GPS_1_PROTOCOL = 6``).

PX4 cannot be installed here, so its NMEA driver and the loop that runs it are re-written below as
a small model (our code, not theirs): the byte decoder, the sentence handlers and the fields they
write into the ``sensor_gps`` report, what completes a report, the reads of the serial port, the
timeout, the reconnects and the baud probing. The model reads the exact bytes the device writes
(``virtualgps replay`` in-process: the profile's sentence order, digits and no-fix style), timed
as they leave the device: each epoch's bytes from the epoch's time on, at baud / 10 bytes per
second (8N1), handed over in the pty's 16 ms slices, the device's 2 s output queue dropping the
oldest epochs where the baud cannot carry the rate (docs/device.md, "The pty and the serial
port"). Each report PX4 would publish is compared with the replay's fixes CSV. One test feeds the
model the bytes of the real daemon as they arrive on a pty.

Sources read (through the project's source index; every step below cites file and function):
PX4/PX4-GPSDrivers ``src/nmea.cpp`` at cb00fcd7fc6a7c7212664a8ce35ffdb3e23b7eed (2024:
``GPSDriverNMEA::parseChar``, ``handleMessage``, ``receive``, ``configure``; the GLL branch, the
Unicore parser, ``fieldCount``), compared with 039b9ef6779f05ac326efe6932666b9f39f7c056 (2021:
no GLL branch, RMC stamps every report) and a later refactor the index holds without a repository
name (``setTimeUtc``, ``nmeaNextField``, GSV's satellite index bounded): the rules these tests
rest on (the POS/VEL pair, VTG's unconditional _VEL_received, GST alone writing eph/epv, the
comma counts) are the same in all three. ``src/nmea.h`` at 9ff74cb7 (NMEA_RECV_BUFFER_SIZE
1024, NMEA_DEFAULT_BAUDRATE 115200) and ``src/gps_helper.h`` at 4047fd8b (GPS_READ_BUFFER_SIZE
150, GPS_EPOCH_SECS). PX4/PX4-Autopilot ``src/drivers/gps/gps.cpp`` at
00129d0586902c9e9ad4d8d3925df701e5cfb3e6 (``GPS::run``: TIMEOUT_5HZ for every protocol but the
u-blox moving-base rover's TIMEOUT_1HZ, TIMEOUT_DUMP_ADD, the memset of the report after
``configure``, the 500 ms pause after a timeout; ``pollOrRead``; ``GPS_1_PROTOCOL`` 6 ->
``gps_driver_mode_t::NMEA``), the older f706e3541d81f8b735321d07d673977aa76d3db1 (the same
timeouts, its own poll-then-sleep ``pollOrRead``), ``platforms/nuttx/src/px4/common/
SerialImpl.cpp`` at 0a867b5d (``readAtLeast``) and ``src/drivers/gps/module.yaml`` (``gps start
-d ... -b p:SER_GPS1_BAUD``; SER_GPS1_BAUD is 0, auto, by default).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
from nmea_line import DEVICE_MAX_BACKLOG_S, PTY_SLICE_S, byte_times_s, epoch_starts_s

# --- PX4: the constants the model uses, named with their source --------------------------------

PX4_TIMEOUT_5HZ_S = 0.500  # gps.cpp TIMEOUT_5HZ: GPS::run's receive() timeout for NMEA
PX4_TIMEOUT_1HZ_S = 1.300  # gps.cpp TIMEOUT_1HZ: only for the u-blox moving-base rover modes
PX4_TIMEOUT_DUMP_ADD_S = 0.450  # gps.cpp TIMEOUT_DUMP_ADD: added while GPS_DUMP_COMM is set
PX4_RECONNECT_PAUSE_S = 0.500  # gps.cpp GPS::run: px4_usleep(500000) once the port is closed
PX4_PROBE_RECEIVE_S = 0.400  # nmea.cpp GPSDriverNMEA::configure: receive(400) per baud
PX4_PROBE_PAUSE_S = 0.002  # nmea.cpp configure: gps_usleep(2000) after each receive(400)
PX4_PROBE_BAUDS = (9600, 19200, 38400, 57600, 115200, 230400)  # configure: baudrates_to_try
PX4_NMEA_DEFAULT_BAUD = 115200  # nmea.h NMEA_DEFAULT_BAUDRATE: the baud when none answered
PX4_RX_BUFFER = 1024  # nmea.h NMEA_RECV_BUFFER_SIZE; parseChar drops a sentence at 1024 - 5
PX4_READ_BUFFER = 150  # gps_helper.h GPS_READ_BUFFER_SIZE: the most one read() returns
PX4_READ_MIN_CHARS = 32  # gps.cpp pollOrRead character_count (readAtLeast's minimum)
PX4_POLL_MAX_S = 0.050  # gps.cpp pollOrRead max_timeout: 50 ms
PX4_KNOTS_PER_MPS = np.float32(1.9438445)  # nmea.cpp RMC / VTG: ground_speed / 1.9438445f
PX4_GPS_EPOCH_SECS = 1234567890  # gps_helper.h GPS_EPOCH_SECS: earlier times give time_utc 0
PI_F = np.float32(math.pi)  # nmea.cpp M_PI_F

# The sensor_gps fields the NMEA driver writes (the rest stay as gps.cpp's memset left them).
REPORT_FIELDS = ("timestamp", "latitude_deg", "longitude_deg", "altitude_msl_m",
                 "altitude_ellipsoid_m", "hdop", "vdop", "fix_type", "satellites_used",
                 "vel_m_s", "vel_n_m_s", "vel_e_m_s", "vel_ned_valid", "cog_rad",
                 "c_variance_rad", "s_variance_m_s", "eph", "epv", "time_utc_usec")

_STRTOD = re.compile(rb"[ \t\n\v\f\r]*[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_STRTOL = re.compile(rb"[ \t\n\v\f\r]*[+-]?\d+")


def f32(x: float) -> float:
    """A C ``float``: the value rounded to single precision (strtof, float arithmetic)."""
    return float(np.float32(x))


def _c_div(a: float, b: float) -> int:
    """``static_cast<int>(a / b)``: C truncates toward zero."""
    return int(a / b)


def _days_from_civil(y: int, m: int, d: int) -> int:
    """Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's algorithm)."""
    y -= m <= 2
    era = (y if y >= 0 else y - 399) // 400
    yoe = y - era * 400
    doy = (153 * (m + (-3 if m > 2 else 9)) + 2) // 5 + d - 1
    return era * 146097 + yoe * 365 + yoe // 4 - yoe // 100 + doy - 719468


def _mktime_utc(tm_year: int, tm_mon: int, tm_mday: int, h: int, mi: int, s: int) -> int:
    """``mktime`` on a flight controller, whose time zone is UTC: out-of-range months and days
    are carried over as mktime normalises them (RMC's empty date gives 1999-11-30)."""
    y = tm_year + 1900 + tm_mon // 12
    days = _days_from_civil(y, tm_mon % 12 + 1, 1) + tm_mday - 1
    return days * 86400 + h * 3600 + mi * 60 + s


def _tod_s(hhmmss: float) -> float:
    """Seconds of the day of an NMEA ``hhmmss.sss`` time (for matching epochs; not PX4's)."""
    h = _c_div(hhmmss, 10000)
    m = _c_div(hhmmss - h * 10000, 100)
    return round(h * 3600 + m * 60 + (hhmmss - h * 10000 - m * 100), 3)


class _Cursor:
    """handleMessage's walk over a sentence's fields: ``bufptr`` starts on the comma after the
    address (``_rx_buffer + 6``); each field is ``if (*(++bufptr) != ',')`` then a strtod /
    strtof / strtol that leaves ``bufptr`` where the number ended, or a character taken with
    ``*(bufptr++)``; an empty field keeps the variable's default and leaves ``bufptr`` on its
    comma. A field that holds no number converts to 0 and leaves ``bufptr`` where it was, as
    strtod does (the C library's ``inf``, ``nan`` and hexadecimal forms, which the device never
    writes, are not modelled)."""

    def __init__(self, buf: bytes) -> None:
        self.buf, self.p = buf, 6

    def _next(self) -> int:
        self.p += 1
        assert self.p < len(self.buf), "the driver would read past the sentence"
        return self.buf[self.p]

    def _num(self, pattern: re.Pattern, default: float | None) -> float | None:
        if self._next() == 0x2C:
            return default
        m = pattern.match(self.buf, self.p)
        if m is None:
            return 0
        self.p = m.end()
        return float(m.group()) if pattern is _STRTOD else int(m.group())

    def d(self, default: float | None = 0.0) -> float | None:
        """strtod: a C double."""
        return self._num(_STRTOD, default)

    def f(self, default: float | None = 0.0) -> float | None:
        """strtof: a C float."""
        v = self._num(_STRTOD, default)
        return v if v is None else f32(v)

    def i(self, default: int = 0) -> int:
        """strtol(…, 10)."""
        return self._num(_STRTOL, default)

    def c(self, default: str = "?") -> str:
        """``x = *(bufptr++)``."""
        if self._next() == 0x2C:
            return default
        self.p += 1
        return chr(self.buf[self.p - 1])

    def skip_to_comma(self) -> None:
        """GGA's ``while (*(++bufptr) != ',') {} //skip M``."""
        while self._next() != 0x2C:
            pass


def _nmea_deg(x: float) -> float:
    """handleMessage's "convert from degrees, minutes and seconds to degrees" (double)."""
    return int(x * 0.01) + (x * 0.01 - int(x * 0.01)) * 100.0 / 60.0


def _velocity(knots: float, track_deg: float) -> tuple[float, float, float, float]:
    """RMC / VTG: track to radians in [-pi, pi], speed / 1.9438445f, north = v cosf, east =
    v sinf, all in float: (vel_m_s, vel_n, vel_e, cog_rad)."""
    track = np.float32(track_deg) * PI_F / np.float32(180.0)
    if track > PI_F:
        track = track - np.float32(2.0) * PI_F
    v = np.float32(knots) / PX4_KNOTS_PER_MPS
    return float(v), float(v * np.cos(track)), float(v * np.sin(track)), float(track)


class Px4NmeaDecoder:
    """GPSDriverNMEA (PX4-GPSDrivers src/nmea.cpp): parseChar, handleMessage and the state they
    keep, writing into ``report`` (gps.cpp's ``_report_gps_pos``, shared with the loop).

    Besides PX4's own state it keeps, as test instrumentation only, ``src``: for each report
    field, the UTC time (``hhmmss.sss``) of the epoch whose sentence last wrote it (the time of
    the last time-bearing sentence handled, for GSA, GSV and VTG, which carry none).
    """

    def __init__(self, report: dict, src: dict, sat_info: bool = False) -> None:
        self.report, self.src, self.sat_info = report, src, sat_info
        self.state, self.rx = "uninit", bytearray()  # NMEADecodeState, _rx_buffer
        self.last_pos_utc = 0.0  # _last_POS_timeUTC
        self.last_vel_utc = 0.0  # _last_VEL_timeUTC
        self.sat_num_gga = self.sat_num_gns = 0  # uint8_t _sat_num_gga, _sat_num_gns
        self.sat_num_talker = {b"$GP": 0, b"$GL": 0, b"$GA": 0, b"$GB": 0, b"$BD": 0}
        self.pos = self.vel = self.svnum = self.svinfo = self.fix = False  # _*_received
        self.clock_set = False
        self.epoch = None  # instrumentation: the epoch being read (hhmmss.sss)
        self.gga_epoch = None  # instrumentation: the epoch of _sat_num_gga
        self.branches: list[str] = []  # instrumentation: the branch each sentence took
        self.now = 0.0  # gps_absolute_time(), set by the loop

    # -- parseChar --

    def decode_init(self) -> None:
        """GPSDriverNMEA::decodeInit."""
        self.state, self.rx = "uninit", bytearray()

    def feed(self, data: bytes) -> list[bytes]:
        """parseChar over ``data``, byte by byte in effect (scanning for the bytes that change
        the state): uninit waits for ``$``; got_sync1 stores bytes, restarts on ``$``, goes to
        got_asteriks on ``*`` and drops the sentence once it holds 1024 - 5 bytes; the two bytes
        after ``*`` are compared with the XOR of the bytes between ``$`` and ``*`` as upper-case
        hex (HEXDIGIT_CHAR). Returns the sentences that pass, ``$`` to checksum (no CR LF)."""
        out, i, n = [], 0, len(data)
        while i < n:
            if self.state == "uninit":
                k = data.find(b"$", i)
                if k < 0:
                    return out
                self.state, self.rx, i = "sync", bytearray(b"$"), k + 1
            elif self.state == "sync":
                ks, ka = data.find(b"$", i), data.find(b"*", i)
                j = min(k for k in (ks, ka, n) if k >= 0)
                room = PX4_RX_BUFFER - 5 - len(self.rx)
                if j - i > room:  # the byte that finds the buffer full ends the sentence
                    self.decode_init()
                    i += room + 1
                    continue
                self.rx += data[i:j]
                i = j
                if j < n:
                    if data[j] == 0x24:  # '$': start again
                        self.rx = bytearray(b"$")
                    elif len(self.rx) >= PX4_RX_BUFFER - 5:
                        self.decode_init()
                    else:
                        self.rx.append(0x2A)
                        self.state = "asterisk"
                    i = j + 1
            elif self.state == "asterisk":
                self.rx.append(data[i])
                self.state, i = "cs1", i + 1
            else:  # got_first_cs_byte
                self.rx.append(data[i])
                i += 1
                cs = 0
                for b in self.rx[1:-3]:
                    cs ^= b
                if self.rx[-2:] == b"%02X" % cs:
                    out.append(bytes(self.rx))
                self.decode_init()
        return out

    # -- handleMessage --

    def _set(self, name: str, value) -> None:
        self.report[name] = value
        self.src[name] = self.epoch

    def _set_time_utc(self, year: int, month: int, day: int, hhmmss: float) -> None:
        """The ZDA / RMC time: mktime of the date and whole seconds; time_utc_usec 0 unless
        after GPS_EPOCH_SECS; the fraction truncated to microseconds."""
        h = _c_div(hhmmss, 10000)
        mi = _c_div(hhmmss - h * 10000, 100)
        sec = hhmmss - h * 10000 - mi * 100
        epoch = _mktime_utc(year - 1900, month - 1, day, h, mi, int(sec))
        if epoch > PX4_GPS_EPOCH_SECS:
            self.clock_set = True  # (setClock the first time)
            self._set("time_utc_usec", epoch * 1_000_000 + int((sec - int(sec)) * 1e6))
        else:
            self._set("time_utc_usec", 0)

    def handle_message(self, buf: bytes) -> int:
        """GPSDriverNMEA::handleMessage: the branch by ``_rx_buffer + 3`` (a two-letter talker
        assumed) and the comma count (``fieldCount``), then satellites_used, then "a position
        update" (bit 0) once both _POS_received and _VEL_received are set, which clears both.
        Bit 1: a GSV run's last page with satellite info on (GPS_SAT_INFO)."""
        if len(buf) < 7:
            return 0
        commas, kind, cur, r = buf.count(b","), buf[3:7], _Cursor(buf), self.report
        ret = 0
        assert kind not in (b"GNS,", b"HDT,"), "not modelled (the device writes neither)"
        if kind == b"ZDA," and commas == 6:
            utc = cur.d()
            day, month, year = cur.i(), cur.i(), cur.i()
            cur.i(), cur.i()
            self.epoch = utc
            self._set_time_utc(year, month, day, utc)
            self.branches.append("ZDA")
        elif kind == b"GLL," and commas >= 7:
            lat, ns, lon, ew = cur.d(), cur.c(), cur.d(), cur.c()
            utc, valid, mode = cur.d(), cur.c(), cur.c()
            lat, lon = -lat if ns == "S" else lat, -lon if ew == "W" else lon
            self.epoch = utc
            if valid == "A" and mode == "A":  # "only update the values if they are valid"
                self._set("longitude_deg", _nmea_deg(lon))
                self._set("latitude_deg", _nmea_deg(lat))
                if not self.pos and self.last_pos_utc < utc:
                    self.last_pos_utc, self.pos = utc, True
            self.branches.append("GLL")
        elif kind == b"GGA," and commas >= 14:
            utc, lat, ns, lon, ew = cur.d(), cur.d(), cur.c(), cur.d(), cur.c()
            quality, n_sv = cur.i(), cur.i()
            hdop, alt = cur.f(f32(99.9)), cur.f()
            cur.skip_to_comma()
            geoid = cur.f()
            cur.skip_to_comma()
            cur.f(None)  # dgps_age, unused
            lat, lon = -lat if ns == "S" else lat, -lon if ew == "W" else lon
            self.epoch = self.gga_epoch = utc
            self._set("longitude_deg", _nmea_deg(lon))
            self._set("latitude_deg", _nmea_deg(lat))
            self._set("hdop", hdop)
            self._set("altitude_msl_m", alt)
            self._set("altitude_ellipsoid_m", f32(np.float32(alt) + np.float32(geoid)))
            self.sat_num_gga = n_sv & 0xFF
            # quality 0 -> 0; 1 (GPS) -> 3; 2 (DGPS) -> 4; 5 (RTK float) -> 5; 4 (fixed) -> 6
            q = 3 if quality == 5 else quality
            self._set("fix_type", 0 if quality <= 0 else 3 + q - 1)
            if not self.pos and self.last_pos_utc < utc:
                self.last_pos_utc, self.pos = utc, True
                self._set("timestamp", self.now)
            self.svnum = self.fix = True  # (_ALT_received too)
            self._set("c_variance_rad", f32(0.1))
            self.branches.append("GGA")
        elif kind == b"RMC," and commas >= 11:
            utc, status = cur.d(), cur.c("V")
            lat, ns, lon, ew = cur.d(), cur.c(), cur.d(), cur.c()
            knots, track, date = cur.f(), cur.f(), cur.i()
            cur.f()  # magnetic variation, unused
            lat, lon = -lat if ns == "S" else lat, -lon if ew == "W" else lon
            self.epoch = utc
            if status == "V":
                self._set("fix_type", 0)
            v, vn, ve, cog = _velocity(knots, track)
            self._set("cog_rad", cog)
            self._set("c_variance_rad", f32(0.1))
            # (not a Unicore receiver: _unicore_parser.agricaValid() is false)
            self._set("latitude_deg", _nmea_deg(lat))
            self._set("longitude_deg", _nmea_deg(lon))
            if not self.pos and self.last_pos_utc < utc:
                self._set("timestamp", self.now)
                self.last_pos_utc, self.pos = utc, True
            for name, value in (("vel_m_s", v), ("vel_n_m_s", vn), ("vel_e_m_s", ve),
                                ("vel_ned_valid", True), ("s_variance_m_s", 0.0)):
                self._set(name, value)
            if not self.vel and self.last_vel_utc < utc:
                self.last_vel_utc, self.vel = utc, True
            day = date // 10000
            month = (date - day * 10000) // 100
            self._set_time_utc(date - day * 10000 - month * 100 + 2000, month, day, utc)
            self.branches.append("RMC")
        elif kind == b"GST," and commas == 8:
            utc = cur.d()
            for _ in range(4):
                cur.f()  # rms, semi-major, semi-minor, orientation: unused
            lat_err, lon_err, alt_err = cur.f(), cur.f(), cur.f()
            self.epoch = utc
            eph = np.sqrt(np.float32(lat_err) ** 2 + np.float32(lon_err) ** 2)
            self._set("eph", float(np.float32(eph)))
            self._set("epv", alt_err)
            self.branches.append("GST")
        elif kind == b"GSA," and commas >= 17:
            cur.c(" ")
            mode = cur.i()
            for _ in range(12):
                cur.i()
            cur.f(f32(99.9))  # pdop, unused
            hdop, vdop = cur.f(f32(99.9)), cur.f(f32(99.9))
            if mode <= 1:
                self._set("fix_type", 0)
            else:
                self._set("hdop", hdop)
                self._set("vdop", vdop)
            self.branches.append("GSA")
        elif kind == b"GSV,":
            pages, page, in_view = cur.i(), cur.i(), cur.i()
            if page < 1 or page > pages:
                return 0
            if buf[:3] in self.sat_num_talker:
                self.sat_num_talker[buf[:3]] = in_view & 0xFF
            if page == pages:
                self.svnum = self.svinfo = True
                if self.sat_info:
                    ret |= 2  # (its satellites go to satellite_info, not modelled here)
            self.branches.append("GSV")
        elif kind == b"VTG," and commas >= 8:
            track = cur.f()
            cur.c(), cur.f(), cur.c()
            knots = cur.f()
            cur.c(), cur.f(), cur.c()
            v, vn, ve, cog = _velocity(knots, track)
            for name, value in (("vel_m_s", v), ("vel_n_m_s", vn), ("vel_e_m_s", ve),
                                ("vel_ned_valid", True), ("c_variance_rad", f32(0.1)),
                                ("s_variance_m_s", 0.0)):
                self._set(name, value)
            self.vel = True  # (no time check: VTG carries no time)
            self._set("cog_rad", cog)
            self.branches.append("VTG")
        else:
            self.branches.append("none")
        if self.sat_num_gga > 0:
            r["satellites_used"] = self.sat_num_gga
            self.src["satellites_used"] = ("gga", self.gga_epoch)
        elif self.svnum and self.svinfo and self.fix:
            gsv = sum(self.sat_num_talker.values()) & 0xFF
            r["satellites_used"] = max(self.sat_num_gns, gsv)
            self.src["satellites_used"] = ("gsv", self.epoch)
        if self.vel and self.pos:
            ret |= 1
            self.vel = self.pos = False
        return ret


# --- the serial line: the device's bytes as they arrive at PX4's UART ---------------------------


@dataclass
class DeviceLine:
    """What the device writes on the line: every byte with the time it can be read.

    t_s : (n,) arrival times on the simulated clock, non-decreasing; data : the n bytes;
    baud : the device's baud; epochs : (time the epoch is due, time its first byte leaves)
    """

    t_s: np.ndarray
    data: bytes
    baud: int
    epochs: list[tuple[float, float]] = field(default_factory=list)

    @classmethod
    def from_epochs(cls, epoch_t_s, epoch_bytes, baud: int, slice_s: float = PTY_SLICE_S,
                    max_backlog_s: float = DEVICE_MAX_BACKLOG_S):
        """The device's line (nmea_line.py: each epoch from its time on at baud / 10 bytes a
        second, in the pty's slices, the oldest unstarted epochs dropped where the baud cannot
        carry the rate; the client reads all the time, so nothing waits unread in the pty)."""
        t_s = np.asarray(epoch_t_s, float)
        starts = epoch_starts_s([len(b) for b in epoch_bytes], t_s, baud, max_backlog_s)
        sent = [i for i, s in enumerate(starts) if s is not None]
        return cls(np.concatenate([byte_times_s(starts[i], len(epoch_bytes[i]), baud, slice_s)
                                   for i in sent]),
                   b"".join(epoch_bytes[i] for i in sent), baud,
                   [(float(t_s[i]), starts[i]) for i in sent])

    @classmethod
    def from_reads(cls, reads: list[tuple[float, bytes]], baud: int):
        """Bytes read from a pty, each chunk with the time it was read."""
        t = np.concatenate([np.full(len(d), ts) for ts, d in reads])
        return cls(t, b"".join(d for _, d in reads), baud)

    def lag_s(self) -> float:
        """The most an epoch's first byte left after the epoch was due (0: the baud carries
        the rate)."""
        return max((s - te for te, s in self.epochs), default=0.0)


@dataclass
class Px4NmeaGps:
    """PX4-Autopilot's gps driver (src/drivers/gps/gps.cpp) running GPSDriverNMEA on a UART,
    on a simulated clock: GPS::run, GPSDriverNMEA::configure and ::receive, and the port
    under them (GPS::pollOrRead -> Serial::readAtLeast, NuttX SerialImpl).

    configured_baud : SER_GPS1_BAUD (``gps start -b``; 0, auto, by default)
    sat_info : GPS_SAT_INFO; dump_comm : GPS_DUMP_COMM set (adds TIMEOUT_DUMP_ADD)
    """

    line: DeviceLine
    configured_baud: int = 0
    sat_info: bool = False
    dump_comm: bool = False
    t: float = 0.0
    reports: list[dict] = field(default_factory=list)  # one per publish()
    events: list[tuple] = field(default_factory=list)  # ("configured", t0, t1, baud, found)…
    seed: int = 6

    def __post_init__(self) -> None:
        self.report: dict = {}
        self.src: dict = {}
        self.memset()
        self.is_open, self.baud, self.ptr = False, 0, 0
        self.bauds: list[tuple[float, int]] = []  # (since, baud) while the port is open
        self.rng = np.random.default_rng(self.seed)
        self.decoder = Px4NmeaDecoder(self.report, self.src, self.sat_info)

    def memset(self) -> None:
        """GPS::run after configure: ``memset(&_report_gps_pos, 0, ...)``, heading NAN."""
        for name in REPORT_FIELDS:
            self.report[name] = 0
            self.src[name] = None
        self.report["vel_ned_valid"] = False
        self.report["heading"] = math.nan

    # -- the port --

    def open(self) -> None:
        """Serial::open; what came while the port was closed is lost."""
        self.is_open = True
        self.ptr = int(np.searchsorted(self.line.t_s, self.t, side="right"))
        self.bauds = [(self.t, self.baud)]

    def set_baud(self, baud: int) -> None:
        """GPS::setBaudrate -> Serial::setBaudrate (tcsetattr, no flush)."""
        self.baud = baud
        if self.is_open:
            self.bauds.append((self.t, baud))

    def _bytes(self, i: int, j: int) -> bytes:
        """Bytes i..j of the line as the UART received them: noise where its baud at their
        arrival was not the device's (framing errors, never the bytes sent)."""
        out = np.frombuffer(self.line.data[i:j], np.uint8).copy()
        since = np.array([s for s, _ in self.bauds])
        at = np.array([b for _, b in self.bauds])[
            np.searchsorted(since, self.line.t_s[i:j], side="right") - 1]
        wrong = at != self.line.baud
        out[wrong] = self.rng.integers(0, 256, int(wrong.sum()), dtype=np.uint8)
        return out.tobytes()

    def read(self, timeout_ms: int) -> bytes:
        """GPSHelper::read -> GPS::pollOrRead -> readAtLeast(buf, 150, 32, min(50, timeout)):
        poll up to 50 ms; once data is there and fewer than 32 bytes are, sleep 32 characters'
        time; then read what is there, at most 150 bytes; 0 bytes after 50 ms of nothing. One
        read per call: SerialImpl compares the 50 with microseconds elapsed (were they taken as
        milliseconds, an epoch's last bytes would wait up to 50 ms longer; the outcomes of the
        tests here are the same either way)."""
        t_s = self.line.t_s
        wait = min(PX4_POLL_MAX_S, timeout_ms / 1000.0)
        if self.ptr >= len(t_s) or t_s[self.ptr] > self.t + wait:
            self.t += wait
            return b""
        t = max(self.t, float(t_s[self.ptr]))
        if np.searchsorted(t_s, t, side="right") - self.ptr < PX4_READ_MIN_CHARS:
            t += (PX4_READ_MIN_CHARS * 1_000_000 // (self.baud // 10)) / 1e6
        j = min(int(np.searchsorted(t_s, t, side="right")), self.ptr + PX4_READ_BUFFER)
        self.t, data, self.ptr = t, self._bytes(self.ptr, j), j
        return data

    # -- GPSDriverNMEA::receive / configure --

    def receive(self, timeout_ms: int) -> int:
        """GPSDriverNMEA::receive: read and decode until a handled message (the whole read is
        decoded first), or -1 once ``timeout`` ms have passed since the call."""
        t0, handled = self.t, 0
        while True:
            data = self.read(timeout_ms)
            if data:
                for sentence in self.decoder.feed(data):
                    self.decoder.now = self.t
                    handled |= self.decoder.handle_message(sentence)
                if handled > 0:
                    return handled
            if t0 + timeout_ms / 1000.0 < self.t - 1e-9:
                return -1

    def configure(self) -> int:
        """GPSDriverNMEA::configure: receive(400) at SER_GPS1_BAUD if set, then at each of
        9600 ... 230400 until a position (_POS_received) or a handled message; if none answered,
        the configured baud or 115200, and success all the same."""
        dec = self.decoder
        tries = ((self.configured_baud,) if self.configured_baud else ()) + PX4_PROBE_BAUDS
        for baud in tries:
            if dec.pos:
                break
            self.set_baud(baud)
            dec.decode_init()
            ret = self.receive(int(PX4_PROBE_RECEIVE_S * 1000))
            self.t += PX4_PROBE_PAUSE_S
            if dec.pos or ret > 0:
                return baud
        self.set_baud(self.configured_baud or PX4_NMEA_DEFAULT_BAUD)
        return 0

    # -- GPS::run --

    def run(self, until_s: float) -> None:
        """GPS::run for GPS_1_PROTOCOL 6: a new GPSDriverNMEA, the port opened, configure, the
        report cleared, then receive(TIMEOUT_5HZ) and publish() while it returns > 0; on -1
        the port is closed, 500 ms pass, and all of it starts again."""
        timeout_ms = int(1000 * (PX4_TIMEOUT_5HZ_S + (PX4_TIMEOUT_DUMP_ADD_S
                                                     if self.dump_comm else 0.0)))
        while self.t < until_s:
            self.decoder = Px4NmeaDecoder(self.report, self.src, self.sat_info)
            if self.configured_baud:
                self.baud = self.configured_baud
            self.open()
            t0 = self.t
            found = self.configure()
            self.events.append(("configured", t0, self.t, self.baud, found))
            self.memset()
            while self.t < until_s:
                ret = self.receive(timeout_ms)
                if ret <= 0:
                    self.events.append(("timeout", self.t))
                    break
                if ret & 1:
                    self.reports.append(dict(self.report, t=self.t, src=dict(self.src),
                                             connection=len(self.events)))
            self.is_open = False
            self.t += PX4_RECONNECT_PAUSE_S

    def timeouts(self) -> list[float]:
        """The times receive() gave up while the device was still sending."""
        end = float(self.line.t_s[-1])
        return [e[1] for e in self.events if e[0] == "timeout" and e[1] <= end]
