"""Tests of virtualgps.sky.ephemeris against independent references.

- skyfield's az/el of the bundled TLE sets (tests/data/skyfield_azel.csv, written by
  tools/make_skyfield_refs.py; skyfield is not imported here);
- a real receiver's own GSV elevations/azimuths (MT3339 static log, ../shared/data);
- a real later TLE set for the sky-time policy (../shared/data, 2017-02-02 -> 2017-03-26);
- CelesTrak's own checksums for the checksum routine; exact cubics for the Hermite table.
"""

from __future__ import annotations

import csv
import datetime as dt
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from virtualgps.constants import DAY_S, SIDEREAL_DAY_S
from virtualgps.exceptions import ConfigError, InputFileError
from virtualgps.geodesy import azel_to_enu_unit, ecef_to_enu, enu_to_azel
from virtualgps.sky import systems
from virtualgps.sky.ephemeris import (
    BUNDLED_EPHEMERIS_DIR,
    GPS_SKY_REPEAT_S,
    Constellation,
    build_lookup_table,
    default_tle_path,
    load_tle,
    read_prn_table,
    sidereal_shift_s,
    tle_checksum,
)
from virtualgps.sky.lookup import (
    LookupTable,
    is_lookup_table,
    read_lookup_table,
    write_lookup_table,
)

REPO = Path(__file__).resolve().parents[1]
TLE_2017_03_26 = BUNDLED_EPHEMERIS_DIR / "gps-ops-2017-03-26.tle"
TLE_2017_03_28 = BUNDLED_EPHEMERIS_DIR / "gps-ops-2017-03-28.tle"
TLE_2020 = BUNDLED_EPHEMERIS_DIR / "gps-ops-2020-05-14T22Z.tle"
PRN_TABLE = BUNDLED_EPHEMERIS_DIR / "gps-ops-NORAD-PRN.t"

# Tolerances, in units.
SKYFIELD_TOL_DEG = 0.01  # measured 0.0026 deg: UT1-UTC (<0.9 s) and frame-chain differences
TABLE_60S_TOL_M = 0.01  # measured 4 mm (Hermite on SGP4 positions + their derivatives)
TABLE_300S_TOL_M = 1.0  # measured 0.4 m
MM_M = 0.001


def angular_separation_deg(az1_deg, el1_deg, az2_deg, el2_deg) -> np.ndarray:
    """Great-circle angle between two sky directions, degrees.

    Used instead of a plain azimuth difference, which is meaningless near the zenith (there a
    tiny pointing change swings the azimuth by tens of degrees) and at the poles.
    """
    u1 = azel_to_enu_unit(az1_deg, el1_deg)
    u2 = azel_to_enu_unit(az2_deg, el2_deg)
    # atan2 of |cross| and dot is accurate for tiny angles, where arccos(dot) is not.
    cross = np.linalg.norm(np.cross(u1, u2), axis=-1)
    return np.degrees(np.arctan2(cross, np.sum(u1 * u2, axis=-1)))


def sky_azel(sat_ecef_m, lat_deg, lon_deg, alt_m):
    """az, el (degrees) of satellites (..., 3) ECEF from a site (broadcast)."""
    az, el, _ = enu_to_azel(ecef_to_enu(sat_ecef_m, lat_deg, lon_deg, alt_m))
    return az, el


@pytest.fixture(scope="module")
def c2017() -> Constellation:
    return load_tle(TLE_2017_03_26)


@pytest.fixture(scope="module")
def c2020() -> Constellation:
    return load_tle(TLE_2020)


# ------------------------------------------------------------------------------------------
# Bundled sets
# ------------------------------------------------------------------------------------------


def test_bundled_sets_load_and_default_is_newest():
    assert BUNDLED_EPHEMERIS_DIR == REPO / "ephemeris"
    assert (BUNDLED_EPHEMERIS_DIR / "README.md").is_file()
    tles = sorted(BUNDLED_EPHEMERIS_DIR.glob("gps-ops-*.tle"))
    assert len(tles) == 3
    centers = {}
    for path in tles:
        c = load_tle(path)
        assert len(c) == 31
        assert np.all(np.diff(c.prn) > 0) and c.prn.min() >= 1 and c.prn.max() <= 32
        assert len(c.name) == len(c.norad) == c.epoch_unix_s.size == 31
        centers[path] = c.epoch_center_unix_s
    assert default_tle_path() == max(centers, key=centers.get)
    assert default_tle_path().is_file()


def test_epochs_and_names_match_the_file(c2017):
    # PRN 13 is BIIR-2, NORAD 24876, epoch 17084.80454529 (day-of-year 84 of 2017, fraction).
    j = int(np.searchsorted(c2017.prn, 13))
    assert c2017.prn[j] == 13 and c2017.norad[j] == 24876
    assert "BIIR-2" in c2017.name[j]
    expect = dt.datetime(2017, 1, 1, tzinfo=dt.UTC).timestamp() + (84.80454529 - 1.0) * DAY_S
    assert c2017.epoch_unix_s[j] == pytest.approx(expect, abs=1e-3)
    # The median epoch lies within the file's epoch span.
    assert c2017.epoch_unix_s.min() <= c2017.epoch_center_unix_s <= c2017.epoch_unix_s.max()


def test_checksum_matches_celestrak():
    # Every line of the bundled files carries CelesTrak's checksum in column 69.
    for path in BUNDLED_EPHEMERIS_DIR.glob("*.tle"):
        for line in path.read_text().splitlines():
            if line[:2] in ("1 ", "2 "):
                assert tle_checksum(line) == int(line[68])


# ------------------------------------------------------------------------------------------
# Propagation
# ------------------------------------------------------------------------------------------


def test_shapes_and_vectorised_propagation(c2020):
    t0 = c2020.epoch_center_unix_s
    t = t0 + np.arange(5000.0)
    start = time.perf_counter()
    r, v = c2020.sat_state_ecef(t)
    elapsed_s = time.perf_counter() - start
    assert r.shape == v.shape == (5000, 31, 3)
    assert elapsed_s < 2.0  # ~0.2 s measured: one SatrecArray call, no Python loop
    assert c2020.sat_ecef_m(t0).shape == (31, 3)
    assert c2020.sat_ecef_m(np.full((2, 3), t0)).shape == (2, 3, 31, 3)
    # Element i of a batch equals a single call at t[i].
    np.testing.assert_allclose(c2020.sat_ecef_m(t[1234]), r[1234], rtol=0, atol=1e-6)
    # GPS orbit radius ~26,560 km; speed in ECEF ~3.9 km/s inertial minus Earth rotation.
    radius_km = np.linalg.norm(r, axis=-1) / 1e3
    assert np.all((radius_km > 25_000) & (radius_km < 28_000))
    speed = np.linalg.norm(v, axis=-1)
    assert np.all((speed > 1_000) & (speed < 4_500))
    # Velocities are the derivative of positions (central difference over 1 s).
    dr = (c2020.sat_ecef_m(t[:10] + 0.5) - c2020.sat_ecef_m(t[:10] - 0.5)) / 1.0
    np.testing.assert_allclose(dr, v[:10], atol=0.05)  # SGP4 velocity consistency ~0.02 m/s


def test_sgp4_error_gives_nan_not_exception(tmp_path):
    # An ISS TLE (python-sgp4's README example) with an absurd drag term: SGP4 flags an error
    # after a few days; those epochs must be NaN while the good ones are finite.
    l1 = "1 25544U 98067A   19343.69339541  .00001764  00000-0  38792-4 0  9991"
    l2 = "2 25544  51.6439 211.2001 0007417  17.6667  85.6398 15.50103472202482"
    bad1 = l1[:53] + " 50000-0" + l1[61:68]
    bad1 += str(tle_checksum(bad1))
    f = tmp_path / "decay.tle"
    f.write_text(f"ISS (PRN 99)\n{bad1}\n{l2}\n")
    c = load_tle(f)
    t = c.epoch_unix_s[0] + np.array([0.0, 60.0, 30 * DAY_S, 100 * DAY_S])
    r, v = c.sat_state_ecef(t)
    assert np.all(np.isfinite(r[:2])) and np.all(np.isfinite(v[:2]))
    assert np.all(np.isnan(r[2:])) and np.all(np.isnan(v[2:]))


def test_azel_matches_skyfield():
    rows = list(csv.DictReader((REPO / "tests" / "data" / "skyfield_azel.csv").open()))
    assert len(rows) > 1000
    tle_file = np.array([r["tle_file"] for r in rows])
    lat = np.array([float(r["lat_deg"]) for r in rows])
    lon = np.array([float(r["lon_deg"]) for r in rows])
    alt = np.array([float(r["alt_m"]) for r in rows])
    t = np.array([float(r["t_unix_s"]) for r in rows])
    prn = np.array([int(r["prn"]) for r in rows])
    norad = np.array([int(r["norad"]) for r in rows])
    az_ref = np.array([float(r["az_deg"]) for r in rows])
    el_ref = np.array([float(r["el_deg"]) for r in rows])
    checked = {}
    for name in np.unique(tle_file):
        # (BeiDou: three satellites of chosen elements, tools/make_skyfield_refs.py: no BeiDou
        # TLE set is at hand)
        folder = REPO / "tests" / "data" if name.startswith("beidou-synthetic") else \
            BUNDLED_EPHEMERIS_DIR
        c = load_tle(folder / name)
        if name.startswith("beidou-synthetic"):  # numbered 400 + the C number of the name
            assert dict(zip(c.norad.tolist(), c.prn.tolist(), strict=True)) == {
                90019: 419, 90038: 438, 90001: 401}
        # (the reference knows satellites by NORAD number: GLONASS spares in no slot are left
        # out of the constellation, and their rows here)
        sel = (tle_file == name) & (el_ref > -5.0) & np.isin(norad, c.norad)
        times, ti = np.unique(t[sel], return_inverse=True)
        order = np.argsort(c.norad)
        si = order[np.searchsorted(c.norad[order], norad[sel])]
        assert np.all(c.norad[si] == norad[sel])
        gps = prn[sel] > 0
        assert np.all(c.prn[si][gps] == prn[sel][gps])  # GPS: the PRN of the name, too
        sat = c.sat_ecef_m(times)[ti, si]  # (n_rows, 3)
        az, el = sky_azel(sat, lat[sel], lon[sel], alt[sel])
        sep = angular_separation_deg(az, el, az_ref[sel], el_ref[sel])
        assert np.max(np.abs(el - el_ref[sel])) < SKYFIELD_TOL_DEG
        assert np.max(sep) < SKYFIELD_TOL_DEG, f"{name}: worst {np.max(sep):.4f} deg"
        for system in set(systems.letters(c.prn[si]).tolist()):
            checked[system] = checked.get(system, 0) + int(
                (systems.letters(c.prn[si]) == system).sum())
    assert checked["G"] > 800 and checked["R"] > 300 and checked["E"] > 200, checked
    assert checked["C"] > 40, checked
    # The table covers the poles, the antimeridian and a high site.
    assert {90.0, -90.0} <= set(lat.tolist()) and 180.0 in lon and alt.max() >= 3000.0


# ------------------------------------------------------------------------------------------
# Real sky: the MT3339 receiver's own GSV angles
# ------------------------------------------------------------------------------------------


def _nmea_ok(sentence: str) -> bool:
    """True if an NMEA sentence's XOR checksum (NMEA 0183) is right."""
    body, star, cs = sentence[1:].partition("*")
    if not star or len(cs) < 2:
        return False
    x = 0
    for ch in body:
        x ^= ord(ch)
    return cs[:2].upper() == f"{x:02X}"


def _read_mt3339(path: Path):
    """GGA positions and GSV (t_unix_s, prn, el_deg, az_deg) of the MT3339 log."""
    text = path.read_text(encoding="ascii", errors="replace")
    date_ddmmyy, tod_s = None, None
    lat, lon, alt = [], [], []
    obs = []
    for raw in text.splitlines():
        start = raw.rfind("$")
        if start < 0:
            continue
        s = raw[start:].strip()
        if not _nmea_ok(s):
            continue
        f = s.split("*")[0].split(",")
        if f[0] == "$GPRMC" and len(f) > 9 and f[9]:
            date_ddmmyy = f[9]
        elif f[0] == "$GPGGA" and f[1]:
            tod_s = int(f[1][:2]) * 3600 + int(f[1][2:4]) * 60 + float(f[1][4:])
            if f[6] not in ("", "0") and f[2] and f[4]:
                la = int(f[2][:2]) + float(f[2][2:]) / 60.0
                lo = int(f[4][:3]) + float(f[4][3:]) / 60.0
                lat.append(-la if f[3] == "S" else la)
                lon.append(-lo if f[5] == "W" else lo)
                alt.append(float(f[9]) + float(f[11]))  # MSL + geoid separation = HAE
        elif f[0] == "$GPGSV" and tod_s is not None:
            for k in range(4, len(f) - 3, 4):
                p, el, az = f[k], f[k + 1], f[k + 2]
                if p and el and az:  # empty el/az before the almanac is known: skip
                    obs.append((tod_s, int(p), float(el), float(az)))
    day = dt.datetime.strptime(date_ddmmyy, "%d%m%y").replace(tzinfo=dt.UTC).timestamp()
    o = np.array(obs)
    o[:, 0] += day  # the log runs 18:40-19:39 UTC: no midnight inside
    return (np.median(lat), np.median(lon), np.median(alt)), o


@pytest.fixture(scope="module")
def mt3339(shared_data):
    return _read_mt3339(shared_data / "mt3339-static" / "hour_test_1.txt")


def _gsv_separation(c: Constellation, site, obs, shift_s: float = 0.0) -> np.ndarray:
    """Per-(PRN, epoch) separation of our sky from the GSV angles, on every 60th epoch."""
    times = np.unique(obs[:, 0])[::60]
    sel = np.isin(obs[:, 0], times) & np.isin(obs[:, 1], c.prn)
    o = obs[sel]
    ti = np.searchsorted(times, o[:, 0])
    si = np.searchsorted(c.prn, o[:, 1].astype(int))
    az, el = sky_azel(c.sat_ecef_m(times - shift_s)[ti, si], *site)
    return angular_separation_deg(az, el, o[:, 3], o[:, 2])


def test_real_receiver_gsv_matches(c2017, mt3339):
    site, obs = mt3339
    assert site[0] == pytest.approx(44.9837, abs=1e-3) and site[1] == pytest.approx(
        -93.2441, abs=1e-3
    )
    sep = _gsv_separation(c2017, site, obs)  # TLE 15 days after the log, propagated straight
    assert sep.size > 300
    # GSV angles are whole degrees: rounding alone gives a mean separation of ~0.38 deg
    # (|(U1, U2)| for U uniform in +-0.5). Measured 0.42 deg.
    assert np.mean(sep) <= 1.0
    assert np.median(sep) < 0.6
    assert np.max(sep) < 2.0


# ------------------------------------------------------------------------------------------
# Sky-time policy
# ------------------------------------------------------------------------------------------


def test_sidereal_shift_cases():
    epoch = 1_600_000_000.0
    assert sidereal_shift_s(epoch, epoch) == 0.0
    assert sidereal_shift_s(epoch + 2.9 * DAY_S, epoch) == 0.0
    assert sidereal_shift_s(epoch - 3.0 * DAY_S, epoch) == 0.0
    assert sidereal_shift_s(epoch + 1.0 * DAY_S, epoch, max_offset_days=0.5) == GPS_SKY_REPEAT_S
    for days in (3.5, 10.0, -10.0, 365.25, -1000.3, 2000.0):
        t = epoch + days * DAY_S + 1234.5
        shift = sidereal_shift_s(t, epoch)
        k = shift / GPS_SKY_REPEAT_S
        assert k == round(k) and k != 0
        # t - shift lies nearest the epoch: within half a repeat period of it.
        assert abs(t - shift - epoch) <= GPS_SKY_REPEAT_S / 2
        shift_sid = sidereal_shift_s(t, epoch, repeat_s=SIDEREAL_DAY_S)
        assert shift_sid / SIDEREAL_DAY_S == round(shift_sid / SIDEREAL_DAY_S)
        assert abs(t - shift_sid - epoch) <= SIDEREAL_DAY_S / 2
    assert sidereal_shift_s(float("nan"), epoch) == 0.0


def _mean_shift_drift_deg(c: Constellation, k: int, repeat_s: float) -> float:
    """Mean sky separation between the same TLE at t + k*repeat and at t (satellites > 5 deg)."""
    t = c.epoch_center_unix_s + np.arange(0.0, DAY_S, 1800.0)
    r_near, r_far = c.sat_ecef_m(t), c.sat_ecef_m(t + k * repeat_s)
    seps = []
    for lat, lon in ((52.14, 11.64), (44.98, -93.24), (0.0, 0.0), (-33.9, 151.2)):
        az0, el0 = sky_azel(r_near, lat, lon, 0.0)
        az1, el1 = sky_azel(r_far, lat, lon, 0.0)
        seps.append(angular_separation_deg(az0, el0, az1, el1)[el0 > 5.0])
    return float(np.mean(np.concatenate(seps)))


def test_sky_repeat_drift_is_as_documented(c2017):
    # Documented in sidereal_shift_s: 0.02 deg per day of shift with 86155 s, 0.07 with the
    # sidereal day (mean separation), growing linearly.
    gps = {k: _mean_shift_drift_deg(c2017, k, GPS_SKY_REPEAT_S) for k in (1, 10, 100)}
    sid = {k: _mean_shift_drift_deg(c2017, k, SIDEREAL_DAY_S) for k in (1, 10, 100)}
    assert gps[1] < 0.04 and gps[10] < 0.35 and gps[100] < 3.0
    assert sid[1] > 0.05 and sid[100] > 5.0
    for k in (1, 10, 100):
        assert gps[k] < 0.5 * sid[k]
    # Linear growth: 100 days drift ~100 x 1 day drift.
    assert 50 < gps[100] / gps[1] < 200


def test_shift_against_a_real_later_sky(c2017, shared_data):
    # The 2017-02-02 set, 50 days older, against the 2017-03-26 set at its epoch (the real sky
    # within ~0.005 deg). Measured: straight SGP4 0.23 deg, shift by 86155 s 1.0 deg, by the
    # sidereal day 3.6 deg.
    old = load_tle(shared_data / "magdeburg-campus" / "tle" / "gps-ops.2017-02-02.current.tle")
    common = np.intersect1d(old.prn, c2017.prn)
    i_old, i_new = np.searchsorted(old.prn, common), np.searchsorted(c2017.prn, common)
    t = c2017.epoch_center_unix_s + np.arange(0.0, DAY_S, 1800.0)
    truth = c2017.sat_ecef_m(t)[:, i_new]

    def mean_sep(shift_s: float) -> float:
        r = old.sat_ecef_m(t - shift_s)[:, i_old]
        az0, el0 = sky_azel(truth, 52.14, 11.64, 100.0)
        az1, el1 = sky_azel(r, 52.14, 11.64, 100.0)
        return float(np.mean(angular_separation_deg(az0, el0, az1, el1)[el0 > 5.0]))

    direct = mean_sep(0.0)
    gps = mean_sep(sidereal_shift_s(t[0], old.epoch_center_unix_s))
    sid = mean_sep(sidereal_shift_s(t[0], old.epoch_center_unix_s, repeat_s=SIDEREAL_DAY_S))
    assert direct < 0.5
    assert gps < 1.6
    assert gps < sid


# ------------------------------------------------------------------------------------------
# TLE parsing
# ------------------------------------------------------------------------------------------


def _two_line_text(path: Path) -> str:
    lines = [s for s in path.read_text().splitlines() if s[:2] in ("1 ", "2 ")]
    return "\n".join(lines) + "\n"


def test_two_line_with_table_equals_three_line(tmp_path, c2020):
    two = tmp_path / "two" / "gps.tle"
    two.parent.mkdir()
    two.write_text(_two_line_text(TLE_2020))
    explicit = load_tle(two, prn_table=PRN_TABLE)
    np.testing.assert_array_equal(explicit.prn, c2020.prn)
    np.testing.assert_array_equal(explicit.norad, c2020.norad)
    np.testing.assert_array_equal(explicit.epoch_unix_s, c2020.epoch_unix_s)
    assert explicit.name == ("",) * 31
    # Without a table the PRNs are unknown: an error naming the file and line.
    with pytest.raises(InputFileError, match=r"gps\.tle:1: satellite \d+ has no PRN"):
        load_tle(two)
    # A table beside the file is found automatically.
    (two.parent / "gps-ops-NORAD-PRN.t").write_text(PRN_TABLE.read_text())
    auto = load_tle(two)
    np.testing.assert_array_equal(auto.prn, c2020.prn)
    t = c2020.epoch_center_unix_s + np.array([0.0, 3600.0])
    np.testing.assert_array_equal(auto.sat_ecef_m(t), c2020.sat_ecef_m(t))


def test_prn_table_reader():
    table = read_prn_table(PRN_TABLE)
    assert len(table) == 32
    assert table[37753] == 1 and table[24876] == 13 and table[43873] == 4


def test_crlf_blank_lines_and_trailing_spaces(tmp_path, c2017):
    lines = TLE_2017_03_26.read_text().splitlines()
    messy = "\r\n".join(s + "   " if i % 2 else s for i, s in enumerate(lines))
    messy = "\r\n\r\n" + messy.replace("\r\nGPS", "\r\n\r\nGPS") + "\r\n\r\n"
    f = tmp_path / "messy.tle"
    f.write_bytes(messy.encode("ascii"))
    c = load_tle(f)
    np.testing.assert_array_equal(c.prn, c2017.prn)
    np.testing.assert_array_equal(c.epoch_unix_s, c2017.epoch_unix_s)
    assert c.name == c2017.name


def test_duplicate_prn_keeps_newest_epoch(tmp_path):
    both = tmp_path / "both.tle"
    both.write_text(TLE_2017_03_28.read_text() + TLE_2017_03_26.read_text())
    a, b = load_tle(TLE_2017_03_26), load_tle(TLE_2017_03_28)
    c = load_tle(both)
    np.testing.assert_array_equal(c.prn, a.prn)
    np.testing.assert_array_equal(c.epoch_unix_s, np.maximum(a.epoch_unix_s, b.epoch_unix_s))


def _corrupt(tmp_path: Path, line_index: int, new_line: str) -> Path:
    lines = TLE_2017_03_26.read_text().splitlines()
    lines[line_index] = new_line
    f = tmp_path / "bad.tle"
    f.write_text("\n".join(lines) + "\n")
    return f


def test_bad_checksum_names_the_line(tmp_path):
    lines = TLE_2017_03_26.read_text().splitlines()
    line = lines[4]  # line 1 of the second satellite: file line 5
    wrong = str((int(line[68]) + 3) % 10)
    f = _corrupt(tmp_path, 4, line[:68] + wrong)
    with pytest.raises(InputFileError, match=r"bad\.tle:5: checksum") as err:
        load_tle(f)
    assert err.value.line == 5


def test_truncated_line_names_the_line_and_layout(tmp_path):
    lines = TLE_2017_03_26.read_text().splitlines()
    f = _corrupt(tmp_path, 8, lines[8][:50])  # line 2 of the third satellite: file line 9
    with pytest.raises(InputFileError, match=r"bad\.tle:9: TLE line 2 has 50 columns") as err:
        load_tle(f)
    assert "2 NNNNN NNN.NNNN" in str(err.value)  # the expected column template


def test_other_layout_errors(tmp_path):
    lines = TLE_2017_03_26.read_text().splitlines()
    # A missing line 2.
    f = tmp_path / "missing.tle"
    f.write_text("\n".join(lines[:5] + lines[6:]) + "\n")
    with pytest.raises(InputFileError, match=r"missing\.tle:6: expected TLE line 2"):
        load_tle(f)
    # A 2-line file missing a line 1: the orphan line 2 is not taken for a name.
    f = tmp_path / "orphan.tle"
    two = _two_line_text(TLE_2017_03_26).splitlines()
    f.write_text("\n".join(two[1:]) + "\n")
    with pytest.raises(InputFileError, match=r"orphan\.tle:1: TLE line 2 without its line 1"):
        load_tle(f)
    # Line 2 of another satellite.
    f = tmp_path / "mixed.tle"
    f.write_text("\n".join(lines[:2] + [lines[5]]) + "\n")
    with pytest.raises(InputFileError, match=r"mixed\.tle:3: satellite number"):
        load_tle(f)
    # A shifted column (blank where a digit should be).
    f = _corrupt(tmp_path, 1, " " + lines[1][:-1])
    with pytest.raises(InputFileError, match=r"bad\.tle:2"):
        load_tle(f)
    # A letter in a number (sgp4's own parser would silently accept it), with a valid checksum.
    bad = lines[1][:20] + "O" + lines[1][21:68]
    f = _corrupt(tmp_path, 1, bad + str(tle_checksum(bad)))
    with pytest.raises(InputFileError, match=r"bad\.tle:2: columns 19-32 \(epoch"):
        load_tle(f)
    # An inclination out of range (555 deg).
    bad = lines[2][:8] + "5" + lines[2][9:68]
    f = _corrupt(tmp_path, 2, bad + str(tle_checksum(bad)))
    with pytest.raises(InputFileError, match=r"bad\.tle:3: columns 9-16 \(inclination"):
        load_tle(f)
    # No satellites at all.
    f = tmp_path / "empty.tle"
    f.write_text("\n\n  \n")
    with pytest.raises(InputFileError, match=r"empty\.tle: no satellites"):
        load_tle(f)
    # A missing file.
    with pytest.raises(InputFileError, match="cannot read"):
        load_tle(tmp_path / "nope.tle")


# ------------------------------------------------------------------------------------------
# The paper's lookup table
# ------------------------------------------------------------------------------------------


def test_lookup_table_matches_sgp4(c2020):
    t0 = c2020.epoch_center_unix_s
    rng = np.random.default_rng(7)
    t = t0 + rng.uniform(0.0, 7200.0, 2000)
    r, v = c2020.sat_state_ecef(t)
    for step_s, tol_m in ((60.0, TABLE_60S_TOL_M), (300.0, TABLE_300S_TOL_M)):
        table = build_lookup_table(c2020, t0, 7200.0, step_s)
        assert table.t_unix_s[-1] >= t0 + 7200.0
        ri, vi = table.sat_state_ecef(t)
        assert ri.shape == (2000, 31, 3)
        assert np.max(np.linalg.norm(ri - r, axis=-1)) < tol_m
        assert np.max(np.linalg.norm(vi - v, axis=-1)) < 0.1  # SGP4's own velocity ~0.02 m/s
    np.testing.assert_array_equal(table.prn, c2020.prn)


def test_lookup_table_interpolates_between_rows(c2020):
    t0 = c2020.epoch_center_unix_s
    table = build_lookup_table(c2020, t0, 600.0, 60.0)
    t_mid = t0 + 90.0  # half way between rows 1 and 2
    r_mid = table.sat_ecef_m(t_mid)
    truth = c2020.sat_ecef_m(t_mid)
    assert np.max(np.linalg.norm(r_mid - truth, axis=-1)) < TABLE_60S_TOL_M
    # Not "the last row before t" (the paper's code): that is ~100 km off after 30 s.
    assert np.min(np.linalg.norm(r_mid - table.sat_ecef_m_rows[1], axis=-1)) > 50_000.0
    # Exact at the rows, including both ends.
    np.testing.assert_allclose(
        table.sat_ecef_m(table.t_unix_s), table.sat_ecef_m_rows, rtol=0, atol=1e-6
    )


def test_a_time_outside_the_lookup_table_is_named(c2020):
    from virtualgps.run.config import coverage_note

    table = build_lookup_table(c2020, c2020.epoch_center_unix_s, 600.0, 60.0)
    first, last = table.coverage_unix_s
    assert coverage_note(table, first) is None and coverage_note(table, last) is None
    assert np.isfinite(table.sat_ecef_m(np.array([first, last]))).all()
    assert np.isnan(table.sat_ecef_m(np.array([first - 1.0, last + 1.0]))).all()
    note = coverage_note(table, last + 1.0)
    assert note is not None and table.source in note and "not at" in note
    assert coverage_note(c2020, last + 1e9) is None  # SGP4 propagates to any time


def test_hermite_is_exact_for_cubics():
    # Independent reference: a cubic in time is reproduced exactly by cubic Hermite from its
    # values and derivatives at unevenly spaced rows.
    t_rows = np.array([0.0, 10.0, 25.0, 70.0, 71.0])
    coef = np.array(
        [[1.0e7, -2.0e6, 3.0e5], [300.0, 20.0, -5.0], [0.2, -0.3, 0.1], [1e-3, 2e-3, -4e-4]]
    )  # (power, xyz)

    def cubic(t):
        t = np.asarray(t)[..., None]
        return coef[0] + coef[1] * t + coef[2] * t**2 + coef[3] * t**3

    def dcubic(t):
        t = np.asarray(t)[..., None]
        return coef[1] + 2 * coef[2] * t + 3 * coef[3] * t**2

    table = LookupTable(
        prn=np.array([7]),
        t_unix_s=t_rows,
        sat_ecef_m_rows=cubic(t_rows)[:, None, :],
        sat_vel_ecef_mps_rows=dcubic(t_rows)[:, None, :],
        source="synthetic",
        step_s=0.0,
    )
    t = np.linspace(0.0, 71.0, 503)
    r, v = table.sat_state_ecef(t)
    np.testing.assert_allclose(r[:, 0], cubic(t), rtol=0, atol=1e-6)
    np.testing.assert_allclose(v[:, 0], dcubic(t), rtol=0, atol=1e-9)


def test_lookup_table_nan_outside_span(c2020):
    t0 = c2020.epoch_center_unix_s
    table = build_lookup_table(c2020, t0, 600.0, 60.0)
    r, v = table.sat_state_ecef(np.array([t0 - 0.001, t0 + 600.001, np.nan, t0 + 300.0]))
    assert np.all(np.isnan(r[:3])) and np.all(np.isnan(v[:3]))
    assert np.all(np.isfinite(r[3]))
    assert table.sat_ecef_m(t0 + 1e6).shape == (31, 3)
    assert table.epoch_center_unix_s == pytest.approx(t0 + 300.0)


def test_lookup_table_file_round_trip(tmp_path, c2020):
    t0 = c2020.epoch_center_unix_s
    table = build_lookup_table(c2020, t0, 1800.0, 60.0)
    f = tmp_path / "mtv.sat"
    write_lookup_table(table, f)
    assert is_lookup_table(f) and not is_lookup_table(TLE_2020)
    head = f.read_text().splitlines()[:5]
    assert head[0].startswith("# virtualgps satellite lookup table")
    assert any("gps-ops-2020-05-14T22Z.tle" in h for h in head)
    assert any("step_s: 60" in h for h in head)
    back = read_lookup_table(f)
    np.testing.assert_array_equal(back.prn, table.prn)
    np.testing.assert_allclose(back.t_unix_s, table.t_unix_s, rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.sat_ecef_m_rows, table.sat_ecef_m_rows, rtol=0, atol=MM_M)
    np.testing.assert_allclose(
        back.sat_vel_ecef_mps_rows, table.sat_vel_ecef_mps_rows, rtol=0, atol=1e-6
    )
    assert back.step_s == 60.0 and back.source == "gps-ops-2020-05-14T22Z.tle"
    t = t0 + np.array([45.5, 1000.25])
    np.testing.assert_allclose(
        back.sat_ecef_m(t), c2020.sat_ecef_m(t), rtol=0, atol=TABLE_60S_TOL_M
    )


def test_lookup_table_bad_files(tmp_path, c2020):
    table = build_lookup_table(c2020, c2020.epoch_center_unix_s, 120.0, 60.0)
    f = tmp_path / "t.sat"
    write_lookup_table(table, f)
    lines = f.read_text().splitlines()
    n_head = sum(1 for s in lines if s.startswith("#"))
    # A row with 7 fields: file line n_head + 4.
    bad = list(lines)
    bad[n_head + 3] = " ".join(bad[n_head + 3].split()[:7])
    g = tmp_path / "bad.sat"
    g.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputFileError, match=rf"bad\.sat:{n_head + 4}: 7 fields"):
        read_lookup_table(g)
    # A word where a number belongs.
    bad = list(lines)
    bad[n_head] = bad[n_head].replace(" 1 ", " one ", 1)
    g.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputFileError, match=rf"bad\.sat:{n_head + 1}: not a number"):
        read_lookup_table(g)
    # A row missing at the second time: the PRN pattern breaks there.
    bad = list(lines)
    del bad[n_head + 31 + 5]
    g.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputFileError, match=rf"bad\.sat:{n_head + 31 + 6}: expected every time"):
        read_lookup_table(g)
    # Time going backwards.
    bad = lines[:n_head] + lines[n_head + 31 : n_head + 62] + lines[n_head : n_head + 31]
    g.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputFileError, match=rf"bad\.sat:{n_head + 32}: time goes backwards"):
        read_lookup_table(g)
    # Nonsense parameters.
    with pytest.raises(ConfigError, match="step_s"):
        build_lookup_table(c2020, 0.0, 100.0, 0.0)
    with pytest.raises(ConfigError, match="duration_s"):
        build_lookup_table(c2020, 0.0, -1.0, 60.0)


def test_make_lookup_table_tool(tmp_path):
    out = tmp_path / "mtv.sat"
    proc = subprocess.run(
        [
            sys.executable,
            str(REPO / "tools" / "make_lookup_table.py"),
            str(TLE_2020),
            "--start",
            "2020-05-14T22:00:00Z",
            "--duration-s",
            "600",
            "--step-s",
            "60",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    table = read_lookup_table(out)
    assert table.t_unix_s.size == 11 and len(table) == 31
    assert table.t_unix_s[0] == dt.datetime(2020, 5, 14, 22, tzinfo=dt.UTC).timestamp()
