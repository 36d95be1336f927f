"""The wire between a flight stack's u-blox driver and the emulated module, for the driver tests.

PX4 and ArduPilot cannot be installed here, so ``test_ubx_px4.py`` and ``test_ubx_ardupilot.py``
re-write each driver's u-blox logic as a small model (our code, not theirs) that writes the bytes
the driver writes, in its order, at its baud rates, and judges every answer the way the driver
does. This module is what both models share: the drivers' UBX framing and byte-wise decoder, and
the module end of a simulated UART (bytes sent at a baud other than the module's arrive as noise;
what the module writes reaches the driver only at the baud it was written at) driving the pure
:class:`~virtualgps.device.ubx.link.UbxLink` on a simulated clock, so each replay takes well
under a second.
"""

from __future__ import annotations

import struct
from datetime import UTC, datetime

import numpy as np

from virtualgps.device.nmea import nmea_checksum
from virtualgps.device.ubx.link import UbxLink, default_settings
from virtualgps.receiver.records import Fixes

# --- the wire, as the drivers see it --------------------------------------------------------

CLS_NAV, CLS_RXM, CLS_ACK, CLS_CFG, CLS_MON, CLS_TIM = 0x01, 0x02, 0x05, 0x06, 0x0A, 0x0D
NAV_POSLLH, NAV_STATUS, NAV_DOP, NAV_SOL, NAV_PVT = 0x02, 0x03, 0x04, 0x06, 0x07
NAV_VELNED, NAV_TIMEGPS, NAV_TIMEUTC, NAV_SVINFO, NAV_SAT = 0x12, 0x20, 0x21, 0x30, 0x35
ACK_NAK, ACK_ACK = 0x00, 0x01
CFG_PRT, CFG_MSG, CFG_RST, CFG_RATE, CFG_CFG, CFG_SBAS = 0x00, 0x01, 0x04, 0x08, 0x09, 0x16
CFG_NAV5, CFG_GNSS, CFG_VALSET = 0x24, 0x3E, 0x8A
MON_VER, MON_HW, MON_HW2, MON_RF = 0x04, 0x09, 0x0B, 0x38
RXM_RTCM, TIM_TM2 = 0x32, 0x03


def ubx(cls: int, mid: int, payload: bytes = b"") -> bytes:
    """A UBX frame as the drivers write it (PX4 GPSDriverUBX::sendMessage / calcChecksum,
    ArduPilot AP_GPS_UBLOX::_send_message / _update_checksum): sync, class, id, little-endian
    length, payload, then the 8-bit Fletcher sums over class..payload. Written here rather than
    taken from the emulation, so the emulation's own encoder is not what checks it."""
    body = struct.pack("<BBH", cls, mid, len(payload)) + payload
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes((a, b))


class Scanner:
    """The drivers' byte-wise UBX decoder (PX4 GPSDriverUBX::parseChar, ArduPilot
    AP_GPS_UBLOX::read): sync B5 62, class, id, length, payload, checksum; bytes outside a frame
    (NMEA, noise) are skipped; a frame with a wrong checksum is dropped and the search goes on
    after its sync; a payload longer than ``max_payload`` is taken for noise (ArduPilot drops
    anything larger than its receive buffer)."""

    def __init__(self, max_payload: int = 0xFFFF) -> None:
        self.buf = bytearray()
        self.max_payload = max_payload
        self.bad = 0

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        """Return the (class, id, payload) of every complete, valid frame in ``data``."""
        self.buf += data
        out = []
        while True:
            k = self.buf.find(b"\xb5\x62")
            if k < 0:
                self.buf = self.buf[-1:] if self.buf[-1:] == b"\xb5" else bytearray()
                return out
            del self.buf[:k]
            if len(self.buf) < 6:
                return out
            n = self.buf[4] | (self.buf[5] << 8)
            if n > self.max_payload:
                del self.buf[:2]
                continue
            if len(self.buf) < n + 8:
                return out
            frame = bytes(self.buf[: n + 8])
            if ubx(frame[2], frame[3], frame[6:-2]) == frame:
                out.append((frame[2], frame[3], frame[6:-2]))
                del self.buf[: n + 8]
            else:
                self.bad += 1
                del self.buf[:2]


# --- a receiver in motion: one epoch at a time -----------------------------------------------

T0_UNIX_S = datetime(2024, 6, 1, 10, 0, 0, tzinfo=UTC).timestamp()
LAT0_DEG, LON0_DEG, ALT0_M, GEOID_M = 52.1405, 11.6401, 100.0, 41.0
SPEED_MPS, COURSE_DEG = 5.0, 45.0
#: (prn, azimuth deg, elevation deg, C/N0 dB-Hz, used): GPS, GLONASS (65..), Galileo (301..),
#: and an SBAS satellite tracked but not used (virtualgps.sky.systems numbering).
SKY = ((2, 40.0, 62.0, 45.0, True), (5, 120.0, 35.0, 42.0, True), (12, 200.0, 50.0, 44.0, True),
       (15, 300.0, 20.0, 38.0, True), (24, 80.0, 15.0, 33.0, True), (29, 250.0, 70.0, 46.0, True),
       (66, 10.0, 40.0, 41.0, True), (70, 160.0, 55.0, 43.0, True), (75, 330.0, 25.0, 36.0, True),
       (303, 60.0, 45.0, 40.0, True), (311, 220.0, 30.0, 37.0, True),
       (131, 190.0, 30.0, 39.0, False))
N_USED = sum(s[4] for s in SKY)


def fix_at(t_s: float, fix: bool = True) -> Fixes:
    """One epoch, ``t_s`` seconds after T0: a 3D fix moving north-east at 5 m/s (or, with
    ``fix`` False, the same sky tracked without a fix)."""
    d_m = SPEED_MPS * t_s / np.sqrt(2.0)
    lat = LAT0_DEG + d_m / 111_320.0
    lon = LON0_DEG + d_m / (111_320.0 * np.cos(np.radians(LAT0_DEG)))
    nan = np.array([np.nan])
    sky = np.array([s[:4] for s in SKY], float)
    used = np.array([[s[4] for s in SKY]]) & fix
    return Fixes(
        t_unix_s=np.array([T0_UNIX_S + t_s]),
        lat_deg=np.array([lat]) if fix else nan, lon_deg=np.array([lon]) if fix else nan,
        alt_msl_m=np.array([ALT0_M]) if fix else nan, geoid_sep_m=np.array([GEOID_M]),
        quality=np.array([1 if fix else 0], np.int8), mode=np.array([3 if fix else 1], np.int8),
        hdop=np.array([0.8]) if fix else nan, vdop=np.array([1.2]) if fix else nan,
        pdop=np.array([1.44]) if fix else nan,
        speed_mps=np.array([SPEED_MPS]) if fix else nan,
        course_deg=np.array([COURSE_DEG]) if fix else nan,
        prn=sky[:, 0].astype(int), az_deg=sky[None, :, 1], el_deg=sky[None, :, 2],
        cn0_dbhz=sky[None, :, 3], in_view=np.ones((1, len(SKY)), bool), used=used,
        truth_lat_deg=np.array([LAT0_DEG]), truth_lon_deg=np.array([LON0_DEG]),
        truth_alt_hae_m=np.array([ALT0_M + GEOID_M]),
        sigma_enu_m=np.array([[1.1, 1.3, 2.0]]) if fix else None,
        range_rms_m=np.array([2.5]) if fix else None,
    )


class Module:
    """The module end of a UART: a :class:`UbxLink` at its current baud, on a simulated clock.

    ``write`` delivers a driver's bytes (as noise where the driver's baud is not the module's:
    framing errors, never the bytes sent) and queues the replies at the baud they go out at (a
    baud change is answered at the old baud, then applied). ``advance`` makes the navigation
    epochs due, at the link's period, with its UBX output and (while NMEA is on) a placeholder
    NMEA sentence. ``read`` hands a driver everything written at its baud; the rest is lost.
    """

    def __init__(self, generation: str, no_fix: tuple[float, float] | None = None) -> None:
        self.link = UbxLink(default_settings(generation))
        self.t = 0.0
        self.next_epoch_s = 0.5
        self.epochs = 0
        self.no_fix = no_fix  # (from, to) seconds: epochs without a fix
        self.queue: list[tuple[float, int, bytes]] = []  # (time s, baud, bytes) not yet read
        self.replies: list[tuple[bytes, bytes]] = []  # (command frame, reply) in order
        self.rng = np.random.default_rng(2024)
        self.noise_bytes = 0

    @property
    def baud(self) -> int:
        """The module's UART1 baud now, bits/s."""
        return self.link.settings.baud

    def advance(self, t: float) -> None:
        """Produce the epochs due up to ``t`` seconds."""
        while self.next_epoch_s <= t + 1e-9:
            te = self.next_epoch_s
            fix = not (self.no_fix and self.no_fix[0] <= te < self.no_fix[1])
            nmea = b""
            if self.link.nmea_enabled():
                body = "GNGGA,100000.00,,,,,0,00,99.99,,,,,,"
                nmea = f"${body}*{nmea_checksum(body)}\r\n".encode()
            out = self.link.output(fix_at(te, fix), 0, self.epochs, nmea)
            if out:
                self.queue.append((te, self.baud, out))
            self.epochs += 1
            self.next_epoch_s = te + self.link.settings.nav_period_ms / 1000.0
        self.t = max(self.t, t)

    def write(self, data: bytes, baud: int, t: float) -> None:
        """The driver writes ``data`` at ``baud`` at time ``t``."""
        self.advance(t)
        if baud != self.baud:
            self.noise_bytes += len(data)
            data = self.rng.integers(0, 256, len(data), dtype=np.uint8).tobytes()
        baud_now = self.baud
        for resp in self.link.feed(data):
            if resp.reply:  # (at the baud before the command's own settings apply)
                self.queue.append((t, baud_now, resp.reply))
                self.replies.append((data, resp.reply))
            if resp.settings is not None:
                baud_now = resp.settings.baud

    def read(self, baud: int, t: float) -> bytes:
        """Everything written up to ``t`` that a driver listening at ``baud`` receives."""
        self.advance(t)
        got = b"".join(d for te, b, d in self.queue if te <= t + 1e-9 and b == baud)
        self.queue = [q for q in self.queue if q[0] > t + 1e-9]
        return got


def acks_and_naks(module: Module) -> list[tuple[str, int, int]]:
    """Every ACK-ACK / ACK-NAK the module sent: ("ACK" or "NAK", class, id)."""
    out = []
    for _, reply in module.replies:
        for c, i, p in Scanner().feed(reply):
            if c == CLS_ACK:
                out.append(("ACK" if i == ACK_ACK else "NAK", p[0], p[1]))
    return out
