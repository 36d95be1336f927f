"""The u-blox command link: UBX and ``$PUBX`` input, replies, settings, and each epoch's output.

Owns what a client may change over the port (:class:`UbxSettings`), the state machine that
answers each command (:class:`UbxLink`) and the assembly of one epoch's UBX output at the
configured rates. Pure: no I/O, no clock; the daemon feeds it bytes, writes the replies, applies
returned settings *after* writing the reply (a baud change is acknowledged at the old baud, as
the module does: UBX-13003221 CFG-PRT; PX4's driver reads the ACK before switching), and calls
:meth:`UbxLink.output` once per navigation solution.

Answers (u-blox 8 / M8 receiver description UBX-13003221 and M9 SPG 4.04 interface description,
"UBX-CFG" messages; what we chose where they are silent):

=================  =============================================================================
CFG-PRT 06 00      poll (no payload: this port; 1 byte: that port) -> CFG-PRT + ACK; set: one or
                   more 20-byte blocks (PX4 sends UART1 and USB in one message) -> ACK, then the
                   new baud and protocol masks. Bauds outside :data:`keys.BAUDS` -> NAK. The
                   mode word (data bits, parity) is stored; the line stays 8N1.
CFG-MSG 06 01      poll (2 bytes) -> the 8-byte form + ACK; set for this port (3 bytes) or all
                   six ports (8 bytes) -> ACK. A class no u-blox outputs -> NAK. Rates of
                   messages we do not emit are stored and never used.
CFG-RST 06 04      no reply (the module sends none); navBbrMask 0x0000 hot, 0x0001 (ephemeris
                   only) warm, 0xFFFF or any mask clearing almanac or position cold, else warm.
                   resetMode 0/1/4 (hardware or software reset) also reloads the saved settings;
                   2 restarts GNSS only; 8 stops and 9 starts GNSS.
CFG-RATE 06 08     poll / set measRate >= 25 ms, navRate 1..127, timeRef 0..4.
CFG-CFG 06 09      clear (saved := defaults), save (saved := current), load (current := saved),
                   in that order, whatever the section bits -> ACK.
CFG-SBAS 06 16     poll / set (stored: mode, usage, maxSBAS, scan masks).
CFG-NAV5 06 24     poll / set of the masked fields; invalid dynModel or fixMode -> NAK.
CFG-GNSS 06 3E     poll / set of blocks; reserved channels beyond the channels in use, a
                   reserved count above its maximum, or a gnssId above 6 -> NAK. The M8 limit of
                   three concurrent major GNSS is not checked (its reply is not documented).
CFG-VALSET 06 8A   M9 only (an M8 NAKs it: PX4 tells the generations apart that way). Keys of
CFG-VALGET 06 8B   :mod:`.keys`; any unknown key or invalid value -> NAK and nothing applied.
CFG-VALDEL 06 8C   Layers RAM (the current settings), BBR and Flash (one saved copy, see
                   below), Default. Transactions (VALSET version 1): start / ongoing / apply are
                   kept; a value is validated when it arrives rather than when applied. VALGET
                   wildcards (item 0xFFF, group 0xFF) are expanded; the answer is VALGET + ACK.
CFG-NAVX5 TP5 ...  the other legacy CFG messages drivers send (NAVX5, TP5, INF, ITFM, PM2, RXM,
                   NMEA, ANT, ODO, PMS) are stored with an ACK and echoed on poll (zeros before
                   a set); they change nothing here.
other CFG          ACK-NAK; a CFG message of a wrong length -> ACK-NAK.
NAV/MON polls      an empty NAV message we emit -> that message for the last epoch output
                   (nothing before the first epoch); MON-VER, MON-HW (and MON-RF on M9) -> it.
other classes      silence, as the module.
$PUBX,41 / ,40     port protocols and baud / NMEA rates per port; no reply (u-blox sends none).
=================  =============================================================================

Input is honoured only in the protocols the port's inProtoMask allows (UBX bit 0, NMEA bit 1):
a client that switches UBX input off locks itself out, as on the module. Replies are sent
whatever the outProtoMask (not confirmed on hardware). BBR and Flash are one saved copy: a key
deleted by VALDEL reads back its default there (the module would omit it). On M9 the legacy
CFG-PRT/MSG/RATE/NAV5/GNSS/SBAS messages are still accepted: M9 firmware keeps them (deprecated)
and ArduPilot and older PX4 paths still send them. NAV-SOL and NAV-SVINFO are not in M9
firmware: their rates are stored there but they are never output.

Output order within an epoch: UBX NAV messages in class/id order (u-blox firmware outputs its
periodic messages in its message-table order, which is class/id order), then the NMEA sentences
the caller passes, then NAV-EOE (UBX-13003221 UBX-NAV-EOE: "output after all enabled NAV class
messages ... and after all enabled NMEA messages"), then MON-HW / MON-RF. A message with rate n
is output on every n-th navigation solution (``epoch_counter % n == 0``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, replace

from virtualgps.device.nmea import format_sentence, nmea_checksum
from virtualgps.device.ubx import keys as K
from virtualgps.device.ubx import messages as M
from virtualgps.device.ubx.frame import InputSplitter, decode, encode
from virtualgps.device.ubx.settings import (
    N_MSG_PORTS,
    NAV5_FIELDS,
    NAV5_FORMAT,
    NAV5_MASK_FIELDS,
    NMEA_IDS,
    PROTO_NMEA,
    PROTO_UBX,
    GnssBlock,
    SbasConfig,
    UbxSettings,
    default_settings,
    key_value,
    with_key,
)
from virtualgps.receiver.records import Fixes

# The settings records live in .settings; these are part of the link's API.
__all__ = ["UbxLink", "UbxResponse", "UbxSettings", "default_settings"]

CLASS_CFG = 0x06
#: Classes a u-blox outputs (CFG-MSG accepts only these): NAV RXM INF MON AID TIM ESF MGA LOG SEC
#: HNR, NMEA standard (F0) and PUBX (F1).
OUTPUT_CLASSES = frozenset((0x01, 0x02, 0x04, 0x0A, 0x0B, 0x0D, 0x10, 0x13, 0x21, 0x27, 0x28,
                            0xF0, 0xF1))
# Legacy CFG messages stored without effect: id -> (set lengths (0: any multiple of 10), polls).
_PASSIVE = {0x02: ((0,), (1,)), 0x11: ((2,), (0,)), 0x13: ((4,), (0,)),
            0x17: ((4, 12, 20), (0,)), 0x1E: ((20,), (0,)), 0x23: ((40, 44), (0,)),
            0x31: ((32,), (0, 1)), 0x39: ((8,), (0,)), 0x3B: ((44, 48), (0,)),
            0x86: ((8,), (0,))}
_M8_ONLY = frozenset((M.NAV_SOL, M.NAV_SVINFO))
_M9_ONLY = frozenset((M.MON_RF,))


@dataclass(frozen=True)
class UbxResponse:
    """What one command asks of the daemon.

    reply : bytes to write now (may be empty)
    settings : settings to apply *after* ``reply`` is written (baud, masks, rates), or None
    restart : "hot", "warm" or "cold" to restart the receiver (CFG-RST), else None
    stop : GNSS stopped (CFG-RST resetMode 8): no output until a restart
    command : what was answered, e.g. "CFG-PRT", "PUBX,41"
    """

    reply: bytes = b""
    settings: UbxSettings | None = None
    restart: str | None = None
    stop: bool = False
    command: str = ""


# --- the link --------------------------------------------------------------------------------


class UbxLink:
    """The UBX link's state: a splitter over the client's bytes, the current and saved settings.

    Parameters
    ----------
    defaults : settings at power-on (see :func:`default_settings`)
    port : the port the client is on (1: UART1, 3: USB)
    uere_m : range sigma behind accuracies where fixes carry none (see :mod:`.messages`)

    Attributes
    ----------
    settings : UbxSettings now; saved : the BBR/Flash copy; defaults : at power-on
    commands : UBX frames and $PUBX lines answered or applied
    ignored : frames and lines ignored (input protocol off, unknown, not for us)
    internal_errors : commands that raised inside the link (a bug: they are ignored, and the
        tests require 0)
    """

    protocol = "u-blox"  # (for people: log lines)

    def __init__(self, defaults: UbxSettings, port: int = K.PORT_UART1,
                 uere_m: float = M.FALLBACK_UERE_M) -> None:
        self.defaults = self.settings = self.saved = defaults
        self.port = port
        self.uere_m = uere_m
        self.commands = 0
        self.ignored = 0
        self.internal_errors = 0
        self.gnss_stopped = False
        self._splitter = InputSplitter()
        self._tx: tuple[int, list[tuple[K.ConfigKey, int]]] | None = None  # (layers, pairs)
        self._sol: tuple[Fixes, M.Solution] | None = None
        self._last_i = -1
        self._start_t_unix_s: float | None = None
        self._ttff_ms: int | None = None  # after the first fix since start or restart

    def startup(self) -> bytes:
        """The notices the module prints at power-on when NMEA output is on: ``$GNTXT,01,01,02,``
        with the maker, the chip and hwVersion, swVersion and each MON-VER extension (as NEO-M8N
        modules print them, e.g. ``HW UBX-M8030 00080000``, ``ROM CORE 3.01 (107888)``,
        ``PROTVER=18.00``: logs quoted in public repositories; the M9's chip is the UBX-M9140).
        """
        s = self.settings
        if not s.ports[self.port].out_proto & PROTO_NMEA:
            return b""
        chip = "UBX-M8030" if s.generation == "M8" else "UBX-M9140"
        texts = ("u-blox AG - www.u-blox.com", f"HW {chip} {s.hw_version}", s.sw_version,
                 *s.extensions)
        return "".join(format_sentence(f"GNTXT,01,01,02,{t}") for t in texts).encode("ascii")

    @property
    def bad_checksum(self) -> int:
        """UBX frames dropped for a wrong checksum (:class:`InputSplitter`)."""
        return self._splitter.bad_checksum

    @property
    def splitter(self) -> InputSplitter:
        """The input splitter (its counters: bad checksums, skipped bytes)."""
        return self._splitter

    def feed(self, data: bytes) -> list[UbxResponse]:
        """Answer every complete command in ``data``; ``self.settings`` follows each one.

        Parameters
        ----------
        data : raw bytes from the client (pieces, NMEA lines, noise allowed); never raises

        Returns
        -------
        responses : one per command answered or applied, in order
        """
        out = []
        for item in self._splitter.feed(data):
            try:
                resp = self._handle(item)
            except Exception:  # a bug here must never stop the daemon: count it, go on
                self.internal_errors += 1
                resp = None
            if resp is None:
                self.ignored += 1
                continue
            self.commands += 1
            if resp.settings is not None:
                self.settings = resp.settings
            if resp.restart is not None:
                self._start_t_unix_s, self._ttff_ms = None, None
                self.gnss_stopped = False
            if resp.stop:
                self.gnss_stopped = True
            out.append(resp)
        return out

    def _handle(self, item: bytes) -> UbxResponse | None:
        mask = self.settings.ports[self.port].in_proto
        if item[:1] == b"$":
            return self._handle_line(item) if mask & PROTO_NMEA else None
        if not mask & PROTO_UBX:
            return None
        parsed = decode(item)
        if parsed is None:
            return None
        cls, mid, payload = parsed
        if cls == CLASS_CFG:
            if mid != 0x8A:
                self._tx = None  # any other CFG message cancels a VALSET transaction
            return self._handle_cfg(mid, payload)
        if payload:
            return None  # output messages are not input; MGA/AID/RXM input is not modelled
        return self._handle_poll(cls, mid)

    # -- polls of output messages --

    def _handle_poll(self, cls: int, mid: int) -> UbxResponse | None:
        s, name = self.settings, _name(cls, mid)
        if (cls, mid) == M.MON_VER:
            return UbxResponse(M.mon_ver(s.sw_version, s.hw_version, s.extensions), command=name)
        if (cls, mid) == M.MON_HW:
            return UbxResponse(M.mon_hw(**M.MON_HW_DEFAULTS), command=name)
        if (cls, mid) == M.MON_RF and s.generation == "M9":
            return UbxResponse(M.mon_rf(**M.MON_HW_DEFAULTS), command=name)
        if (cls, mid) in _EPOCH_ENCODERS and self._sol is not None and self._supported(cls, mid):
            return UbxResponse(self._encode(cls, mid, self._sol[1], self._last_i), command=name)
        return None

    def _supported(self, cls: int, mid: int) -> bool:
        m9 = self.settings.generation == "M9"
        return not (((cls, mid) in _M8_ONLY and m9) or ((cls, mid) in _M9_ONLY and not m9))

    def _encode(self, cls: int, mid: int, sol: M.Solution, i: int) -> bytes:
        if (cls, mid) == M.NAV_STATUS:
            t = float(sol.fixes.t_unix_s[i])
            start = self._start_t_unix_s if self._start_t_unix_s is not None else t
            ttff = self._ttff_ms if self._ttff_ms is not None else 0
            return M.nav_status(sol, i, ttff, round((t - start) * 1000.0))
        if (cls, mid) == M.NAV_PVT:
            return M.nav_pvt(sol, i, self.settings.protver)
        return _EPOCH_ENCODERS[(cls, mid)](sol, i)

    # -- CFG --

    def _handle_cfg(self, mid: int, p: bytes) -> UbxResponse | None:
        s, n = self.settings, len(p)
        name = _name(CLASS_CFG, mid)

        def ok(reply: bytes = b"", new: UbxSettings | None = None) -> UbxResponse:
            return UbxResponse(reply + M.ack(CLASS_CFG, mid), new, command=name)

        nak = UbxResponse(M.nak(CLASS_CFG, mid), command=name)
        if mid == 0x00:  # CFG-PRT
            if n <= 1:
                port = self.port if n == 0 else p[0]
                return ok(_cfg_prt(s, port)) if port < 5 else nak
            if n % 20:
                return nak
            new = s
            for j in range(0, n, 20):
                port, _, mode, baud, inp, outp, _ = struct.unpack("<BxHIIHHH2x", p[j : j + 20])
                if port >= 5:
                    return nak
                if port in (K.PORT_UART1, K.PORT_UART2):
                    if baud not in K.BAUDS:
                        return nak
                    new = new.with_port(port, baud=baud, mode=mode)
                new = new.with_port(port, in_proto=inp, out_proto=outp)
            return ok(new=new)
        if mid == 0x01:  # CFG-MSG
            if n not in (2, 3, 8) or p[0] not in OUTPUT_CLASSES:
                return nak
            if n == 2:
                rates = [s.rate(p[0], p[1], port) for port in range(N_MSG_PORTS)]
                return ok(encode(CLASS_CFG, 0x01, bytes([p[0], p[1], *rates])))
            new_rates = {self.port: p[2]} if n == 3 else dict(enumerate(p[2:8]))
            return ok(new=s.with_rates(p[0], p[1], new_rates))
        if mid == 0x04:  # CFG-RST: no acknowledgement (UBX-13003221 CFG-RST)
            return self._reset(p) if n == 4 else nak
        if mid == 0x08:  # CFG-RATE
            if n == 0:
                return ok(encode(CLASS_CFG, 0x08, struct.pack(
                    "<HHH", s.meas_rate_ms, s.nav_rate, s.time_ref)))
            if n != 6:
                return nak
            meas, nav, ref = struct.unpack("<HHH", p)
            if meas < K.MEAS_RATE_MIN_MS or not 1 <= nav <= K.NAV_RATE_MAX or ref > 4:
                return nak
            return ok(new=replace(s, meas_rate_ms=meas, nav_rate=nav, time_ref=ref))
        if mid == 0x09:  # CFG-CFG
            if n not in (12, 13):
                return nak
            clear, save, load = struct.unpack("<III", p[:12])
            if clear:
                self.saved = self.defaults
            if save:
                self.saved = s
            return ok(new=self.saved if load else None)
        if mid == 0x16:  # CFG-SBAS
            sb = s.sbas
            if n == 0:
                return ok(encode(CLASS_CFG, 0x16, struct.pack(
                    "<BBBBI", sb.mode, sb.usage, sb.max_sbas, sb.scanmode2, sb.scanmode1)))
            if n != 8:
                return nak
            return ok(new=replace(s, sbas=SbasConfig(*struct.unpack("<BBBBI", p))))
        if mid == 0x24:  # CFG-NAV5
            return self._nav5(p, ok, nak)
        if mid == 0x3E:  # CFG-GNSS
            return self._gnss(p, ok, nak)
        if mid in (0x8A, 0x8B, 0x8C) and s.generation == "M9":
            return (self._valset, self._valget, self._valdel)[mid - 0x8A](p, ok, nak)
        if mid in _PASSIVE:
            sets, polls = _PASSIVE[mid]
            stored = dict(s.passive)
            if n in polls:
                size = sets[0] or 10  # INF: one 10-byte block per protocol
                body = stored.get(mid, bytes(p[:1]) + bytes(size - n))
                return ok(encode(CLASS_CFG, mid, body))
            if n in sets or (sets == (0,) and n and n % 10 == 0):
                stored[mid] = bytes(p)
                return ok(new=replace(s, passive=tuple(sorted(stored.items()))))
        return nak

    def _reset(self, p: bytes) -> UbxResponse | None:
        mask, mode = struct.unpack("<HBx", p)
        if mask == 0:
            kind = "hot"
        elif mask == 0xFFFF or mask & 0x0012:  # almanac (bit 1) or position (bit 4) cleared
            kind = "cold"
        else:
            kind = "warm"
        if mode in (0, 1, 4):  # hardware or software reset: the RAM configuration is reloaded
            return UbxResponse(b"", self.saved, kind, command="CFG-RST")
        if mode in (2, 9):
            return UbxResponse(b"", None, kind, command="CFG-RST")
        if mode == 8:
            return UbxResponse(b"", None, None, stop=True, command="CFG-RST")
        return None

    def _nav5(self, p: bytes, ok, nak) -> UbxResponse:
        s = self.settings
        if len(p) == 0:
            body = struct.pack(NAV5_FORMAT, 0xFFFF, *(getattr(s.nav5, f) for f in NAV5_FIELDS))
            return ok(encode(CLASS_CFG, 0x24, body))
        if len(p) != 36:
            return nak
        mask, *values = struct.unpack(NAV5_FORMAT, p)
        given = dict(zip(NAV5_FIELDS, values, strict=True))
        changes = {f: given[f] for bit, fields in NAV5_MASK_FIELDS if mask & bit for f in fields}
        models = K.DYN_MODELS_M9 if s.protver >= 19.2 else K.DYN_MODELS_M8
        if "dyn_model" in changes and changes["dyn_model"] not in models:
            return nak
        if "fix_mode" in changes and not 1 <= changes["fix_mode"] <= 3:
            return nak
        return ok(new=replace(s, nav5=replace(s.nav5, **changes)))

    def _gnss(self, p: bytes, ok, nak) -> UbxResponse:
        s = self.settings
        if len(p) == 0:
            body = struct.pack("<BBBB", 0, s.num_trk_ch_hw, s.num_trk_ch_use, len(s.gnss))
            body += b"".join(struct.pack("<BBBxI", b.gnss_id, b.res_trk_ch, b.max_trk_ch,
                                         int(b.enabled) | (b.sig_cfg_mask << 16))
                             for b in s.gnss)
            return ok(encode(CLASS_CFG, 0x3E, body))
        if len(p) < 4 or p[0] != 0 or len(p) != 4 + 8 * p[3]:
            return nak
        use = s.num_trk_ch_hw if p[2] == 0xFF else min(p[2], s.num_trk_ch_hw)
        blocks = {b.gnss_id: b for b in s.gnss}
        for j in range(4, len(p), 8):
            gid, res, mx, flags = struct.unpack("<BBBxI", p[j : j + 8])
            if gid > 6 or res > mx:
                return nak
            blocks[gid] = GnssBlock(gid, res, mx, bool(flags & 1), (flags >> 16) & 0xFF)
        if sum(b.res_trk_ch for b in blocks.values() if b.enabled) > use:
            return nak
        gnss = tuple(blocks[g] for g in sorted(blocks))
        return ok(new=replace(s, gnss=gnss, num_trk_ch_use=use))

    # -- M9 configuration interface --

    def _valset(self, p: bytes, ok, nak) -> UbxResponse:
        if len(p) < 4 or p[0] not in (0, 1):
            self._tx = None
            return nak
        layers, action = p[1] & 0x07, (p[2] & 0x03) if p[0] == 1 else 0
        raw = K.parse_cfgdata(p[4:])
        pairs: list[tuple[K.ConfigKey, int]] = []
        for key_id, value in raw or ():
            key = K.KEYS.get(key_id & 0x7FFFFFFF)
            v = K.decode_value(key, value) if key is not None else None
            if key is None or v is None or not key.accepts(v):
                raw = None
                break
            pairs.append((key, v))
        if raw is None or len(pairs) > 64 or not layers:
            self._tx = None
            return nak
        if action == 1:  # (re)start a transaction
            self._tx = (layers, pairs)
            return ok()
        if action in (2, 3):
            if self._tx is None or self._tx[0] != layers:
                self._tx = None
                return nak
            pairs = self._tx[1] + pairs
            if action == 2:
                self._tx = (layers, pairs)
                return ok()
        self._tx = None
        new = self.settings
        for key, v in pairs:
            if layers & 0x01:
                new = with_key(new, key, v)
            if layers & 0x06:
                self.saved = with_key(self.saved, key, v)
        return ok(new=new if layers & 0x01 else None)

    def _valget(self, p: bytes, ok, nak) -> UbxResponse:
        n = len(p)
        if n < 4 or (n - 4) % 4 or p[0] != 0 or p[1] not in (0, 1, 2, 7) or n > 4 + 4 * 64:
            return nak
        source = {0: self.settings, 1: self.saved, 2: self.saved, 7: self.defaults}[p[1]]
        position = p[2] | (p[3] << 8)
        found = _keys_named(p)
        if found is None:
            return nak
        data = b"".join(k.key_id.to_bytes(4, "little") + K.encode_value(k, key_value(source, k))
                        for k in found[position : position + 64])
        return ok(encode(CLASS_CFG, 0x8B, bytes((1, p[1], p[2], p[3])) + data))

    def _valdel(self, p: bytes, ok, nak) -> UbxResponse:
        n = len(p)
        if n < 4 or (n - 4) % 4 or p[0] not in (0, 1) or not p[1] & 0x06 or n > 4 + 4 * 64:
            return nak
        found = _keys_named(p)
        if found is None:
            return nak
        for k in found:
            self.saved = with_key(self.saved, k, key_value(self.defaults, k))
        return ok()

    # -- $PUBX --

    def _handle_line(self, line: bytes) -> UbxResponse | None:
        if not line.startswith(b"$PUBX,4") or not line.isascii():
            return None
        text = line[1:].decode("ascii").strip()
        body, star, given = text.rpartition("*")
        if not star or given.upper() != nmea_checksum(body):
            return None
        f = body.split(",")
        s = self.settings
        if f[1] == "41" and len(f) == 7:
            port, in_p, out_p, baud = _num(f[2]), _num(f[3], 16), _num(f[4], 16), _num(f[5])
            if port is None or in_p is None or out_p is None or baud is None:
                return None
            if port >= 5 or (port in (K.PORT_UART1, K.PORT_UART2) and baud not in K.BAUDS):
                return None
            new = s.with_port(port, in_proto=in_p & 0xFFFF, out_proto=out_p & 0xFFFF)
            if port in (K.PORT_UART1, K.PORT_UART2):
                new = new.with_port(port, baud=baud)
            return UbxResponse(b"", new, command="PUBX,41")
        if f[1] == "40" and len(f) == 9 and f[2].upper() in NMEA_IDS:
            rates = {port: _num(r) for port, r in enumerate(f[3:8])}
            if any(r is None or not 0 <= r <= 255 for r in rates.values()):
                return None
            return UbxResponse(b"", s.with_rates(0xF0, NMEA_IDS[f[2].upper()], rates),
                               command="PUBX,40")
        return None

    # -- output --

    def _solution(self, fixes: Fixes) -> M.Solution:
        if self._sol is None or self._sol[0] is not fixes:
            self._sol = (fixes, M.solution(fixes, self.uere_m))
        return self._sol[1]

    def output(self, fixes: Fixes, i: int, epoch_counter: int, nmea: bytes = b"",
               solution: M.Solution | None = None) -> bytes:
        """The bytes of one navigation solution on this port, at the configured rates.

        Parameters
        ----------
        fixes : the batch holding the epoch; i : its index
        epoch_counter : navigation solutions since start (0, 1, 2, ...); a message of rate n
            is written when ``epoch_counter % n == 0``
        nmea : the epoch's NMEA sentences, placed where the module writes them (written only
            when NMEA output is on for this port)
        solution : :func:`virtualgps.device.ubx.messages.solution` of ``fixes`` where the caller
            has it (a fleet's batch: made once for all its receivers)

        Returns
        -------
        bytes : UBX NAV messages in class/id order, the NMEA, NAV-EOE, then MON-HW/MON-RF;
            empty while GNSS is stopped
        """
        if solution is not None:
            self._sol = (fixes, solution)
        sol = self._solution(fixes)
        self._last_i = i
        t = float(fixes.t_unix_s[i])
        if self._start_t_unix_s is None:
            self._start_t_unix_s = t
        if self._ttff_ms is None and sol.fix_ok[i]:
            self._ttff_ms = round((t - self._start_t_unix_s) * 1000.0)
        if self.gnss_stopped:
            return b""
        s = self.settings
        out_proto = s.ports[self.port].out_proto
        parts = []

        def emit(ids: tuple[tuple[int, int], ...]) -> None:
            if not out_proto & PROTO_UBX:
                return
            for cls, mid in ids:
                r = s.rate(cls, mid, self.port)
                if r and epoch_counter % r == 0 and self._supported(cls, mid):
                    if (cls, mid) in _EPOCH_ENCODERS:
                        parts.append(self._encode(cls, mid, sol, i))
                    elif (cls, mid) == M.MON_HW:
                        parts.append(M.mon_hw(**M.MON_HW_DEFAULTS))
                    else:
                        parts.append(M.mon_rf(**M.MON_HW_DEFAULTS))

        emit(_NAV_ORDER)
        if out_proto & PROTO_NMEA:
            parts.append(nmea)
        emit((M.NAV_EOE, M.MON_HW, M.MON_RF))
        return b"".join(parts)

    def summary(self) -> str:
        """The settings a client changes most, in one line (the daemon's exit log): baud,
        navigation period, dynamic model and the messages on for this port with their rates."""
        s = self.settings
        on = [f"{_name(cls, mid)}/{r[self.port]}" for cls, mid, r in s.msg_rates
              if r[self.port] and cls != 0xF0]
        nmea = [f"{n}/{r}" for n, r in self.nmea_every().items()] if self.nmea_enabled() else []
        return (f"{s.generation} at {s.baud} baud, navigation every {s.nav_period_ms} ms, "
                f"dynamic model {s.dyn_model}; UBX out: {', '.join(on) or 'none'}; NMEA out: "
                f"{', '.join(nmea) or 'none'}")

    def nmea_enabled(self) -> bool:
        """Whether NMEA output is on for this port (CFG-PRT outProtoMask bit 1)."""
        return bool(self.settings.ports[self.port].out_proto & PROTO_NMEA)

    def nmea_every(self) -> dict[str, int]:
        """NMEA sentences on this port with their rate (every n-th solution), enabled only."""
        out = {}
        for name, mid in NMEA_IDS.items():
            r = self.settings.rate(0xF0, mid, self.port)
            if r:
                out[name] = r
        return out


_EPOCH_ENCODERS = {
    M.NAV_POSLLH: M.nav_posllh, M.NAV_STATUS: None, M.NAV_DOP: M.nav_dop, M.NAV_SOL: M.nav_sol,
    M.NAV_PVT: None, M.NAV_VELNED: M.nav_velned, M.NAV_TIMEGPS: M.nav_timegps,
    M.NAV_TIMEUTC: M.nav_timeutc, M.NAV_SVINFO: M.nav_svinfo, M.NAV_SAT: M.nav_sat,
    M.NAV_EOE: M.nav_eoe,
}
_NAV_ORDER = tuple(sorted(k for k in _EPOCH_ENCODERS if k != M.NAV_EOE))
_NAMES = {M.NAV_POSLLH: "NAV-POSLLH", M.NAV_STATUS: "NAV-STATUS", M.NAV_DOP: "NAV-DOP",
          M.NAV_SOL: "NAV-SOL", M.NAV_PVT: "NAV-PVT", M.NAV_VELNED: "NAV-VELNED",
          M.NAV_TIMEGPS: "NAV-TIMEGPS", M.NAV_TIMEUTC: "NAV-TIMEUTC",
          M.NAV_SVINFO: "NAV-SVINFO", M.NAV_SAT: "NAV-SAT", M.NAV_EOE: "NAV-EOE",
          M.MON_VER: "MON-VER", M.MON_HW: "MON-HW", M.MON_RF: "MON-RF",
          (1, 0x01): "NAV-POSECEF", (1, 0x11): "NAV-VELECEF", (1, 0x26): "NAV-TIMELS",
          (6, 0x00): "CFG-PRT", (6, 0x01): "CFG-MSG", (6, 0x04): "CFG-RST",
          (6, 0x08): "CFG-RATE", (6, 0x09): "CFG-CFG", (6, 0x16): "CFG-SBAS",
          (6, 0x24): "CFG-NAV5", (6, 0x3E): "CFG-GNSS", (6, 0x8A): "CFG-VALSET",
          (6, 0x8B): "CFG-VALGET", (6, 0x8C): "CFG-VALDEL", (6, 0x02): "CFG-INF",
          (6, 0x11): "CFG-RXM", (6, 0x13): "CFG-ANT", (6, 0x17): "CFG-NMEA",
          (6, 0x1E): "CFG-ODO", (6, 0x23): "CFG-NAVX5", (6, 0x31): "CFG-TP5",
          (6, 0x39): "CFG-ITFM", (6, 0x3B): "CFG-PM2", (6, 0x86): "CFG-PMS"}


def _num(text: str, base: int = 10) -> int | None:
    """A non-negative integer field of a $PUBX sentence, or None."""
    t = text.strip()
    digits = "0123456789abcdefABCDEF"[: 10 if base == 10 else 22]
    return int(t, base) if t and all(c in digits for c in t) else None


def _keys_named(p: bytes) -> list[K.ConfigKey] | None:
    """The keys a VALGET / VALDEL payload names after its 4-byte header (wildcards expanded),
    or None when one is unknown."""
    found: list[K.ConfigKey] = []
    for j in range(4, len(p), 4):
        ks = K.lookup(int.from_bytes(p[j : j + 4], "little"))
        if ks is None:
            return None
        found += ks
    return found


def _name(cls: int, mid: int) -> str:
    return _NAMES.get((cls, mid), f"{cls:02X}-{mid:02X}")


def _cfg_prt(s: UbxSettings, port: int) -> bytes:
    """The CFG-PRT answer for one port (baud and mode only for the UARTs)."""
    pc = s.ports[port]
    uart = port in (K.PORT_UART1, K.PORT_UART2)
    return encode(CLASS_CFG, 0x00, struct.pack(
        "<BxHIIHHH2x", port, 0, pc.mode if uart else 0, pc.baud if uart else 0,
        pc.in_proto, pc.out_proto, 0))
