"""Receiver profiles: TOML files (built-ins in ``virtualgps/receiver/profiles/``) read, checked
and built into a :class:`~virtualgps.receiver.params.Profile`.

Precedence of settings (documented once, in docs/usage.md): built-in defaults < profile < config
file (``--config``) < command-line flags. A config file may hold run settings at its top level
(``scene``, ``seed``, ...; see :data:`RUN_KEYS`), a ``[georef]`` table, and any profile key or
table, which overrides the profile's (e.g. ``[noise] max_noise_m = 8.0``).
"""

from __future__ import annotations

import re
from dataclasses import replace
from importlib import resources
from pathlib import Path
from typing import Any

from virtualgps.exceptions import ConfigError, InputFileError, VirtualGPSError
from virtualgps.receiver.nmea_format import NmeaFormat
from virtualgps.receiver.params import (
    Cn0TrackingParams,
    ColdStartParams,
    ConstellationsParams,
    CorrelatedErrorParams,
    DopErrorParams,
    FoliageParams,
    LatencyParams,
    MultipathParams,
    NavFilterParams,
    NlosParams,
    NoiseParams,
    Profile,
    SbasParams,
    SignalParams,
    SkyParams,
    StaticHoldParams,
    UbxParams,
)
from virtualgps.sky import systems as _sys
from virtualgps.sky.skymask import SKY_MASK_MAX_CELL, SkyMaskParams
from virtualgps.tomlfile import read_toml, toml_key_line

BUILTIN_PROFILES = ("holux-m1000", "usarsim", "ideal", "ublox-m8n", "ublox-m9n", "phone")
DEFAULT_PROFILE = "holux-m1000"

# Settings of a run (not of the receiver) that a config file may set at its top level.
RUN_KEYS = frozenset(
    {
        "scene",
        "profile",
        "tle",
        "poses",
        "link",
        "serial",
        "baud_rate",
        "rate",
        "start_time",
        "seed",
        "origin",
        "out",
        "fixes",
        "georef",
    }
)


class SettingError(ConfigError):
    """A bad setting; ``section`` and ``key`` locate it in its TOML file ("" = top level)."""

    def __init__(self, section: str, key: str | None, message: str) -> None:
        super().__init__(message)
        self.section, self.key = section, key


_CHOICES = {
    ("", "georef"): ("wgs84", "flat_earth"),
    ("sky", "foliage"): ("block", "ignore"),
    ("noise", "model"): ("usarsim", "none"),
    ("cold_start", "power_on"): ("none", "hot", "warm", "cold"),
    ("correlated_error", "domain"): ("range", "position"),
    ("", "command_link"): ("mtk", "ubx", "none"),
    ("ubx", "generation"): ("M8", "M9"),
}
_NMEA_TEXT = frozenset(chr(c) for c in range(32, 127)) - set("$*!\\")
_TABLES = {
    "sky": SkyParams,
    "noise": NoiseParams,
    "signal": SignalParams,
    "cold_start": ColdStartParams,
    "dop_error": DopErrorParams,
    "correlated_error": CorrelatedErrorParams,
    "cn0_tracking": Cn0TrackingParams,
    "latency": LatencyParams,
    "nav_filter": NavFilterParams,
    "static_hold": StaticHoldParams,
    "sbas": SbasParams,
    "nlos": NlosParams,
    "multipath": MultipathParams,
    "foliage": FoliageParams,
    "constellations": ConstellationsParams,
    "ubx": UbxParams,
}


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Deep-merge two tables, ``over`` winning; neither input is modified.

    Parameters
    ----------
    base, over : nested dicts (TOML tables)

    Returns
    -------
    merged : a new nested dict
    """
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def profile_path(name_or_path: str) -> Path | None:
    """Where a built-in profile lives, or None if ``name_or_path`` is not a built-in name."""
    if name_or_path in BUILTIN_PROFILES:
        builtins = resources.files("virtualgps.receiver") / "profiles"
        return Path(str(builtins.joinpath(f"{name_or_path}.toml")))
    return None


def load_profile_dict(name_or_path: str) -> tuple[dict[str, Any], str]:
    """Read a built-in profile by name, or a profile TOML file by path.

    Returns
    -------
    data : the profile table
    source : the file it came from
    """
    path = profile_path(name_or_path)
    if path is None:
        path = Path(name_or_path)
        if not path.exists():
            raise ConfigError(
                f"unknown profile {name_or_path!r}: give one of {', '.join(BUILTIN_PROFILES)} "
                "or the path of a profile TOML file"
            )
    return read_toml(path), str(path)


def _float(value: Any, section: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        name = f"{section}.{key}" if section else key
        raise SettingError(section, key, f"{name} must be a number, got {value!r}")
    return float(value)


def _build_table(cls: type, table: dict[str, Any], prefix: str) -> Any:
    fields = cls.__dataclass_fields__
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        full = f"{prefix}.{key}"
        if key not in fields:
            raise SettingError(
                prefix, key, f"unknown setting {full!r}; known in [{prefix}]: {', '.join(fields)}"
            )
        default = fields[key].default
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise SettingError(prefix, key, f"{full} must be true or false, got {value!r}")
        elif isinstance(default, float):
            value = _float(value, prefix, key)
        elif isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise SettingError(prefix, key, f"{full} must be an integer, got {value!r}")
        elif str(fields[key].type).startswith("tuple[tuple[str, float]"):
            # (a table by name: name = number)
            if not isinstance(value, dict) or not all(
                    isinstance(v, int | float) and not isinstance(v, bool)
                    for v in value.values()):
                raise SettingError(prefix, key, f"{full} must be a table of numbers by name, "
                                   f"e.g. {{GLONASS = 1.0}}, got {value!r}")
            # (entries override the defaults system by system)
            value = tuple(sorted({**dict(default),
                                  **{str(k): float(v) for k, v in value.items()}}.items()))
        elif isinstance(default, tuple):  # (a list of names)
            if not isinstance(value, list) or not value or not all(
                    isinstance(v, str) for v in value):
                raise SettingError(prefix, key, f"{full} must be a non-empty list of names, "
                                   f"got {value!r}")
            value = tuple(value)
        choices = _CHOICES.get((prefix, key))
        if choices and value not in choices:
            raise SettingError(prefix, key, f"{full} must be one of {choices}, got {value!r}")
        kwargs[key] = value
    return cls(**kwargs)


def _bins(value: float, whole_deg: float, section: str, key: str) -> int:
    """How many bins of ``value`` degrees make ``whole_deg``; SettingError unless a whole number."""
    n = round(whole_deg / value) if value > 0 else 0
    if n < 1 or abs(n * value - whole_deg) > 1e-9:
        raise SettingError(section, key, f"{section}.{key} must divide {whole_deg:g} deg into "
                           f"whole bins (e.g. 5, 10, 15), got {value!r}")
    return n


def _mask_grid(
    value: Any, section: str, key: str, n_el: int, n_az: int
) -> tuple[tuple[float, ...], ...]:
    """Validate one sky-mask grid (a list of rows of dB values) and freeze it."""
    name = f"{section}.{key}" if section == "sky_mask" else f'{section}."{key}"'
    layout = (f"a list of at most {n_el} rows (elevation bins from the horizon up), each a list "
              f"of {n_az} attenuations in dB (azimuth bins from north)")
    if not isinstance(value, list) or not all(isinstance(r, list) for r in value):
        raise SettingError(section, key, f"{name} must be {layout}; got {value!r:.60}")
    if len(value) > n_el:
        raise SettingError(section, key, f"{name} has {len(value)} rows, more than the {n_el} "
                           "elevation bins (90 / el_bin_deg)")
    for r, row in enumerate(value, start=1):
        if len(row) != n_az:
            raise SettingError(section, key, f"{name} row {r} has {len(row)} values; expected "
                               f"{n_az} (360 / az_bin_deg)")
        for c, x in enumerate(row, start=1):
            if isinstance(x, bool) or not isinstance(x, int | float) or not x >= 0.0:
                raise SettingError(section, key, f"{name} row {r} column {c} must be an "
                                   f"attenuation >= 0 dB (inf blocks), got {x!r}")
    return tuple(tuple(float(x) for x in row) for row in value)


def _build_sky_mask(table: dict[str, Any]) -> SkyMaskParams:
    """Validate ``[sky_mask]`` (and ``[sky_mask.cells]``) into :class:`SkyMaskParams`."""
    grids = ("atten_db", "cells")
    mask = _build_table(SkyMaskParams, {k: v for k, v in table.items() if k not in grids},
                        "sky_mask")
    n_az = _bins(mask.az_bin_deg, 360.0, "sky_mask", "az_bin_deg")
    n_el = _bins(mask.el_bin_deg, 90.0, "sky_mask", "el_bin_deg")
    if not mask.block_db > 0.0:
        raise SettingError("sky_mask", "block_db", f"sky_mask.block_db must be > 0 dB, got "
                           f"{mask.block_db!r}")
    if not 0.0 <= mask.cell_m < float("inf"):
        raise SettingError("sky_mask", "cell_m", "sky_mask.cell_m must be >= 0 metres (0: no "
                           f"cells), got {mask.cell_m!r}")
    atten = _mask_grid(table.get("atten_db", []), "sky_mask", "atten_db", n_el, n_az)
    cells_in = table.get("cells", {})
    if not isinstance(cells_in, dict):
        raise SettingError("sky_mask", "cells", '[sky_mask.cells] must be a table of grids '
                           'keyed "i,j" (east, north cell indices)')
    if cells_in and mask.cell_m == 0.0:
        raise SettingError("sky_mask.cells", None, "sky_mask.cells needs sky_mask.cell_m > 0, "
                           "the side of the cells in metres")
    cells = {}
    for key, grid in cells_in.items():
        m = re.fullmatch(r"\s*(-?\d+)\s*,\s*(-?\d+)\s*", key)
        ij = (int(m.group(1)), int(m.group(2))) if m else None
        if ij is None or max(abs(ij[0]), abs(ij[1])) > SKY_MASK_MAX_CELL:
            raise SettingError("sky_mask.cells", key, f'sky_mask.cells."{key}": a cell is '
                               f'written "i,j" (integers within +-{SKY_MASK_MAX_CELL}: east, '
                               "north indices of floor(position / cell_m))")
        if ij in cells:
            raise SettingError("sky_mask.cells", key, f'sky_mask.cells."{key}" repeats cell {ij}')
        cells[ij] = _mask_grid(grid, "sky_mask.cells", key, n_el, n_az)
    return replace(mask, atten_db=atten, cells=tuple(sorted(cells.items())))


def build_profile(data: dict[str, Any], source: str = "<profile>") -> Profile:  # noqa: C901
    """Validate a profile table and build the :class:`Profile`.

    Parameters
    ----------
    data : the merged profile table (profile file, then config-file overrides)
    source : named in error messages

    Returns
    -------
    profile : Profile

    Raises
    ------
    ConfigError : an unknown key, a wrong type or an out-of-range value, naming the key.
    """
    kwargs: dict[str, Any] = {"source": source}
    top = Profile.__dataclass_fields__
    for key, value in data.items():
        if key in _TABLES:
            if not isinstance(value, dict):
                raise SettingError("", key, f"[{key}] must be a table")
            kwargs[key] = _build_table(_TABLES[key], value, key)
        elif key == "sky_mask":
            if not isinstance(value, dict):
                raise SettingError("", key, "[sky_mask] must be a table")
            kwargs[key] = _build_sky_mask(value)
        elif key == "nmea":
            if not isinstance(value, dict):
                raise SettingError("", key, "[nmea] must be a table")
            try:
                NmeaFormat.from_dict(value)
            except ConfigError as exc:
                nmea_key = str(exc).split(":", 1)[0].removeprefix("nmea.")
                raise SettingError(
                    "nmea", nmea_key if nmea_key in value else None, str(exc)
                ) from None
            kwargs[key] = dict(value)
        elif key in top and key != "source":
            if key in ("rate_hz", "pose_timeout_s"):
                value = _float(value, "", key)
            elif key == "baud" and (isinstance(value, bool) or not isinstance(value, int)):
                raise SettingError("", key, f"baud must be an integer, got {value!r}")
            elif key in ("name", "description", "firmware") and not isinstance(value, str):
                raise SettingError("", key, f"{key} must be a string, got {value!r}")
            elif key == "firmware" and not set(value) <= _NMEA_TEXT:
                raise SettingError("", key, "firmware must be printable ASCII without $ * ! \\")
            choices = _CHOICES.get(("", key))
            if choices and value not in choices:
                raise SettingError("", key, f"{key} must be one of {choices}, got {value!r}")
            kwargs[key] = value
        else:
            raise SettingError(
                "",
                key,
                f"unknown profile setting {key!r}; known: "
                f"{', '.join(k for k in top if k != 'source')}",
            )
    if "name" not in kwargs:
        raise SettingError("", None, "a profile needs a name")
    prof = Profile(**kwargs)
    if not 0.0 < prof.rate_hz <= 20.0:
        raise SettingError("", "rate_hz", f"rate_hz must be in (0, 20], got {prof.rate_hz}")
    if prof.baud < 300:
        raise SettingError("", "baud", f"baud must be at least 300, got {prof.baud}")
    if prof.pose_timeout_s <= 0:
        raise SettingError("", "pose_timeout_s", "pose_timeout_s must be positive")
    if not -10.0 <= prof.sky.elevation_mask_deg < 90.0:
        raise SettingError(
            "sky", "elevation_mask_deg", "sky.elevation_mask_deg must be in [-10, 90)"
        )
    if not 4 <= prof.sky.max_channels <= 72:
        raise SettingError("sky", "max_channels", "sky.max_channels must be in [4, 72]")
    if not prof.sky.pdop_mask > 0.0:  # (NaN too)
        raise SettingError("sky", "pdop_mask", "sky.pdop_mask must be positive (inf: none), "
                           f"got {prof.sky.pdop_mask}")
    if prof.dop_error.enabled and prof.noise.model != "none":
        raise SettingError("noise", "model", 'dop_error replaces the baseline noise: set '
                           'noise.model = "none" (or disable dop_error)')
    cs = prof.constellations
    for key, names in (("systems", cs.systems), ("sis_factor", [n for n, _ in cs.sis_factor]),
                       ("cn0_offset_db", [n for n, _ in cs.cn0_offset_db])):
        try:
            if any(_sys.system_named(n) is _sys.SBAS for n in names):
                raise ValueError("SBAS is not a system tracked for the fix (see [sbas])")
        except ValueError as exc:
            raise SettingError("constellations", key, f"constellations.{key}: {exc}") from None
    if any(not 0.0 < v <= 100.0 for _, v in cs.sis_factor):
        raise SettingError("constellations", "sis_factor",
                           "constellations.sis_factor: each factor must be in (0, 100]")
    ce = prof.correlated_error
    if ce.enabled and ce.domain == "range" and not prof.dop_error.enabled:
        raise SettingError("correlated_error", "domain", 'correlated_error.domain = "range" '
                           'needs dop_error.enabled (or use domain = "position")')
    ct = prof.cn0_tracking
    if ct.acq_dbhz < ct.track_dbhz or ct.fade_tau_s <= 0 or ct.reacq_s < 0:
        raise SettingError("cn0_tracking", "acq_dbhz", "need acq_dbhz >= track_dbhz, "
                           "fade_tau_s > 0 and reacq_s >= 0")
    if prof.nav_filter.tau_s <= 0 or prof.latency.latency_s < 0 or (
        prof.static_hold.threshold_mps < 0
    ):
        raise SettingError("nav_filter", "tau_s", "need nav_filter.tau_s > 0, "
                           "latency.latency_s >= 0 and static_hold.threshold_mps >= 0")
    if ce.tau_s <= 0 or ce.sigma_m < 0:
        raise SettingError("correlated_error", "tau_s", "need tau_s > 0 and sigma_m >= 0")
    mp = prof.multipath
    if mp.enabled and not prof.dop_error.enabled:
        raise SettingError("multipath", "enabled", "multipath needs dop_error.enabled (its "
                           "range errors are solved by least squares with the others)")
    for key, rule, good in (
        ("tau_s", "> 0 s", mp.tau_s > 0), ("sigma_m", ">= 0 m", mp.sigma_m >= 0),
        ("el0_deg", "> 0 deg", mp.el0_deg > 0), ("max_dist_m", "> 0 m", mp.max_dist_m > 0),
        ("open_sky_factor", "in [0, 1]", 0 <= mp.open_sky_factor <= 1),
    ):
        if not good:
            raise SettingError("multipath", key, f"multipath.{key} must be {rule}, got "
                               f"{getattr(mp, key)!r}")
    if prof.noise.min_noise_m < 0 or prof.noise.max_noise_m < prof.noise.min_noise_m:
        raise SettingError(
            "noise",
            "min_noise_m",
            "need 0 <= noise.min_noise_m <= noise.max_noise_m, got "
            f"{prof.noise.min_noise_m} and {prof.noise.max_noise_m}",
        )
    return prof


def _in_file(exc: SettingError, path: str | Path | None) -> VirtualGPSError:
    """Point a setting error at its file and line (or keep it as is without a file)."""
    if path is None:
        return exc
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError:
        text = ""
    line = toml_key_line(text, exc.section, exc.key) or toml_key_line(text, exc.section, None)
    return InputFileError(path, str(exc), line)


def _has(table: dict[str, Any], section: str, key: str | None) -> bool:
    where: Any = table
    for part in section.split(".") if section else ():  # "sky_mask.cells": a nested table
        where = where.get(part) if isinstance(where, dict) else None
    if not isinstance(where, dict):
        return False
    return key is None or key in where


def load_profile(
    name_or_path: str,
    overrides: dict[str, Any] | None = None,
    overrides_path: str | Path | None = None,
    flag_overrides: dict[str, Any] | None = None,
) -> Profile:
    """Load a profile and apply config-file overrides (built-in defaults < profile < config).

    Parameters
    ----------
    name_or_path : a built-in name (``holux-m1000``, ``usarsim``, ``ideal``) or a TOML path
    overrides : profile keys/tables from a config file, applied on top
    overrides_path : the config file they came from (named, with the line, in errors)
    flag_overrides : profile keys set by command-line flags, applied last

    Returns
    -------
    profile : Profile

    Raises
    ------
    InputFileError : a bad setting, naming the file (profile or config) and its line
    """
    data, source = load_profile_dict(name_or_path)
    try:
        prof = build_profile(data, source)
    except SettingError as exc:
        raise _in_file(exc, source) from None
    if overrides:
        data = merge(data, overrides)
        source = f"{source} + {overrides_path or 'config'}"
        try:
            prof = build_profile(data, source)
        except SettingError as exc:
            # The profile alone was valid: the setting at fault comes from the overrides.
            blame = overrides_path if _has(overrides, exc.section, exc.key) else source
            raise _in_file(exc, blame) from None
    if flag_overrides:
        try:
            prof = build_profile(merge(data, flag_overrides), f"{source} + flags")
        except SettingError as exc:
            raise ConfigError(f"command line: {exc}") from None
    return prof
