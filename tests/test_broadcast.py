"""Broadcast orbits from RINEX navigation files (issue #9): the IS-GPS-200 user algorithm
against a scalar transcription of Table 20-IV on records parsed here by hand, the GSDC day's
broadcast orbits against its TLE set (~2 km apart, SOURCES.md), and ``--tle FILE.20n``."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from calendar import timegm

import numpy as np
import pytest

from virtualgps.sky import broadcast
from virtualgps.sky.ephemeris import load_ephemeris_file, load_tle

NAV = "gsdc-2020-05-14-mtv/hour1350.20n"
TLE = "gsdc-2020-05-14-mtv/gps-ops_2020-05-14T22Z.tle"


def _records(text: str) -> list[dict]:
    """The GPS records of a RINEX 2 navigation file, parsed by column (RINEX 2.11, Table A4)."""
    lines = text.splitlines()
    body = lines[next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1:]
    names = ["IODE", "Crs", "DeltaN", "M0", "Cuc", "e", "Cus", "sqrtA", "Toe", "Cic", "Omega0",
             "Cis", "Io", "Crc", "omega", "OmegaDot", "IDOT", "L2", "week", "L2P", "acc",
             "health", "TGD", "IODC", "ttx", "fit"]
    out = []
    for k in range(0, len(body) - 7, 8):
        head, orbit = body[k], body[k + 1 : k + 8]
        vals = [float(ln[3 + 19 * j : 3 + 19 * (j + 1)].replace("D", "E") or 0.0)
                for ln in orbit for j in range(4) if ln[3 + 19 * j : 3 + 19 * (j + 1)].strip()]
        rec = dict(zip(names, vals, strict=False))
        rec["prn"] = int(head[:2])
        out.append(rec)
    return out


def _table_20_iv(r: dict, t_gps_week_s: float) -> tuple[float, float, float]:
    """IS-GPS-200 Table 20-IV, one satellite and time, as written there (Kepler's equation by
    fixed-point iteration, not the module's Newton steps)."""
    mu, we = 3.986005e14, 7.2921151467e-5
    a = r["sqrtA"] ** 2
    tk = t_gps_week_s - r["Toe"]
    n = math.sqrt(mu / a**3) + r["DeltaN"]
    mk = r["M0"] + n * tk
    ek = mk
    for _ in range(60):
        ek = mk + r["e"] * math.sin(ek)
    vk = math.atan2(math.sqrt(1 - r["e"] ** 2) * math.sin(ek), math.cos(ek) - r["e"])
    phik = vk + r["omega"]
    uk = phik + r["Cus"] * math.sin(2 * phik) + r["Cuc"] * math.cos(2 * phik)
    rk = a * (1 - r["e"] * math.cos(ek)) + r["Crs"] * math.sin(2 * phik) \
        + r["Crc"] * math.cos(2 * phik)
    ik = r["Io"] + r["IDOT"] * tk + r["Cis"] * math.sin(2 * phik) + r["Cic"] * math.cos(2 * phik)
    xp, yp = rk * math.cos(uk), rk * math.sin(uk)
    om = r["Omega0"] + (r["OmegaDot"] - we) * tk - we * r["Toe"]
    return (xp * math.cos(om) - yp * math.cos(ik) * math.sin(om),
            xp * math.sin(om) + yp * math.cos(ik) * math.cos(om), yp * math.sin(ik))


def test_broadcast_orbits_are_table_20_iv(shared_data):
    path = shared_data / NAV
    nav = load_ephemeris_file(path)
    assert isinstance(nav, broadcast.BroadcastEphemeris) and len(nav) == 31
    recs = [r for r in _records(path.read_text()) if r["health"] == 0]
    # Each record at its own toe (it is then the nearest record): the vectorised orbit equals
    # the scalar transcription to 1 mm.
    gps_utc = 18.0  # leap seconds in 2020
    for r in recs[::7]:
        t_unix = broadcast.GPS_EPOCH_UNIX_S + r["week"] * 604800.0 + r["Toe"] - gps_utc
        got = nav.sat_ecef_m(t_unix)[np.searchsorted(nav.prn, r["prn"])]
        np.testing.assert_allclose(got, _table_20_iv(r, r["Toe"]), atol=1e-3)
    # And the orbit function away from toe (+-2 h), where Kepler's equation matters.
    r = recs[0]
    el = {k: np.float64(v) for k, v in r.items()}
    el["Eccentricity"] = el["e"]
    for dt in (-7200.0, -1800.0, 3600.0, 7200.0):
        got = broadcast.orbit_ecef_m(el, np.float64(dt))
        np.testing.assert_allclose(got, _table_20_iv(r, r["Toe"] + dt), atol=1e-3)


def test_broadcast_orbits_agree_with_the_days_tle_set(shared_data):
    nav = load_ephemeris_file(shared_data / NAV)
    tle = load_tle(shared_data / TLE)
    t = timegm((2020, 5, 14, 22, 0, 0)) + np.arange(0.0, 2700.0, 60.0)  # the drive
    common = np.intersect1d(nav.prn, tle.prn)
    d = np.linalg.norm(nav.sat_ecef_m(t)[:, np.searchsorted(nav.prn, common)]
                       - tle.sat_ecef_m(t)[:, np.searchsorted(tle.prn, common)], axis=-1)
    assert common.size >= 30 and np.isfinite(d).all()
    assert 0.5e3 < np.median(d) < 3.0e3 and d.max() < 10e3  # SOURCES.md: median 1.7 km
    # Far from every record, no position (a receiver without a valid ephemeris has none).
    assert np.isnan(nav.sat_ecef_m(t[0] + 3 * 86400.0)).all()


def test_sky_from_a_rinex_navigation_file(shared_data):
    lla = ["--scene", "none", "--lla", "37.42,-122.08,0", "--time", "2020-05-14T22:20:00Z",
           "--json"]
    runs = [subprocess.run([sys.executable, "-m", "virtualgps", "sky", "--tle",
                            str(shared_data / f), *lla], capture_output=True, text=True,
                           timeout=120) for f in (NAV, TLE)]
    assert all(r.returncode == 0 for r in runs), runs[0].stderr + runs[1].stderr
    sky_nav, sky_tle = (json.loads(r.stdout) for r in runs)
    el_tle = {s["prn"]: s["el_deg"] for s in sky_tle}
    common = [s for s in sky_nav if s["prn"] in el_tle]
    assert len(common) >= 8
    # ~2 km at ~20,000 km: the two skies agree within a few hundredths of a degree
    assert max(abs(s["el_deg"] - el_tle[s["prn"]]) for s in common) < 0.1


def test_coverage_is_where_some_satellite_has_an_orbit(shared_data):
    nav = load_ephemeris_file(shared_data / NAV)
    first, last = nav.coverage_unix_s
    assert last - first > 24 * 3600.0  # a day's file: 2020-05-13T20Z .. 2020-05-15T04Z
    inside = nav.sat_ecef_m(np.array([first + 1.0, last - 1.0]))
    outside = nav.sat_ecef_m(np.array([first - 1.0, last + 1.0]))
    assert np.isfinite(inside).any(axis=(1, 2)).all()
    assert np.isnan(outside).all()


def test_a_time_outside_the_navigation_file_is_said_not_an_empty_sky(shared_data, tmp_path):
    """sky at a time the file does not cover: one error line naming its span, not an empty
    table; replay there: a warning that there will be no fix (and the epochs, without one)."""
    cli = [sys.executable, "-m", "virtualgps"]
    nav = str(shared_data / NAV)
    r = subprocess.run([*cli, "sky", "--scene", "none", "--lla", "37.42,-122.08,0", "--tle", nav,
                        "--time", "2020-05-16T09:00:00Z"], capture_output=True, text=True,
                       timeout=120)
    errors = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert r.returncode == 2 and len(errors) == 1, r.stderr
    assert "2020-05-13T19:59" in errors[0] and "2020-05-15T03:59" in errors[0]
    assert "--time" in errors[0] and r.stdout == ""
    walk = tmp_path / "w.jsonl"
    walk.write_text("".join(json.dumps({"t": 1589619600.0 + k, "lat": 37.42, "lon": -122.08,
                                        "alt": 10.0}) + "\n" for k in range(5)))
    out = tmp_path / "o.nmea"
    for start, covered in (("2020-05-16T09:00:00Z", False), ("2020-05-14T22:00:00Z", True)):
        r = subprocess.run([*cli, "replay", str(walk), "--scene", "none", "--tle", nav,
                            "--start-time", start, "--profile", "ideal", "--out", str(out)],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert ("no satellite, no fix" in r.stderr) is not covered, r.stderr
        quality = {ln.split(",")[6] for ln in out.read_text().splitlines()
                   if ln.startswith("$GPGGA")}
        assert quality == ({"1"} if covered else {"0"})


def test_gap_refuses_a_navigation_file_that_misses_the_log(shared_data, tmp_path):
    """A log three days after the file (within the days a set is used unshifted): the
    simulation would have no satellite, so the gap tool says which file misses which run."""
    cli = [sys.executable, "-m", "virtualgps"]
    walk = tmp_path / "w.jsonl"
    walk.write_text("".join(json.dumps({"t": 1589709600.0 + k, "lat": 37.42, "lon": -122.08,
                                        "alt": 10.0}) + "\n" for k in range(20)))
    real = tmp_path / "real17.nmea"  # 2020-05-17T10:00Z, its sky from the TLE set
    r = subprocess.run([*cli, "replay", str(walk), "--scene", "none", "--tle",
                        str(shared_data / TLE), "--profile", "ideal", "--out", str(real)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([*cli, "gap", "--real", str(real), "--truth", "static:37.42,-122.08,10",
                        "--scene", "none", "--tle", str(shared_data / NAV), "--seeds", "2",
                        "--out", str(tmp_path / "gap")], capture_output=True, text=True,
                       timeout=120)
    errors = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert r.returncode == 2 and len(errors) == 1, r.stderr
    assert "real17" in errors[0] and "not at 2020-05-17T10:00:00Z" in errors[0]
    assert not (tmp_path / "gap" / "report.json").exists()


def test_bad_rinex_file_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.20n"
    bad.write_text("     2              NAVIGATION DATA                         RINEX VERSION / "
                   "TYPE\n" + "garbage\n" * 3)
    with pytest.raises(Exception, match="bad.20n") as info:
        load_ephemeris_file(bad)
    assert type(info.value).__name__ == "InputFileError"


def _as_rinex3(text: str) -> str:
    """The GPS records of a RINEX 2 navigation file rewritten as RINEX 3.04 (Table A6/A8:
    ``Gnn yyyy mm dd hh mm ss`` then the same D19.12 fields, orbit lines indented by 4)."""
    lines = text.splitlines()
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln)
    out = [f"{'3.04':>9}{'':11}{'N: GNSS NAV DATA':<20}{'G: GPS':<20}RINEX VERSION / TYPE",
           f"{'':60}END OF HEADER"]
    body = lines[end + 1:]
    for k in range(0, len(body) - 7, 8):
        head = body[k]
        yy, mo, dd, hh, mi = (int(head[i : i + 3]) for i in (2, 5, 8, 11, 14))
        ss = int(float(head[17:22]))
        out.append(f"G{int(head[:2]):02d} {2000 + yy:04d} {mo:02d} {dd:02d} {hh:02d} {mi:02d} "
                   f"{ss:02d}{head[22:]}")
        out += [" " + ln for ln in body[k + 1 : k + 8]]
    return "\n".join(out) + "\n"


def test_rinex3_navigation_file_gives_the_same_orbits(shared_data, tmp_path):
    nav2 = shared_data / NAV
    nav3 = tmp_path / "BRDC00IGS_R_20201350000_01D_GN.rnx"
    nav3.write_text(_as_rinex3(nav2.read_text()))
    a, b = load_ephemeris_file(nav2), load_ephemeris_file(nav3)
    assert isinstance(b, broadcast.BroadcastEphemeris)
    np.testing.assert_array_equal(a.prn, b.prn)
    t = timegm((2020, 5, 14, 22, 0, 0)) + np.arange(0.0, 2700.0, 300.0)
    np.testing.assert_allclose(b.sat_ecef_m(t), a.sat_ecef_m(t), atol=1e-6)


# --- RINEX 3 mixed navigation files: Galileo, BeiDou, GLONASS (issue 23) ----------------------


def _rinex3(records: list[tuple[str, tuple, list, list]]) -> str:
    """A RINEX 3.04 mixed navigation file of (sv, (y, m, d, h, mi, s), clock 3, orbit rows)."""
    def d(x: float) -> str:
        return f"{x:.12E}".rjust(19)

    out = ["     3.04           N: GNSS NAV DATA    M: MIXED            RINEX VERSION / TYPE",
           "virtualgps tests".ljust(60) + "PGM / RUN BY / DATE", " " * 60 + "END OF HEADER"]
    for sv, (y, mo, dd, h, mi, s), clock, rows in records:
        out.append(f"{sv} {y:04d} {mo:02d} {dd:02d} {h:02d} {mi:02d} {s:02d}"
                   + "".join(d(v) for v in clock))
        out += ["    " + "".join(d(v) for v in row) for row in rows]
    return "\n".join(out) + "\n"


# A GPS record's elements (realistic magnitudes), toe 22:00 GPS time on Monday 2020-05-18
# (week 2106)
KEP = {"Crs": 20.0, "DeltaN": 4.5e-9, "M0": 0.5, "Cuc": 1e-6, "e": 0.01, "Cus": 8e-6,
       "sqrtA": 5153.7, "Toe": 86400.0 + 79200.0, "Cic": 1e-7, "Omega0": 1.0, "Cis": -1e-7,
       "Io": 0.95, "Crc": 200.0, "omega": 0.3, "OmegaDot": -8e-9, "IDOT": 1e-10}


def _kepler_rows(k: dict, week: float, *, galileo: bool = False, beidou: bool = False) -> list:
    rows = [[1.0, k["Crs"], k["DeltaN"], k["M0"]], [k["Cuc"], k["e"], k["Cus"], k["sqrtA"]],
            [k["Toe"], k["Cic"], k["Omega0"], k["Cis"]],
            [k["Io"], k["Crc"], k["omega"], k["OmegaDot"]]]
    if galileo:
        rows += [[k["IDOT"], 517.0, week, 0.0], [3.12, 0.0, 0.0, 0.0], [k["Toe"], 0.0, 0.0, 0.0]]
    elif beidou:
        rows += [[k["IDOT"], 0.0, week, 0.0], [2.0, 0.0, 0.0, 0.0], [k["Toe"], 0.0, 0.0, 0.0]]
    else:
        rows += [[k["IDOT"], 1.0, week, 0.0], [2.0, 0.0, 0.0, 1.0], [k["Toe"], 4.0, 0.0, 0.0]]
    return rows


def test_galileo_and_beidou_records_run_on_their_own_time_scales(tmp_path):
    # The same orbit broadcast by GPS, by Galileo (GST = GPS time, its week GPS's in RINEX 3)
    # and by BeiDou (BDT = GPS time - 14 s, BDT week = GPS week - 1356): the same positions
    # but for the systems' constants (mu, Earth rotation: metres over an hour). A wrong week
    # or a missing 14 s would move them by tens of kilometres.
    # (the node's longitude at toe, Omega0 - omega_e toe, is the orbit's: BeiDou's Omega0
    # refers to its own week's start and Earth rotation rate)
    bdt = dict(KEP, Toe=KEP["Toe"] - 14.0,
               Omega0=KEP["Omega0"] - 7.2921151467e-5 * KEP["Toe"] + 7.292115e-5 * (
                   KEP["Toe"] - 14.0))
    path = tmp_path / "mixed.rnx"
    path.write_text(_rinex3([
        ("G05", (2020, 5, 18, 22, 0, 0), [0.0, 0.0, 0.0], _kepler_rows(KEP, 2106)),
        ("E05", (2020, 5, 18, 22, 0, 0), [0.0, 0.0, 0.0], _kepler_rows(KEP, 2106,
                                                                        galileo=True)),
        ("C25", (2020, 5, 18, 21, 59, 46), [0.0, 0.0, 0.0], _kepler_rows(bdt, 2106 - 1356,
                                                                          beidou=True)),
    ]))
    eph = load_ephemeris_file(path, None)
    assert eph.prn.tolist() == [5, 305, 425]
    t = timegm((2020, 5, 18, 22, 0, 0)) - 18.0 + np.arange(-3600.0, 3601.0, 600.0)  # (UTC)
    pos = eph.sat_ecef_m(t)
    assert np.isfinite(pos).all()
    assert np.linalg.norm(pos[:, 1] - pos[:, 0], axis=-1).max() < 5.0
    assert np.linalg.norm(pos[:, 2] - pos[:, 0], axis=-1).max() < 5.0
    # only the systems asked for
    assert load_ephemeris_file(path, "G").prn.tolist() == [5]


def test_a_beidou_geostationary_satellite_stays_over_its_longitude(tmp_path):
    # BDS-SIS-ICD-B1I: a GEO's elements are broadcast in a frame turned by 5 degrees about x
    # (inclination 5 degrees there, its node opposite the x axis); turned back, a circular
    # orbit of the Earth's own rate stays over one point of the equator. (Taking the node
    # inertial before the turn, or turning the wrong way, tilts it by 5-10 degrees.)
    mu, we = 3.986004418e14, 7.292115e-5
    toe = 86400.0 + 79186.0
    geo = dict(KEP, e=0.0, DeltaN=0.0, Crs=0.0, Crc=0.0, Cus=0.0, Cuc=0.0, Cis=0.0, Cic=0.0,
               IDOT=0.0, OmegaDot=0.0, omega=0.0, sqrtA=(mu / we**2) ** (1 / 6), Toe=toe,
               Io=np.radians(5.0), Omega0=we * toe + np.pi, M0=1.0)
    path = tmp_path / "geo.rnx"
    path.write_text(_rinex3([("C03", (2020, 5, 18, 21, 59, 46), [0.0, 0.0, 0.0],
                              _kepler_rows(geo, 2106 - 1356, beidou=True))]))
    eph = load_ephemeris_file(path, None)
    t = timegm((2020, 5, 18, 22, 0, 0)) + np.arange(-7200.0, 7201.0, 900.0)
    p = eph.sat_ecef_m(t)[:, 0]
    lat = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    lon = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    assert np.abs(lat).max() < 0.01 and np.ptp(lon) < 0.01
    assert np.linalg.norm(p, axis=-1) == pytest.approx((mu / we**2) ** (1 / 3), rel=1e-9)


def test_glonass_state_vectors_integrate_along_the_tle_orbit(tmp_path):
    # A GLONASS record made of SGP4's state of a real GLONASS satellite at 12:00 UTC; the
    # PZ-90 integration (J2, Earth rotation) must follow SGP4's orbit over the +-15 min a
    # record serves: lunisolar terms (not in the record here) and SGP4's higher harmonics
    # make about 2 m there (measured, 2026-11-27); a wrong sign or frame makes kilometres.
    from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR

    glo = load_tle(BUNDLED_EPHEMERIS_DIR / "glo-ops-2017-03-28.tle")
    t0 = float(timegm((2017, 3, 28, 12, 0, 0)))
    # (the velocity as the derivative of SGP4's ECEF positions, +-0.5 s)
    pos = glo.sat_ecef_m(np.array([t0 - 0.5, t0, t0 + 0.5]))
    k = int(np.flatnonzero(np.isfinite(pos[1, :, 0]) & (glo.prn >= 65))[0])
    slot = int(glo.prn[k]) - 64
    x, v = pos[1, k] / 1000.0, (pos[2, k] - pos[0, k]) / 1000.0  # (RINEX: km, km/s)
    path = tmp_path / "glo.rnx"
    path.write_text(_rinex3([(f"R{slot:02d}", (2017, 3, 28, 12, 0, 0), [0.0, 0.0, 43200.0],
                              [[x[0], v[0], 0.0, 0.0], [x[1], v[1], 0.0, 1.0],
                               [x[2], v[2], 0.0, 0.0]])]))
    eph = load_ephemeris_file(path, None)
    assert eph.prn.tolist() == [64 + slot]
    t = t0 + np.array([-900.0, -300.0, 0.0, 300.0, 900.0])
    ours = eph.sat_ecef_m(t)[:, 0]
    sgp4 = glo.sat_ecef_m(t)[:, k]
    err = np.linalg.norm(ours - sgp4, axis=-1)
    assert err[2] < 0.01 and err.max() < 5.0, err
    # beyond half an hour a record no longer serves
    assert np.isnan(eph.sat_ecef_m(np.array([t0 + 2400.0]))).all()
