"""The MediaTek (MTK) command link: ``$PMTK`` packets a client writes to the receiver, and replies.

Owns the byte-stream splitter for client input, ``$PMTK`` parsing with checksum validation, the
link settings a client may change (:class:`MtkSettings`) and the state machine that turns each
command into replies and new settings (:class:`MtkLink`, :func:`handle_command`). Pure: no I/O,
no clock; the daemon feeds it bytes and applies what it returns.

Packet format (MediaTek "PMTK command packet" manuals, e.g. GlobalTop Rev.A08 for MT3318/MT3329/
MT3339; EB-230 data sheet 3.1.2): ``$PMTK`` + a three-digit packet type + ``,field`` ... +
``*HH`` + CR LF, at most 255 bytes. ``$PMTK001,<type>,<flag>`` acknowledges a command with flag
0 (invalid packet), 1 (unsupported packet type), 2 (valid, but the action failed) or 3 (valid,
and succeeded); ``$PMTK010,001`` is the start-up message (gpsd-mtk/mtk-3301.log:1 and
quectel-L70.log, written at power-up).

Commands answered (and what we chose where the manuals are silent):

========  ====================================================================================
000       test: ``$PMTK001,0,3``
101-104   hot / warm / cold / full-cold restart: ack 3, then ``$PMTK010,001`` when the restart
          is made; no fix until that start's TTFF (104 is a cold start). Restarts reset the
          static-navigation threshold (Linx RXM-GPS-FM manual: "periodic mode and static
          navigation settings are returned to default"); 104 restores every setting
          (Quectel L80 protocol: a full cold start also restores the baud rate)
220, 300  fix interval in ms, 100..10000; flag 2 if the enabled sentences of one epoch cannot
          leave the line in one interval at the current baud (the MTK firmware "calculates the
          required data bandwidth and returns an action failed response (Flg = 2)", Linx manual)
251       baud: 0 (default), 4800, 9600, 14400, 19200, 38400, 57600, 115200; the ack goes out
          at the old rate
301, 313  DGPS mode (0 none, 1 RTCM, 2 SBAS/WAAS) and SBAS on/off: stored
314       per-sentence rates, 19 fields of 0..5 (0 off, n: every n-th fix); ``-1`` alone
          restores the defaults (the profile's sentences)
320       power save 0/1: stored, no effect on the output
386, 397  static-navigation speed threshold, 0..2.0 m/s (0 disables): stored
400 401   queries of the fix interval, DGPS mode, SBAS, sentence rates and static-navigation
413 414   threshold, answered by 500, 501, 513, 514, 527
447
605       firmware release query: ``$PMTK705,<firmware>`` (no ack, as real firmware)
========  ====================================================================================

Flags: 0 for a packet without checksum or with fields that are not what the command takes
(wrong count, not a number); 1 for any other three-digit packet type; 2 for well-formed values
the receiver cannot apply (out of range, non-standard baud, too fast for the line); 3 otherwise.
A packet whose checksum is *wrong* gets no reply at all: its packet type is as untrustworthy as
the rest of it, and acknowledging a guessed type would mislead the client (counted in
``MtkLink.bad_checksum``). Lines that are not ``$PMTK`` (gpsd's probes for other receivers:
``$PGRMCE``, ``$PSRF100``, ``$PFEC``, ``$PASHQ``, UBX and Evermore binary) are ignored, as MTK
firmware ignores them.

PMTK314's 19 fields are GLL, RMC, VTG, GGA, GSA, GSV, GRS, GST, 6 reserved, ALM, EPH, DGP, DBG,
ZDA, CHN (gpsd drivers/driver_nmea0183.c lists the same). We output GLL, RMC, VTG, GGA, GSA, GSV
and ZDA; other rates are accepted and ignored, as firmware does for sentences it lacks ("0 -
disabled or not supported sentence"). GST is left out: MT3318-class firmware does not write it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from virtualgps.device.nmea import format_sentence, nmea_checksum

#: Longest MTK packet, bytes (EB-230 data sheet: "Maximum packet length is restricted to 255").
MAX_PACKET_BYTES = 255

#: PMTK314 field index of each sentence we can write.
PMTK314_FIELDS = {"GLL": 0, "RMC": 1, "VTG": 2, "GGA": 3, "GSA": 4, "GSV": 5, "ZDA": 17}
PMTK314_N_FIELDS = 19
PMTK314_MAX_RATE = 5

#: Rates accepted by PMTK251 (MTK manuals); 0 means the default.
MTK_BAUDS = (4800, 9600, 14400, 19200, 38400, 57600, 115200)

FIX_INTERVAL_MIN_MS = 100  # 10 Hz, the fastest MTK fix rate
FIX_INTERVAL_MAX_MS = 10_000
STATIC_NAV_MAX_MPS = 2.0

START_KINDS = {101: "hot", 102: "warm", 103: "cold", 104: "cold"}
STARTUP_MESSAGE = format_sentence("PMTK010,001")  # "$PMTK010,001*2E\r\n"

# Sentences that 314 may enable but the profile does not list go after the profile's own, in
# this order (mt3339.log: ZDA follows RMC).
_EXTRA_ORDER = ("GLL", "ZDA")

FLAG_INVALID, FLAG_UNSUPPORTED, FLAG_FAILED, FLAG_OK = 0, 1, 2, 3


@dataclass(frozen=True)
class PmtkPacket:
    """One ``$PMTK`` packet as the client wrote it.

    number : packet type, 0..999
    fields : the data fields after the type
    checksum : "ok", "wrong" or "absent"
    """

    number: int
    fields: tuple[str, ...]
    checksum: str


@dataclass(frozen=True)
class MtkSettings:
    """What a client may change over the link.

    fix_interval_ms : time between fixes (PMTK220/300)
    baud : serial speed (PMTK251)
    rates : the 19 PMTK314 rates (0 off, n: every n-th fix)
    dgps_mode : 0 none, 1 RTCM, 2 SBAS/WAAS (PMTK301)
    sbas_enabled : SBAS search on (PMTK313)
    power_save : PMTK320
    static_nav_mps : static-navigation speed threshold, m/s; 0 disables (PMTK386/397)
    """

    fix_interval_ms: int = 1000
    baud: int = 38400
    rates: tuple[int, ...] = (0, 1, 1, 1, 1, 1) + (0,) * 13
    dgps_mode: int = 2
    sbas_enabled: bool = True
    power_save: bool = False
    static_nav_mps: float = 0.0

    @property
    def rate_hz(self) -> float:
        """Fixes per second."""
        return 1000.0 / self.fix_interval_ms

    @property
    def sbas_active(self) -> bool:
        """Whether SBAS corrections are used: SBAS searched for and DGPS source SBAS."""
        return self.sbas_enabled and self.dgps_mode == 2

    def sentence_every(self) -> dict[str, int]:
        """The sentences we write with their PMTK314 rate (every n-th fix), enabled ones only."""
        out = {}
        for name, idx in PMTK314_FIELDS.items():
            if self.rates[idx] > 0:
                out[name] = self.rates[idx]
        return out


def default_settings(
    sentences: tuple[str, ...],
    every: dict[str, int],
    rate_hz: float,
    baud: int,
    dgps_mode: int = 2,
    sbas_enabled: bool = True,
    static_nav_mps: float = 0.0,
) -> MtkSettings:
    """The settings at power-on, from the profile's output format.

    Parameters
    ----------
    sentences : the profile's sentence types (``NmeaFormat.sentences``)
    every : their rates, ``{sentence: n}`` (``dict(NmeaFormat.every)``); 1 where absent
    rate_hz : the profile's output rate
    baud : the profile's baud
    dgps_mode, sbas_enabled : the SBAS defaults (MTK firmware ships with SBAS on, WAAS as the
        DGPS source); their effect on fixes belongs to the ``sbas`` effect of the profile
    static_nav_mps : the static-navigation threshold at power-on (0: off)

    Returns
    -------
    MtkSettings
    """
    rates = [0] * PMTK314_N_FIELDS
    for name in sentences:
        if name in PMTK314_FIELDS:
            rates[PMTK314_FIELDS[name]] = min(max(int(every.get(name, 1)), 1), PMTK314_MAX_RATE)
    interval = min(max(round(1000.0 / rate_hz), FIX_INTERVAL_MIN_MS), FIX_INTERVAL_MAX_MS)
    return MtkSettings(
        fix_interval_ms=interval,
        baud=int(baud),
        rates=tuple(rates),
        dgps_mode=dgps_mode,
        sbas_enabled=sbas_enabled,
        static_nav_mps=float(static_nav_mps),
    )


def sentence_order(profile_sentences: tuple[str, ...], settings: MtkSettings) -> tuple[str, ...]:
    """The sentences to write, in output order: the profile's order, then GLL and ZDA.

    Sentences the profile lists but we cannot switch by PMTK314 (GST) are kept as they are.

    Returns
    -------
    sentences : tuple of sentence types; may be empty when the client switched all off
    """
    enabled = settings.sentence_every()
    order = [s for s in profile_sentences if s in enabled or s not in PMTK314_FIELDS]
    order += [s for s in _EXTRA_ORDER if s in enabled and s not in order]
    return tuple(order)


@dataclass(frozen=True)
class MtkResponse:
    """What one command asks of the daemon.

    replies : sentences to write now, ``$...*HH\\r\\n`` each, in order
    settings : the link settings after the command (the same object when unchanged)
    restart : "hot", "warm" or "cold" to restart the receiver, else None
    """

    replies: tuple[str, ...] = ()
    settings: MtkSettings = field(default_factory=MtkSettings)
    restart: str | None = None


# --- bytes -> lines -> packets ----------------------------------------------------------------


class PacketSplitter:
    """Split client bytes into candidate ``$...`` lines; tolerant and bounded.

    A line starts at ``$`` and ends at CR or LF. Bytes outside a line (binary probes, noise) are
    dropped; a ``$`` inside a line starts a new one (``$`` is reserved in NMEA 0183, so the
    earlier bytes were a broken line); a line longer than :data:`MAX_PACKET_BYTES` is dropped.
    Lines may arrive in any number of pieces. At most ``MAX_PACKET_BYTES`` are ever buffered.

    Attributes
    ----------
    dropped_lines : lines discarded for being too long
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._in_line = False
        self.dropped_lines = 0

    def feed(self, data: bytes) -> list[bytes]:
        """Return the complete lines in ``data`` (with what came before), without CR/LF.

        Parameters
        ----------
        data : raw bytes from the client

        Returns
        -------
        lines : list of bytes, each starting with ``$``
        """
        lines: list[bytes] = []
        i, n = 0, len(data)
        while i < n:
            if not self._in_line:
                j = data.find(b"$", i)
                if j < 0:
                    break
                self._in_line, self._buf = True, bytearray(b"$")
                i = j + 1
                continue
            # Inside a line: up to the next CR, LF or '$'.
            k = n
            for stop in (b"\r", b"\n", b"$"):
                p = data.find(stop, i, k)
                if p >= 0:
                    k = p
            self._buf += data[i:k]
            if len(self._buf) > MAX_PACKET_BYTES:
                self.dropped_lines += 1
                self._in_line = False
                self._buf = bytearray()
                i = k
                continue
            if k == n:
                break
            if data[k : k + 1] == b"$":
                self._in_line = False  # a broken line; the next one starts here
                self._buf = bytearray()
                i = k
                continue
            lines.append(bytes(self._buf))
            self._in_line = False
            self._buf = bytearray()
            i = k + 1
        return lines


def parse_pmtk(line: bytes) -> PmtkPacket | None:
    """Parse one ``$PMTKnnn,...*HH`` line.

    Parameters
    ----------
    line : bytes starting with ``$``, without CR/LF

    Returns
    -------
    PmtkPacket, or None when the line is not a PMTK packet (another talker, not ASCII, or no
    three-digit packet type)
    """
    if not line.startswith(b"$PMTK") or not line.isascii():
        return None
    text = line[1:].decode("ascii").rstrip(" \t\x00")
    star = text.rfind("*")
    if star >= 0:
        body, given = text[:star], text[star + 1 :]
        checksum = "ok" if given.upper() == nmea_checksum(body) else "wrong"
    else:
        body, checksum = text, "absent"
    head, *rest = body.split(",")
    number = head[4:]
    if len(number) != 3 or not number.isdigit():
        return None
    return PmtkPacket(int(number), tuple(rest), checksum)


# --- commands -> replies ------------------------------------------------------------------------


def ack(number: int, flag: int) -> str:
    """``$PMTK001,<type>,<flag>*HH\\r\\n`` (the type without leading zeros, as firmware)."""
    return format_sentence(f"PMTK001,{number},{flag}")


def _int(text: str) -> int | None:
    t = text.strip()
    if t[:1] in ("+", "-"):
        sign, t = t[0], t[1:]
    else:
        sign = ""
    return int(sign + t) if t.isdigit() else None


def _float(text: str) -> float | None:
    if "_" in text:
        return None  # float() accepts digit separators; NMEA does not
    try:
        v = float(text)
    except ValueError:
        return None
    return v if v == v and abs(v) != float("inf") else None


def line_bytes_per_s(baud: int) -> float:
    """Bytes per second a serial line carries at ``baud``, 8N1 (10 bits per byte)."""
    return baud / 10.0


def handle_command(
    pkt: PmtkPacket,
    settings: MtkSettings,
    defaults: MtkSettings,
    firmware: str,
    epoch_bytes: int,
) -> MtkResponse:
    """Answer one packet: the replies, the new settings and a restart, if any.

    Parameters
    ----------
    pkt : the packet (its checksum already judged by the caller: see :class:`MtkLink`)
    settings : the link settings now
    defaults : the settings at power-on (PMTK104 and ``$PMTK314,-1`` restore them)
    firmware : the body of the PMTK705 reply after ``PMTK705,``
    epoch_bytes : bytes of one epoch of the enabled sentences (for the too-fast check)

    Returns
    -------
    MtkResponse
    """
    n, f = pkt.number, pkt.fields

    def answer(flag: int, new: MtkSettings | None = None, *more: str) -> MtkResponse:
        return MtkResponse((ack(n, flag), *more), settings if new is None else new)

    if pkt.checksum != "ok":
        return answer(FLAG_INVALID)
    if n == 0:
        return answer(FLAG_OK if not f else FLAG_INVALID)
    if n in START_KINDS:
        if f:
            return answer(FLAG_INVALID)
        new = defaults if n == 104 else replace(settings, static_nav_mps=defaults.static_nav_mps)
        return MtkResponse((ack(n, FLAG_OK), STARTUP_MESSAGE), new, START_KINDS[n])
    if n in (220, 300):
        if not (1 <= len(f) <= (1 if n == 220 else 5)):
            return answer(FLAG_INVALID)
        ms = _int(f[0])
        if ms is None or any(_float(x) is None for x in f[1:]):
            return answer(FLAG_INVALID)
        if not FIX_INTERVAL_MIN_MS <= ms <= FIX_INTERVAL_MAX_MS:
            return answer(FLAG_FAILED)
        if epoch_bytes > line_bytes_per_s(settings.baud) * ms / 1000.0:
            return answer(FLAG_FAILED)
        return answer(FLAG_OK, replace(settings, fix_interval_ms=ms))
    if n == 251:
        baud = _int(f[0]) if len(f) == 1 else None
        if baud is None:
            return answer(FLAG_INVALID)
        if baud == 0:
            baud = defaults.baud
        if baud not in MTK_BAUDS and baud != defaults.baud:
            return answer(FLAG_FAILED)
        return answer(FLAG_OK, replace(settings, baud=baud))
    if n in (301, 313, 320):
        v = _int(f[0]) if len(f) == 1 else None
        if v is None:
            return answer(FLAG_INVALID)
        if not 0 <= v <= (2 if n == 301 else 1):
            return answer(FLAG_FAILED)
        key = {301: "dgps_mode", 313: "sbas_enabled", 320: "power_save"}[n]
        return answer(FLAG_OK, replace(settings, **{key: v if n == 301 else bool(v)}))
    if n == 314:
        if len(f) == 1 and f[0].strip() == "-1":
            return answer(FLAG_OK, replace(settings, rates=defaults.rates))
        rates = [_int(x) for x in f]
        if len(rates) != PMTK314_N_FIELDS or any(r is None for r in rates):
            return answer(FLAG_INVALID)
        if any(not 0 <= r <= PMTK314_MAX_RATE for r in rates):  # type: ignore[operator]
            return answer(FLAG_FAILED)
        return answer(FLAG_OK, replace(settings, rates=tuple(rates)))  # type: ignore[arg-type]
    if n in (386, 397):
        v = _float(f[0]) if len(f) == 1 else None
        if v is None:
            return answer(FLAG_INVALID)
        if not 0.0 <= v <= STATIC_NAV_MAX_MPS:
            return answer(FLAG_FAILED)
        return answer(FLAG_OK, replace(settings, static_nav_mps=v))
    queries = {
        400: lambda s: f"PMTK500,{s.fix_interval_ms},0,0,0.0,0.0",
        401: lambda s: f"PMTK501,{s.dgps_mode}",
        413: lambda s: f"PMTK513,{int(s.sbas_enabled)}",
        414: lambda s: "PMTK514," + ",".join(str(r) for r in s.rates),
        447: lambda s: f"PMTK527,{s.static_nav_mps:.2f}",
        605: lambda s: f"PMTK705,{firmware}",
    }
    if n in queries:
        if f:
            return answer(FLAG_INVALID)
        return MtkResponse((format_sentence(queries[n](settings)),), settings)
    return answer(FLAG_UNSUPPORTED)


class MtkLink:
    """The command link's state: a splitter over the client's bytes and the current settings.

    Parameters
    ----------
    defaults : settings at power-on (see :func:`default_settings`)
    firmware : the PMTK705 body (the profile's ``firmware``)

    Attributes
    ----------
    settings : MtkSettings now
    defaults : MtkSettings at power-on
    commands : packets answered
    bad_checksum : packets ignored for a wrong checksum
    """

    protocol = "MTK"  # (for people: log lines)

    def __init__(self, defaults: MtkSettings, firmware: str) -> None:
        self.defaults = defaults
        self.settings = defaults
        self.firmware = firmware
        self._splitter = PacketSplitter()
        self.commands = 0
        self.bad_checksum = 0

    def summary(self) -> str:
        """The link's settings in one line (the daemon's exit log)."""
        return str(self.settings)

    def startup(self) -> str:
        """The sentence written at power-on, ``$PMTK010,001*2E\\r\\n``."""
        return STARTUP_MESSAGE

    def feed(self, data: bytes, epoch_bytes: int) -> list[MtkResponse]:
        """Answer every complete packet in ``data``; ``self.settings`` follows each one.

        Parameters
        ----------
        data : raw bytes from the client (pieces of lines, junk and binary allowed)
        epoch_bytes : bytes of one epoch of the enabled sentences, for the too-fast check

        Returns
        -------
        responses : one per packet answered, in order
        """
        out = []
        for line in self._splitter.feed(data):
            pkt = parse_pmtk(line)
            if pkt is None:
                continue
            if pkt.checksum == "wrong":
                self.bad_checksum += 1
                continue
            resp = handle_command(pkt, self.settings, self.defaults, self.firmware, epoch_bytes)
            self.settings = resp.settings
            self.commands += 1
            out.append(resp)
        return out
