"""The u-blox link's settings: ports, message rates, rate, navigation, GNSS, SBAS, identity.

Frozen records of what a client may change over the port (CFG-PRT, CFG-MSG, CFG-RATE, CFG-NAV5,
CFG-GNSS, CFG-SBAS and the M9 configuration keys), the power-on defaults of a NEO-M8N and a
NEO-M9N, and the mapping between M9 configuration keys (:mod:`.keys`) and these records. Pure
data; :mod:`.link` changes them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from virtualgps.device.ubx import keys as K

PROTO_UBX, PROTO_NMEA = 0x01, 0x02  # CFG-PRT in/outProtoMask bits
UART_MODE_8N1 = 0x000008C0  # charLen 8 bit (bits 6-7 = 3), parity none (bits 9-11 = 4)
N_MSG_PORTS = 6  # CFG-MSG rates: I2C, UART1, UART2, USB, SPI, reserved
NMEA_IDS = {"GGA": 0x00, "GLL": 0x01, "GSA": 0x02, "GSV": 0x03, "RMC": 0x04, "VTG": 0x05,
            "GRS": 0x06, "GST": 0x07, "ZDA": 0x08, "GBS": 0x09, "DTM": 0x0A, "GNS": 0x0D,
            "VLW": 0x0F}  # UBX class 0xF0 message IDs (UBX-13003221 UBX-CFG-MSG)
GNSS_NAMES = {0: "GPS", 1: "SBAS", 2: "Galileo", 3: "BeiDou", 4: "IMES", 5: "QZSS", 6: "GLONASS"}
GNSS_BY_NAME = {v.lower(): k for k, v in GNSS_NAMES.items()}


@dataclass(frozen=True)
class PortConfig:
    """One port (CFG-PRT): protocol masks, and for a UART its baud (bits/s) and mode word."""

    in_proto: int
    out_proto: int
    baud: int = 0
    mode: int = UART_MODE_8N1


@dataclass(frozen=True)
class Nav5:
    """CFG-NAV5 navigation settings (defaults as u-center shows an M8 at power-on; units in the
    names: cm, cm^2 (fixedAltVar is 0.0001 m^2), m, s, cm/s, dB-Hz; DOP masks x 10)."""

    dyn_model: int = 0
    fix_mode: int = 3
    fixed_alt_cm: int = 0
    fixed_alt_var_cm2: int = 10_000
    min_elev_deg: int = 5
    dr_limit_s: int = 0
    pdop_x10: int = 250
    tdop_x10: int = 250
    pacc_m: int = 100
    tacc_m: int = 350
    static_hold_cmps: int = 0
    dgnss_timeout_s: int = 60
    cno_thresh_num_svs: int = 0
    cno_thresh_dbhz: int = 0
    static_hold_max_dist_m: int = 0
    utc_standard: int = 0


#: CFG-NAV5 payload (UBX-13003221 UBX-CFG-NAV5, 36 bytes): mask, then the fields of
#: NAV5_FIELDS in order (fixedAlt I4 0.01 m, fixedAltVar U4 0.0001 m^2, minElev I1, pDop/tDop
#: U2 x 0.1, staticHoldThresh U1 cm/s, ...).
NAV5_FORMAT = "<HBBiIbBHHHHBBBB2xHB5x"
#: Which fields each CFG-NAV5 mask bit applies (dyn, minEl, posFixMode, drLim, posMask,
#: timeMask, staticHoldMask, dgpsMask, cnoThreshold, utc).
NAV5_MASK_FIELDS = ((0x001, ("dyn_model",)), (0x002, ("min_elev_deg",)),
                    (0x004, ("fix_mode", "fixed_alt_cm", "fixed_alt_var_cm2")),
                    (0x008, ("dr_limit_s",)), (0x010, ("pdop_x10", "pacc_m")),
                    (0x020, ("tdop_x10", "tacc_m")),
                    (0x040, ("static_hold_cmps", "static_hold_max_dist_m")),
                    (0x080, ("dgnss_timeout_s",)),
                    (0x100, ("cno_thresh_num_svs", "cno_thresh_dbhz")),
                    (0x400, ("utc_standard",)))
NAV5_FIELDS = ("dyn_model", "fix_mode", "fixed_alt_cm", "fixed_alt_var_cm2", "min_elev_deg",
               "dr_limit_s", "pdop_x10", "tdop_x10", "pacc_m", "tacc_m", "static_hold_cmps",
               "dgnss_timeout_s", "cno_thresh_num_svs", "cno_thresh_dbhz",
               "static_hold_max_dist_m", "utc_standard")


@dataclass(frozen=True)
class GnssBlock:
    """One CFG-GNSS configuration block: channels reserved / at most, enable, signal mask."""

    gnss_id: int
    res_trk_ch: int
    max_trk_ch: int
    enabled: bool
    sig_cfg_mask: int = 0x01


@dataclass(frozen=True)
class SbasConfig:
    """CFG-SBAS: mode bits (0 enabled, 1 test), usage bits (0 range, 1 diffCorr, 2 integrity),
    maxSBAS channels, PRN scan masks (0: auto-scan)."""

    mode: int = 0x01
    usage: int = 0x03
    max_sbas: int = 3
    scanmode2: int = 0
    scanmode1: int = 0


@dataclass(frozen=True)
class UbxSettings:
    """What a client may change over the link, and the module's identity.

    generation : "M8" or "M9"
    ports : five PortConfig, by port ID (0 I2C, 1 UART1, 2 UART2, 3 USB, 4 SPI)
    msg_rates : ((class, id, rates), ...), rates per CFG-MSG port (6 values; 0 off, n: every
        n-th navigation solution); messages not listed are off
    meas_rate_ms, nav_rate, time_ref : CFG-RATE (a solution every meas_rate_ms * nav_rate ms)
    nav5 : CFG-NAV5 (dynamic model, fix mode, ...)
    gnss : CFG-GNSS blocks; num_trk_ch_hw, num_trk_ch_use : tracking channels
    sbas : CFG-SBAS
    sw_version, hw_version, extensions : the MON-VER strings
    extra : ((key ID, value), ...) M9 keys stored without effect
    passive : ((CFG message id, payload), ...) legacy CFG messages stored without effect
    """

    generation: str = "M8"
    ports: tuple[PortConfig, ...] = ()
    msg_rates: tuple[tuple[int, int, tuple[int, ...]], ...] = ()
    meas_rate_ms: int = 1000
    nav_rate: int = 1
    time_ref: int = 1
    nav5: Nav5 = field(default_factory=Nav5)
    gnss: tuple[GnssBlock, ...] = ()
    num_trk_ch_hw: int = 32
    num_trk_ch_use: int = 32
    sbas: SbasConfig = field(default_factory=SbasConfig)
    sw_version: str = ""
    hw_version: str = ""
    extensions: tuple[str, ...] = ()
    extra: tuple[tuple[int, int], ...] = ()
    passive: tuple[tuple[int, bytes], ...] = ()

    @property
    def baud(self) -> int:
        """UART1's baud rate, bits/s."""
        return self.ports[K.PORT_UART1].baud

    @property
    def dyn_model(self) -> int:
        """CFG-NAV5 dynamic platform model (0 portable, 4 automotive, 8 airborne <4g, ...)."""
        return self.nav5.dyn_model

    @property
    def nav_period_ms(self) -> int:
        """Time between navigation solutions, ms."""
        return self.meas_rate_ms * self.nav_rate

    @property
    def protver(self) -> float:
        """The protocol version MON-VER announces (``PROTVER=18.00``), else 18 (M8) / 32.01."""
        for ext in self.extensions:
            if ext.startswith("PROTVER"):
                try:
                    return float(ext[7:].lstrip("= "))
                except ValueError:
                    break
        return 18.0 if self.generation == "M8" else 32.01

    @property
    def enabled_gnss(self) -> frozenset[str]:
        """Names of the enabled systems ("GPS", "SBAS", "Galileo", "BeiDou", "QZSS",
        "GLONASS"): the block enabled with its L1 signal."""
        return frozenset(GNSS_NAMES[b.gnss_id] for b in self.gnss
                         if b.enabled and b.sig_cfg_mask & 0x01 and b.gnss_id in GNSS_NAMES)

    @property
    def sbas_enabled(self) -> bool:
        """SBAS in use: CFG-SBAS enabled and the SBAS system enabled."""
        return bool(self.sbas.mode & 0x01) and "SBAS" in self.enabled_gnss

    def rate(self, msg_class: int, msg_id: int, port: int = K.PORT_UART1) -> int:
        """A message's output rate on a port (0: off, n: every n-th solution)."""
        for c, i, rates in self.msg_rates:
            if (c, i) == (msg_class, msg_id):
                return rates[port]
        return 0

    def with_rates(self, msg_class: int, msg_id: int, rates: dict[int, int]) -> UbxSettings:
        """A copy with the message's rates on the given ports ({port: rate}) changed."""
        table = {(c, i): list(r) for c, i, r in self.msg_rates}
        row = table.setdefault((msg_class, msg_id), [0] * N_MSG_PORTS)
        for port, r in rates.items():
            row[port] = int(r) & 0xFF
        new = tuple((c, i, tuple(r)) for (c, i), r in sorted(table.items()))
        return replace(self, msg_rates=new)

    def with_port(self, port: int, **changes: int) -> UbxSettings:
        """A copy with fields of one PortConfig changed."""
        ports = list(self.ports)
        ports[port] = replace(ports[port], **changes)
        return replace(self, ports=tuple(ports))


#: MON-VER of a NEO-M8N with ROM SPG 3.01 and of a NEO-M9N with SPG 4.04, as the modules answer
#: (M8: the strings driver logs quote for ROM 3.01, not re-checked against a module here; M9:
#: ubxtool's output of a NEO-M9N as quoted in a public project's README).
MON_VER_M8 = ("ROM CORE 3.01 (107888)", "00080000",
              ("FWVER=SPG 3.01", "PROTVER=18.00", "GPS;GLO;GAL;BDS", "SBAS;IMES;QZSS"))
MON_VER_M9 = ("EXT CORE 4.04 (7f89f7)", "00190000",
              ("ROM BASE 0x118B2060", "FWVER=SPG 4.04", "PROTVER=32.01", "MOD=NEO-M9N",
               "GPS;GLO;GAL;BDS", "SBAS;QZSS"))


def default_settings(generation: str = "M8", *, baud: int | None = None, rate_hz: float = 1.0,
                     gnss: tuple[str, ...] | None = None,
                     mon_ver: tuple[str, str, tuple[str, ...]] | None = None) -> UbxSettings:
    """The settings at power-on.

    Parameters
    ----------
    generation : "M8" (NEO-M8N: 9600 baud, GPS + GLONASS + SBAS + QZSS) or "M9" (NEO-M9N:
        38400 baud, GPS + GLONASS + Galileo + BeiDou + SBAS + QZSS)
    baud : UART1 baud at power-on, bits/s (default: the module's)
    rate_hz : navigation solutions per second
    gnss : names of the systems enabled (default: the module's)
    mon_ver : (swVersion, hwVersion, extensions) (default: :data:`MON_VER_M8` / ``_M9``)

    Returns
    -------
    UbxSettings, with NMEA GGA GLL GSA GSV RMC VTG on at every solution on every port, UBX and
    NMEA in and out on every port (u-blox default configuration)
    """
    if generation not in ("M8", "M9"):
        raise ValueError(f"u-blox generation {generation!r}; expected 'M8' or 'M9'")
    m9 = generation == "M9"
    baud = baud if baud is not None else (38400 if m9 else 9600)
    in_proto = 0x23 if m9 else 0x07  # UBX NMEA RTCM3 (M9) / UBX NMEA RTCM (M8)
    bauds = {K.PORT_UART1: baud, K.PORT_UART2: 38400 if m9 else 9600}
    ports = tuple(PortConfig(in_proto, PROTO_UBX | PROTO_NMEA, bauds.get(p, 0))
                  for p in range(5))
    nmea_on = tuple((0xF0, NMEA_IDS[s], (1, 1, 1, 1, 1, 0))
                    for s in ("GGA", "GLL", "GSA", "GSV", "RMC", "VTG"))
    # (gnssId, reserved, max channels, enabled): u-center's M8 defaults; M9's are our choice.
    blocks = ((0, 8, 16, True), (1, 1, 3, True), (2, 4, 8, m9), (3, 8, 16, m9),
              (4, 0, 8, False), (5, 0, 3, True), (6, 8, 14, True))
    if m9:
        blocks = tuple(b for b in blocks if b[0] != 4)  # M9 has no IMES
    if gnss is not None:
        unknown = [name for name in gnss if name.lower() not in GNSS_BY_NAME]
        if unknown:
            raise ValueError(f"unknown GNSS {unknown}; expected names among "
                             + ", ".join(GNSS_NAMES.values()))
        wanted = {GNSS_BY_NAME[name.lower()] for name in gnss}
        blocks = tuple((g, r, m, g in wanted) for g, r, m, _ in blocks)
    sw, hw, ext = mon_ver if mon_ver is not None else (MON_VER_M9 if m9 else MON_VER_M8)
    return UbxSettings(
        generation=generation, ports=ports, msg_rates=nmea_on,
        meas_rate_ms=max(round(1000.0 / rate_hz), K.MEAS_RATE_MIN_MS),
        gnss=tuple(GnssBlock(g, r, m, e) for g, r, m, e in blocks),
        sw_version=sw, hw_version=hw, extensions=tuple(ext),
        extra=tuple((k.key_id, k.default) for k in K.KEYS.values() if k.target[0] == "extra"),
    )


# --- M9 configuration keys <-> settings --------------------------------------------------------


def key_value(s: UbxSettings, key: K.ConfigKey) -> int:
    """The value of a configuration key in settings ``s``."""
    t = key.target
    if t[0] == "baud":
        return s.ports[t[1]].baud
    if t[0] in ("inprot", "outprot"):
        p = s.ports[t[1]]
        return ((p.in_proto if t[0] == "inprot" else p.out_proto) >> t[2]) & 1
    if t[0] == "rate":
        return s.rate(t[1], t[2], t[3])
    if t[0] in ("meas", "nav", "timeref"):
        return {"meas": s.meas_rate_ms, "nav": s.nav_rate, "timeref": s.time_ref}[t[0]]
    if t[0] == "nav5":
        return getattr(s.nav5, t[1])
    if t[0] in ("gnss", "signal"):
        b = next((b for b in s.gnss if b.gnss_id == t[1]), None)
        if b is None:
            return 0
        return int(b.enabled) if t[0] == "gnss" else (b.sig_cfg_mask >> t[2]) & 1
    if t[0] == "sbas":
        sb = s.sbas
        return {"test": (sb.mode >> 1) & 1, "range": sb.usage & 1,
                "diffcorr": (sb.usage >> 1) & 1, "integrity": (sb.usage >> 2) & 1,
                "scanmask": sb.scanmode1 | (sb.scanmode2 << 32)}[t[1]]
    return dict(s.extra).get(key.key_id, key.default)


def _bit(word: int, bit: int, on: int) -> int:
    return (word | (1 << bit)) if on else (word & ~(1 << bit))


def with_key(s: UbxSettings, key: K.ConfigKey, value: int) -> UbxSettings:
    """A copy of settings ``s`` with one configuration key set (value already validated)."""
    t, v = key.target, int(value)
    if t[0] == "baud":
        return s.with_port(t[1], baud=v)
    if t[0] == "inprot":
        return s.with_port(t[1], in_proto=_bit(s.ports[t[1]].in_proto, t[2], v))
    if t[0] == "outprot":
        return s.with_port(t[1], out_proto=_bit(s.ports[t[1]].out_proto, t[2], v))
    if t[0] == "rate":
        return s.with_rates(t[1], t[2], {t[3]: v})
    if t[0] in ("meas", "nav", "timeref"):
        return replace(s, **{{"meas": "meas_rate_ms", "nav": "nav_rate",
                              "timeref": "time_ref"}[t[0]]: v})
    if t[0] == "nav5":
        return replace(s, nav5=replace(s.nav5, **{t[1]: v}))
    if t[0] in ("gnss", "signal"):
        blocks = list(s.gnss)
        idx = next((j for j, b in enumerate(blocks) if b.gnss_id == t[1]), None)
        if idx is None:
            blocks.append(GnssBlock(t[1], 0, 0, False))
            idx = len(blocks) - 1
        b = blocks[idx]
        blocks[idx] = (replace(b, enabled=bool(v)) if t[0] == "gnss"
                       else replace(b, sig_cfg_mask=_bit(b.sig_cfg_mask, t[2], v)))
        return replace(s, gnss=tuple(blocks))
    if t[0] == "sbas":
        sb = s.sbas
        if t[1] == "scanmask":
            sb = replace(sb, scanmode1=v & 0xFFFFFFFF, scanmode2=(v >> 32) & 0xFF)
        elif t[1] == "test":
            sb = replace(sb, mode=_bit(sb.mode, 1, v))
        else:
            sb = replace(sb, usage=_bit(sb.usage, {"range": 0, "diffcorr": 1,
                                                   "integrity": 2}[t[1]], v))
        return replace(s, sbas=sb)
    extra = dict(s.extra)
    extra[key.key_id] = v
    return replace(s, extra=tuple(sorted(extra.items())))
