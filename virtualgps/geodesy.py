"""Geodesy: WGS-84 geodetic <-> ECEF <-> ENU, azimuth/elevation, TEME -> ECEF, geoid separation,
and the paper's flat-earth conversion.

Every function takes scalars or arrays and broadcasts over leading axes; vectors have xyz on the
last axis, ``(..., 3)``. Angles in degrees unless the name says ``_rad``.

Accepted approximations (with their size):
- UT1 is taken equal to UTC (|UT1-UTC| < 0.9 s): moves a GPS satellite by up to ~1.7 km along its
  ECEF track, i.e. ~0.004 deg as seen from the ground.
- TEME -> ECEF ignores polar motion (< 0.5 arcsec, ~15 m at the Earth's surface, ~0.00004 deg on
  a GPS satellite as seen from the ground); the same choice as Vallado's ``teme2ecef`` with
  xp = yp = 0.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

import numpy as np
from numpy.typing import ArrayLike, NDArray

from virtualgps.constants import (
    DAY_S,
    FLAT_EARTH_M_PER_DEG,
    J2000_JD,
    OMEGA_EARTH_RAD_S,
    UNIX_EPOCH_JD,
    WGS84_A_M,
    WGS84_B_M,
    WGS84_E2,
    WGS84_EP2,
)

F64 = NDArray[np.float64]


def geodetic_to_ecef(lat_deg: ArrayLike, lon_deg: ArrayLike, alt_hae_m: ArrayLike) -> F64:
    """Convert WGS-84 geodetic coordinates to ECEF.

    Parameters
    ----------
    lat_deg, lon_deg : (...) float, degrees
    alt_hae_m : (...) float, metres above the ellipsoid

    Returns
    -------
    ecef_m : (..., 3) float, metres, ECEF
    """
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    h = np.asarray(alt_hae_m, dtype=float)
    sin_lat, cos_lat = np.sin(lat), np.cos(lat)
    n_m = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)  # prime-vertical radius
    x = (n_m + h) * cos_lat * np.cos(lon)
    y = (n_m + h) * cos_lat * np.sin(lon)
    z = (n_m * (1.0 - WGS84_E2) + h) * sin_lat
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(ecef_m: ArrayLike) -> tuple[F64, F64, F64]:
    """Convert ECEF to WGS-84 geodetic coordinates.

    Bowring's parametric-latitude iteration (Bowring 1976), three passes: better than 1e-9 m
    between the Earth's surface and GPS orbit. Exact at the poles (height from the formula
    h = p cos(lat) + z sin(lat) - a sqrt(1 - e2 sin^2 lat), which has no 1/cos(lat)).

    Parameters
    ----------
    ecef_m : (..., 3) float, metres, ECEF

    Returns
    -------
    lat_deg, lon_deg, alt_hae_m : (...) float; lon in [-180, 180]
    """
    r = np.asarray(ecef_m, dtype=float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    beta = np.arctan2(z * WGS84_A_M, p * WGS84_B_M)  # parametric latitude, first guess
    for _ in range(3):
        lat = np.arctan2(
            z + WGS84_EP2 * WGS84_B_M * np.sin(beta) ** 3,
            p - WGS84_E2 * WGS84_A_M * np.cos(beta) ** 3,
        )
        beta = np.arctan2(WGS84_B_M * np.sin(lat), WGS84_A_M * np.cos(lat))
    sin_lat = np.sin(lat)
    h = p * np.cos(lat) + z * sin_lat - WGS84_A_M * np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    return np.degrees(lat), np.degrees(lon), h


def ecef_to_enu_matrix(lat_deg: ArrayLike, lon_deg: ArrayLike) -> F64:
    """Rotation from ECEF to the local East/North/Up frame at a geodetic point.

    Parameters
    ----------
    lat_deg, lon_deg : (...) float, degrees

    Returns
    -------
    rot : (..., 3, 3) float; rows are the E, N, U unit vectors in ECEF, so
        ``enu = rot @ ecef_vector``.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    rot = np.zeros(np.broadcast_shapes(lat.shape, lon.shape) + (3, 3))
    rot[..., 0, 0], rot[..., 0, 1] = -so, co  # East
    rot[..., 1, 0], rot[..., 1, 1], rot[..., 1, 2] = -sl * co, -sl * so, cl  # North
    rot[..., 2, 0], rot[..., 2, 1], rot[..., 2, 2] = cl * co, cl * so, sl  # Up
    return rot


def ecef_to_enu(
    ecef_m: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, alt0_hae_m: ArrayLike
) -> F64:
    """Express ECEF points in the ENU frame of a geodetic origin.

    Parameters
    ----------
    ecef_m : (..., 3) float, metres, ECEF
    lat0_deg, lon0_deg, alt0_hae_m : (...) float, the origin (broadcast against ``ecef_m[..., 0]``)

    Returns
    -------
    enu_m : (..., 3) float, metres, ENU at the origin
    """
    origin = geodetic_to_ecef(lat0_deg, lon0_deg, alt0_hae_m)
    rot = ecef_to_enu_matrix(lat0_deg, lon0_deg)
    d = np.asarray(ecef_m, dtype=float) - origin
    return np.einsum("...ij,...j->...i", rot, d)


def enu_to_ecef(
    enu_m: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, alt0_hae_m: ArrayLike
) -> F64:
    """Inverse of :func:`ecef_to_enu`.

    Parameters
    ----------
    enu_m : (..., 3) float, metres, ENU at the origin
    lat0_deg, lon0_deg, alt0_hae_m : (...) float, the origin

    Returns
    -------
    ecef_m : (..., 3) float, metres, ECEF
    """
    origin = geodetic_to_ecef(lat0_deg, lon0_deg, alt0_hae_m)
    rot = ecef_to_enu_matrix(lat0_deg, lon0_deg)
    return origin + np.einsum("...ji,...j->...i", rot, np.asarray(enu_m, dtype=float))


def enu_to_geodetic(
    enu_m: ArrayLike, lat0_deg: float, lon0_deg: float, alt0_hae_m: float
) -> tuple[F64, F64, F64]:
    """Geodetic coordinates of points given in the ENU frame of an origin (exact, WGS-84).

    Parameters
    ----------
    enu_m : (..., 3) float, metres, ENU at the origin
    lat0_deg, lon0_deg, alt0_hae_m : float, the origin

    Returns
    -------
    lat_deg, lon_deg, alt_hae_m : (...) float
    """
    return ecef_to_geodetic(enu_to_ecef(enu_m, lat0_deg, lon0_deg, alt0_hae_m))


def enu_to_azel(enu_m: ArrayLike) -> tuple[F64, F64, F64]:
    """Azimuth, elevation and range of ENU vectors.

    Parameters
    ----------
    enu_m : (..., 3) float, metres

    Returns
    -------
    az_deg : (...) float, degrees clockwise from north, in [0, 360)
    el_deg : (...) float, degrees above the horizon, in [-90, 90]
    range_m : (...) float, metres
    """
    v = np.asarray(enu_m, dtype=float)
    e, n, u = v[..., 0], v[..., 1], v[..., 2]
    horiz = np.hypot(e, n)
    az = np.degrees(np.arctan2(e, n)) % 360.0
    el = np.degrees(np.arctan2(u, horiz))
    return az, el, np.sqrt(horiz**2 + u**2)


def azel_to_enu_unit(az_deg: ArrayLike, el_deg: ArrayLike) -> F64:
    """Unit ENU direction vectors of azimuths and elevations.

    Parameters
    ----------
    az_deg, el_deg : (...) float, degrees

    Returns
    -------
    unit_enu : (..., 3) float
    """
    az = np.radians(np.asarray(az_deg, dtype=float))
    el = np.radians(np.asarray(el_deg, dtype=float))
    ce = np.cos(el)
    return np.stack(np.broadcast_arrays(ce * np.sin(az), ce * np.cos(az), np.sin(el)), axis=-1)


def unix_to_jd(t_unix_s: ArrayLike) -> tuple[F64, F64]:
    """Split Julian date (whole day at noon boundary + fraction) of UTC Unix seconds.

    Splitting keeps ~microsecond resolution in float64, the form sgp4 wants.

    Parameters
    ----------
    t_unix_s : (...) float, seconds since 1970-01-01 UTC

    Returns
    -------
    jd, fr : (...) float, days; jd + fr is the Julian date (UTC, taken as UT1)
    """
    t = np.asarray(t_unix_s, dtype=float)
    days = np.floor(t / DAY_S)
    fr = (t - days * DAY_S) / DAY_S
    return days + UNIX_EPOCH_JD, fr


def gmst82_rad(t_unix_s: ArrayLike) -> F64:
    """Greenwich mean sidereal time, IAU 1982 (the angle SGP4's TEME frame expects).

    Vallado, Crawford, Hujsak & Kelso, "Revisiting Spacetrack Report #3" (AIAA 2006-6753), eq. for
    GMST: 67310.54841 s + (876600 h + 8640184.812866 s) T + 0.093104 s T^2 - 6.2e-6 s T^3.

    Parameters
    ----------
    t_unix_s : (...) float, UTC seconds (taken as UT1)

    Returns
    -------
    gmst_rad : (...) float, radians in [0, 2 pi)
    """
    jd, fr = unix_to_jd(t_unix_s)
    t_cent = ((jd - J2000_JD) + fr) / 36525.0
    gmst_s = (
        67310.54841
        + (876600.0 * 3600.0 + 8640184.812866) * t_cent
        + 0.093104 * t_cent**2
        - 6.2e-6 * t_cent**3
    )
    return np.radians((gmst_s % DAY_S) / 240.0) % (2.0 * np.pi)


def teme_to_ecef(
    r_teme_m: ArrayLike, t_unix_s: ArrayLike, v_teme_mps: ArrayLike | None = None
) -> tuple[F64, F64 | None]:
    """Rotate SGP4 TEME positions (and velocities) to ECEF by GMST-1982 (no polar motion).

    Parameters
    ----------
    r_teme_m : (..., 3) float, metres, TEME
    t_unix_s : (...) float, UTC seconds, broadcast against ``r_teme_m[..., 0]``
    v_teme_mps : (..., 3) float, metres per second, TEME, optional

    Returns
    -------
    r_ecef_m : (..., 3) float, metres, ECEF
    v_ecef_mps : (..., 3) float, metres per second, ECEF (Earth-fixed velocity), or None
    """
    theta = gmst82_rad(t_unix_s)
    c, s = np.cos(theta), np.sin(theta)
    r = np.asarray(r_teme_m, dtype=float)
    x = c * r[..., 0] + s * r[..., 1]
    y = -s * r[..., 0] + c * r[..., 1]
    r_ecef = np.stack(np.broadcast_arrays(x, y, r[..., 2]), axis=-1)
    if v_teme_mps is None:
        return r_ecef, None
    v = np.asarray(v_teme_mps, dtype=float)
    vx = c * v[..., 0] + s * v[..., 1] + OMEGA_EARTH_RAD_S * y
    vy = -s * v[..., 0] + c * v[..., 1] - OMEGA_EARTH_RAD_S * x
    return r_ecef, np.stack(np.broadcast_arrays(vx, vy, v[..., 2]), axis=-1)


def radii_of_curvature_m(lat_deg: ArrayLike) -> tuple[F64, F64]:
    """Meridian (M) and prime-vertical (N) radii of curvature of WGS-84.

    Parameters
    ----------
    lat_deg : (...) float, degrees

    Returns
    -------
    m_m, n_m : (...) float, metres. A northward step of d metres changes the latitude by
        d / (M + h) radians; an eastward one the longitude by d / ((N + h) cos(lat)).
    """
    s2 = np.sin(np.radians(np.asarray(lat_deg, dtype=float))) ** 2
    w = np.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w


def offset_geodetic_deg(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    alt_hae_m: ArrayLike,
    east_m: ArrayLike,
    north_m: ArrayLike,
) -> tuple[F64, F64]:
    """Move a geodetic point by small east/north offsets (first order, WGS-84 radii).

    Good to ~1e-6 relative for offsets of tens of metres (the second-order term is d^2/R).

    Parameters
    ----------
    lat_deg, lon_deg, alt_hae_m : (...) float
    east_m, north_m : (...) float, metres

    Returns
    -------
    lat_deg, lon_deg : (...) float; lon wrapped to [-180, 180)
    """
    m_m, n_m = radii_of_curvature_m(lat_deg)
    h = np.asarray(alt_hae_m, dtype=float)
    lat = np.asarray(lat_deg, dtype=float)
    dlat = np.degrees(np.asarray(north_m, dtype=float) / (m_m + h))
    coslat = np.maximum(np.cos(np.radians(lat)), 1e-12)
    dlon = np.degrees(np.asarray(east_m, dtype=float) / ((n_m + h) * coslat))
    return lat + dlat, wrap_lon_deg(np.asarray(lon_deg, dtype=float) + dlon)


def wrap_lon_deg(lon_deg: ArrayLike) -> F64:
    """Wrap longitudes to [-180, 180).

    Parameters
    ----------
    lon_deg : (...) float, degrees

    Returns
    -------
    lon_deg : (...) float, degrees in [-180, 180)
    """
    return (np.asarray(lon_deg, dtype=float) + 180.0) % 360.0 - 180.0


def flat_earth_to_geodetic(
    east_m: ArrayLike, north_m: ArrayLike, lat0_deg: float, lon0_deg: float
) -> tuple[F64, F64]:
    """The paper's flat-earth conversion of map offsets to latitude/longitude, with its wraps.

    The seed paper (USARSim GPS, section 2.3 and Fig. 3) converts metres to degrees with one
    surface distance per degree, X -> latitude and Y -> longitude, and handles the singularities:
    driving north past 90 deg N the latitude decreases again and the longitude jumps by 180 deg;
    longitudes wrap at +-180 deg. We use ``FLAT_EARTH_M_PER_DEG`` (111,319.49 m) per degree of
    latitude and that times cos(lat0) per degree of longitude (the map is flat: one scale over
    the whole map, taken at the georeference point).

    Parameters
    ----------
    east_m, north_m : (...) float, metres from the georeference point
    lat0_deg, lon0_deg : float, the georeference point

    Returns
    -------
    lat_deg, lon_deg : (...) float; lat in [-90, 90], lon in [-180, 180)
    """
    lat = lat0_deg + np.asarray(north_m, dtype=float) / FLAT_EARTH_M_PER_DEG
    coslat0 = max(np.cos(np.radians(lat0_deg)), 1e-12)
    lon = lon0_deg + np.asarray(east_m, dtype=float) / (FLAT_EARTH_M_PER_DEG * coslat0)
    return fold_pole_deg(lat, lon)


def fold_pole_deg(lat_deg: ArrayLike, lon_deg: ArrayLike) -> tuple[F64, F64]:
    """Fold latitudes that ran past a pole back into [-90, 90], flipping longitude by 180 deg.

    Parameters
    ----------
    lat_deg, lon_deg : (...) float, degrees; lat may be any real number

    Returns
    -------
    lat_deg, lon_deg : (...) float; lat in [-90, 90], lon in [-180, 180)
    """
    lat = (np.asarray(lat_deg, dtype=float) + 90.0) % 360.0 - 90.0  # in [-90, 270)
    over = lat > 90.0
    lat = np.where(over, 180.0 - lat, lat)
    lon = np.asarray(lon_deg, dtype=float) + np.where(over, 180.0, 0.0)
    return lat, wrap_lon_deg(lon)


def flat_earth_offset_deg(
    lat_deg: ArrayLike, lon_deg: ArrayLike, east_m: ArrayLike, north_m: ArrayLike
) -> tuple[F64, F64]:
    """Add east/north noise in metres to a position with the paper's flat-earth scale.

    Parameters
    ----------
    lat_deg, lon_deg : (...) float, degrees
    east_m, north_m : (...) float, metres

    Returns
    -------
    lat_deg, lon_deg : (...) float, folded at the poles and wrapped at +-180 deg
    """
    lat = np.asarray(lat_deg, dtype=float)
    coslat = np.maximum(np.cos(np.radians(lat)), 1e-12)
    return fold_pole_deg(
        lat + np.asarray(north_m, dtype=float) / FLAT_EARTH_M_PER_DEG,
        np.asarray(lon_deg, dtype=float)
        + np.asarray(east_m, dtype=float) / (FLAT_EARTH_M_PER_DEG * coslat),
    )


@lru_cache(maxsize=1)
def _geoid_grid() -> tuple[np.ndarray, float]:
    """Load the bundled EGM96 geoid grid: (rows lat -90..90, cols lon -180..180] , step_deg."""
    with resources.files("virtualgps").joinpath("data/egm96-30min.npz").open("rb") as f:
        z = np.load(f)
        grid_m = z["geoid_cm"].astype(np.float64) / 100.0
        step_deg = float(z["step_deg"])
    return grid_m, step_deg


def geoid_sep_m(lat_deg: ArrayLike, lon_deg: ArrayLike) -> F64:
    """EGM96 geoid height above the WGS-84 ellipsoid (N = h_ellipsoid - h_msl).

    Bilinear interpolation of a 30' grid downsampled from NGA's EGM96 15' grid (as shipped by
    PROJ, ``egm96_15.gtx``; see ``virtualgps/data/README.md``). Differs from interpolating the
    15' grid by < 0.5 m RMS (worst ~2 m in the Himalaya/Andes), below a consumer receiver's noise.

    Parameters
    ----------
    lat_deg, lon_deg : (...) float, degrees

    Returns
    -------
    geoid_sep_m : (...) float, metres
    """
    grid, step = _geoid_grid()
    n_rows, n_cols = grid.shape  # n_cols covers 360 deg without the duplicate column
    lat = np.clip(np.asarray(lat_deg, dtype=float), -90.0, 90.0)
    lon = np.asarray(lon_deg, dtype=float)
    fy = (lat + 90.0) / step
    fx = ((lon + 180.0) % 360.0) / step
    y0 = np.clip(np.floor(fy).astype(int), 0, n_rows - 2)
    x0 = np.floor(fx).astype(int) % n_cols
    x1 = (x0 + 1) % n_cols
    wy = fy - y0
    wx = fx - np.floor(fx)
    g00, g01 = grid[y0, x0], grid[y0, x1]
    g10, g11 = grid[y0 + 1, x0], grid[y0 + 1, x1]
    return (g00 * (1 - wx) + g01 * wx) * (1 - wy) + (g10 * (1 - wx) + g11 * wx) * wy
