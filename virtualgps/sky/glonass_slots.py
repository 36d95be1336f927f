"""Which GLONASS satellite broadcast in which orbital slot, and when.

NMEA and RINEX identify a GLONASS satellite by its orbital slot (1-24, more for spares); TLE
sets name it by its COSMOS and GLONASS numbers (``COSMOS 2456 (730)``), and satellites change
slots as the constellation is replenished. The bundled table (``ephemeris/glonass-slots.csv``,
its header names the sources) gives each satellite's slot with the dates it held it;
:func:`read_slot_table` reads it or a user's table of the same layout.
"""

from __future__ import annotations

import csv
import datetime as dt
import math
from dataclasses import dataclass
from pathlib import Path

from virtualgps.bundled import bundled_dir
from virtualgps.exceptions import InputFileError

BUNDLED_SLOT_TABLE = bundled_dir("ephemeris") / "glonass-slots.csv"
# The date of the bundled table's latest source (the IAC status of 2021-10-24): a satellite
# placed later is assumed to have kept its slot since.
BUNDLED_KNOWN_UNTIL = "2021-10-24"
COLUMNS = ("glonass_number", "cosmos", "norad", "slot", "channel", "from", "to", "source")


@dataclass(frozen=True)
class SlotEntry:
    """One satellite in one slot.

    glonass_number : e.g. "730", "702K"; cosmos : e.g. 2456; norad : catalogue number (0: not
    known); slot : 1-32; channel : FDMA frequency channel (-7..6)
    from_unix_s, to_unix_s : UTC seconds, the satellite held the slot from <= t < to (-inf /
    +inf where not known)
    source : where the row comes from
    """

    glonass_number: str
    cosmos: int
    norad: int
    slot: int
    channel: int
    from_unix_s: float
    to_unix_s: float
    source: str

    def holds(self, t_unix_s: float) -> bool:
        """Whether the satellite held its slot at ``t_unix_s``."""
        return self.from_unix_s <= t_unix_s < self.to_unix_s


def date_unix_s(day: str) -> float:
    """UTC seconds of a ``YYYY-MM-DD`` date's midnight (ValueError if malformed)."""
    d = dt.date.fromisoformat(day.strip())
    return dt.datetime(d.year, d.month, d.day, tzinfo=dt.UTC).timestamp()


def _date_s(text: str, default: float, path: Path, line: int) -> float:
    if not text.strip():
        return default
    try:
        return date_unix_s(text)
    except ValueError:
        raise InputFileError(path, f"date {text!r} is not YYYY-MM-DD", line=line) from None


def read_slot_table(path: str | Path = BUNDLED_SLOT_TABLE) -> list[SlotEntry]:
    """Read a GLONASS slot table (CSV, ``#`` comments, header ``glonass_number,cosmos,norad,
    slot,channel,from,to,source``; dates YYYY-MM-DD UTC, empty where not known).

    Raises
    ------
    InputFileError : unreadable, another header, or a row out of range (file and line named)
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputFileError(path, f"cannot read the GLONASS slot table: {exc.strerror}"
                             ) from None
    rows = [(i, ln) for i, ln in enumerate(text.splitlines(), start=1)
            if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows or tuple(c.strip() for c in rows[0][1].split(",")) != COLUMNS:
        raise InputFileError(path, "expected the header " + ",".join(COLUMNS),
                             line=rows[0][0] if rows else None)
    out = []
    for line, values in zip((i for i, _ in rows[1:]),
                            csv.reader(ln for _, ln in rows[1:]), strict=True):
        if len(values) != len(COLUMNS):
            raise InputFileError(path, f"{len(values)} fields, expected {len(COLUMNS)}",
                                 line=line)
        gc, cosmos, norad, slot, channel, t0, t1, source = (v.strip() for v in values)
        try:
            entry = SlotEntry(gc, int(cosmos), int(norad) if norad else 0, int(slot),
                              int(channel), _date_s(t0, -math.inf, path, line),
                              _date_s(t1, math.inf, path, line), source)
        except ValueError:
            raise InputFileError(path, "cosmos, norad, slot and channel must be integers",
                                 line=line) from None
        if not 1 <= entry.slot <= 32 or not -7 <= entry.channel <= 6:
            raise InputFileError(path, f"slot {entry.slot} / channel {entry.channel}: expected "
                                 "a slot 1-32 and a channel -7..6", line=line)
        out.append(entry)
    return out


def slot_at(table: list[SlotEntry], t_unix_s: float, glonass_number: str | None = None,
            norad: int | None = None) -> int | None:
    """The slot a satellite (by GLONASS number, else NORAD number) held at ``t_unix_s``; None
    where the table does not place it then."""
    for e in table:
        same = (glonass_number is not None and e.glonass_number.upper() == glonass_number.upper()
                ) or (glonass_number is None and norad is not None and e.norad == norad)
        if same and e.holds(t_unix_s):
            return e.slot
    return None
