"""TOML files as users write them: read with errors that name the file and line, and find the
line of a setting to point a user at it (profiles, configs, scenes, fleets).
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

from virtualgps.exceptions import InputFileError


def read_toml(path: Path) -> dict[str, Any]:
    """Read a TOML file, turning syntax errors into one line naming the file and line.

    Parameters
    ----------
    path : the file

    Returns
    -------
    data : the parsed table
    """
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise InputFileError(path, "no such file") from None
    except tomllib.TOMLDecodeError as exc:
        # tomllib's message ends with "(at line L, column C)".
        raise InputFileError(path, f"invalid TOML: {exc}") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror}") from None


def toml_key_line(text: str, section: str, key: str | None) -> int | None:
    """1-based line of ``key`` in ``[section]`` of a TOML text (of the table header when ``key``
    is None), or None. A plain scan, enough to point a user at a bad setting.

    Parameters
    ----------
    text : the TOML text
    section : table name ("" for the top level)
    key : the key, or None for the table header

    Returns
    -------
    line : int or None
    """
    current = ""
    for i, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        header = re.match(r"\[\s*([^\]]+?)\s*\]", stripped)
        if header:
            current = header.group(1).strip('"')
            if (key is None and current == section) or (section == "" and current == key):
                return i  # the table itself ([section], or a top-level key that is a table)
            continue
        if (
            key is not None
            and current == section
            and re.match(rf'"?{re.escape(key)}"?\s*[=.]', stripped)
        ):
            return i
    return None
