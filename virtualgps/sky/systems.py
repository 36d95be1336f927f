"""Satellite systems (GPS, GLONASS, Galileo, BeiDou, QZSS, SBAS) and the one number each
satellite goes by here.

Every satellite of a constellation has one integer, its ``prn`` column, unique across systems:

======== ================ ========================================= ======================
system   letter (RINEX 3)  number here                               NMEA 4.11 (talker, ID)
======== ================ ========================================= ======================
GPS      G                PRN 1-32                                  GP, 1-32
SBAS     S                PRN 120-158                               GP, 33-64 (PRN - 87)
GLONASS  R                64 + orbital slot: 65-96                  GL, 65-96
Galileo  E                300 + PRN: 301-336                        GA, 1-36
BeiDou   C                400 + PRN: 401-463                        GB, 1-63
QZSS     J                PRN 193-202                               GQ, 1-10 (PRN - 192)
======== ================ ========================================= ======================

GPS, SBAS and GLONASS keep the numbers NMEA 0183 has always given them (a GPS-only constellation
is numbered as before), so only Galileo and BeiDou, whose NMEA IDs overlap GPS's, are moved up.
The NMEA 4.11 system IDs (GSA field 18, GSV's last field's system) are 1 GPS, 2 GLONASS,
3 Galileo, 4 BeiDou, 5 QZSS (NMEA 0183 v4.11, table of system IDs; SBAS satellites are
reported as GPS).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class System:
    """One satellite system.

    name : e.g. "GLONASS"; letter : its RINEX 3 letter; first, last : its numbers here
    (inclusive); offset : number here = offset + its own identifier (PRN, or GLONASS slot)
    talker : its NMEA talker ID; nmea_id : its NMEA 4.11 system ID; nmea_offset : NMEA
    satellite ID = number here - nmea_offset; nmea_signal : the NMEA 4.11 signal ID of its L1
    civil signal (GSV's last field), the one signal simulated here
    """

    name: str
    letter: str
    first: int
    last: int
    offset: int
    talker: str
    nmea_id: int
    nmea_offset: int
    nmea_signal: int = 1


# Signal IDs (NMEA 0183 v4.11 signal ID table, as u-blox M8/F9 interface descriptions list it):
# 1 GPS L1 C/A, GLONASS L1 OF, BeiDou B1I, QZSS L1 C/A; 7 Galileo E1 (B/C).
GPS = System("GPS", "G", 1, 32, 0, "GP", 1, 0)
SBAS = System("SBAS", "S", 120, 158, 0, "GP", 1, 87)
GLONASS = System("GLONASS", "R", 65, 96, 64, "GL", 2, 0)
GALILEO = System("Galileo", "E", 301, 336, 300, "GA", 3, 300, nmea_signal=7)
BEIDOU = System("BeiDou", "C", 401, 463, 400, "GB", 4, 400)
QZSS = System("QZSS", "J", 193, 202, 0, "GQ", 5, 192)
SYSTEMS: tuple[System, ...] = (GPS, GLONASS, GALILEO, BEIDOU, QZSS, SBAS)
# CelesTrak's group of each system's operational satellites (TLE files here are named by it).
GROUPS = {"G": "gps-ops", "R": "glo-ops", "E": "galileo", "C": "beidou"}
BY_NAME = {s.name.lower(): s for s in SYSTEMS} | {s.letter.lower(): s for s in SYSTEMS}


def system_named(name: str) -> System:
    """A system by its name or RINEX letter, any case ("glonass", "R"); ValueError if none."""
    s = BY_NAME.get(name.strip().lower())
    if s is None:
        raise ValueError(f"unknown satellite system {name!r}; expected one of "
                         + ", ".join(x.name for x in SYSTEMS))
    return s


def system_of(number: int) -> System | None:
    """The system a satellite number belongs to (None: outside every system's range)."""
    for s in SYSTEMS:
        if s.first <= number <= s.last:
            return s
    return None


def letters(numbers: ArrayLike) -> NDArray[np.str_]:
    """(k,) RINEX letters of satellite numbers ('?' outside every range)."""
    out = []
    for n in np.asarray(numbers, dtype=np.int64).ravel():
        s = system_of(int(n))
        out.append(s.letter if s is not None else "?")
    return np.array(out, dtype="<U1")


def number(system: System, ident: int) -> int:
    """A satellite's number here from its system and its own identifier (PRN, GLONASS slot);
    ValueError outside the system's range."""
    n = system.offset + int(ident)
    if not system.first <= n <= system.last:
        raise ValueError(f"{system.name} {ident} is outside {system.first - system.offset}-"
                         f"{system.last - system.offset}")
    return n


def rinex_name(number: int) -> str:
    """A satellite's RINEX 3 name: ``G05``, ``R07`` (slot 7), ``E11``, ``C19``, ``J01``,
    ``S23`` (SBAS PRN 123)."""
    s = system_of(number)
    if s is None:
        return f"?{number}"
    own = number - s.offset
    if s is QZSS:
        own -= 192
    elif s is SBAS:
        own -= 100
    return f"{s.letter}{own:02d}"


# Identifiers in TLE names (CelesTrak): "GPS BIIR-2  (PRN 13)", "GSAT0101 (PRN E11)",
# "BEIDOU-3 M1 (C19)", "QZS-1 (QZSS/PRN 193)", "COSMOS 2456 (730)" (a GLONASS number, not a slot:
# see virtualgps.sky.glonass_slots).
_PRN_IN_NAME = re.compile(r"\bPRN\s*([EC]?)0*(\d{1,3})\b", re.IGNORECASE)
_BEIDOU_IN_NAME = re.compile(r"\bBEIDOU\b.*\(C0*(\d{1,2})\)", re.IGNORECASE)
_GLONASS_IN_NAME = re.compile(r"^COSMOS\s+\d+\s+\((\d{3}K?)\)", re.IGNORECASE)


def number_from_name(name: str) -> int | None:
    """A satellite's number here from its TLE name (None: the name does not carry it; GLONASS
    names carry no slot: :func:`glonass_number_from_name`)."""
    m = _PRN_IN_NAME.search(name)
    if m is not None:
        letter, ident = m.group(1).upper(), int(m.group(2))
        system = {"E": GALILEO, "C": BEIDOU}.get(letter)
        if system is None:  # (a PRN outside every range keeps its number, system unknown)
            return ident
        return system.offset + ident if system.first <= system.offset + ident <= system.last \
            else None
    m = _BEIDOU_IN_NAME.search(name)
    if m is not None:
        return BEIDOU.offset + int(m.group(1))
    return None


def glonass_number_from_name(name: str) -> str | None:
    """The GLONASS number a TLE name carries (``COSMOS 2456 (730)`` -> ``"730"``), or None."""
    m = _GLONASS_IN_NAME.search(name.strip())
    return m.group(1).upper() if m is not None else None
