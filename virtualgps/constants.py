"""Physical and geodetic constants, each with its unit in the name and its source."""

# WGS-84 ellipsoid, NIMA TR8350.2 (3rd ed., 2000), Table 3.1.
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared
WGS84_EP2 = WGS84_E2 / (1.0 - WGS84_E2)  # second eccentricity squared

# Earth rotation rate, IS-GPS-200 section 20.3.3.4.3 (OMEGA_dot_e).
OMEGA_EARTH_RAD_S = 7.2921151467e-5

# Speed of light, IS-GPS-200 (defined value).
C_MPS = 299792458.0

# GPS L1 carrier, IS-GPS-200 section 3.3.1.1.
GPS_L1_HZ = 1575.42e6

# Time.
DAY_S = 86400.0
# Sidereal day (mean, 1982 IAU): 23 h 56 min 4.0905 s. GPS orbits repeat their ground track
# (and so the sky seen from a fixed site) about every sidereal day (2 revolutions).
SIDEREAL_DAY_S = 86164.0905
UNIX_EPOCH_JD = 2440587.5  # Julian date of 1970-01-01T00:00:00 UTC
J2000_JD = 2451545.0

# The paper's flat-earth conversion uses one surface distance per degree. We take the WGS-84
# equatorial circumference / 360 (111,319.49 m per degree), a sphere of radius WGS84_A_M.
FLAT_EARTH_M_PER_DEG = 2.0 * 3.141592653589793 * WGS84_A_M / 360.0
