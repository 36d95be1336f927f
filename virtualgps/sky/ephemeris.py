"""Ephemeris: TLE files -> GPS satellites with PRNs; SGP4 propagation to ECEF; tabulating them
into the paper's lookup table; the sky-time shift; any ephemeris file by its kind.

What this module owns
---------------------
- :func:`load_tle` reads 2-line and 3-line TLE files (CelesTrak, Space-Track ``0 NAME`` style),
  validates the column layout and the mod-10 checksums, and finds each satellite's PRN from its
  name (``GPS BIIR-2  (PRN 13)``) or from a NORAD -> PRN table (``GPS,BIIF-2,G01,37753U,11036A``).
- :class:`Constellation` propagates every satellite at once with sgp4's ``SatrecArray`` and
  rotates TEME to ECEF (GMST-1982, :func:`virtualgps.geodesy.teme_to_ecef`).
- :func:`build_lookup_table` tabulates a constellation into the seed paper's offline lookup
  table (section 2.1: satellite positions computed ahead of time over an interval with a fixed
  step and read at run time; :mod:`virtualgps.sky.lookup` holds the table, its file and its
  interpolation).
- :func:`sidereal_shift_s` maps a simulated time far from the TLE epoch onto the same sky near
  the epoch (whole GPS sky-repeat periods), because a TLE describes the orbit of its own days:
  years away, satellites have been manoeuvred, relocated or replaced.

Times are UTC Unix seconds (``t_unix_s``) everywhere outside this module; sgp4's split Julian
date is made here only (:func:`virtualgps.geodesy.unix_to_jd`).

Accepted approximations (with their size)
-----------------------------------------
- UT1 = UTC and no polar motion in TEME -> ECEF: < 0.005 deg as seen from the ground (see
  :mod:`virtualgps.geodesy`).
- The TLE/SGP4 model itself: a GPS TLE is good to about 1-2 km near its epoch (the bundled
  2020-05-14 set agrees with that day's broadcast orbits to a median 1.7 km), i.e. about
  0.005 deg as seen from the ground. Measured against skyfield (same SGP4 model, its own frame
  chain): 0.003 deg at most; against a real receiver's integer-degree GSV angles 15 days off
  epoch: 0.42 deg mean, of which rounding to whole degrees alone makes ~0.38 deg (tests).
- Sky-time shift by whole repeat periods: see :func:`sidereal_shift_s` for the measured drift.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from sgp4.api import Satrec, SatrecArray

from virtualgps.bundled import bundled_dir
from virtualgps.constants import DAY_S, UNIX_EPOCH_JD
from virtualgps.exceptions import ConfigError, InputFileError
from virtualgps.geodesy import teme_to_ecef, unix_to_jd
from virtualgps.sky import systems
from virtualgps.sky.lookup import (
    LookupTable,
    is_lookup_table,
    read_lookup_table,
)

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)

# The pinned TLE sets: the repository's ephemeris/ folder, packaged into wheels.
BUNDLED_EPHEMERIS_DIR = bundled_dir("ephemeris")
# The newest bundled set is the default (see ephemeris/README.md for sources and epochs).
DEFAULT_TLE_NAME = "gps-ops-2020-05-14T22Z.tle"

# Period after which the sky seen from a fixed site repeats, used by sidereal_shift_s. GPS
# satellites make two revolutions per sidereal day, but J2 makes their nodes regress and their
# argument of latitude run slightly fast, so their own repeat is several seconds shorter and
# differs between satellites (Agnew & Larson 2007, "Finding the repeat times of the GPS
# constellation", GPS Solutions 11). Measured with SGP4 on the bundled 2017 sets: the per-satellite
# best repeat periods span 86146-86161 s (median 86154.7 s); shifting the whole sky by 86155 s
# drifts 0.020 deg per day of shift (mean great-circle separation; 2.0 deg after 100 days),
# shifting by the sidereal day 0.070 deg per day (7.0 deg after 100 days). See
# sidereal_shift_s and ephemeris/README.md.
GPS_SKY_REPEAT_S = 86155.0

# The official TLE column template (Space-Track / CelesTrak documentation), quoted in errors.
TLE_LINE1_TEMPLATE = "1 NNNNNC NNNNNAAA NNNNN.NNNNNNNN +.NNNNNNNN +NNNNN-N +NNNNN-N N NNNNN"
TLE_LINE2_TEMPLATE = "2 NNNNN NNN.NNNN NNN.NNNN NNNNNNN NNN.NNNN NNN.NNNN NN.NNNNNNNNNNNNNN"
TLE_LINE_LENGTH = 69
# 0-based columns that must be blank in each line (the separators of the templates).
_LINE1_BLANKS = (1, 8, 17, 32, 43, 52, 61, 63)
_LINE2_BLANKS = (1, 7, 16, 25, 33, 42, 51)
# The fields of each line: name, 1-based first and last column, pattern (from the templates;
# satellite numbers may be Alpha-5, e.g. A0001; numbers may be blank-padded on the left).
_EXP = r"[ +-]\d{5}[+-]\d"  # the TLE's implied-decimal exponent form, e.g. " 38792-4"
_ANGLE = r"[ \d]{2}\d\.\d{4}"
_LINE1_FIELDS = (
    ("satellite number", 3, 7, r"[A-Z\d]\d{4}|[ \d]{4}\d"),
    ("classification", 8, 8, r"[UCS ]"),
    ("international designator", 10, 17, r"[ \w-]{8}"),
    ("epoch (YYDDD.DDDDDDDD)", 19, 32, r"\d{2}[ \d]{2}\d\.\d{8}"),
    ("first derivative of mean motion", 34, 43, r"[ +-]\.\d{8}"),
    ("second derivative of mean motion", 45, 52, _EXP),
    ("BSTAR drag term", 54, 61, _EXP),
    ("ephemeris type", 63, 63, r"[ \d]"),
    ("element set number", 65, 68, r"[ \d]{3}\d"),
)
_LINE2_FIELDS = (
    ("satellite number", 3, 7, r"[A-Z\d]\d{4}|[ \d]{4}\d"),
    ("inclination (deg)", 9, 16, _ANGLE),
    ("right ascension of the node (deg)", 18, 25, _ANGLE),
    ("eccentricity (implied leading decimal point)", 27, 33, r"\d{7}"),
    ("argument of perigee (deg)", 35, 42, _ANGLE),
    ("mean anomaly (deg)", 44, 51, _ANGLE),
    ("mean motion (rev/day)", 53, 63, r"[ \d]\d\.[\d ]{8}"),
    ("revolution number", 64, 68, r"[ \d]{4}\d"),
)
# Value ranges of line 2's angles and mean motion (degrees, revolutions per day).
_LINE2_RANGES = (
    ("inclination (deg)", 9, 16, 0.0, 180.0),
    ("right ascension of the node (deg)", 18, 25, 0.0, 360.0),
    ("argument of perigee (deg)", 35, 42, 0.0, 360.0),
    ("mean anomaly (deg)", 44, 51, 0.0, 360.0),
    ("mean motion (rev/day)", 53, 63, 1e-6, 20.0),
)

_TABLE_PRN = re.compile(r"^G0*(\d{1,3})$", re.IGNORECASE)
_TABLE_NORAD = re.compile(r"^(\d{1,5})[A-Z]?$", re.IGNORECASE)


def default_tle_path() -> Path:
    """Return the path of the default bundled TLE set (the newest one).

    Returns
    -------
    path : Path, ``ephemeris/gps-ops-2020-05-14T22Z.tle`` in the repository
    """
    return BUNDLED_EPHEMERIS_DIR / DEFAULT_TLE_NAME


# --------------------------------------------------------------------------------------------
# TLE parsing
# --------------------------------------------------------------------------------------------


def tle_checksum(line: str) -> int:
    """Compute the mod-10 checksum of a TLE line.

    Digits count their value, a minus sign counts 1, everything else 0, over columns 1-68
    (NORAD Two-Line Element format, as documented by CelesTrak and Space-Track).

    Parameters
    ----------
    line : str, a TLE line of at least 68 characters

    Returns
    -------
    checksum : int in 0..9, the value column 69 must hold
    """
    total = 0
    for ch in line[:68]:
        if ch.isdigit():
            total += int(ch)
        elif ch == "-":
            total += 1
    return total % 10


def _check_tle_line(path: Path, line_no: int, text: str, which: int) -> None:
    """Raise InputFileError unless ``text`` has the layout of TLE line ``which`` (1 or 2)."""
    template = TLE_LINE1_TEMPLATE if which == 1 else TLE_LINE2_TEMPLATE
    expect = f"expected TLE line {which} laid out as '{template}' ({TLE_LINE_LENGTH} columns)"
    if len(text) != TLE_LINE_LENGTH:
        raise InputFileError(
            path, f"TLE line {which} has {len(text)} columns, {expect}", line=line_no
        )
    blanks = _LINE1_BLANKS if which == 1 else _LINE2_BLANKS
    for col in blanks:
        if text[col] != " ":
            raise InputFileError(path, f"column {col + 1} should be blank, {expect}", line=line_no)
    for field, first, last, pattern in _LINE1_FIELDS if which == 1 else _LINE2_FIELDS:
        value = text[first - 1 : last]
        if re.fullmatch(pattern, value) is None:
            raise InputFileError(
                path,
                f"columns {first}-{last} ({field}) hold {value!r}, {expect}",
                line=line_no,
            )
    if which == 2:
        for field, first, last, lo, hi in _LINE2_RANGES:
            value = float(text[first - 1 : last])
            if not lo <= value <= hi:
                raise InputFileError(
                    path,
                    f"columns {first}-{last} ({field}) = {value:g}, expected {lo:g} to {hi:g}",
                    line=line_no,
                )
    if not text[-1].isdigit():
        raise InputFileError(path, f"column 69 must be the checksum digit, {expect}", line=line_no)
    want = tle_checksum(text)
    if int(text[-1]) != want:
        raise InputFileError(
            path,
            f"checksum digit is {text[-1]} but the mod-10 sum of columns 1-68 is {want} "
            "(digits count their value, '-' counts 1): the line is corrupt",
            line=line_no,
        )


def read_prn_table(path: str | Path) -> dict[int, int]:
    """Read a NORAD -> PRN table (CelesTrak/GNSS-list style CSV).

    Lines look like ``GPS,BIIF-2,G01,37753U,11036A`` (system, name, PRN, NORAD catalogue
    number with classification letter, international designator). Blank lines and ``#``
    comments are skipped; rows whose PRN is not a GPS ``Gnn`` are ignored.

    Parameters
    ----------
    path : str or Path, the table file

    Returns
    -------
    norad_to_prn : dict int -> int

    Raises
    ------
    InputFileError
        if the file cannot be read or a row is not in that layout.
    """
    path = Path(path)
    text = _read_text(path)
    table: dict[int, int] = {}
    for line_no, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        expect = "expected 'SYSTEM,NAME,Gnn,NNNNNU,YYNNNA' (e.g. GPS,BIIF-2,G01,37753U,11036A)"
        if len(fields) < 4:
            raise InputFileError(path, f"{len(fields)} fields, {expect}", line=line_no)
        prn_field, norad_field = fields[2], fields[3]
        if prn_field[:1].upper() != "G":
            continue  # another constellation's row (Rnn, Enn, ...): not a GPS PRN
        m_prn, m_norad = _TABLE_PRN.match(prn_field), _TABLE_NORAD.match(norad_field)
        if m_prn is None or m_norad is None:
            raise InputFileError(
                path,
                f"cannot read PRN {prn_field!r} / NORAD {norad_field!r}, {expect}",
                line=line_no,
            )
        table[int(m_norad.group(1))] = int(m_prn.group(1))
    return table


def _read_text(path: Path) -> str:
    """Read a text file, turning OS errors into InputFileError."""
    try:
        return path.read_bytes().decode("ascii", errors="replace")
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror or exc}") from exc


def _find_prn_table(folder: Path) -> Path | None:
    """A NORAD -> PRN table beside a TLE file: ``*NORAD-PRN*`` first, then ``*.t``."""
    for pattern in ("*NORAD-PRN*", "*.t"):
        found = sorted(p for p in folder.glob(pattern) if p.is_file())
        if found:
            return found[0]
    return None


@dataclass(frozen=True)
class _TleEntry:
    name: str
    line1: str
    line2: str
    line_no: int  # line number of TLE line 1 in the file


def _split_tle_entries(path: Path, text: str) -> list[_TleEntry]:
    """Group the lines of a TLE file into (name, line 1, line 2) with their line numbers."""
    lines = [(i, raw.rstrip()) for i, raw in enumerate(text.splitlines(), start=1)]
    lines = [(i, s) for i, s in lines if s.strip()]
    entries: list[_TleEntry] = []
    k = 0
    while k < len(lines):
        line_no, s = lines[k]
        name = ""
        if not s.startswith("1 "):
            if s.startswith("2 ") and len(s) >= 60 and s[2:7].strip().isdigit():
                raise InputFileError(
                    path,
                    f"TLE line 2 without its line 1, expected '{TLE_LINE1_TEMPLATE}' first",
                    line=line_no,
                )
            # A name line (3-line format; Space-Track writes it as "0 NAME").
            name = s[2:].strip() if s.startswith("0 ") else s.strip()
            k += 1
            if k >= len(lines):
                raise InputFileError(
                    path,
                    f"name line {name!r} is not followed by TLE line 1, expected "
                    f"'{TLE_LINE1_TEMPLATE}'",
                    line=line_no,
                )
            line_no, s = lines[k]
            if not s.startswith("1 "):
                raise InputFileError(
                    path,
                    f"expected TLE line 1 '{TLE_LINE1_TEMPLATE}' after the name line, "
                    f"found {s[:20]!r}",
                    line=line_no,
                )
        _check_tle_line(path, line_no, s, 1)
        if k + 1 >= len(lines) or not lines[k + 1][1].startswith("2 "):
            where = lines[k + 1][0] if k + 1 < len(lines) else line_no + 1
            raise InputFileError(
                path, f"expected TLE line 2 '{TLE_LINE2_TEMPLATE}' after line 1", line=where
            )
        line2_no, s2 = lines[k + 1]
        _check_tle_line(path, line2_no, s2, 2)
        if s[2:7] != s2[2:7]:
            raise InputFileError(
                path,
                f"satellite number {s2[2:7]!r} differs from line 1's {s[2:7]!r}, expected "
                "the two lines of one satellite",
                line=line2_no,
            )
        entries.append(_TleEntry(name=name, line1=s, line2=s2, line_no=line_no))
        k += 2
    return entries


@dataclass(frozen=True, eq=False)
class Constellation:
    """GPS satellites from one TLE file, propagated together with SGP4.

    Attributes
    ----------
    prn : (n_sat,) int, PRNs sorted ascending (unique)
    name : tuple of n_sat str, the TLE names ('' in 2-line files)
    norad : (n_sat,) int, NORAD catalogue numbers
    epoch_unix_s : (n_sat,) float, each TLE's epoch, UTC Unix seconds
    satrec_array : sgp4.api.SatrecArray over the satellites in ``prn`` order
    source : str, the TLE file it came from
    """

    prn: NDArray[np.int64]
    name: tuple[str, ...]
    norad: NDArray[np.int64]
    epoch_unix_s: F64
    satrec_array: SatrecArray
    source: str
    # SGP4 costs ~1 us per satellite and epoch on smooth orbits: the receiver interpolates its
    # positions between nodes (virtualgps.sky.satnodes) instead of propagating every epoch.
    node_interpolation: ClassVar[bool] = True

    def __len__(self) -> int:
        return int(self.prn.shape[0])

    @property
    def epoch_center_unix_s(self) -> float:
        """Median TLE epoch, UTC Unix seconds: the time the set is most accurate around."""
        return float(np.median(self.epoch_unix_s))

    def sat_state_ecef(
        self, t_unix_s: ArrayLike, with_velocity: bool = True
    ) -> tuple[F64, F64 | None]:
        """Propagate every satellite to the given times; positions and velocities in ECEF.

        Parameters
        ----------
        t_unix_s : scalar or (...) float, UTC Unix seconds. A 1-D input of n_t times gives
            (n_t, n_sat, 3); a scalar gives (n_sat, 3); any shape S gives S + (n_sat, 3).
        with_velocity : False skips the velocities (returned as None): the receiver needs
            positions only, once per live epoch

        Returns
        -------
        sat_ecef_m : (..., n_sat, 3) float, metres, ECEF (WGS-84 axes, GMST-1982 rotation)
        sat_vel_ecef_mps : (..., n_sat, 3) float, metres per second, Earth-fixed velocity
            Both are NaN where SGP4 reports an error for that satellite and time (it never
            raises).
        """
        t = np.asarray(t_unix_s, dtype=float)
        t_flat = np.ascontiguousarray(t.reshape(-1))
        jd, fr = unix_to_jd(t_flat)
        err, r_km, v_kmps = self.satrec_array.sgp4(
            np.ascontiguousarray(jd), np.ascontiguousarray(fr)
        )
        # sgp4 gives (n_sat, n_t, ...); we keep time first, satellites second.
        r_teme_m = np.transpose(r_km, (1, 0, 2)) * 1000.0
        v_teme_mps = np.transpose(v_kmps, (1, 0, 2)) * 1000.0 if with_velocity else None
        r_ecef, v_ecef = teme_to_ecef(r_teme_m, t_flat[:, None], v_teme_mps)
        bad = (err.T != 0)[..., None]
        shape = t.shape + (len(self), 3)
        if bad.any():
            r_ecef = np.where(bad, np.nan, r_ecef)
        if v_ecef is None:
            return r_ecef.reshape(shape), None
        v_ecef = np.where(bad, np.nan, v_ecef)
        return r_ecef.reshape(shape), v_ecef.reshape(shape)

    def sat_ecef_m(self, t_unix_s: ArrayLike) -> F64:
        """Satellite positions in ECEF at the given times (see :meth:`sat_state_ecef`).

        Parameters
        ----------
        t_unix_s : scalar or (...) float, UTC Unix seconds; (n_t,) gives (n_t, n_sat, 3)

        Returns
        -------
        sat_ecef_m : (..., n_sat, 3) float, metres, ECEF; NaN where SGP4 failed
        """
        return self.sat_state_ecef(t_unix_s, with_velocity=False)[0]


def _place_glonass(entries: list[_TleEntry], norad: NDArray[np.int64], epoch_unix_s: F64,
                   prn: NDArray[np.int64], which: list[int], by_name: bool = True) -> list[int]:
    """Number GLONASS entries 64 + slot by the bundled slot table at each one's TLE epoch (in
    ``prn``, in place), by the GLONASS number in their names, else by NORAD number; returns
    those it cannot place."""
    if not which:
        return []
    from virtualgps.sky import glonass_slots

    table = glonass_slots.read_slot_table()
    known_until = glonass_slots.date_unix_s(glonass_slots.BUNDLED_KNOWN_UNTIL)
    unplaced = []
    if by_name and any(float(epoch_unix_s[i]) > known_until for i in which):
        log.warning("GLONASS slots after %s (the slot table's latest source) are assumed "
                    "unchanged since", glonass_slots.BUNDLED_KNOWN_UNTIL)
    for i in which:
        t = float(epoch_unix_s[i])
        slot = glonass_slots.slot_at(table, t, systems.glonass_number_from_name(
            entries[i].name)) if by_name else None
        if slot is None:
            slot = glonass_slots.slot_at(table, t, norad=int(norad[i]))
        if slot is None:
            unplaced.append(i)
        else:
            prn[i] = systems.GLONASS.offset + slot
    return unplaced


_WARNED: set[tuple[str, int, int]] = set()


def _warn_once(path: Path) -> bool:
    """Whether this file's warnings are still to be given in this process (a set is read
    again to date it, and by every receiver of a run: one warning is enough)."""
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    if key in _WARNED:
        return False
    _WARNED.add(key)
    return True


def _kept_letters(kept: str) -> list[str]:
    """The letters :func:`systems.letters` gives the satellites kept: a PRN of no known system
    (a test's ``(PRN 99)``) counts as GPS, as it always did."""
    return list(kept) + (["?"] if "G" in kept else [])


def _check_systems(path: str | Path, prn: NDArray[np.int64], kept: str) -> None:
    """ConfigError when a TLE set holds no satellite of the systems kept (e.g. a GLONASS set
    given to a GPS receiver), naming what it holds."""
    have = systems.letters(prn[prn >= 0])
    if not np.isin(have, _kept_letters(kept)).any():
        held = ", ".join(f"{systems.system_named(x).name}: {int((have == x).sum())}"
                         for x in sorted(set(have.tolist())) if x != "?")
        wanted = ", ".join(systems.system_named(x).name for x in kept)
        raise ConfigError(f"{path}: holds no {wanted} satellite ({held or 'none placed'}); "
                          f"give a set of the systems the receiver tracks")


def _read_tle_file(path: Path, prn_table: str | Path | None
                   ) -> tuple[list[str], NDArray[np.int64], NDArray[np.int64], F64, list[Satrec]]:
    """The satellites of one TLE file: names, NORAD numbers, numbers here (PRNs, GLONASS
    64 + slot, ...), epochs (UTC s) and SGP4 records (see :func:`load_tle`)."""
    path = Path(path)
    entries = _split_tle_entries(path, _read_text(path))
    if not entries:
        raise InputFileError(
            path,
            "no satellites: expected 2-line or 3-line TLE entries "
            f"('{TLE_LINE1_TEMPLATE}' / '{TLE_LINE2_TEMPLATE}')",
        )
    table: dict[int, int] = {} if prn_table is None else read_prn_table(prn_table)
    table_source = None if prn_table is None else Path(prn_table)

    satrecs: list[Satrec] = []
    for entry in entries:
        try:
            sat = Satrec.twoline2rv(entry.line1, entry.line2)
        except (ValueError, IndexError) as exc:
            raise InputFileError(
                path,
                f"cannot read the TLE fields ({exc}), expected '{TLE_LINE1_TEMPLATE}'",
                line=entry.line_no,
            ) from exc
        if sat.error != 0:
            raise InputFileError(
                path,
                f"SGP4 rejects these elements (error code {sat.error}): expected a valid "
                "orbit (eccentricity in [0, 1), positive mean motion)",
                line=entry.line_no,
            )
        satrecs.append(sat)

    norad = np.array([s.satnum for s in satrecs], dtype=np.int64)
    epoch = np.array([((s.jdsatepoch - UNIX_EPOCH_JD) + s.jdsatepochF) * DAY_S for s in satrecs])
    prn = np.full(len(entries), -1, dtype=np.int64)
    glonass: list[int] = []  # GLONASS satellites: placed by the slot table at their epoch
    for i, entry in enumerate(entries):
        if int(norad[i]) in table:
            prn[i] = table[int(norad[i])]
            continue
        number = systems.number_from_name(entry.name)
        if number is not None:
            prn[i] = number
        elif systems.glonass_number_from_name(entry.name) is not None:
            glonass.append(i)
    unplaced = _place_glonass(entries, norad, epoch, prn, glonass)
    prn[unplaced] = -2  # (named GLONASS satellites the slot table cannot place)
    if np.any(prn == -1) and prn_table is None:
        table_source = _find_prn_table(path.parent)
        if table_source is not None:
            table = read_prn_table(table_source)
            for i in np.flatnonzero(prn == -1):
                prn[i] = table.get(int(norad[i]), -1)
    # a 2-line GLONASS set: by NORAD number in the slot table (and what it cannot place there,
    # in a set the table shows to be GLONASS, is a GLONASS satellite in no known slot)
    left = _place_glonass(entries, norad, epoch, prn,
                          [int(i) for i in np.flatnonzero(prn == -1)], by_name=False)
    if left and np.any(prn >= systems.GLONASS.first) and np.all(
            (prn < 0) | (systems.letters(prn) == "R")):
        unplaced += left
        prn[left] = -2
    if unplaced and not log.disabled and _warn_once(path):
        log.warning("%s: %d GLONASS satellite(s) in no orbital slot at their TLE epoch by the "
                    "slot table (%s): left out", path.name, len(unplaced),
                    ", ".join(entries[i].name or f"NORAD {norad[i]}" for i in unplaced))
    missing = np.flatnonzero(prn == -1)
    if missing.size:
        i = int(missing[0])
        where = f"table {table_source}" if table_source is not None else "no NORAD-PRN table"
        raise InputFileError(
            path,
            f"satellite {norad[i]} has no PRN: expected a name like 'GPS BIIR-2  (PRN 13)' or "
            f"a NORAD -> PRN table row like 'GPS,BIIF-2,G01,{norad[i]}U,...' ({where})",
            line=entries[i].line_no,
        )

    keep = np.flatnonzero(prn >= 0)
    return ([entries[i].name for i in keep], norad[keep], prn[keep], epoch[keep],
            [satrecs[i] for i in keep])


def load_tle(path: str | Path, prn_table: str | Path | None = None,
             systems_kept: str | None = None) -> Constellation:
    """Read a 2-line or 3-line TLE file into a :class:`Constellation`.

    The file may hold any system's satellites. GPS, Galileo, BeiDou, QZSS and SBAS satellites
    are numbered from the PRN in their names (``(PRN 13)``, ``(PRN E11)``, ``(C19)``; see
    :mod:`virtualgps.sky.systems`); GLONASS satellites, whose names carry their GLONASS number
    (``COSMOS 2456 (730)``), by the orbital slot the slot table gives for their TLE epoch
    (:mod:`virtualgps.sky.glonass_slots`; one warning names those it cannot place, which are
    left out).

    Blank lines, trailing blanks and CRLF line ends are accepted. Each satellite's PRN comes
    from, in order: ``prn_table`` when given (a table for the file's date is the authority,
    as PRNs are reassigned between satellites over the years), the name (``... (PRN 13)``),
    and otherwise a NORAD -> PRN table found beside the file (``*NORAD-PRN*``, else ``*.t``).
    A table found beside the file must match the file's date: it is not checked.
    When two entries have the same PRN, the one with the newest epoch is kept.

    Parameters
    ----------
    path : str or Path, the TLE file
    prn_table : str or Path, optional, a NORAD -> PRN table (see :func:`read_prn_table`)
    systems_kept : RINEX letters of the systems to keep (e.g. ``"G"``, ``"GRE"``); None: all
        (ConfigError when the file holds none of them)

    Returns
    -------
    constellation : Constellation, satellites sorted by PRN

    Raises
    ------
    InputFileError
        naming the file and line, if a line breaks the TLE column layout or its checksum, if a
        satellite has no PRN, or if the file holds no satellite.
    """
    return load_tle_sets([path], prn_table, systems_kept)


def load_tle_sets(paths: list[str | Path], prn_table: str | Path | None = None,
                  systems_kept: str | None = None) -> Constellation:
    """Read several TLE files (e.g. one per group: gps-ops, glo-ops, galileo) into one
    :class:`Constellation` (see :func:`load_tle`; a satellite in several files keeps its
    newest epoch)."""
    parts = [_read_tle_file(Path(p), prn_table) for p in paths]
    names = [n for part in parts for n in part[0]]
    norad, prn, epoch = (np.concatenate([part[k] for part in parts]) for k in (1, 2, 3))
    satrecs = [r for part in parts for r in part[4]]
    source = ", ".join(str(p) for p in paths)
    if systems_kept is not None:
        _check_systems(source, prn, systems_kept)
        prn = np.where(np.isin(systems.letters(prn), _kept_letters(systems_kept)), prn, -2)
    # Keep one entry per PRN, the newest epoch: sort by (PRN, -epoch), take the first of each.
    order = np.lexsort((-epoch, prn))
    order = order[prn[order] >= 0]
    first = np.ones(order.size, dtype=bool)
    first[1:] = prn[order][1:] != prn[order][:-1]
    keep = order[first]
    if keep.size == 0:
        raise InputFileError(source, "no satellite could be numbered (GLONASS ones need the "
                             "slot table to reach the set's date: see ephemeris/README.md)")
    return Constellation(
        prn=prn[keep],
        name=tuple(names[i] for i in keep),
        norad=norad[keep],
        epoch_unix_s=epoch[keep],
        satrec_array=SatrecArray([satrecs[i] for i in keep]),
        source=source,
    )


# --------------------------------------------------------------------------------------------
# The paper's offline lookup table (the table itself: virtualgps.sky.lookup)
# --------------------------------------------------------------------------------------------


def build_lookup_table(
    constellation: Constellation, start_unix_s: float, duration_s: float, step_s: float
) -> LookupTable:
    """Tabulate a constellation's ECEF states over an interval (the paper's offline approach).

    Rows run from ``start_unix_s`` every ``step_s`` until they cover ``duration_s`` (the last
    row is at or after ``start_unix_s + duration_s``).

    Parameters
    ----------
    constellation : Constellation
    start_unix_s : float, UTC Unix seconds of the first row
    duration_s : float, seconds to cover, >= 0
    step_s : float, seconds between rows, > 0 (60 s keeps positions within ~4 mm of SGP4,
        300 s within ~0.4 m)

    Returns
    -------
    table : LookupTable

    Raises
    ------
    ConfigError
        if the step is not positive or the duration is negative or not finite.
    """
    if not (math.isfinite(step_s) and step_s > 0):
        raise ConfigError(f"lookup table step_s={step_s}: expected a positive number of seconds")
    if not (math.isfinite(duration_s) and duration_s >= 0):
        raise ConfigError(f"lookup table duration_s={duration_s}: expected seconds >= 0")
    if not math.isfinite(start_unix_s):
        raise ConfigError(f"lookup table start_unix_s={start_unix_s}: expected a finite time")
    n_row = int(math.ceil(duration_s / step_s - 1e-9)) + 1
    t = start_unix_s + step_s * np.arange(n_row, dtype=float)
    # Velocities are the central difference of SGP4's ECEF positions over +-0.5 s (truncation
    # error h^2/6 |jerk| ~ 1e-5 m/s), not SGP4's own velocity output, which is not exactly the
    # derivative of its positions (they differ by up to ~0.02 m/s for GPS). Hermite needs the
    # true derivative: with SGP4's velocities the interpolation error at 60 s steps is ~0.12 m,
    # with these ~4 mm (measured, 2020-05-14 set).
    half_s = 0.5
    r_all = constellation.sat_ecef_m(t[None, :] + np.array([[0.0], [-half_s], [half_s]]))
    r = r_all[0]
    v = (r_all[2] - r_all[1]) / (2.0 * half_s)
    return LookupTable(
        prn=constellation.prn.copy(),
        t_unix_s=t,
        sat_ecef_m_rows=r,
        sat_vel_ecef_mps_rows=v,
        source=constellation.source,
        step_s=float(step_s),
    )


# --------------------------------------------------------------------------------------------
# Sky-time policy
# --------------------------------------------------------------------------------------------


def sidereal_shift_s(
    t_unix_s: float,
    epoch_unix_s: float,
    max_offset_days: float = 3.0,
    repeat_s: float = GPS_SKY_REPEAT_S,
) -> float:
    """Seconds to subtract from a simulated time so the sky is computed near the TLE epoch.

    The sky over a fixed site repeats after about one sidereal day (GPS satellites make two
    revolutions while the Earth turns once relative to the stars), so the sky at ``t`` is
    close to the sky at ``t - k * repeat_s``. SGP4 is accurate near the epoch only, so the
    caller computes satellite positions at ``t - shift`` (logging the shift once) while NMEA
    times keep ``t``.

    Size of the approximation (measured; mean great-circle separation of satellites above 5 deg
    seen from six sites over one day, script in tests/test_ephemeris.py, numbers in
    ephemeris/README.md):

    - Same TLE at ``t`` and ``t - k * repeat_s`` (the shift alone; 2017-03-26 set): with the
      GPS repeat of 86155 s (the default) 0.020 deg per day of shift (0.20 deg at k = 10,
      2.0 deg at k = 100, 7.3 deg at k = 365); with the sidereal day 86164.09 s 0.070 deg per
      day (7.0 deg at k = 100). No single period fits every satellite (their own repeats span
      86146-86161 s), hence the linear drift. Satellites being relocated (PRN 21 and 23 in the
      2020-05-14 set) do not repeat at all and drift by degrees per day.
    - Against the real sky: SGP4 propagated straight to ``t`` stays better than a shift for at
      least 50 days (2017-02-02 set vs the 2017-03-26 set 50 days later: direct 0.23 deg,
      shifted 1.0 deg, sidereal 3.6 deg; a real receiver's GSV angles 15 and 37 days off:
      direct 0.42 and 0.39 deg, at the 0.38 deg floor of its integer-degree rounding; shifted
      0.51 and 0.97 deg). Three years off (2017 set vs the 2020 set) the shift wins: 9 deg
      against 24 deg direct (and 73 deg with the sidereal day). A far date thus gives a
      plausible sky, not the real one.

    Parameters
    ----------
    t_unix_s : float, the simulated UTC time
    epoch_unix_s : float, the ephemeris' centre (``Constellation.epoch_center_unix_s``)
    max_offset_days : float, no shift while |t - epoch| <= this many days (SGP4 is good
        to a few km there)
    repeat_s : float, the sky repeat period; default ``GPS_SKY_REPEAT_S`` (86155 s);
        ``constants.SIDEREAL_DAY_S`` gives whole sidereal days

    Returns
    -------
    shift_s : float, 0.0 or a whole number of ``repeat_s`` periods; ``t - shift_s`` is the
        time nearest ``epoch_unix_s`` with the same sky
    """
    offset_s = float(t_unix_s) - float(epoch_unix_s)
    if not math.isfinite(offset_s) or abs(offset_s) <= max_offset_days * DAY_S:
        return 0.0
    return float(round(offset_s / repeat_s)) * float(repeat_s)


def load_ephemeris_file(path: str | Path, systems_kept: str | None = "G"):
    """Satellites from any ephemeris file ``--tle`` accepts: a lookup table
    (:func:`virtualgps.sky.lookup.write_lookup_table`), a RINEX 2/3 GPS navigation file (broadcast
    orbits, :mod:`virtualgps.sky.broadcast`) or a TLE set.

    Parameters
    ----------
    path : the file
    systems_kept : RINEX letters of the systems a TLE set keeps (default ``"G"``: the receivers
        track GPS; None: every system, as ``sky`` lists them; the same for a RINEX
        navigation file's GPS, Galileo, BeiDou and GLONASS records); lookup tables hold GPS
        only

    Returns
    -------
    ephemeris : LookupTable, BroadcastEphemeris or Constellation (one interface: ``prn``,
        ``sat_ecef_m``, ``sat_state_ecef``, ``epoch_center_unix_s``)
    """
    from virtualgps.sky import broadcast

    if is_lookup_table(path):
        return read_lookup_table(path)
    if broadcast.is_rinex_nav(path):
        return broadcast.read_rinex_nav(path, systems_kept)
    return load_tle(path, systems_kept=systems_kept)


__all__ = [
    "BUNDLED_EPHEMERIS_DIR",
    "DEFAULT_TLE_NAME",
    "GPS_SKY_REPEAT_S",
    "Constellation",
    "build_lookup_table",
    "default_tle_path",
    "load_ephemeris_file",
    "load_tle",
    "read_prn_table",
    "sidereal_shift_s",
    "tle_checksum",
]
