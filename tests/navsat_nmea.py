"""A model of the ROS ``nmea_navsat_driver`` (``nmea_serial_driver`` node, its driver and parser).

The package is not on PyPI and needs ROS, so it cannot run here. This is our own code written
from reading ``ros-drivers/nmea_navsat_driver`` in the source index (stored versions, Python):

- ``src/libnmea_navsat_driver/checksum_utils.py`` @ 0b77e8e67759b6a1dd6a6a2eb1c58f24a5d26888:
  ``check_nmea_checksum``.
- ``src/libnmea_navsat_driver/driver.py`` @ 0092158a144dd28d82a6aa9640a2593572083f7e (noetic
  layout: ``gps_qualities``, GST, VTG, HDT, ``use_GNSS_time``), compared with
  ``nmea_navsat_driver/driver.py`` @ 18536146fa59e40ac7e14864fb214d47ac5063ad and
  ``libnmea_navsat_driver/driver.py`` @ 0e8e6515ee8006c07c783e05f3880919df1521b5 (ROS 2 branch):
  ``RosNMEADriver.add_sentence``, identical in what is modelled here except the ``valid_fix``
  rule (see ``VALID_FIX_RULES``).
- ``parser.py``: a stored copy (index id 1014680147; its repository and commit were not
  identified, so not pinned to a ros-drivers commit) with the GST, HDT and VTG parse maps,
  ``field_delimiter_regex`` and ``convert_time_rmc``: the parser ``driver.py`` @ 0092158a needs
  (it indexes ``data['utc_time'][0]``); the older ``src/libnmea_navsat_driver/parser.py``
  @ c3a6c5d6e774 and @ 02962310adfd know only GGA and RMC and are not modelled.
- ``src/libnmea_navsat_driver/nodes/nmea_serial_driver.py`` @ 03106e08fc9f (ROS 1) and the ROS 2
  node: ``GPS.readline().strip()``, decoded as UTF-8 when bytes (ROS 2), each line to
  ``add_sentence``; a ``ValueError`` (a missing field ``int()`` cannot take, a decode error) is
  logged and the line dropped. Anything else would end the node.

Left out: ROS headers and stamps (``use_GNSS_time`` is off by default), HDT (the device writes no
HDT), the frame id, the socket and topic nodes.
"""

from __future__ import annotations

import calendar
import datetime
import math
import re
from dataclasses import dataclass, field

# sensor_msgs/NavSatStatus and NavSatFix constants
STATUS_NO_FIX, STATUS_FIX, STATUS_SBAS_FIX, STATUS_GBAS_FIX = -1, 0, 1, 2
SERVICE_GPS = 1
COVARIANCE_TYPE_UNKNOWN, COVARIANCE_TYPE_APPROXIMATED = 0, 1
COVARIANCE_TYPE_DIAGONAL_KNOWN, COVARIANCE_TYPE_KNOWN = 2, 3

KNOTS_TO_MPS = 0.514444444444  # parser.convert_knots_to_mps

#: driver.py ``__init__``: the ``~epe_quality*`` parameters' defaults (metres), by GGA quality
DEFAULT_EPE = {0: 1000000.0, 1: 4.0, 2: 0.1, 4: 0.02, 5: 4.0, 9: 3.0}

#: driver.py ``gps_qualities``: GGA quality -> (default epe, status, covariance type); any other
#: quality is looked up as -1
GPS_QUALITIES = {
    -1: (DEFAULT_EPE[0], STATUS_NO_FIX, COVARIANCE_TYPE_UNKNOWN),
    0: (DEFAULT_EPE[0], STATUS_NO_FIX, COVARIANCE_TYPE_UNKNOWN),
    1: (DEFAULT_EPE[1], STATUS_FIX, COVARIANCE_TYPE_APPROXIMATED),
    2: (DEFAULT_EPE[2], STATUS_SBAS_FIX, COVARIANCE_TYPE_APPROXIMATED),
    4: (DEFAULT_EPE[4], STATUS_GBAS_FIX, COVARIANCE_TYPE_APPROXIMATED),
    5: (DEFAULT_EPE[5], STATUS_GBAS_FIX, COVARIANCE_TYPE_APPROXIMATED),
    9: (DEFAULT_EPE[9], STATUS_GBAS_FIX, COVARIANCE_TYPE_APPROXIMATED),
}

#: How a GGA sets ``valid_fix`` (which gates VTG velocities) in the versions read:
#: ``fix_type``: ``self.valid_fix = (fix_type > 0)`` (later noetic copies);
#: ``status``: ``if current_fix.status.status > 0`` (ROS 2 @ 18536146: only SBAS/GBAS fixes);
#: @ 0092158a and @ 0e8e6515 compare the ``gps_qual`` list with 0: always True on Python 2, a
#: ``TypeError`` on Python 3 (which the serial node does not catch).
VALID_FIX_RULES = ("fix_type", "status")


# --- checksum_utils.py ------------------------------------------------------------------------

def check_nmea_checksum(sentence: str) -> bool:
    """``check_nmea_checksum``: exactly one ``*``; XOR of everything after the first character
    up to it, as two upper-case hex digits, equal to what follows it (stripped, upper-cased)."""
    parts = sentence.split("*")
    if len(parts) != 2:
        return False
    cs = 0
    for c in parts[0][1:]:
        cs ^= ord(c)
    return f"{cs:02X}" == parts[1].strip().upper()


# --- parser.py --------------------------------------------------------------------------------

def safe_float(s: str) -> float:
    try:
        return float(s)
    except ValueError:
        return math.nan


def safe_int(s: str) -> int:
    try:
        return int(s)
    except ValueError:
        return 0


def convert_latitude(s: str) -> float:
    """``convert_latitude``: two digits of degrees, the rest minutes (no hemisphere)."""
    return safe_float(s[0:2]) + safe_float(s[2:]) / 60.0


def convert_longitude(s: str) -> float:
    """``convert_longitude``: three digits of degrees, the rest minutes."""
    return safe_float(s[0:3]) + safe_float(s[3:]) / 60.0


def convert_time(s: str, now: datetime.datetime | None = None) -> tuple[float, float]:
    """``convert_time`` (GGA, GST): (NaN, NaN) when hh, mm or ss is missing; else
    ``int(s[0:2])`` etc. (a ValueError on non-digits), nanoseconds from the digits after the dot,
    and the seconds of the host's UTC ``now`` moved by ``int((now.hour - hh) / 12)`` days. The
    parser's ``utc_time.replace(hour=..)`` result is discarded, so the seconds are the host's,
    not the sentence's; only the nanoseconds come from the sentence."""
    if not s[0:2] or not s[2:4] or not s[4:6]:
        return math.nan, math.nan
    now = now or datetime.datetime.now(datetime.UTC).replace(tzinfo=None)
    hh, _mm, _ss = int(s[0:2]), int(s[2:4]), int(s[4:6])
    nanos = int(s[7:]) * 10 ** (9 - len(s[7:])) if len(s) > 7 else 0
    now += datetime.timedelta(int((now.hour - hh) / 12.0))
    return calendar.timegm(now.timetuple()), nanos


def convert_time_rmc(date: str, s: str, today_year: int | None = None) -> tuple[float, float]:
    """``convert_time_rmc``: (NaN, NaN) when hh, mm or ss is missing; else the date DDMMYY (the
    century from the host's year) and time; ``int(s[7:])`` is taken unguarded (a time without
    a fraction raises ValueError)."""
    if not s[0:2] or not s[2:4] or not s[4:6]:
        return math.nan, math.nan
    pc_year = today_year or datetime.date.today().year
    utc_year = int(date[4:6])
    year = pc_year + int((pc_year % 100 - utc_year) / 50.0)
    nanos = int(s[7:]) * 10 ** (9 - len(s[7:]))
    secs = calendar.timegm((year, int(date[2:4]), int(date[0:2]),
                            int(s[0:2]), int(s[2:4]), int(s[4:6])))
    return secs, nanos


def _status_flag(s: str) -> bool:
    return s == "A"


def _knots(s: str) -> float:
    return safe_float(s) * KNOTS_TO_MPS


def _deg_to_rad(s: str) -> float:
    return math.radians(safe_float(s))


#: ``parse_maps``: sentence -> (name, conversion, field index) after splitting on ``,`` and ``*``
PARSE_MAPS = {
    "GGA": [("fix_type", int, 6), ("latitude", convert_latitude, 2),
            ("latitude_direction", str, 3), ("longitude", convert_longitude, 4),
            ("longitude_direction", str, 5), ("altitude", safe_float, 9),
            ("mean_sea_level", safe_float, 11), ("hdop", safe_float, 8),
            ("num_satellites", safe_int, 7), ("utc_time", convert_time, 1)],
    "RMC": [("fix_valid", _status_flag, 2), ("latitude", convert_latitude, 3),
            ("latitude_direction", str, 4), ("longitude", convert_longitude, 5),
            ("longitude_direction", str, 6), ("speed", _knots, 7),
            ("true_course", _deg_to_rad, 8)],
    "GST": [("utc_time", convert_time, 1), ("ranges_std_dev", safe_float, 2),
            ("semi_major_ellipse_std_dev", safe_float, 3),
            ("semi_minor_ellipse_std_dev", safe_float, 4),
            ("semi_major_orientation", safe_float, 5), ("lat_std_dev", safe_float, 6),
            ("lon_std_dev", safe_float, 7), ("alt_std_dev", safe_float, 8)],
    "HDT": [("heading", safe_float, 1)],
    # VTG's course is kept in DEGREES (safe_float), yet add_sentence takes sin/cos of it
    "VTG": [("true_course", safe_float, 1), ("speed", _knots, 5)],
}

_SENTENCE_RE = re.compile(r"(^\$GP|^\$GN|^\$GL|^\$IN).*\*[0-9A-Fa-f]{2}$")


def parse_nmea_sentence(sentence: str) -> dict | None:
    """``parse_nmea_sentence``: strip; the talker must be GP, GN, GL or IN and the line end in
    ``*`` and two hex digits; the type is ``fields[0][3:]``; only the types of ``PARSE_MAPS``;
    RMC's time from ``convert_time_rmc(fields[9], fields[1])``. A conversion's ValueError or an
    IndexError of a short sentence propagates (the node catches only ValueError)."""
    sentence = sentence.strip()
    if not _SENTENCE_RE.match(sentence):
        return None
    fields = re.split(r"[,*]", sentence)
    kind = fields[0][3:]
    if kind not in PARSE_MAPS:
        return None
    out = {name: conv(fields[i]) for name, conv, i in PARSE_MAPS[kind]}
    if kind == "RMC":
        out["utc_time"] = convert_time_rmc(fields[9], fields[1])
    return {kind: out}


# --- driver.py --------------------------------------------------------------------------------

@dataclass
class NavSatFix:
    latitude: float
    longitude: float
    altitude: float
    status: int
    service: int
    position_covariance: list[float]
    position_covariance_type: int
    source: str  # "GGA" or "RMC" (useRMC)


@dataclass
class Twist:
    """geometry_msgs/TwistStamped's linear x (east) and y (north), m/s."""

    x: float
    y: float
    source: str  # "RMC" or "VTG"


@dataclass
class TimeReference:
    secs: float
    nanos: float


@dataclass
class NavSatDriver:
    """``RosNMEADriver`` with its default parameters (``useRMC`` false, the ``epe_quality*``
    defaults); what it would publish is appended to ``fixes``, ``vels`` and ``time_refs``."""

    use_rmc: bool = False
    valid_fix_rule: str = "fix_type"
    valid_fix: bool = False
    using_receiver_epe: bool = False
    lat_std_dev: float = math.nan
    lon_std_dev: float = math.nan
    alt_std_dev: float = math.nan
    fixes: list[NavSatFix] = field(default_factory=list)
    vels: list[Twist] = field(default_factory=list)
    time_refs: list[TimeReference] = field(default_factory=list)
    bad_checksum: list[str] = field(default_factory=list)

    def add_sentence(self, s: str) -> bool:
        """``add_sentence``: checksum first (a warning, the line dropped), then the parser; GGA
        (not useRMC) publishes a fix; VTG (not useRMC) a velocity if ``valid_fix``; RMC a fix
        only with useRMC and a velocity whenever its status is A; GST stores the sigmas."""
        if not check_nmea_checksum(s):
            self.bad_checksum.append(s)
            return False
        parsed = parse_nmea_sentence(s)
        if not parsed:
            return False
        if not self.use_rmc and "GGA" in parsed:
            self._gga(parsed["GGA"])
        elif not self.use_rmc and "VTG" in parsed:
            d = parsed["VTG"]
            if self.valid_fix:
                c = d["true_course"]  # degrees, used as radians (as the driver does)
                self.vels.append(Twist(d["speed"] * math.sin(c), d["speed"] * math.cos(c), "VTG"))
        elif "RMC" in parsed:
            d = parsed["RMC"]
            if self.use_rmc:
                self.fixes.append(NavSatFix(
                    _signed(d["latitude"], d["latitude_direction"], "S"),
                    _signed(d["longitude"], d["longitude_direction"], "W"), math.nan,
                    STATUS_FIX if d["fix_valid"] else STATUS_NO_FIX, SERVICE_GPS, [0.0] * 9,
                    COVARIANCE_TYPE_UNKNOWN, "RMC"))
                if not math.isnan(d["utc_time"][0]):
                    self.time_refs.append(TimeReference(*d["utc_time"]))
            if d["fix_valid"]:
                c = d["true_course"]
                self.vels.append(Twist(d["speed"] * math.sin(c), d["speed"] * math.cos(c), "RMC"))
        elif "GST" in parsed:
            d = parsed["GST"]
            self.using_receiver_epe = True
            self.lon_std_dev, self.lat_std_dev = d["lon_std_dev"], d["lat_std_dev"]
            self.alt_std_dev = d["alt_std_dev"]
        else:
            return False
        return True

    def _gga(self, d: dict) -> None:
        q = d["fix_type"] if d["fix_type"] in GPS_QUALITIES else -1
        epe, status, cov_type = GPS_QUALITIES[q]
        self.valid_fix = q > 0 if self.valid_fix_rule == "fix_type" else status > 0
        # the default epe unless a GST gave sigmas (a NaN sigma falls back too)
        if not self.using_receiver_epe or math.isnan(self.lon_std_dev):
            self.lon_std_dev = epe
        if not self.using_receiver_epe or math.isnan(self.lat_std_dev):
            self.lat_std_dev = epe
        if not self.using_receiver_epe or math.isnan(self.alt_std_dev):
            self.alt_std_dev = epe * 2
        h = d["hdop"]
        cov = [0.0] * 9
        cov[0] = (h * self.lon_std_dev) ** 2
        cov[4] = (h * self.lat_std_dev) ** 2
        cov[8] = (2 * h * self.alt_std_dev) ** 2
        self.fixes.append(NavSatFix(
            _signed(d["latitude"], d["latitude_direction"], "S"),
            _signed(d["longitude"], d["longitude_direction"], "W"),
            d["altitude"] + d["mean_sea_level"],  # "Altitude is above ellipsoid"
            status, SERVICE_GPS, cov, cov_type, "GGA"))
        if not math.isnan(d["utc_time"][0]):
            self.time_refs.append(TimeReference(*d["utc_time"]))


def _signed(v: float, hemi: str, neg: str) -> float:
    return -v if hemi == neg else v


# --- nodes/nmea_serial_driver.py --------------------------------------------------------------

@dataclass
class SerialNode:
    """The serial node's loop over a byte stream: ``readline()`` (up to and with ``\\n``),
    ``.strip()``, UTF-8 decode, ``add_sentence``; a ValueError is logged (``value_errors``)."""

    driver: NavSatDriver = field(default_factory=NavSatDriver)
    value_errors: list[tuple[bytes, str]] = field(default_factory=list)
    lines: int = 0
    pending: bytes = b""

    def feed(self, data: bytes) -> None:
        *complete, self.pending = (self.pending + data).split(b"\n")
        for raw in complete:
            line = raw.strip()
            self.lines += 1
            try:
                self.driver.add_sentence(line.decode("utf-8"))
            except ValueError as e:
                self.value_errors.append((line, str(e)))
