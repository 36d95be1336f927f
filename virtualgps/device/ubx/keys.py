"""The M9 configuration keys we answer (UBX-CFG-VALSET / VALGET / VALDEL), as data.

A key ID (u-blox M9 SPG 4.04 interface description, "Configuration items") is 32 bits: bits
28-30 the value's storage size (1: one bit, stored in one byte; 2: one byte; 3: two; 4: four; 5:
eight bytes), bits 16-23 the group, bits 0-11 the item. Values are little-endian. The IDs are
that document's; they were copied from pyubx2's configuration database, which transcribes
u-blox's tables (a test checks every one against it).

Each :class:`ConfigKey` names what it sets as a *target* tuple that
:mod:`virtualgps.device.ubx.link` reads and writes in its settings:

=========================  ================================================================
("baud", port)             the port's baud rate
("inprot", port, bit)      a bit of the port's CFG-PRT inProtoMask (0 UBX, 1 NMEA, 5 RTCM3)
("outprot", port, bit)     a bit of the port's outProtoMask (0 UBX, 1 NMEA)
("rate", cls, id, port)    a message's output rate on a port (CFG-MSG's)
("meas",) ("nav",)         CFG-RATE measRate (ms), navRate (cycles), timeRef
("timeref",)
("nav5", field)            a field of the CFG-NAV5 settings
("gnss", gnssId)           a GNSS enabled (CFG-GNSS block "enable")
("signal", gnssId, bit)    a bit of its sigCfgMask (bit 0: the L1 signal)
("sbas", field)            CFG-SBAS mode/usage bits and PRN scan mask
("extra",)                 stored and read back, no effect on the emulation
=========================  ================================================================

The set is what PX4 (PX4-GPSDrivers ``src/ubx.cpp``, ``configure`` / ``configureDevice``,
including the NAVSPG-INFIL_MINCNO / CONSTR_DGNSSTO keys of its 2025 revision),
ArduPilot and gpsd write to an M9: UART1/UART2/USB/I2C/SPI protocol enables and baud rates,
the UART framing keys, RATE, NAVSPG, ODO, ITFM, SBAS and SIGNAL keys, and the MSGOUT keys of
every NAV/MON message we emit (plus RXM-RTCM and the standard NMEA sentences), per port. A key
outside it is unknown to us and NAKed, as the module NAKs a key unknown to its firmware
(e.g. PX4's CFG-NAVHPG-DGNSSMODE, which only RTK modules know).
"""

from __future__ import annotations

from dataclasses import dataclass

PORT_I2C, PORT_UART1, PORT_UART2, PORT_USB, PORT_SPI = range(5)
PORT_NAMES = ("I2C", "UART1", "UART2", "USB", "SPI")

#: Baud rates a u-blox UART takes (UBX-13003221 CFG-PRT; M9 CFG-UART1-BAUDRATE).
BAUDS = (4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
#: CFG-NAV5 / CFG-NAVSPG-DYNMODEL values: 0 portable, 2 stationary, 3 pedestrian, 4 automotive,
#: 5 sea, 6/7/8 airborne <1g/<2g/<4g, 9 wrist, 10 motorbike (UBX-13003221 CFG-NAV5: 9 from
#: protocol 18, 10 from 19.20; the M9 interface description's CFG-NAVSPG-DYNMODEL: 0, 2-10).
DYN_MODELS_M8 = (0, 2, 3, 4, 5, 6, 7, 8, 9)
DYN_MODELS_M9 = (0, 2, 3, 4, 5, 6, 7, 8, 9, 10)
MEAS_RATE_MIN_MS = 25  # 40 Hz, the fastest any u-blox M8/M9 measurement rate the documents allow
NAV_RATE_MAX = 127  # UBX-13003221 CFG-RATE: "max. 127 cycles"

_SIZE_BYTES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8}


@dataclass(frozen=True)
class ConfigKey:
    """One configuration item.

    key_id : the 32-bit ID; name : e.g. "CFG-UART1-BAUDRATE"; target : what it sets (see the
    module docstring); signed : the value is two's complement; lo, hi : accepted range;
    allowed : accepted values (None: any in [lo, hi]); default : the value of an "extra" key
    at power-on
    """

    key_id: int
    name: str
    target: tuple
    signed: bool = False
    lo: int = 0
    hi: int = 2**64 - 1
    allowed: tuple[int, ...] | None = None
    default: int = 0

    @property
    def size_bytes(self) -> int:
        """Bytes of the value on the wire."""
        return _SIZE_BYTES[(self.key_id >> 28) & 0x7]

    def accepts(self, value: int) -> bool:
        """Whether ``value`` (already sign-converted) is valid for this key."""
        if self.allowed is not None:
            return value in self.allowed
        return self.lo <= value <= self.hi


def value_size(key_id: int) -> int | None:
    """Bytes of a key's value from its ID's size field; None for a reserved size code."""
    return _SIZE_BYTES.get((key_id >> 28) & 0x7)


def parse_cfgdata(data: bytes) -> list[tuple[int, bytes]] | None:
    """Split VALSET ``cfgData`` into (key ID, raw value bytes) pairs.

    Returns
    -------
    pairs, or None when the data ends inside a pair or a key has a reserved size code
    """
    out, i, n = [], 0, len(data)
    while i < n:
        if i + 4 > n:
            return None
        key = int.from_bytes(data[i : i + 4], "little")
        size = value_size(key)
        if size is None or i + 4 + size > n:
            return None
        out.append((key, bytes(data[i + 4 : i + 4 + size])))
        i += 4 + size
    return out


def decode_value(key: ConfigKey, raw: bytes) -> int:
    """A key's value from its little-endian bytes (sign-converted for signed keys)."""
    return int.from_bytes(raw, "little", signed=key.signed)


def encode_value(key: ConfigKey, value: int) -> bytes:
    """A key's value as little-endian bytes (wrapped to its size)."""
    size = key.size_bytes
    return (int(value) % (1 << (8 * size))).to_bytes(size, "little")


def _bool(key_id: int, name: str, target: tuple, default: int = 0) -> ConfigKey:
    return ConfigKey(key_id, name, target, lo=0, hi=1, default=default)


def _build() -> dict[int, ConfigKey]:
    keys: list[ConfigKey] = []
    # Port protocol enables: (in group, out group) per port (M9 CFG-I2CINPROT ...).
    groups = {PORT_I2C: (0x71, 0x72), PORT_UART1: (0x73, 0x74), PORT_UART2: (0x75, 0x76),
              PORT_USB: (0x77, 0x78), PORT_SPI: (0x79, 0x7A)}
    for port, (gin, gout) in groups.items():
        name = PORT_NAMES[port]
        for item, proto, bit in ((1, "UBX", 0), (2, "NMEA", 1), (4, "RTCM3X", 5)):
            keys.append(_bool(0x10000000 | (gin << 16) | item, f"CFG-{name}INPROT-{proto}",
                              ("inprot", port, bit)))
        for item, proto, bit in ((1, "UBX", 0), (2, "NMEA", 1)):
            keys.append(_bool(0x10000000 | (gout << 16) | item, f"CFG-{name}OUTPROT-{proto}",
                              ("outprot", port, bit)))
    # UARTs: baud (active) and framing (stored; the line stays 8N1).
    for port, group in ((PORT_UART1, 0x52), (PORT_UART2, 0x53)):
        name = PORT_NAMES[port]
        keys.append(ConfigKey(0x40000001 | (group << 16), f"CFG-{name}-BAUDRATE",
                              ("baud", port), allowed=BAUDS))
        keys.append(ConfigKey(0x20000002 | (group << 16), f"CFG-{name}-STOPBITS", ("extra",),
                              lo=0, hi=3, default=1))  # 1: one stop bit
        keys.append(ConfigKey(0x20000003 | (group << 16), f"CFG-{name}-DATABITS", ("extra",),
                              lo=0, hi=1, default=0))  # 0: eight
        keys.append(ConfigKey(0x20000004 | (group << 16), f"CFG-{name}-PARITY", ("extra",),
                              lo=0, hi=2, default=0))  # 0: none
        keys.append(_bool(0x10000005 | (group << 16), f"CFG-{name}-ENABLED", ("extra",), 1))
    # Message output rates: the I2C key of each message; UART1, UART2, USB, SPI follow at +1..+4.
    msgout = (
        ("UBX_NAV_POSLLH", 0x01, 0x02, 0x029), ("UBX_NAV_STATUS", 0x01, 0x03, 0x01A),
        ("UBX_NAV_DOP", 0x01, 0x04, 0x038), ("UBX_NAV_PVT", 0x01, 0x07, 0x006),
        ("UBX_NAV_VELNED", 0x01, 0x12, 0x042), ("UBX_NAV_TIMEGPS", 0x01, 0x20, 0x047),
        ("UBX_NAV_TIMEUTC", 0x01, 0x21, 0x05B), ("UBX_NAV_SAT", 0x01, 0x35, 0x015),
        ("UBX_NAV_EOE", 0x01, 0x61, 0x15F), ("UBX_MON_HW", 0x0A, 0x09, 0x1B4),
        ("UBX_MON_RF", 0x0A, 0x38, 0x359), ("UBX_RXM_RTCM", 0x02, 0x32, 0x268),
        ("NMEA_ID_GGA", 0xF0, 0x00, 0x0BA), ("NMEA_ID_GLL", 0xF0, 0x01, 0x0C9),
        ("NMEA_ID_GSA", 0xF0, 0x02, 0x0BF), ("NMEA_ID_GSV", 0xF0, 0x03, 0x0C4),
        ("NMEA_ID_RMC", 0xF0, 0x04, 0x0AB), ("NMEA_ID_VTG", 0xF0, 0x05, 0x0B0),
        ("NMEA_ID_GRS", 0xF0, 0x06, 0x0CE), ("NMEA_ID_GST", 0xF0, 0x07, 0x0D3),
        ("NMEA_ID_ZDA", 0xF0, 0x08, 0x0D8), ("NMEA_ID_GBS", 0xF0, 0x09, 0x0DD),
        ("NMEA_ID_DTM", 0xF0, 0x0A, 0x0A6), ("NMEA_ID_GNS", 0xF0, 0x0D, 0x0B5),
        ("NMEA_ID_VLW", 0xF0, 0x0F, 0x0E7),
    )
    for name, cls, mid, item in msgout:
        for port in range(5):
            keys.append(ConfigKey(0x20910000 | (item + port),
                                  f"CFG-MSGOUT-{name}_{PORT_NAMES[port]}",
                                  ("rate", cls, mid, port), lo=0, hi=255))
    keys += [
        ConfigKey(0x30210001, "CFG-RATE-MEAS", ("meas",), lo=MEAS_RATE_MIN_MS, hi=0xFFFF),
        ConfigKey(0x30210002, "CFG-RATE-NAV", ("nav",), lo=1, hi=NAV_RATE_MAX),
        ConfigKey(0x20210003, "CFG-RATE-TIMEREF", ("timeref",), lo=0, hi=4),
        ConfigKey(0x20210004, "CFG-RATE-NAV_PRIO", ("extra",), lo=0, hi=30),
        ConfigKey(0x20110021, "CFG-NAVSPG-DYNMODEL", ("nav5", "dyn_model"),
                  allowed=DYN_MODELS_M9),
        ConfigKey(0x20110011, "CFG-NAVSPG-FIXMODE", ("nav5", "fix_mode"), lo=1, hi=3),
        ConfigKey(0x2011001C, "CFG-NAVSPG-UTCSTANDARD", ("nav5", "utc_standard"),
                  allowed=(0, 3, 5, 6, 7)),
        ConfigKey(0x201100A4, "CFG-NAVSPG-INFIL_MINELEV", ("nav5", "min_elev_deg"),
                  signed=True, lo=-90, hi=90),
        ConfigKey(0x201100AA, "CFG-NAVSPG-INFIL_NCNOTHRS", ("nav5", "cno_thresh_num_svs"),
                  hi=255),
        ConfigKey(0x201100AB, "CFG-NAVSPG-INFIL_CNOTHRS", ("nav5", "cno_thresh_dbhz"), hi=255),
        # The M9's output filters (U2, DOPs x 0.1, accuracies in m) are CFG-NAV5's pDop, tDop,
        # pAcc and tAcc (UBX-13003221 CFG-NAV5): PDOP is the receiver's fix mask
        # (``sky.pdop_mask``), the others are stored.
        ConfigKey(0x301100B1, "CFG-NAVSPG-OUTFIL_PDOP", ("nav5", "pdop_x10"), hi=0xFFFF),
        ConfigKey(0x301100B2, "CFG-NAVSPG-OUTFIL_TDOP", ("nav5", "tdop_x10"), hi=0xFFFF),
        ConfigKey(0x301100B3, "CFG-NAVSPG-OUTFIL_PACC", ("nav5", "pacc_m"), hi=0xFFFF),
        ConfigKey(0x301100B4, "CFG-NAVSPG-OUTFIL_TACC", ("nav5", "tacc_m"), hi=0xFFFF),
        ConfigKey(0x401100C1, "CFG-NAVSPG-CONSTR_ALT", ("nav5", "fixed_alt_cm"), signed=True,
                  lo=-(2**31), hi=2**31 - 1),
        ConfigKey(0x401100C2, "CFG-NAVSPG-CONSTR_ALTVAR", ("nav5", "fixed_alt_var_cm2"),
                  hi=2**32 - 1),
        # PX4-GPSDrivers src/ubx.cpp, GPSDriverUBX::configureDevice (since PR #189, 2025) puts
        # these two in the batch it needs ACKed when GPS_UBX_MIN_CNO / GPS_UBX_DGNSS_TO are set:
        # unknown to us, the whole batch was NAKed and PX4 gave up configuring the M9.
        # CONSTR_DGNSSTO (s) is CFG-NAV5's dgnssTimeout (UBX-13003221 CFG-NAV5); INFIL_MINCNO
        # (dB-Hz) has no CFG-NAV5 field and is stored. Its default, 6 dB-Hz, is the one
        # PX4-Autopilot PR #25720 quotes, not checked against the interface description here.
        ConfigKey(0x201100A3, "CFG-NAVSPG-INFIL_MINCNO", ("extra",), hi=255, default=6),
        ConfigKey(0x201100C4, "CFG-NAVSPG-CONSTR_DGNSSTO", ("nav5", "dgnss_timeout_s"), hi=255),
        _bool(0x10220001, "CFG-ODO-USE_ODO", ("extra",)),
        _bool(0x10220002, "CFG-ODO-USE_COG", ("extra",)),
        _bool(0x10220003, "CFG-ODO-OUTLPVEL", ("extra",)),
        _bool(0x10220004, "CFG-ODO-OUTLPCOG", ("extra",)),
        _bool(0x1041000D, "CFG-ITFM-ENABLE", ("extra",)),
        _bool(0x10360002, "CFG-SBAS-USE_TESTMODE", ("sbas", "test")),
        _bool(0x10360003, "CFG-SBAS-USE_RANGING", ("sbas", "range")),
        _bool(0x10360004, "CFG-SBAS-USE_DIFFCORR", ("sbas", "diffcorr")),
        _bool(0x10360005, "CFG-SBAS-USE_INTEGRITY", ("sbas", "integrity")),
        ConfigKey(0x50360006, "CFG-SBAS-PRNSCANMASK", ("sbas", "scanmask"), hi=2**39 - 1),
    ]
    # Signals (M9 CFG-SIGNAL): the system switch and its L1 signal, per GNSS.
    for gid, system, ena, sig_item, sig in ((0, "GPS", 0x1F, 0x01, "L1CA"),
                                            (1, "SBAS", 0x20, 0x05, "L1CA"),
                                            (2, "GAL", 0x21, 0x07, "E1"),
                                            (3, "BDS", 0x22, 0x0D, "B1"),
                                            (5, "QZSS", 0x24, 0x12, "L1CA"),
                                            (6, "GLO", 0x25, 0x18, "L1")):
        keys.append(_bool(0x10310000 | ena, f"CFG-SIGNAL-{system}_ENA", ("gnss", gid)))
        keys.append(_bool(0x10310000 | sig_item, f"CFG-SIGNAL-{system}_{sig}_ENA",
                          ("signal", gid, 0)))
    keys.append(_bool(0x10310014, "CFG-SIGNAL-QZSS_L1S_ENA", ("signal", 5, 2)))
    table = {k.key_id: k for k in keys}
    assert len(table) == len(keys), "duplicate configuration key IDs"
    return table


#: Every key we know, by ID.
KEYS: dict[int, ConfigKey] = _build()
KEYS_BY_NAME: dict[str, ConfigKey] = {k.name: k for k in KEYS.values()}


def lookup(key_id: int) -> list[ConfigKey] | None:
    """The keys a VALGET key ID asks for: itself, or a wildcard's matches.

    A wildcard (UBX-CFG-VALGET: all items of a group, or all items) has item ID 0xFFF; group
    0xFF means every group.

    Returns
    -------
    keys : list of ConfigKey in ID order, or None when the ID is unknown (an empty group
        wildcard is unknown too)
    """
    if (key_id & 0xFFF) == 0xFFF:
        group = (key_id >> 16) & 0xFF
        found = sorted((k for k in KEYS.values()
                        if group == 0xFF or ((k.key_id >> 16) & 0xFF) == group),
                       key=lambda k: k.key_id)
        return found or None
    k = KEYS.get(key_id & 0x7FFFFFFF)  # bit 31 is reserved
    return [k] if k is not None else None
