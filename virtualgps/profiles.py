"""Receiver profiles: TOML files (built-ins in ``virtualgps/profiles/``) into frozen dataclasses.

Precedence of settings (documented once, in the README): built-in defaults < profile < config
file (``--config``) < command-line flags. A config file may hold run settings at its top level
(``scene``, ``seed``, ...; see :data:`RUN_KEYS`), a ``[georef]`` table, and any profile key or
table, which overrides the profile's (e.g. ``[noise] max_noise_m = 8.0``).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from virtualgps.exceptions import ConfigError, InputFileError

BUILTIN_PROFILES = ("holux-m1000", "usarsim", "ideal")
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


@dataclass(frozen=True)
class SkyParams:
    """What the antenna can see.

    elevation_mask_deg : satellites below are not used (the paper: 5 deg)
    max_channels : at most this many satellites are used (GSA has 12 fields)
    foliage : "block" (foliage-class objects block like buildings) or "ignore"
    """

    elevation_mask_deg: float = 5.0
    max_channels: int = 12
    foliage: str = "block"


@dataclass(frozen=True)
class NoiseParams:
    """The baseline position error (DESIGN section 6, ``noise_level``).

    model : "usarsim" (the paper's Eq. 1-3 white noise) or "none"
    max_noise_m : the paper's maxNoise, error bound (3 sigma) with 4 satellites, metres
    min_noise_m : the paper's minNoise, error bound (3 sigma) with 12 satellites, metres
    """

    model: str = "usarsim"
    max_noise_m: float = 3.0
    min_noise_m: float = 1.0


@dataclass(frozen=True)
class SignalParams:
    """GSV signal strength of tracked satellites: linear in sin(elevation) between two values."""

    cn0_horizon_dbhz: float = 20.0
    cn0_zenith_dbhz: float = 45.0


@dataclass(frozen=True)
class Profile:
    """A receiver profile: output format, rates and the error model's parameters.

    rate_hz : epochs per second; baud : serial speed the output is paced to (8N1);
    pose_timeout_s : a pose older than this gives no-fix epochs;
    georef : "wgs84" (exact) or "flat_earth" (the paper's conversion);
    nmea : the ``[nmea]`` table, read by :class:`virtualgps.nmea.NmeaFormat`.
    """

    name: str
    description: str = ""
    rate_hz: float = 1.0
    baud: int = 38400
    pose_timeout_s: float = 2.0
    georef: str = "wgs84"
    sky: SkyParams = field(default_factory=SkyParams)
    noise: NoiseParams = field(default_factory=NoiseParams)
    signal: SignalParams = field(default_factory=SignalParams)
    nmea: dict[str, Any] = field(default_factory=dict)
    source: str = ""


_CHOICES = {
    ("", "georef"): ("wgs84", "flat_earth"),
    ("sky", "foliage"): ("block", "ignore"),
    ("noise", "model"): ("usarsim", "none"),
}
_TABLES = {"sky": SkyParams, "noise": NoiseParams, "signal": SignalParams}


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
        return Path(str(resources.files("virtualgps").joinpath(f"profiles/{name_or_path}.toml")))
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


def _float(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{key} must be a number, got {value!r}")
    return float(value)


def _build_table(cls: type, table: dict[str, Any], prefix: str, source: str) -> Any:
    fields = cls.__dataclass_fields__
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        full = f"{prefix}.{key}"
        if key not in fields:
            raise ConfigError(
                f"{source}: unknown setting {full!r}; known in [{prefix}]: {', '.join(fields)}"
            )
        default = fields[key].default
        if isinstance(default, float):
            value = _float(value, full)
        elif isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{source}: {full} must be an integer, got {value!r}")
        choices = _CHOICES.get((prefix, key))
        if choices and value not in choices:
            raise ConfigError(f"{source}: {full} must be one of {choices}, got {value!r}")
        kwargs[key] = value
    return cls(**kwargs)


def build_profile(data: dict[str, Any], source: str = "<profile>") -> Profile:
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
                raise ConfigError(f"{source}: [{key}] must be a table")
            kwargs[key] = _build_table(_TABLES[key], value, key, source)
        elif key == "nmea":
            if not isinstance(value, dict):
                raise ConfigError(f"{source}: [nmea] must be a table")
            kwargs[key] = dict(value)
        elif key in top and key != "source":
            if key in ("rate_hz", "pose_timeout_s"):
                value = _float(value, key)
            elif key == "baud" and (isinstance(value, bool) or not isinstance(value, int)):
                raise ConfigError(f"{source}: baud must be an integer, got {value!r}")
            choices = _CHOICES.get(("", key))
            if choices and value not in choices:
                raise ConfigError(f"{source}: {key} must be one of {choices}, got {value!r}")
            kwargs[key] = value
        else:
            raise ConfigError(
                f"{source}: unknown profile setting {key!r}; known: "
                f"{', '.join(k for k in top if k != 'source')}"
            )
    if "name" not in kwargs:
        raise ConfigError(f"{source}: a profile needs a name")
    prof = Profile(**kwargs)
    if not 0.0 < prof.rate_hz <= 20.0:
        raise ConfigError(f"{source}: rate_hz must be in (0, 20], got {prof.rate_hz}")
    if prof.baud < 300:
        raise ConfigError(f"{source}: baud must be at least 300, got {prof.baud}")
    if prof.pose_timeout_s <= 0:
        raise ConfigError(f"{source}: pose_timeout_s must be positive")
    if not -10.0 <= prof.sky.elevation_mask_deg < 90.0:
        raise ConfigError(f"{source}: sky.elevation_mask_deg must be in [-10, 90)")
    if not 4 <= prof.sky.max_channels <= 12:
        raise ConfigError(f"{source}: sky.max_channels must be in [4, 12]")
    if prof.noise.min_noise_m < 0 or prof.noise.max_noise_m < prof.noise.min_noise_m:
        raise ConfigError(
            f"{source}: need 0 <= noise.min_noise_m <= noise.max_noise_m, got "
            f"{prof.noise.min_noise_m} and {prof.noise.max_noise_m}"
        )
    return prof


def load_profile(name_or_path: str, overrides: dict[str, Any] | None = None) -> Profile:
    """Load a profile and apply config-file overrides (built-in defaults < profile < config).

    Parameters
    ----------
    name_or_path : a built-in name (``holux-m1000``, ``usarsim``, ``ideal``) or a TOML path
    overrides : profile keys/tables from a config file, applied on top

    Returns
    -------
    profile : Profile
    """
    data, source = load_profile_dict(name_or_path)
    if overrides:
        data = merge(data, overrides)
        source = f"{source} (+ config)"
    return build_profile(data, source)
