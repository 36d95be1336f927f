"""Geodesy against pymap3d (an independent implementation), including the poles and +-180 deg,
and the paper's flat-earth conversion with its pole and antimeridian handling."""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest

from virtualgps import geodesy

ONE_MM = 1e-3
ONE_MICRO_DEG = 1e-6

# Edge-case table: poles, equator, both sides of the antimeridian, below the ellipsoid, GPS orbit.
LAT = np.array([0.0, 90.0, -90.0, 52.14, -33.9, 0.0, 0.0, 89.999, 45.0, 10.0])
LON = np.array([0.0, 0.0, 123.0, 11.64, 151.2, 180.0, -179.999, 179.999, -93.2, 45.0])
ALT = np.array([0.0, 100.0, -20.0, 55.0, 3000.0, 0.0, 1.0, 0.0, -500.0, 20_200e3])


def test_geodetic_to_ecef_matches_pymap3d():
    ours = geodesy.geodetic_to_ecef(LAT, LON, ALT)
    ref = np.stack(pymap3d.geodetic2ecef(LAT, LON, ALT), axis=-1)
    np.testing.assert_allclose(ours, ref, atol=ONE_MM)


def test_ecef_to_geodetic_matches_pymap3d_and_round_trips():
    ecef = np.stack(pymap3d.geodetic2ecef(LAT, LON, ALT), axis=-1)
    lat, lon, alt = geodesy.ecef_to_geodetic(ecef)
    ref_lat, ref_lon, ref_alt = pymap3d.ecef2geodetic(ecef[:, 0], ecef[:, 1], ecef[:, 2])
    # pymap3d's own iteration is good to ~1e-6 deg at GPS altitude; ours round-trips exactly.
    np.testing.assert_allclose(lat, ref_lat, atol=2 * ONE_MICRO_DEG)
    np.testing.assert_allclose(lat, LAT, atol=1e-9)
    np.testing.assert_allclose(alt, ref_alt, atol=ONE_MM)
    np.testing.assert_allclose(alt, ALT, atol=ONE_MM)
    # Longitude is undefined at the poles; elsewhere compare on the circle.
    off_pole = np.abs(LAT) < 90
    dlon = geodesy.wrap_lon_deg(lon - np.asarray(ref_lon))[off_pole]
    np.testing.assert_allclose(dlon, 0.0, atol=ONE_MICRO_DEG * 1e-3)


def test_enu_and_azel_match_pymap3d():
    rng = np.random.default_rng(1)
    target_ecef = geodesy.geodetic_to_ecef(
        rng.uniform(-90, 90, 50), rng.uniform(-180, 180, 50), rng.uniform(0, 2e7, 50)
    )
    for lat0, lon0, h0 in [
        (90.0, 0.0, 0.0),
        (-90.0, 45.0, 10.0),
        (0.0, 180.0, 0.0),
        (52.1, 11.6, 55.0),
    ]:
        enu = geodesy.ecef_to_enu(target_ecef, lat0, lon0, h0)
        ref = np.stack(pymap3d.ecef2enu(*target_ecef.T, lat0, lon0, h0), axis=-1)
        np.testing.assert_allclose(enu, ref, atol=ONE_MM * 10)
        az, el, rng_m = geodesy.enu_to_azel(enu)
        raz, rel, rrng = pymap3d.enu2aer(*ref.T)
        # Azimuth compared on the circle, scaled by cos(el) (it is degenerate at the zenith).
        daz = geodesy.wrap_lon_deg(az - raz) * np.cos(np.radians(el))
        np.testing.assert_allclose(daz, 0.0, atol=1e-7)
        np.testing.assert_allclose(el, rel, atol=1e-7)
        np.testing.assert_allclose(rng_m, rrng, atol=ONE_MM * 10)
        back = geodesy.enu_to_ecef(enu, lat0, lon0, h0)
        np.testing.assert_allclose(back, target_ecef, atol=ONE_MM * 10)


def test_arrays_broadcast_over_leading_axes():
    ecef = geodesy.geodetic_to_ecef(np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((4, 3)))
    assert ecef.shape == (4, 3, 3)
    lat, lon, h = geodesy.ecef_to_geodetic(ecef)
    assert lat.shape == (4, 3)


def test_teme_to_ecef_is_a_z_rotation_by_gmst():
    # At any time, TEME->ECEF preserves the z component and the norm, and rotates by -GMST.
    t = np.array([0.0, 1.49e9, 1.7e9])
    r = np.array([[7000e3, 0.0, 1000e3]] * 3)
    ecef, _ = geodesy.teme_to_ecef(r, t)
    np.testing.assert_allclose(ecef[:, 2], 1000e3)
    np.testing.assert_allclose(np.linalg.norm(ecef, axis=-1), np.linalg.norm(r, axis=-1))
    ang = np.arctan2(ecef[:, 1], ecef[:, 0])
    np.testing.assert_allclose(np.cos(ang + geodesy.gmst82_rad(t)), 1.0, atol=1e-12)


def test_gmst_at_j2000_matches_the_almanac_value():
    # GMST at 2000-01-01 12:00 UT1 is 18h 41m 50.54841s = 280.46061837 deg (the constant term).
    t_j2000_unix_s = (2451545.0 - 2440587.5) * 86400.0
    assert np.degrees(geodesy.gmst82_rad(t_j2000_unix_s)) == pytest.approx(280.46061837, abs=1e-6)


def test_geoid_grid_matches_the_full_15_minute_grid():
    """The bundled 30' grid against PROJ's 15' EGM96 grid (Debian proj-data), where installed;
    under CI (``CI`` set) the reference must be there (tools/test.sh installs it)."""
    import os
    import struct
    from pathlib import Path

    gtx = Path("/usr/share/proj/egm96_15.gtx")
    if not gtx.exists():
        if os.environ.get("CI"):
            pytest.fail(f"{gtx} is missing: install Debian's proj-data (tools/test.sh does)")
        pytest.skip("proj-data's egm96_15.gtx not installed")
    raw = gtx.read_bytes()
    _, _, _, _, rows, cols = struct.unpack(">4d2i", raw[:40])
    full = np.frombuffer(raw[40:], dtype=">f4").reshape(rows, cols)
    # Nodes of the 15' grid that lie between our 30' nodes: bilinear error stays small.
    iy, ix = np.meshgrid(np.arange(1, rows - 1, 7), np.arange(1, cols, 7), indexing="ij")
    lat = -90.0 + 0.25 * iy
    lon = -180.0 + 0.25 * ix
    err = geodesy.geoid_sep_m(lat, lon) - full[iy, ix]
    assert np.sqrt(np.mean(err**2)) < 0.5
    assert np.max(np.abs(err)) < 6.0


def test_offset_geodetic_matches_pymap3d_enu2geodetic():
    lat, lon = geodesy.offset_geodetic_deg(52.0, 179.9999, 100.0, 30.0, -40.0)
    rlat, rlon, _ = pymap3d.enu2geodetic(30.0, -40.0, 0.0, 52.0, 179.9999, 100.0)
    assert lat == pytest.approx(rlat, abs=1e-8)
    assert geodesy.wrap_lon_deg(lon - rlon) == pytest.approx(0.0, abs=1e-8)
    assert -180.0 <= lon < 180.0


def test_flat_earth_pole_crossing_decreases_latitude_and_flips_longitude():
    # Start 1 km south of the north pole and drive 3 km north along the map's X (north) axis.
    lat0 = 90.0 - 1000.0 / 111_319.49
    north_m = np.linspace(0.0, 3000.0, 31)
    lat, lon = geodesy.flat_earth_to_geodetic(np.zeros_like(north_m), north_m, lat0, 20.0)
    peak = np.argmax(lat)
    assert lat[peak] == pytest.approx(90.0, abs=1e-6)
    assert np.all(np.diff(lat[: peak + 1]) > 0) and np.all(np.diff(lat[peak + 1 :]) < 0)
    assert np.all(lon[:peak] == pytest.approx(20.0))
    assert np.all(lon[peak + 1 :] == pytest.approx(-160.0))  # jumped by 180 deg
    # 3 km of driving: 1 km up to the pole, then 2 km south of it on the other side.
    assert lat[-1] == pytest.approx(90.0 - 2000.0 / 111_319.49, abs=1e-9)


def test_flat_earth_south_pole_and_antimeridian_wrap():
    lat, lon = geodesy.flat_earth_to_geodetic(0.0, -2000.0, -89.99, 10.0)
    assert lat > -90.0 and lon == pytest.approx(-170.0)
    # Driving east across 180 deg wraps to -180.
    east = np.array([0.0, 5000.0, 20000.0])
    lat, lon = geodesy.flat_earth_to_geodetic(east, 0.0, 0.0, 179.95)
    assert lon[0] == pytest.approx(179.95)
    assert lon[1] == pytest.approx(179.95 + 5000 / 111_319.49, abs=1e-9) or lon[1] < 0
    assert lon[2] == pytest.approx(179.95 + 20000 / 111_319.49 - 360.0, abs=1e-8)
    assert np.all((lon >= -180.0) & (lon < 180.0))


def test_flat_earth_scale_is_the_papers_surface_distance_per_degree():
    lat, lon = geodesy.flat_earth_to_geodetic(
        111_319.49 * np.cos(np.radians(60.0)), 111_319.49, 60.0, 0.0
    )
    assert lat == pytest.approx(61.0, abs=1e-7)
    assert lon == pytest.approx(1.0, abs=1e-7)
