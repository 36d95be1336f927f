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
