"""The profile's ``[nmea]`` table: how a receiver writes NMEA (talker, sentences, digits, rates).

Part of the receiver's description, as its fix records are (:mod:`.records`); the device renders
both (:mod:`virtualgps.device.nmea.writer`). Defined here so that a profile is checked whole when
it is loaded, without the receiver stage importing the device above it.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from virtualgps.exceptions import ConfigError

SENTENCE_TYPES = ("GGA", "GSA", "GSV", "RMC", "VTG", "GLL", "GST", "ZDA")
NO_FIX_STYLES = ("mtk", "empty", "ublox")
NMEA_VERSIONS = ("2.3", "4.10", "4.11")

# GSV: NMEA 0183 v2.3 allows 1 to 9 messages of 4 satellites.
GSV_MAX_SATS = 36


@dataclass(frozen=True)
class NmeaFormat:
    """How a receiver profile writes NMEA (the profile's ``[nmea]`` table).

    Attributes
    ----------
    talker : two upper-case letters, ``"GP"`` for a GPS-only receiver
    sentences : sentence types in output order; any of ``SENTENCE_TYPES``
    time_decimals : decimals of the UTC seconds (3: ``hhmmss.sss`` as MTK), 0..3
    latlon_decimals : decimals of the minutes (4: ``ddmm.mmmm`` as MTK), 1..7
    alt_decimals : decimals of the altitude and geoid separation (MTK: 1), 0..3
    dop_decimals : decimals of PDOP/HDOP/VDOP (MTK: 2), 1..3
    speed_decimals, course_decimals : decimals of speed (knots, km/h) and course (MTK: 2), 0..3
    sats_used_digits : width of the GGA satellites-used field; 2 as NMEA 0183 ``xx`` (MT3339
        pads, ``0,04``; older MT3329 firmware writes ``1,4``: set 1 to mimic it)
    no_fix_style : ``"mtk"`` (placeholders ``8960.0000,N,00000.0000,E``, altitude 137.0, geoid
        13.0, speed and course 0.00, as MT3301/MT3329 firmware), ``"empty"`` (empty fields,
        as MT3339 firmware and most other receivers) or ``"ublox"`` (empty fields, their unit
        letters too, and DOPs 99.99, as u-blox modules: ``$GNGGA,,,,,,0,00,99.99,,,,,,``)
    dgps_fields : ``"mtk"`` (``0000,0000`` in GGA's DGPS age/station with quality 2) or ``"empty"``
    mode_letter : write the NMEA 2.3 mode letter (A/D/N) in RMC, VTG and GLL
    gsv_max_sats : at most this many satellites in GSV (1..36)
    zda_local_zone : ``"zero"`` (``00,00``) or ``"empty"`` (as MT3339 firmware)
    every : ``{sentence: n}``: write that sentence only every n-th fix (PMTK314 semantics); the
        fix number is ``round(t_unix_s * fix_rate_hz)``
    fix_rate_hz : the output rate, used only to count fixes for ``every``
    version : ``"2.3"`` (NMEA 0183 v2.3, as MTK firmware: one GSA and one run of GSV, every
        satellite by its number, all under ``talker``) or ``"4.11"`` (as u-blox M8/M9/F9 and
        phones write several systems: a GSA per system ending in its system ID, a run of GSV
        per system's talker (GP, GL, GA, GB, GQ) ending in the signal ID, satellites by their
        NMEA IDs, RMC's navigational status ``V``; ``talker`` ``GN`` where several systems are
        tracked). ``"4.10"`` writes the same bytes (u-blox M8 receiver description, NMEA
        protocol: GSA's system ID, GSV's signal ID and RMC's navigational status all appear
        from NMEA 4.10 on). 4.10 and 4.11 need ``mode_letter``.
    """

    talker: str = "GP"
    sentences: tuple[str, ...] = ("GGA", "GSA", "GSV", "RMC", "VTG")
    time_decimals: int = 3
    latlon_decimals: int = 4
    alt_decimals: int = 1
    dop_decimals: int = 2
    speed_decimals: int = 2
    course_decimals: int = 2
    sats_used_digits: int = 2
    no_fix_style: str = "mtk"
    dgps_fields: str = "mtk"
    mode_letter: bool = True
    gsv_max_sats: int = GSV_MAX_SATS
    zda_local_zone: str = "zero"
    every: tuple[tuple[str, int], ...] = ()
    fix_rate_hz: float = 1.0
    version: str = "2.3"

    def __post_init__(self) -> None:
        _check(
            "talker",
            self.talker,
            isinstance(self.talker, str) and re.fullmatch(r"[A-Z]{2}", self.talker) is not None,
            "two upper-case letters such as 'GP' or 'GN'",
        )
        ok = (
            isinstance(self.sentences, tuple)
            and len(self.sentences) > 0
            and all(s in SENTENCE_TYPES for s in self.sentences)
            and len(set(self.sentences)) == len(self.sentences)
        )
        _check(
            "sentences", self.sentences, ok, f"a non-empty list without repeats of {SENTENCE_TYPES}"
        )
        for key, lo, hi in (
            ("time_decimals", 0, 3),
            ("latlon_decimals", 1, 7),
            ("alt_decimals", 0, 3),
            ("dop_decimals", 1, 3),
            ("speed_decimals", 0, 3),
            ("course_decimals", 0, 3),
            ("sats_used_digits", 1, 2),
            ("gsv_max_sats", 1, GSV_MAX_SATS),
        ):
            v = getattr(self, key)
            _check(key, v, _is_int(v) and lo <= v <= hi, f"an integer from {lo} to {hi}")
        _check(
            "no_fix_style",
            self.no_fix_style,
            self.no_fix_style in NO_FIX_STYLES,
            f"one of {NO_FIX_STYLES}",
        )
        _check(
            "dgps_fields",
            self.dgps_fields,
            self.dgps_fields in ("mtk", "empty"),
            "'mtk' or 'empty'",
        )
        _check(
            "zda_local_zone",
            self.zda_local_zone,
            self.zda_local_zone in ("zero", "empty"),
            "'zero' or 'empty'",
        )
        _check("mode_letter", self.mode_letter, isinstance(self.mode_letter, bool), "true or false")
        ok = isinstance(self.every, tuple) and all(
            isinstance(p, tuple)
            and len(p) == 2
            and p[0] in SENTENCE_TYPES
            and _is_int(p[1])
            and 1 <= p[1] <= 100
            for p in self.every
        )
        _check("every", self.every, ok, "a table {SENTENCE = n} with n from 1 to 100")
        ok = (
            isinstance(self.fix_rate_hz, (int, float))
            and not isinstance(self.fix_rate_hz, bool)
            and 0.0 < self.fix_rate_hz <= 100.0
        )
        _check("fix_rate_hz", self.fix_rate_hz, ok, "a number in (0, 100]")
        _check("version", self.version, self.version in NMEA_VERSIONS,
               f"one of {NMEA_VERSIONS} (a string)")
        _check("mode_letter", self.mode_letter, self.mode_letter or self.version == "2.3",
               "true with version 4.10 or 4.11 (their RMC, VTG and GLL end in the mode letter)")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], section: str = "nmea") -> NmeaFormat:
        """Build a format from a profile's ``[nmea]`` TOML table.

        Parameters
        ----------
        d : the table; keys are the attribute names; lists become tuples, ``every`` a table
        section : the table's name, used in error messages

        Returns
        -------
        NmeaFormat

        Raises
        ------
        ConfigError
            naming ``section.key`` for an unknown key or a value of the wrong type or range.
        """
        if not isinstance(d, Mapping):
            raise ConfigError(f"[{section}] must be a table, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        kwargs: dict[str, Any] = {}
        for key, value in d.items():
            if key not in known:
                raise ConfigError(
                    f"{section}.{key}: unknown setting; allowed: {', '.join(sorted(known))}"
                )
            if key == "sentences" and isinstance(value, list):
                value = tuple(str(s).upper() if isinstance(s, str) else s for s in value)
            elif key == "every" and isinstance(value, Mapping):
                value = tuple(sorted((str(k).upper(), v) for k, v in value.items()))
            kwargs[key] = value
        try:
            return cls(**kwargs)
        except ConfigError as e:
            raise ConfigError(f"{section}.{e}") from None

    def every_n(self, sentence: str) -> int:
        """How often ``sentence`` is written: every n-th fix (1 = every fix)."""
        return dict(self.every).get(sentence, 1)


def _is_int(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _check(key: str, value: object, ok: bool, expected: str) -> None:
    if not ok:
        raise ConfigError(f"{key}: expected {expected}, got {value!r}")
