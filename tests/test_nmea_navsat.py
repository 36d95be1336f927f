"""The NMEA profiles against the ROS ``nmea_navsat_driver`` (``nmea_serial_driver``).

The driver needs ROS and is not on PyPI: ``navsat_nmea.py`` models its serial node, driver and
parser (its docstring names the revisions read). The tests feed the model the exact bytes of
``virtualgps replay`` (a two-minute drive: accelerate, turn, brake, stop, with no poses from 95
to 105 s so the fix is lost) for every NMEA profile at its defaults, and again with GST added.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
from navsat_nmea import (
    COVARIANCE_TYPE_APPROXIMATED,
    COVARIANCE_TYPE_UNKNOWN,
    DEFAULT_EPE,
    KNOTS_TO_MPS,
    SERVICE_GPS,
    STATUS_FIX,
    STATUS_GBAS_FIX,
    STATUS_NO_FIX,
    STATUS_SBAS_FIX,
    NavSatDriver,
    SerialNode,
    check_nmea_checksum,
    parse_nmea_sentence,
)
from nmea_replay import replay_epochs
from test_nmea_px4 import write_trajectory

from virtualgps.device.nmea import nmea_checksum
from virtualgps.receiver.profiles import load_profile

NMEA_PROFILES = ("holux-m1000", "usarsim", "ideal", "phone", "ublox-m8n", "ublox-m9n")
#: GGA quality -> NavSatStatus as driver.py's gps_qualities maps it
STATUS_OF_QUALITY = {0: STATUS_NO_FIX, 1: STATUS_FIX, 2: STATUS_SBAS_FIX, 4: STATUS_GBAS_FIX,
                     5: STATUS_GBAS_FIX, 9: STATUS_GBAS_FIX}


def _sentence(body: str) -> str:
    return f"${body}*{nmea_checksum(body)}"


def _decimals(s: str) -> int:
    return len(s.split(".")[1]) if "." in s else 0


def _half_ulp(s: str) -> float:
    """Half a unit of the last printed digit of field ``s``."""
    return 0.5 * 10.0 ** -_decimals(s)


@dataclass
class Fed:
    """One replay through the model: per epoch its sentences (str) and the slices of what the
    driver published while its bytes were read."""

    run: object
    node: SerialNode
    lines: list[list[str]]
    fixes: list[list]
    vels: list[list]
    time_refs: list[list]

    def field(self, e: int, kind: str) -> list[str]:
        return next(s for s in self.lines[e] if s[3:6] == kind).split("*")[0].split(",")

    def quality(self, e: int) -> int:
        return int(float(self.run.rows[e]["quality"]))


def _feed(run) -> Fed:
    node = SerialNode()
    d = node.driver
    lines, fixes, vels, refs = [], [], [], []
    for b in run.epoch_bytes:
        n = (len(d.fixes), len(d.vels), len(d.time_refs))
        node.feed(b)
        lines.append(b.decode().split("\r\n")[:-1])
        fixes.append(d.fixes[n[0]:])
        vels.append(d.vels[n[1]:])
        refs.append(d.time_refs[n[2]:])
    return Fed(run, node, lines, fixes, vels, refs)


@pytest.fixture(scope="module")
def fed(tmp_path_factory):
    """``fed(profile, gst)``: the profile's replay at its defaults (``gst``: with "GST" put first
    in ``[nmea] sentences``) through the model, each made once."""
    tmp = tmp_path_factory.mktemp("nmea-navsat")
    poses = write_trajectory(tmp / "drive.jsonl", duration_s=120.0, gap=(95.0, 105.0))
    cache: dict[tuple[str, bool], Fed] = {}

    def get(name: str, gst: bool = False) -> Fed:
        if (name, gst) not in cache:
            prof = load_profile(name)
            sentences = ["GST", *prof.nmea["sentences"]] if gst else None
            cache[name, gst] = _feed(replay_epochs(tmp, poses, name, prof.rate_hz, sentences))
        return cache[name, gst]

    return get


def _clean(f: Fed) -> None:
    """Every line read, none rejected by its checksum, none raising in the parser."""
    assert f.node.pending == b""
    assert f.node.lines == sum(len(ls) for ls in f.lines)
    assert f.node.driver.bad_checksum == []
    assert f.node.value_errors == []


# --- the model ----------------------------------------------------------------------------

def test_the_model_parses_as_the_driver_does():
    """The parser's rules on hand-made sentences: checksum, talkers, minutes, the GGA altitude
    plus geoid separation, RMC's fraction-less time (ValueError), VTG's degrees used as radians,
    a GST's NaN sigma falling back to the default epe."""
    assert check_nmea_checksum(_sentence("GPGGA,1"))
    assert not check_nmea_checksum(_sentence("GPGGA,1")[:-1] + "0")
    assert parse_nmea_sentence(_sentence("GBGGA,1")) is None  # talker not GP/GN/GL/IN
    assert parse_nmea_sentence(_sentence("GPGSA,A,3")) is None  # type not parsed
    gga = _sentence("GPGGA,100000.50,5208.4000,S,01138.4000,W,1,08,0.9,37.4,M,43.1,M,,")
    d = NavSatDriver()
    d.add_sentence(gga)
    (fix,) = d.fixes
    assert fix.latitude == pytest.approx(-52.14) and fix.longitude == pytest.approx(-11.64)
    assert fix.altitude == pytest.approx(80.5) and fix.status == STATUS_FIX
    assert fix.position_covariance[0] == pytest.approx((0.9 * 4.0) ** 2)
    assert fix.position_covariance[8] == pytest.approx((2 * 0.9 * 8.0) ** 2)
    assert d.time_refs[0].nanos == 500_000_000
    with pytest.raises(ValueError):
        parse_nmea_sentence(_sentence("GPRMC,100000,A,5208.4,N,01138.4,E,1.0,90.0,010624,,"))
    d.add_sentence(_sentence("GPVTG,90.00,T,,M,1.944,N,3.6,K,A"))
    assert d.vels[0].x == pytest.approx(math.sin(90.0), rel=1e-3)  # not sin(pi/2)
    d.add_sentence(_sentence("GPGST,100001.00,,,,,,,"))
    d.add_sentence(gga)
    assert d.fixes[-1].position_covariance[0] == pytest.approx((0.9 * 4.0) ** 2)
    node = SerialNode()
    node.feed(b"\xff\xfe" + gga.encode() + b"\r\n")
    assert node.value_errors and not node.driver.fixes  # UnicodeDecodeError is a ValueError


# --- the device's bytes ----------------------------------------------------------------------

@pytest.mark.parametrize("name", NMEA_PROFILES)
def test_one_navsatfix_per_gga_as_the_fixes_csv(name, fed):
    """Each epoch's GGA gives one NavSatFix and one TimeReference; the status is the table's
    for the CSV's quality (NO_FIX, covariance UNKNOWN at quality 0); with a fix the latitude and
    longitude equal the CSV's within the printed minutes, the altitude is the GGA's MSL altitude
    plus the geoid separation (the ellipsoidal height, CSV alt_msl_m + geoid_sep_m) and the
    covariance the driver's HDOP one: (4 HDOP)^2, (4 HDOP)^2, (16 HDOP)^2, APPROXIMATED."""
    f = fed(name)
    _clean(f)
    qualities = [f.quality(e) for e in range(len(f.lines))]
    assert 0 in qualities and any(q > 0 for q in qualities)  # the gap loses the fix
    for e, row in enumerate(f.run.rows):
        (fix,) = f.fixes[e]
        assert len(f.time_refs[e]) == 1
        g = f.field(e, "GGA")
        q = qualities[e]
        assert fix.status == STATUS_OF_QUALITY[q] and fix.service == SERVICE_GPS
        ns = round(math.modf(float(g[1]))[0] * 1e9, -3)
        assert f.time_refs[e][0].nanos == pytest.approx(ns, abs=1e3)
        if q == 0:  # published all the same, at what the placeholders convert to: the MTK's
            # 8960.0000,N,00000.0000,E as 90.0, 0.0 (and 137.0 + 13.0 m); u-blox's empty as NaN
            assert fix.position_covariance_type == COVARIANCE_TYPE_UNKNOWN
            assert (g[2] == "8960.0000" and fix.latitude == 90.0) or math.isnan(fix.latitude)
            continue
        assert fix.position_covariance_type == COVARIANCE_TYPE_APPROXIMATED
        tol_lat = _half_ulp(g[2]) / 60.0 + 1e-9
        tol_lon = _half_ulp(g[4]) / 60.0 + 1e-9
        assert abs(fix.latitude - float(row["lat_deg"])) <= tol_lat
        assert abs(fix.longitude - float(row["lon_deg"])) <= tol_lon
        ell = float(row["alt_msl_m"]) + float(row["geoid_sep_m"])
        assert abs(fix.altitude - ell) <= _half_ulp(g[9]) + _half_ulp(g[11]) + 1e-3
        hdop, tol_h = float(row["hdop"]), _half_ulp(g[8]) + 5e-4
        assert abs(math.sqrt(fix.position_covariance[0]) / 4.0 - hdop) <= tol_h
        assert abs(math.sqrt(fix.position_covariance[4]) / 4.0 - hdop) <= tol_h
        assert abs(math.sqrt(fix.position_covariance[8]) / 16.0 - hdop) <= tol_h


@pytest.mark.parametrize("name", NMEA_PROFILES)
def test_velocity_from_rmc_and_vtg(name, fed):
    """RMC gives a TwistStamped in every epoch with a fix (status A), east/north equal to the
    CSV speed and course within the printed knots and degrees. VTG gives one only when the last
    GGA read had a fix (``valid_fix``, set by GGA: the GGA of the epoch before for the u-blox
    order RMC, VTG, GGA); its speed is the CSV's, its direction the driver's sin/cos of the
    course in degrees taken as radians (a driver defect, not the device's)."""
    f = fed(name)
    _clean(f)
    prev_q = 0
    nan_vtg_epochs = []
    for e, row in enumerate(f.run.rows):
        q = f.quality(e)
        rmc, vtg = (f.field(e, k) for k in ("RMC", "VTG"))
        assert (rmc[2] == "A") == (q > 0)
        kinds = [s[3:6] for s in f.lines[e]]
        gga_first = kinds.index("GGA") < kinds.index("VTG")
        vtg_gate = q if gga_first else prev_q
        prev_q = q
        by = {v.source: v for v in f.vels[e]}
        assert len(by) == len(f.vels[e])
        assert ("RMC" in by) == (q > 0)
        assert ("VTG" in by) == (vtg_gate > 0)
        if q == 0:
            if "VTG" in by:
                nan_vtg_epochs.append(e)
                assert math.isnan(by["VTG"].x) and vtg[1] == ""
            continue
        speed, course = float(row["speed_mps"]), float(row["course_deg"])
        r = by["RMC"]
        tol_v = _half_ulp(rmc[7]) * KNOTS_TO_MPS + 1e-3
        assert abs(math.hypot(r.x, r.y) - speed) <= tol_v
        if speed > 1.0:
            tol_c = _half_ulp(rmc[8]) + 0.005 + math.degrees(tol_v / speed)
            err = (math.degrees(math.atan2(r.x, r.y)) - course + 180.0) % 360.0 - 180.0
            assert abs(err) <= tol_c
        if "VTG" in by:
            v = by["VTG"]
            assert abs(math.hypot(v.x, v.y) - speed) <= _half_ulp(vtg[5]) * KNOTS_TO_MPS + 1e-3
            c = float(vtg[1])
            assert abs(c - course) <= _half_ulp(vtg[1]) + 0.005 or speed < 1.0
            assert v.x == pytest.approx(float(vtg[5]) * KNOTS_TO_MPS * math.sin(c), abs=1e-9)
    # the u-blox order (VTG before GGA): the first epoch without a fix still passes the gate
    # and publishes a NaN velocity (one per loss of fix); GGA-first profiles never do
    gga_first_profiles = ("holux-m1000", "usarsim", "ideal", "phone")
    assert (nan_vtg_epochs == []) == (name in gga_first_profiles)


@pytest.mark.parametrize("name", NMEA_PROFILES)
def test_gst_sigmas_become_the_covariance(name, fed):
    """With GST first in the epoch the driver takes the epoch's own sigmas: the covariance is
    (HDOP sigma_lon)^2, (HDOP sigma_lat)^2, (2 HDOP sigma_alt)^2 (driver.py multiplies the GST
    sigmas by the HDOP too), type APPROXIMATED (from gps_qualities, never DIAGONAL_KNOWN); the
    sigmas equal the receiver's own (``Fixes.gst_sigma_m``) within GST's printed digits; an
    empty GST field (no sigma: usarsim's altitude, all of ideal's) leaves the driver's default
    epe (4 m, 8 m for the altitude). Without GST it is the HDOP one (the test above)."""
    f = fed(name, gst=True)
    _clean(f)
    assert f.run.sigma_m is not None
    for e in range(len(f.run.rows)):
        kinds = [s[3:6] for s in f.lines[e]]
        assert kinds.index("GST") < kinds.index("GGA")
        (fix,) = f.fixes[e]
        if f.quality(e) == 0:
            assert fix.status == STATUS_NO_FIX
            continue
        assert fix.position_covariance_type == COVARIANCE_TYPE_APPROXIMATED
        g, s = f.field(e, "GGA"), f.field(e, "GST")
        hdop = float(g[8])
        sig_lat, sig_lon, sig_alt = f.run.sigma_m[e]
        epe = DEFAULT_EPE[f.quality(e)]
        for k, sigma, i, scale, default in ((0, sig_lon, 7, 1.0, epe), (4, sig_lat, 6, 1.0, epe),
                                            (8, sig_alt, 8, 2.0, 2 * epe)):
            got = math.sqrt(fix.position_covariance[k]) / (scale * hdop)
            if math.isnan(sigma):  # no sigma (usarsim's altitude, ideal's all): the default epe
                assert s[i] == "" and got == pytest.approx(default, rel=1e-12)
                continue
            assert abs(float(s[i]) - sigma) <= _half_ulp(s[i]) + 1e-9
            assert got == pytest.approx(float(s[i]), rel=1e-12)
