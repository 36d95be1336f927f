"""A model of ArduPilot's NMEA GPS driver, for test_nmea_ardupilot.py (``GPS1_TYPE = 5``).

ArduPilot cannot be installed here, so the part of it that reads an NMEA receiver is re-written
below as a small model (our code, not theirs): AP_GPS's detection (the baud rates it probes,
1.2 s each, the init blob it writes at each, the NMEA detector, the 4 s timeout that deletes the
driver and probes again, the health it derives from the time between messages) and AP_GPS_NMEA
(the byte decoder and its checksum, the terms it reads and how it converts them, the rule that
makes a set of sentences "a new message", the state it fills). The model is driven by the exact
bytes the device writes: ``virtualgps replay`` of a drive (accelerate, turn, stop, a gap in the
poses) for each NMEA profile, each epoch's bytes sent from the epoch's time on a simulated UART
at the profile's baud (8N1: 10 bits a byte) behind the device's own bounded queue, and read by
the model every 20 ms on a simulated clock; and, once, the bytes the real daemon writes on its
pty, with the times they arrived.

Sources read (through the project's source index; each step below cites file and function):

- ``libraries/AP_GPS/AP_GPS_NMEA.cpp`` and ``AP_GPS_NMEA.h``: the 4.6-era revision
  (yuri-rage/ardupilot 6c45a0911ffcc0a7bf133cee03cdb82022fae5e7, whose GGA altitude goes through
  ``set_alt_amsl_cm``; ArduPilot/ardupilot's own header at 0044c3d807e2908775c548f50c8f0e4685b5926f
  declares the same members, and the 4.5-era file with the Unicore sentences reads the same
  everywhere this model looks): ``_decode``, ``_parse_decimal_100``, ``_parse_degrees``,
  ``_have_new_message``, ``_term_complete``, ``_detect``, ``send_config``, ``is_healthy``.
  Older revisions differ in what matters here: those with ``_gps_data_good`` kept the position
  of an RMC with status ``V`` or a GGA with quality 0 out; this one lets GGA's quality alone set
  the status, and reads RMC's status field and ignores it.
- ``libraries/AP_GPS/AP_GPS.cpp``: the 4.6-era revision (``params[instance].type``,
  ``NEW_NOTHROW``, ``dstate->probe_baud``: the index did not name its commit), which the model
  follows, and ArduPilot/ardupilot 7bb5b6ef646fc4a3c56b6e0622046abf2fdc8ccf (4.4-era: the same
  rules, except that its first probe is 115200, not the port's own rate): ``_baudrates``,
  ``GPS_BAUD_TIME_MS``, ``GPS_TIMEOUT_MS``, ``detect_instance``, ``_detect_instance`` (in
  both, the NMEA detector runs for GPS1_TYPE 5, not for 1: auto detects NMEA no more; 3.x-era
  copies ran it under auto after a whole cycle of rates), ``update_instance``, ``is_healthy``,
  ``send_blob_start``.
- ``libraries/AP_GPS/GPS_Backend.cpp``: ``make_gps_time``, ``set_uart_timestamp``;
  ``libraries/AP_HAL_ChibiOS/UARTDriver.cpp``: ``receive_time_constraint_us``;
  ``libraries/AP_SerialManager/AP_SerialManager.h``: ``AP_SERIALMANAGER_GPS_BAUD``; the
  vehicles' scheduler tables (``SCHED_TASK_CLASS(AP_GPS, ..., update, 50, ...)``).

What the model leaves out, because nothing the device writes reaches it: the Unicore ``#``
sentences (their CRC32), ``$PHD``, ``$KSXT``, ``HDT``/``THS`` (yaw), and the other protocols'
detectors under ``GPS1_TYPE = 1`` (u-blox, SBP, SiRF, ERB: an NMEA text stream carries none of
their preambles with a valid checksum; the u-blox profiles' answer to the blob at 230400 baud is
``tests/test_ubx_ardupilot.py``'s). Bytes sent at a baud other than the one the port is set to
are taken as lost (a UART at the wrong rate reads framing errors; for them to pass the NMEA
detector, a ``$``, a ``*`` and the two right hex digits of a checksum would have to come out of
the noise). A baud change discards what the old rate received but the driver had not read (the
HAL's ``begin()`` is taken to flush: not checked; the model reads every 20 ms, so at most 20 ms
of bytes are concerned). The init blob is taken to be written at once (the HAL's transmit buffer
holds it: not checked).
"""

from __future__ import annotations

import calendar
import math
from dataclasses import dataclass, field, replace

import numpy as np
from nmea_line import byte_times_s, epoch_starts_s

# --- ArduPilot: AP_GPS (AP_GPS.cpp) ----------------------------------------------------------

#: AP_GPS.cpp ``_baudrates``: after the port's own rate, ``_detect_instance`` cycles through
#: these from the second (``current_baud++`` before use: "this will skip the first element")
AP_BAUDS = (9600, 115200, 4800, 19200, 38400, 57600, 230400, 460800)
AP_BAUD_TIME_MS = 1200  # AP_GPS.cpp GPS_BAUD_TIME_MS: the next rate once now - last change > it
AP_GPS_TIMEOUT_MS = 4000  # AP_GPS.cpp GPS_TIMEOUT_MS: no message for it, driver deleted
AP_LOOP_MS = 20  # the vehicles' scheduler tables: AP_GPS::update at 50 Hz; read() each time
#: AP_SerialManager.h AP_SERIALMANAGER_GPS_BAUD: SERIALn_BAUD's default on a GPS port, the
#: rate ``_detect_instance`` probes first (``probe_baud = port->get_baud_rate()``)
AP_PORT_BAUD = 38400
AP_DETECT_MAX_BYTES = 8192  # _detect_instance: MIN(8192U, available()) bytes a call
AP_MAX_DELTA_MS = 245  # update_instance gps_max_delta_ms: "200 ms (5Hz) + 45 ms buffer"
AP_DELAY_AVG_MAX_MS = 215  # is_healthy delay_avg_max (not an RTK rover)
AP_DELAY_THRESHOLD = 2  # is_healthy delay_threshold: delayed frames allowed in a row
GPS_TYPE_AUTO, GPS_TYPE_NMEA = 1, 5  # AP_GPS.h GPS_Type
#: AP_GPS.h GPS_Status (= MAVLink's GPS_FIX_TYPE)
NO_GPS, NO_FIX, FIX_2D, FIX_3D, FIX_3D_DGPS, FIX_RTK_FLOAT, FIX_RTK_FIXED = range(7)
GPS_UNKNOWN_DOP = 9999  # AP_GPS.h: hdop/vdop of a reset state
#: AP_GPS.h UBLOX_SET_BINARY_230400, the head of AP_GPS::_initialisation_blob that
#: send_blob_start writes at every probed rate when GPS_AUTO_CONFIG >= 1, whatever GPS1_TYPE
#: (NMEA included): CFG-MSG NAV-SOL rate 1, then $PUBX,41 (UBX + NMEA + RTCM3 in, UBX out,
#: 230400 baud). (SiRF's and Unicore's parts follow where those backends are built in.)
AP_INIT_BLOB = (b"\xb5\x62\x06\x01\x03\x00\x01\x06\x01\x12\x4f"
                b"$PUBX,41,1,0023,0001,230400,0*1E\r\n")

# --- ArduPilot: AP_GPS_NMEA (AP_GPS_NMEA.cpp, AP_GPS_NMEA.h) ------------------------------------

NMEA_SET_MS = 150  # _have_new_message: GGA, RMC (and VTG once seen) each within 150 ms of now
NMEA_TERM_BYTES = 30  # AP_GPS_NMEA.h ``char _term[30]``: longer terms are cut at 29 characters
#: AP_GPS_NMEA.h ``_sentence_types``; _term_complete switches on type + term number
SENTENCE_OTHER, SENTENCE_RMC, SENTENCE_GGA, SENTENCE_VTG = 0, 32, 64, 96
SENTENCE_NAMES = {SENTENCE_RMC: "RMC", SENTENCE_GGA: "GGA", SENTENCE_VTG: "VTG"}
#: _term_complete, GGA: the quality indicator's status (any other value: 3D)
GGA_QUALITY_STATUS = {0: NO_FIX, 1: FIX_3D, 2: FIX_3D_DGPS, 3: FIX_3D, 4: FIX_RTK_FIXED,
                      5: FIX_RTK_FLOAT, 6: NO_FIX}
GPS_LEAPSECONDS_S = 18  # GPS_LEAPSECONDS_MILLIS / 1000, make_gps_time's leap seconds
UNIX_TO_GPS_S = 315964800  # make_gps_time ``unix_to_GPS_secs``
SEC_PER_WEEK = 604800  # AP_SEC_PER_WEEK
F32 = np.float32
F32_1E7_OVER_60 = F32(F32(1.0e7) / F32(60.0))  # _parse_degrees ``1.0e7f / 60.0f``


def c_strtol(s: str) -> tuple[int, int]:
    """C ``strtol(s, &end, 10)``: (value, index of end); end 0 where no digits were read."""
    i = 0
    while i < len(s) and s[i] in " \t":
        i += 1
    sign = 1
    if i < len(s) and s[i] in "+-":
        sign = -1 if s[i] == "-" else 1
        i += 1
    j = i
    while j < len(s) and "0" <= s[j] <= "9":
        j += 1
    if j == i:
        return 0, 0
    return sign * int(s[i:j]), j


def c_atol(s: str) -> int:
    return c_strtol(s)[0]


def c_strtoul16(s: str) -> int:
    """C ``strtoul(s, nullptr, 16)`` of a checksum term (its leading hex digits)."""
    j = 0
    while j < len(s) and s[j] in "0123456789abcdefABCDEF":
        j += 1
    return int(s[:j], 16) if j else 0


def parse_decimal_100(s: str) -> int:
    """AP_GPS_NMEA::_parse_decimal_100: ``100 * strtol`` plus the first two decimals, the third
    rounding. The sign comes from the integer part: ``-0.5`` reads +50 (as ArduPilot's)."""
    v, end = c_strtol(s)
    ret = 100 * v
    sign = -1 if ret < 0 else 1
    if ret >= 2**31 - 1:
        return 2**31 - 1
    if ret <= -(2**31):
        return -(2**31)
    if end == 0 or end >= len(s) or s[end] != ".":
        return ret
    d = s[end + 1:end + 4]
    if d[:1].isdigit():
        ret += sign * 10 * int(d[0])
        if d[1:2].isdigit():
            ret += sign * int(d[1])
            if d[2:3].isdigit():
                ret += sign * (int(d[2]) >= 5)
    return ret


def parse_degrees(s: str) -> int:
    """AP_GPS_NMEA::_parse_degrees: ``dddmm.mmmm`` to degrees x 1e7. Degrees and minutes are
    uint8_t, the fraction of a minute a float summed digit by digit, and each part truncated."""
    p = 0
    while p < len(s) and "0" <= s[p] <= "9":
        p += 1
    q = deg = mins = 0
    while p - q > 2:
        deg = (deg * 10 + ord(s[q]) - 48) & 0xFF
        q += 1
    while p > q:
        mins = (mins * 10 + ord(s[q]) - 48) & 0xFF
        q += 1
    frac = F32(0.0)
    if p < len(s) and s[p] == ".":
        scale = F32(0.1)
        q = p + 1
        while q < len(s) and "0" <= s[q] <= "9":
            frac = F32(frac + F32(ord(s[q]) - 48) * scale)
            scale = F32(scale * F32(0.1))
            q += 1
    return deg * 10_000_000 + (mins * 10_000_000) // 60 + int(F32(frac * F32_1E7_OVER_60))


def wrap_360(deg: float) -> float:
    """AP_Math wrap_360."""
    r = math.fmod(deg, 360.0)
    return r + 360.0 if r < 0 else r


def gps_week_ms(t_unix_s: float) -> tuple[int, int]:
    """GPS week and milliseconds of week of a UTC time (make_gps_time's conversion)."""
    ms = round((t_unix_s + GPS_LEAPSECONDS_S - UNIX_TO_GPS_S) * 1000)
    return ms // (SEC_PER_WEEK * 1000), ms % (SEC_PER_WEEK * 1000)


@dataclass
class GpsState:
    """The AP_GPS::GPS_State fields AP_GPS_NMEA fills (location in 1e-7 degrees and cm)."""

    status: int = NO_GPS
    lat: int = 0
    lng: int = 0
    alt_cm: int = 0
    ground_speed: float = 0.0
    ground_course: float = 0.0
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hdop: int = GPS_UNKNOWN_DOP
    num_sats: int = 0
    time_week: int = 0
    time_week_ms: int = 0
    last_gps_time_ms: int = 0
    last_corrected_gps_time_us: int = 0
    corrected_timestamp_updated: bool = False


@dataclass
class Chunk:
    """Bytes the flight controller's UART hands over at one read: from absolute byte index
    ``k0`` of the port, the last of them received at ``t_last_ms``."""

    data: bytes = b""
    k0: int = 0
    t_last_ms: float = 0.0

    def __add__(self, other: Chunk) -> Chunk:
        if not self.data:
            return other
        if not other.data:
            return self
        assert other.k0 == self.k0 + len(self.data)
        return Chunk(self.data + other.data, self.k0, other.t_last_ms)

    def tail(self, i: int) -> Chunk:
        return Chunk(self.data[i:], self.k0 + i, self.t_last_ms)


class ApNmea:
    """AP_GPS_NMEA with GPS1_TYPE = 5: ``_decode`` byte by byte, ``_term_complete`` on each
    term, ``_have_new_message`` after each sentence whose checksum holds."""

    def __init__(self, baud: int, epoch_of, log: list | None = None) -> None:
        self.baud = baud
        self.epoch_of = epoch_of  # port byte index -> epoch (bookkeeping of the tests)
        self.state = GpsState(status=NO_FIX)
        self.parity = 0
        self.is_checksum_term = False
        self.term = bytearray()
        self.sentence_type = SENTENCE_OTHER
        self.term_number = 0
        self.sentence_length = 0
        self.sentence_done = False
        self.is_unicore = False
        # _new_*: kept from sentence to sentence (an empty field leaves the last value)
        self.new_time = self.new_date = self.new_lat = self.new_lng = self.new_alt = 0
        self.new_speed = self.new_course = self.new_hdop = self.new_sats = 0
        self.new_quality = 0
        self.last_rmc_ms = self.last_gga_ms = self.last_vtg_ms = 0
        self.last_fix_ms = 0
        # (type, now ms, epoch) of each GGA, RMC and VTG whose checksum held
        self.sentences: list[tuple[str, int, int]] = [] if log is None else log
        self.bad_checksums = 0
        self._now = 0
        self._k = 0
        self._rest = 0
        self._t_last_us = 0

    def read(self, chunk: Chunk, now_ms: int) -> tuple[bool, list[int]]:
        """AP_GPS_NMEA::read: every byte available; True if any completed a new message (and
        the epochs of the bytes that did)."""
        parsed, epochs = False, []
        self._now = now_ms
        self._t_last_us = int(chunk.t_last_ms * 1000)
        n = len(chunk.data)
        for i, c in enumerate(chunk.data):
            self._k = chunk.k0 + i
            self._rest = n - i - 1  # available() while this byte is decoded
            if self._decode(c):
                parsed = True
                epochs.append(self.epoch_of(self._k))
        return parsed, epochs

    def _decode(self, c: int) -> bool:
        self.sentence_length += 1
        if c == 59:  # ';': Unicore's header separator, else dropped (not in the parity)
            if not self.is_unicore:
                return False
        if c in (44, 59, 13, 10, 42):  # ',' (';'), '\r', '\n', '*': a term ends
            if c in (44, 59):
                self.parity ^= c
            if self.sentence_done:
                return False
            valid = False
            if len(self.term) < NMEA_TERM_BYTES:
                valid = self._term_complete()
            self.term_number += 1
            self.term.clear()
            self.is_checksum_term = c == 42
            return valid
        if c in (36, 35):  # '$', '#' (Unicore: its CRC32 is not modelled, it never passes)
            self.is_unicore = c == 35
            self.term_number = 0
            self.term.clear()
            self.parity = 0
            self.sentence_type = SENTENCE_OTHER
            self.is_checksum_term = False
            self.sentence_length = 1
            self.sentence_done = False
            return False
        if len(self.term) < NMEA_TERM_BYTES - 1:
            self.term.append(c)
        if not self.is_checksum_term:
            self.parity ^= c
        return False

    def _term_complete(self) -> bool:
        term = self.term.decode("latin-1")
        now = self._now
        st = self.state
        if self.is_checksum_term:
            self.sentence_done = True
            if self.is_unicore or c_strtoul16(term) != self.parity:
                self.bad_checksums += 1
                return False
            kind = self.sentence_type
            if kind == SENTENCE_RMC:
                self.last_rmc_ms = now
                st.lat, st.lng = self.new_lat, self.new_lng
                st.ground_speed = float(F32(self.new_speed) * F32(0.01))
                st.ground_course = wrap_360(float(F32(self.new_course) * F32(0.01)))
                if st.status >= FIX_3D:
                    self._make_gps_time(self.new_date, self.new_time * 10)
                # set_uart_timestamp(_sentence_length) -> receive_time_constraint_us: the last
                # receive time less 10 bits a byte for the sentence and what is still unread
                byte_us = 1_000_000 * 10 // self.baud
                st.last_corrected_gps_time_us = (
                    self._t_last_us - byte_us * (self.sentence_length + self._rest))
                st.corrected_timestamp_updated = True
                st.last_gps_time_ms = now
                self._fill_3d_velocity()
            elif kind == SENTENCE_GGA:
                self.last_gga_ms = now
                st.alt_cm, st.lat, st.lng = self.new_alt, self.new_lat, self.new_lng
                st.num_sats = self.new_sats
                st.hdop = self.new_hdop
                st.status = GGA_QUALITY_STATUS.get(self.new_quality, FIX_3D)
            elif kind == SENTENCE_VTG:
                self.last_vtg_ms = now
                st.ground_speed = float(F32(self.new_speed) * F32(0.01))
                st.ground_course = wrap_360(float(F32(self.new_course) * F32(0.01)))
                self._fill_3d_velocity()
            if kind in SENTENCE_NAMES:
                self.sentences.append((SENTENCE_NAMES[kind], now, self.epoch_of(self._k)))
            return self._have_new_message()
        if self.term_number == 0:
            # the talker: any two upper-case letters; then the sentence's type
            if len(term) < 2 or not ("A" <= term[0] <= "Z" and "A" <= term[1] <= "Z"):
                self.sentence_type = SENTENCE_OTHER
            else:
                self.sentence_type = {"RMC": SENTENCE_RMC, "GGA": SENTENCE_GGA,
                                      "VTG": SENTENCE_VTG}.get(term[2:], SENTENCE_OTHER)
            return False
        if self.sentence_type == SENTENCE_OTHER or not term:
            return False  # (an empty field keeps the last value)
        code = self.sentence_type + self.term_number
        if code == SENTENCE_GGA + 6:  # fix quality
            self.new_quality = ord(term[0]) - 48 if term[0] > "0" else 0
        elif code == SENTENCE_GGA + 7:  # satellites used
            self.new_sats = c_atol(term) & 0xFF
        elif code == SENTENCE_GGA + 8:  # HDOP
            self.new_hdop = parse_decimal_100(term) & 0xFFFF
        elif code in (SENTENCE_RMC + 1, SENTENCE_GGA + 1):  # UTC time
            self.new_time = parse_decimal_100(term)
        elif code == SENTENCE_RMC + 9:  # date
            self.new_date = c_atol(term)
        elif code in (SENTENCE_RMC + 3, SENTENCE_GGA + 2):
            self.new_lat = parse_degrees(term)
        elif code in (SENTENCE_RMC + 4, SENTENCE_GGA + 3):
            if term[0] == "S":
                self.new_lat = -self.new_lat
        elif code in (SENTENCE_RMC + 5, SENTENCE_GGA + 4):
            self.new_lng = parse_degrees(term)
        elif code in (SENTENCE_RMC + 6, SENTENCE_GGA + 5):
            if term[0] == "W":
                self.new_lng = -self.new_lng
        elif code == SENTENCE_GGA + 9:  # altitude above mean sea level
            self.new_alt = parse_decimal_100(term)
        elif code in (SENTENCE_RMC + 7, SENTENCE_VTG + 5):  # speed, knots: "approximates *0.514"
            v = parse_decimal_100(term) * 514
            self.new_speed = abs(v) // 1000 * (1 if v >= 0 else -1)  # (C division truncates)
        elif code in (SENTENCE_RMC + 8, SENTENCE_VTG + 1):  # course over ground, true
            self.new_course = parse_decimal_100(term)
        # (RMC + 2, the status A/V, is read and ignored)
        return False

    def _have_new_message(self) -> bool:
        now = self._now
        if self.last_rmc_ms == 0 or self.last_gga_ms == 0:
            return False
        if now - self.last_rmc_ms > NMEA_SET_MS or now - self.last_gga_ms > NMEA_SET_MS:
            return False
        if self.last_vtg_ms != 0 and now - self.last_vtg_ms > NMEA_SET_MS:
            return False
        if self.last_vtg_ms != 0:
            self.last_vtg_ms = 1  # "prevent these messages being used again"
        self.last_fix_ms = now
        self.last_gga_ms = self.last_rmc_ms = 1
        return True

    def _make_gps_time(self, bcd_date: int, bcd_ms: int) -> None:
        """AP_GPS_Backend::make_gps_time: ddmmyy and hhmmss * 1000 + ms to GPS week and ms."""
        msec, v = bcd_ms % 1000, bcd_ms // 1000
        sec, v = v % 100, v // 100
        mins, hour = v % 100, (v // 100) % 100
        day, mon, year = bcd_date // 10000, (bcd_date // 100) % 100, 2000 + bcd_date % 100
        if not 1 <= mon <= 12 or day < 1:
            return  # (not reached: our RMC always carries the date)
        unix = calendar.timegm((year, mon, day, hour, mins, sec, 0, 0, 0))
        ret = (unix + GPS_LEAPSECONDS_S - UNIX_TO_GPS_S) & 0xFFFFFFFF
        self.state.time_week = ret // SEC_PER_WEEK
        self.state.time_week_ms = (ret % SEC_PER_WEEK) * 1000 + msec

    def _fill_3d_velocity(self) -> None:
        """AP_GPS_Backend::fill_3d_velocity: north and east from speed and course, down 0."""
        c = math.radians(self.state.ground_course)
        v = self.state.ground_speed
        self.state.velocity = (v * math.cos(c), v * math.sin(c), 0.0)


@dataclass
class Report:
    """An AP_GPS::update_instance tick at which the backend's read() returned true."""

    t_ms: int
    epochs: list[int]
    state: GpsState


@dataclass
class ArduPilotGps:
    """AP_GPS for one instance on a serial port, at 50 Hz from ``start_ms``: detection
    (``_detect_instance``), the backend's read and the 4 s timeout (``update_instance``), the
    message timing behind ``is_healthy``. Defaults: GPS1_TYPE 5, GPS_AUTO_CONFIG 1,
    SERIALn_BAUD 38400."""

    port: object  # .read(baud, now_ms) -> Chunk; .write(data, baud, now_ms); .epoch(k)
    gps_type: int = GPS_TYPE_NMEA
    auto_config: int = 1
    port_baud: int = AP_PORT_BAUD
    baud: int = AP_PORT_BAUD
    probe_baud: int = 0
    current_baud: int = 0
    last_baud_change_ms: int = 0
    driver: ApNmea | None = None
    state: GpsState = field(default_factory=GpsState)
    pending: Chunk = field(default_factory=Chunk)
    detect_step: int = 0
    detect_ck: int = 0
    last_message_time_ms: int = 0
    delta_time_ms: int = 0
    last_fix_time_ms: int = 0
    delayed_count: int = 0
    average_delta_ms: float = 0.0
    probes: list[tuple[int, int]] = field(default_factory=list)  # (ms, baud)
    detections: list[tuple[int, int, int]] = field(default_factory=list)  # (ms, baud, epoch)
    timeouts: list[int] = field(default_factory=list)
    reports: list[Report] = field(default_factory=list)
    sentences: list[tuple[str, int, int]] = field(default_factory=list)  # every driver's

    def run(self, start_ms: int, end_ms: int) -> None:
        for now in range(start_ms, end_ms, AP_LOOP_MS):
            self.update(now)

    def _take(self, now: int) -> Chunk:
        got = self.pending + self.port.read(self.baud, now)
        self.pending = Chunk()
        return got

    def update(self, now: int) -> None:
        """AP_GPS::update_instance."""
        if self.driver is None:
            self._detect_instance(now)
            return
        result, epochs = self.driver.read(self._take(now), now)
        self.state = self.driver.state
        tnow = now
        logged = False
        if not result:
            if tnow - self.last_message_time_ms > AP_GPS_TIMEOUT_MS:
                self.timeouts.append(now)
                self.state = GpsState(status=NO_GPS)  # (memset; hdop/vdop unknown)
                self.driver = None  # deleted: detection runs again
                self.last_message_time_ms = tnow
                self.delta_time_ms = AP_GPS_TIMEOUT_MS
                logged = True
        else:
            st = self.state
            if st.corrected_timestamp_updated:
                tnow = st.last_corrected_gps_time_us // 1000
                st.corrected_timestamp_updated = False
            self.delta_time_ms = tnow - self.last_message_time_ms
            self.last_message_time_ms = tnow
            if st.status >= FIX_2D:
                self.last_fix_time_ms = tnow
            logged = True
            self.reports.append(Report(now, epochs, replace(st)))
        if logged:
            if self.delta_time_ms > AP_MAX_DELTA_MS:
                self.delayed_count += 1
            else:
                self.delayed_count = 0
            if self.delta_time_ms < 2000:
                if self.average_delta_ms <= 0:
                    self.average_delta_ms = self.delta_time_ms
                else:
                    self.average_delta_ms = (0.98 * self.average_delta_ms
                                             + 0.02 * self.delta_time_ms)

    def _detect_instance(self, now: int) -> None:
        """AP_GPS::detect_instance / _detect_instance for a serial GPS."""
        self.state.status = NO_GPS
        if now - self.last_baud_change_ms > AP_BAUD_TIME_MS:
            self.port.read(self.baud, now)  # (what the old rate received goes with it)
            self.pending = Chunk()
            if self.probe_baud == 0:
                self.probe_baud = self.port_baud
            else:
                self.current_baud = (self.current_baud + 1) % len(AP_BAUDS)
                self.probe_baud = AP_BAUDS[self.current_baud]
            self.baud = self.probe_baud
            self.last_baud_change_ms = now
            self.probes.append((now, self.baud))
            if self.auto_config >= 1:
                self.port.write(AP_INIT_BLOB, self.baud, now)  # send_blob_start / _update
        chunk = self._take(now)
        n = min(AP_DETECT_MAX_BYTES, len(chunk.data))
        for i in range(n):
            # (under GPS1_TYPE 1 the NMEA detector is not consulted: only NMEA, HEMI,
            # ALLYSTAR and the Unicore types run it)
            if self.gps_type == GPS_TYPE_NMEA and self._nmea_detect(chunk.data[i]):
                self.driver = ApNmea(self.baud, self.port.epoch, self.sentences)
                self.state = self.driver.state
                self.last_message_time_ms = now
                self.delta_time_ms = AP_GPS_TIMEOUT_MS
                self.detections.append((now, self.baud, self.port.epoch(chunk.k0 + i)))
                self.pending = chunk.tail(i + 1)  # read by the driver at the next update
                return
        self.pending = chunk.tail(n)

    def _nmea_detect(self, c: int) -> bool:
        """AP_GPS_NMEA::_detect: '$', anything (XORed) up to '*', then the two upper-case hex
        digits of that XOR."""
        hexdigit = "0123456789ABCDEF"
        if self.detect_step == 0:
            self.detect_ck = 0
            if c == 36:
                self.detect_step = 1
        elif self.detect_step == 1:
            if c == 42:
                self.detect_step = 2
            else:
                self.detect_ck ^= c
        elif self.detect_step == 2:
            self.detect_step = 3 if ord(hexdigit[self.detect_ck >> 4]) == c else 0
        else:
            self.detect_step = 0
            return ord(hexdigit[self.detect_ck & 0xF]) == c
        return False

    def is_healthy(self) -> bool:
        """AP_GPS::is_healthy (AP_GPS_NMEA::is_healthy is true for GPS1_TYPE 5)."""
        return (self.delayed_count < AP_DELAY_THRESHOLD
                and self.average_delta_ms < AP_DELAY_AVG_MAX_MS and self.driver is not None)


# --- the device's line ------------------------------------------------------------------------

class Wire:
    """The flight controller's UART end of the device's line: each byte received at the end of
    its stop bit, handed to a read at ``now_ms`` if received by then, and only if the port is at
    the line's baud (else lost); what ArduPilot writes is kept (the device profiles driven
    through it ignore it: their command links answer no UBX and no $PUBX)."""

    def __init__(self, data: bytes, arrival_ms: np.ndarray, epoch: np.ndarray, baud: int,
                 dropped: list[int] | None = None) -> None:
        self.data, self.arrival_ms, self.epochs, self.baud = data, arrival_ms, epoch, baud
        self.dropped = dropped or []
        self.pos = 0
        self.written: list[tuple[int, int, bytes]] = []

    @classmethod
    def from_line(cls, epochs: list[bytes], t_ms: np.ndarray, baud: int) -> Wire:
        """The device's line (nmea_line.py) carrying ``epochs`` due at ``t_ms``."""
        starts = epoch_starts_s([len(e) for e in epochs], np.asarray(t_ms) / 1000.0, baud)
        sent = [i for i, s in enumerate(starts) if s is not None]
        arrival = [1000.0 * byte_times_s(starts[i], len(epochs[i]), baud) for i in sent]
        epoch = [np.full(len(epochs[i]), i) for i in sent]
        return cls(b"".join(epochs[i] for i in sent), np.concatenate(arrival),
                   np.concatenate(epoch), baud, [i for i, s in enumerate(starts) if s is None])

    def read(self, baud: int, now_ms: int) -> Chunk:
        j = int(np.searchsorted(self.arrival_ms, now_ms, side="right"))
        i, self.pos = self.pos, j
        if baud != self.baud or j == i:
            return Chunk(b"", j, 0.0)
        return Chunk(self.data[i:j], i, float(self.arrival_ms[j - 1]))

    def write(self, data: bytes, baud: int, now_ms: int) -> None:
        self.written.append((now_ms, baud, data))

    def epoch(self, k: int) -> int:
        return int(self.epochs[k]) if 0 <= k < len(self.epochs) else -1

    def sentence_ends(self) -> dict[int, dict[str, float]]:
        """Per epoch, when the '\\r' that completes its GGA, RMC and VTG arrived (ms): the
        byte at which AP_GPS_NMEA's checksum term ends."""
        out: dict[int, dict[str, float]] = {}
        k = 0
        while (k := self.data.find(b"$", k)) >= 0:
            end = self.data.find(b"\r", k)
            kind = self.data[k + 3:k + 6].decode("latin-1")
            if end < 0:
                break
            if kind in ("GGA", "RMC", "VTG"):
                out.setdefault(self.epoch(end), {})[kind] = float(self.arrival_ms[end])
            k = end
        return out
