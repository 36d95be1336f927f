"""Records passed between the pure core and the NMEA/I-O shell.

A :class:`Fixes` value holds a batch of epochs for one receiver (the daemon makes batches of one,
replay and the gap tool batches of thousands). Arrays only; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# GGA fix quality (NMEA 0183 v2.3): 0 invalid, 1 GPS (SPS), 2 differential (SBAS/DGPS).
QUALITY_NONE, QUALITY_GPS, QUALITY_DGPS = 0, 1, 2
# GSA navigation mode: 1 no fix, 2 2D, 3 3D.
MODE_NONE, MODE_2D, MODE_3D = 1, 2, 3


@dataclass(frozen=True)
class Fixes:
    """What the receiver reports at each of ``n_t`` epochs, over ``n_sat`` satellites.

    Attributes
    ----------
    t_unix_s : (n_t,) float64, the epoch's UTC time (simulated clock); NMEA times come from it
    lat_deg, lon_deg : (n_t,) float64, degrees, WGS-84; NaN without a fix
    alt_msl_m : (n_t,) float64, metres above mean sea level (EGM96); NaN without a fix
    geoid_sep_m : (n_t,) float64, metres, EGM96 geoid height above the ellipsoid at the fix
    quality : (n_t,) int8, GGA quality (QUALITY_*)
    mode : (n_t,) int8, GSA mode (MODE_*)
    hdop, vdop, pdop : (n_t,) float64, dilutions of precision of the used satellites; NaN if none
    speed_mps : (n_t,) float64, metres per second over ground; NaN without a fix
    course_deg : (n_t,) float64, degrees true, in [0, 360); NaN without a fix
    prn : (n_sat,) int, satellite PRNs (the columns of the per-satellite arrays)
    az_deg, el_deg : (n_t, n_sat) float64, degrees; NaN where not known
    cn0_dbhz : (n_t, n_sat) float64, dB-Hz; NaN where the satellite is not tracked
    in_view : (n_t, n_sat) bool, listed in GSV (above the horizon)
    used : (n_t, n_sat) bool, used in the fix (at most 12 per epoch)
    truth_lat_deg, truth_lon_deg, truth_alt_hae_m : (n_t,) float64, the antenna's true position
        (NaN where there was no pose)
    sigma_enu_m : (n_t, 3) float64, metres, the receiver's own 1-sigma estimate of its east,
        north and up error (for GST), or None; NaN where it has none
    range_rms_m : (n_t,) float64, metres, RMS of the used satellites' range error sigmas, or None
    """

    t_unix_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_msl_m: np.ndarray
    geoid_sep_m: np.ndarray
    quality: np.ndarray
    mode: np.ndarray
    hdop: np.ndarray
    vdop: np.ndarray
    pdop: np.ndarray
    speed_mps: np.ndarray
    course_deg: np.ndarray
    prn: np.ndarray
    az_deg: np.ndarray
    el_deg: np.ndarray
    cn0_dbhz: np.ndarray
    in_view: np.ndarray
    used: np.ndarray
    truth_lat_deg: np.ndarray
    truth_lon_deg: np.ndarray
    truth_alt_hae_m: np.ndarray
    sigma_enu_m: np.ndarray | None = None
    range_rms_m: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t_unix_s.shape[0])

    def gst_sigma_m(self) -> dict[str, np.ndarray] | None:
        """The GST fields (NMEA 0183 v2.3) from ``sigma_enu_m``, or None without an estimate.

        The error ellipse is taken axis-aligned (semi-major = the larger of the east/north
        sigmas, orientation 0 or 90 deg): a receiver's reported ellipse, not a covariance.

        Returns
        -------
        sigma_m : ``range_rms_m``, ``semi_major_m``, ``semi_minor_m``, ``orient_deg``,
            ``lat_m``, ``lon_m``, ``alt_m``, each (n_t,) float
        """
        if self.sigma_enu_m is None:
            return None
        e, n, u = self.sigma_enu_m[:, 0], self.sigma_enu_m[:, 1], self.sigma_enu_m[:, 2]
        rms = self.range_rms_m if self.range_rms_m is not None else np.full(len(self), np.nan)
        return {
            "range_rms_m": rms,
            "semi_major_m": np.maximum(e, n),
            "semi_minor_m": np.minimum(e, n),
            "orient_deg": np.where(n >= e, 0.0, 90.0),
            "lat_m": n,
            "lon_m": e,
            "alt_m": u,
        }

    @property
    def sats_used(self) -> np.ndarray:
        """(n_t,) int, number of satellites used in each fix."""
        return self.used.sum(axis=1)
