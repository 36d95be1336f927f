"""Rebuild tests/data/skyfield_azel.csv: skyfield's azimuth/elevation of every satellite of each
bundled TLE set (GPS, and the GLONASS and Galileo sets of 2017-03-28) and of three BeiDou
satellites of chosen elements (tests/data/beidou-synthetic-2017-03-28.tle, written here: no
BeiDou set is at hand), at a table of sites and times, as an independent reference for
virtualgps.sky.ephemeris + virtualgps.geodesy.

Usage: python tools/make_skyfield_refs.py [--out tests/data/skyfield_azel.csv]

Needs skyfield (pip install 'virtualgps[tools]'); the tests read the CSV and never import it.
The TLE files are parsed here on their own (name line -> PRN, two element lines -> skyfield's
EarthSatellite), not with virtualgps, so the reference does not share our parser.

skyfield differences from virtualgps that the tests tolerate (both < 0.01 deg from the ground):
skyfield uses UT1 from its bundled IERS table (|UT1 - UTC| < 0.9 s; virtualgps takes UT1 = UTC),
and goes TEME -> ITRS -> GCRS -> topocentric with IAU 2000 precession-nutation, where virtualgps
goes TEME -> ECEF by GMST-1982 only. No refraction, geometric positions (no light time), as
``(satellite - site).at(t).altaz()`` gives.
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import re
from pathlib import Path

import numpy as np
from skyfield.api import EarthSatellite, load, wgs84

REPO = Path(__file__).resolve().parents[1]
TLE_FILES = ["gps-ops-2017-03-26.tle", "gps-ops-2017-03-28.tle", "gps-ops-2020-05-14T22Z.tle",
             "glo-ops-2017-03-28.tle", "galileo-2017-03-28.tle"]

# (label, lat_deg, lon_deg, alt_hae_m): the poles, the equator on both sides of the antimeridian,
# the cities of the real logs, and one high site.
SITES = [
    ("north_pole", 90.0, 0.0, 0.0),
    ("south_pole", -90.0, 0.0, 2835.0),
    ("equator_lon0", 0.0, 0.0, 0.0),
    ("equator_lon180", 0.0, 180.0, 0.0),
    ("equator_lon-179.99", 0.0, -179.99, 0.0),
    ("magdeburg", 52.14, 11.64, 100.0),
    ("minneapolis", 44.98, -93.24, 227.0),
    ("mountain_view", 37.42, -122.08, 0.0),
    ("la_paz_3000m", -16.5, -68.15, 3000.0),
]
# Offsets from each set's median TLE epoch, seconds: spread over +-2 days, not round numbers.
OFFSETS_S = [
    -2 * 86400.0 + 1234.5,
    -0.7 * 86400.0,
    3600.0 * 5 + 17.25,
    1.1 * 86400.0,
    2 * 86400.0 - 777.0,
]
# Rows are kept down to this elevation (the tests compare satellites above -5 deg).
MIN_EL_DEG = -10.0

_PRN = re.compile(r"PRN\s*0*(\d+)\)", re.IGNORECASE)


def read_three_line(path: Path) -> list[tuple[int, int, str, str]]:
    """(prn, norad, line1, line2) of a 3-line TLE file; prn 0 where the name carries no GPS
    '(PRN nn)' (GLONASS, Galileo: the tests find those satellites by NORAD number, so the
    reference does not depend on our slot table)."""
    lines = [s.rstrip() for s in path.read_text(encoding="ascii").splitlines() if s.strip()]
    out = []
    for k in range(0, len(lines), 3):
        name, l1, l2 = lines[k : k + 3]
        m = _PRN.search(name)
        out.append((int(m.group(1)) if m else 0, int(l1[2:7]), l1, l2))
    return out


# BeiDou: no TLE set of its group is at hand (none in ../shared/data, none bundled, no network
# at test time), so three satellites with BeiDou's three orbit types are written from chosen
# elements, named as CelesTrak names BeiDou satellites: a MEO (C19, 55 deg, 1.8623 rev/day,
# ~21,500 km up), an IGSO (C38, 55 deg, geosynchronous) and a GEO (C01, over 140 E). They test
# the path from a BeiDou TLE name to its number and its az/el (against skyfield), not orbits.
BEIDOU_SYNTHETIC = "beidou-synthetic-2017-03-28.tle"
_BEIDOU_ELEMENTS = [  # (name, norad, incl_deg, raan_deg, ecc, argp_deg, mean_anom_deg, rev_day)
    ("BEIDOU-3 M1 (C19)", 90019, 55.0, 120.0, 0.0005, 30.0, 200.0, 1.86231000),
    ("BEIDOU-3 IGSO-1 (C38)", 90038, 55.0, 20.0, 0.0020, 180.0, 90.0, 1.00270000),
    ("BEIDOU-2 G1 (C01)", 90001, 0.5, 80.0, 0.0002, 10.0, 56.1, 1.00271000),
]


def _tle_checksum(line: str) -> int:
    return sum(int(ch) if ch.isdigit() else 1 if ch == "-" else 0 for ch in line) % 10


def beidou_synthetic_tle(epoch_yyddd: str = "17087.50000000") -> str:
    """Three-line TLEs of :data:`_BEIDOU_ELEMENTS` at ``epoch_yyddd`` (2017-03-28 12:00 UTC).
    The GEO's mean anomaly puts it over 140 deg E at the epoch (its right ascension of the
    ascending node plus argument of perigee plus mean anomaly minus GMST)."""
    out = []
    for name, norad, incl, raan, ecc, argp, ma, n in _BEIDOU_ELEMENTS:
        l1 = (f"1 {norad:05d}U 17001A   {epoch_yyddd}  .00000000  00000-0  00000-0 0  999")
        l2 = (f"2 {norad:05d} {incl:8.4f} {raan:8.4f} {round(ecc * 1e7):07d} {argp:8.4f} "
              f"{ma:8.4f} {n:11.8f}    1")
        out += [name, l1 + str(_tle_checksum(l1)), l2 + str(_tle_checksum(l2))]
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "tests" / "data" / "skyfield_azel.csv")
    args = ap.parse_args()
    ts = load.timescale()  # bundled UT1/leap-second tables; no download
    rows = []
    synthetic = REPO / "tests" / "data" / BEIDOU_SYNTHETIC
    synthetic.write_text(beidou_synthetic_tle(), encoding="ascii")
    for tle_name in [*TLE_FILES, BEIDOU_SYNTHETIC]:
        folder = synthetic.parent if tle_name == BEIDOU_SYNTHETIC else REPO / "ephemeris"
        sats = read_three_line(folder / tle_name)
        sky_sats = [((prn, norad), EarthSatellite(l1, l2, str(norad), ts))
                    for prn, norad, l1, l2 in sats]
        epochs = np.array([s.epoch.utc_datetime().timestamp() for _, s in sky_sats])
        center_unix_s = float(np.median(epochs))
        t_unix_s = [round(center_unix_s + off, 3) for off in OFFSETS_S]
        times = ts.from_datetimes([dt.datetime.fromtimestamp(t, dt.UTC) for t in t_unix_s])
        for _label, lat, lon, alt in SITES:
            site = wgs84.latlon(lat, lon, elevation_m=alt)
            for (prn, norad), sat in sky_sats:
                alt_angle, az_angle, _ = (sat - site).at(times).altaz()
                for t, az, el in zip(t_unix_s, az_angle.degrees, alt_angle.degrees, strict=True):
                    if el >= MIN_EL_DEG:
                        rows.append(
                            (tle_name, lat, lon, alt, f"{t:.3f}", prn, norad, f"{az:.6f}",
                             f"{el:.6f}")
                        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(
            ["tle_file", "lat_deg", "lon_deg", "alt_m", "t_unix_s", "prn", "norad", "az_deg",
             "el_deg"]
        )
        w.writerows(rows)
    print(f"wrote {len(rows)} rows to {args.out}")


if __name__ == "__main__":
    main()
