"""Statistics of receiver output: position error, its correlation in time, satellites, DOP, C/N0.

Owns the metrics shared by the profile calibration (docs/profiles.md table, ``tools/real_stats.py``)
and the sim-to-real gap tool (DESIGN section 7.1): pure numpy functions of per-epoch arrays, plus
:func:`summary`, which computes them all for any record holding epochs: the simulator's
:class:`virtualgps.receiver.records.Fixes` and the real-log records of :mod:`mtk_logs`.

Conventions. Errors are ENU metres in the frame of the reference point (the truth at each epoch,
or one fixed point such as the median position of a static log). Missing values are NaN (floats)
or negative (counts) and are left out of every statistic; no function raises on them. Where a
statistic has no data it is NaN. Radial quantiles are plain sample quantiles of the horizontal
error (CEP50: median; R95: 95th percentile), the empirical form of the "95 % horizontal"
accuracy of the GPS SPS Performance Standard (DoD, 5th ed., 2020).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from virtualgps.geodesy import ecef_to_enu_matrix, geodetic_to_ecef, geoid_sep_m

# 1/e: the autocorrelation level that defines the correlation time of a first-order
# Gauss-Markov process (rho(tau) = exp(-|tau| / tau_c), e.g. Brown & Hwang, "Introduction to
# Random Signals and Applied Kalman Filtering", 4th ed., section 2.9).
INV_E = float(np.exp(-1.0))
DETREND_MODES = ("mean", "linear", "none")


# --- position errors -----------------------------------------------------------------------


def errors_enu_m(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    alt_hae_m: ArrayLike,
    ref_lat_deg: ArrayLike,
    ref_lon_deg: ArrayLike,
    ref_alt_hae_m: ArrayLike,
) -> np.ndarray:
    """Position errors of fixes in the ENU frame of a reference (the truth, or one point).

    Exact WGS-84 (fix and reference through ECEF). Both altitudes must share a datum; the
    horizontal errors do not depend on it. A fix without altitude (NaN) keeps its horizontal
    error (it is placed at the reference's height) and gets a NaN Up error; so does every fix
    about a reference without a height (the median of a log that prints no altitude, RMC or
    GLL alone: both are then placed at height 0).

    Parameters
    ----------
    lat_deg, lon_deg : (...) float, degrees, the fixes (e.g. (n,), or (s, n) for s seeds); NaN
        without a fix
    alt_hae_m : (...) float, metres (ellipsoidal, or any datum shared with the reference)
    ref_lat_deg, ref_lon_deg, ref_alt_hae_m : float, degrees and metres, the reference, of
        any shape that broadcasts against the fixes' ((n,): one per epoch; (s, 1): one per seed)

    Returns
    -------
    err_enu_m : (..., 3) float, metres, ENU at the reference: fix minus reference
    """
    lat, lon, alt = (np.asarray(a, dtype=float) for a in (lat_deg, lon_deg, alt_hae_m))
    rlat, rlon, ralt = (np.asarray(a, dtype=float) for a in (ref_lat_deg, ref_lon_deg,
                                                             ref_alt_hae_m))
    ref_has_alt = np.isfinite(ralt)
    ralt = np.where(ref_has_alt, ralt, 0.0)
    no_alt = ~np.isfinite(alt)
    fix_ecef = geodetic_to_ecef(lat, lon, np.where(no_alt, ralt, alt))
    # the reference's frame on its own shape (one truth for every seed's fixes: the rotation
    # is made once per epoch, not once per seed and epoch)
    d = fix_ecef - geodetic_to_ecef(rlat, rlon, ralt)
    enu = (ecef_to_enu_matrix(rlat, rlon) @ d[..., None])[..., 0]
    enu[..., 2] = np.where(no_alt | ~ref_has_alt, np.nan, enu[..., 2])
    return enu


def horizontal_error_m(err_enu_m: ArrayLike) -> np.ndarray:
    """Horizontal error length.

    Parameters
    ----------
    err_enu_m : (..., 2 or 3) float, metres, ENU (Up ignored)

    Returns
    -------
    err_h_m : (...) float, metres, sqrt(E^2 + N^2)
    """
    e = np.asarray(err_enu_m, dtype=float)
    return np.hypot(e[..., 0], e[..., 1])


def median_position(
    lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike
) -> tuple[float, float, float]:
    """Component-wise median of positions: the reference point of a static log without truth.

    The median, unlike the mean, ignores the few outliers of reacquisition (robust; the way
    SOURCES.md measured the MT3339 static hour). Assumes the positions do not straddle the
    antimeridian.

    Parameters
    ----------
    lat_deg, lon_deg : (n,) float, degrees; NaN entries ignored
    alt_m : (n,) float, metres (any datum); NaN entries ignored

    Returns
    -------
    (lat_deg, lon_deg, alt_m) : floats; NaN where there is no data
    """
    return tuple(_nan_stat(np.nanmedian, a) for a in (lat_deg, lon_deg, alt_m))  # type: ignore[return-value]


def _nan_stat(fn: Any, a: ArrayLike, *args: Any) -> float:
    """``fn`` of the finite values of ``a``; NaN when there are none (no warning)."""
    x = np.asarray(a, dtype=float).ravel()
    x = x[np.isfinite(x)]
    return float(fn(x, *args)) if x.size else float("nan")


def cep50_m(err_h_m: ArrayLike) -> float:
    """Circular error probable: the median horizontal error.

    Parameters
    ----------
    err_h_m : (n,) float, metres, horizontal errors; NaN ignored

    Returns
    -------
    cep50_m : float, metres (for E, N independent N(0, sigma^2): 1.1774 sigma)
    """
    return _nan_stat(np.median, err_h_m)


def r95_m(err_h_m: ArrayLike) -> float:
    """Radius containing 95 % of the horizontal errors (sample 95th percentile).

    Parameters
    ----------
    err_h_m : (n,) float, metres, horizontal errors; NaN ignored

    Returns
    -------
    r95_m : float, metres (for E, N independent N(0, sigma^2): 2.4477 sigma)
    """
    return _nan_stat(np.percentile, err_h_m, 95.0)


def bias_enu_m(err_enu_m: ArrayLike) -> np.ndarray:
    """Mean error per axis.

    Parameters
    ----------
    err_enu_m : (n, k) float, metres (k = 2 or 3: E, N[, U]); rows with NaN ignored per axis

    Returns
    -------
    bias_m : (k,) float, metres; NaN for an axis without data
    """
    e = np.asarray(err_enu_m, dtype=float)
    return np.array([_nan_stat(np.mean, e[:, j]) for j in range(e.shape[1])])


def sigma_enu_m(err_enu_m: ArrayLike) -> np.ndarray:
    """Standard deviation of the error per axis (about its mean, ``ddof=1``).

    Parameters
    ----------
    err_enu_m : (n, k) float, metres; NaN ignored per axis

    Returns
    -------
    sigma_m : (k,) float, metres; NaN for an axis with fewer than two values
    """
    e = np.asarray(err_enu_m, dtype=float)
    out = np.full(e.shape[1], np.nan)
    for j in range(e.shape[1]):
        x = e[np.isfinite(e[:, j]), j]
        if x.size > 1:
            out[j] = np.std(x, ddof=1)
    return out


# --- correlation in time -------------------------------------------------------------------


def to_regular_grid(
    t_unix_s: ArrayLike, values: ArrayLike, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Place samples on a regular time grid, NaN where an epoch is missing.

    Each sample goes to the grid point nearest to it (``round((t - t0) / dt_s)``), which absorbs
    time-stamp jitter (the MT3339 log's epochs drift by tens of ms); of two samples on one grid
    point the later wins.

    Parameters
    ----------
    t_unix_s : (n,) float, seconds, non-decreasing
    values : (n,) or (n, k) float
    dt_s : float, seconds, the grid step (the output period)

    Returns
    -------
    grid_t_unix_s : (m,) float, seconds, ``t0 + dt_s * arange(m)``
    grid_values : (m,) or (m, k) float, NaN at grid points without a sample
    """
    t = np.asarray(t_unix_s, dtype=float)
    v = np.asarray(values, dtype=float)
    if t.size == 0:
        return np.zeros(0), v.copy()
    idx = np.rint((t - t[0]) / dt_s).astype(np.int64)
    m = int(idx.max()) + 1
    out = np.full((m,) + v.shape[1:], np.nan)
    out[idx] = v
    return t[0] + dt_s * np.arange(m), out


def autocorrelation(series: ArrayLike, max_lag: int, detrend: str = "mean") -> np.ndarray:
    """Normalised autocorrelation of a regularly sampled, possibly multi-axis, series with gaps.

    Gaps: epochs where any axis is NaN are left out; the autocovariance at lag k is the mean of
    x[i] . x[i+k] over the pairs where both epochs are present (the "masked" estimator, divided
    by the number of pairs, not by n), so gaps and missing epochs neither shorten nor bias the
    lags. Axes are pooled: rho(k) = sum_axes C_a(k) / sum_axes C_a(0), the autocorrelation of
    the error vector (each axis weighted by its variance). Computed by FFT (Wiener-Khinchin).

    Parameters
    ----------
    series : (n,) or (n, k) float, regularly sampled (see :func:`to_regular_grid`); NaN = missing
    max_lag : int, largest lag returned, in samples
    detrend : ``"mean"`` (subtract each axis's mean), ``"linear"`` (subtract each axis's least
        squares line: removes a slow drift that would otherwise stretch the correlation), or
        ``"none"``

    Returns
    -------
    rho : (max_lag + 1,) float, rho[0] = 1; NaN at lags with no pair of present epochs or when
        the series has no variance
    """
    if detrend not in DETREND_MODES:
        raise ValueError(f"detrend={detrend!r}: expected one of {DETREND_MODES}")
    x = np.asarray(series, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    n = x.shape[0]
    present = np.all(np.isfinite(x), axis=1)
    rho = np.full(max_lag + 1, np.nan)
    if present.sum() < 2:
        return rho
    x = np.where(present[:, None], x, 0.0)
    i = np.arange(n, dtype=float)
    if detrend == "mean":
        x = x - x[present].mean(axis=0)
    elif detrend == "linear":
        a = np.stack([np.ones(n), i - i[present].mean()], axis=1)
        coef, *_ = np.linalg.lstsq(a[present], x[present], rcond=None)
        x = x - a @ coef
    x = np.where(present[:, None], x, 0.0)
    n_fft = 1 << int(np.ceil(np.log2(2 * n)))  # zero padding: linear, not circular, correlation
    spec = np.fft.rfft(x, n_fft, axis=0)
    acov_sum = np.fft.irfft((spec * spec.conj()).real.sum(axis=1), n_fft)[: max_lag + 1]
    m = np.fft.rfft(present.astype(float), n_fft)
    n_pairs = np.rint(np.fft.irfft((m * m.conj()).real, n_fft)[: max_lag + 1])
    lags = min(max_lag + 1, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(n_pairs[:lags] > 0, acov_sum[:lags] / n_pairs[:lags], np.nan)
    if c[0] > 0:
        rho[:lags] = c / c[0]
    return rho


def autocorrelation_time_s(
    series: ArrayLike,
    dt_s: float,
    max_lag_s: float | None = None,
    detrend: str = "mean",
) -> float:
    """Lag at which the normalised autocorrelation of an error series first falls below 1/e.

    For a first-order Gauss-Markov error this is its time constant tau. Linear interpolation
    between the two lags around the crossing gives a sub-sample value (white noise gives about
    0.63 dt_s: rho falls from 1 to ~0 in one step). See :func:`autocorrelation` for gaps (NaN
    epochs are left out pair by pair) and multi-axis pooling.

    A finite record biases the estimate low: subtracting the sample mean removes the slowest
    part of the error, so rho(k) is lowered by about 2 tau / T for a record of length T
    (Bartlett 1946); ``detrend="linear"`` lowers it further. Use records much longer than tau.

    Parameters
    ----------
    series : (n,) or (n, k) float, regularly sampled (see :func:`to_regular_grid`); NaN = missing
    dt_s : float, seconds, the sampling period
    max_lag_s : float, seconds, the longest lag searched (default: half the record)
    detrend : ``"mean"``, ``"linear"`` or ``"none"`` (see :func:`autocorrelation`)

    Returns
    -------
    tau_s : float, seconds; NaN when rho stays above 1/e up to ``max_lag_s`` or cannot be
        computed
    """
    n = np.asarray(series).shape[0]
    max_lag = n // 2 if max_lag_s is None else int(np.ceil(max_lag_s / dt_s))
    max_lag = max(1, min(max_lag, n - 1))
    rho = autocorrelation(series, max_lag, detrend)
    below = np.flatnonzero(rho[1:] < INV_E)
    if below.size == 0:
        return float("nan")
    k = int(below[0]) + 1
    r0, r1 = rho[k - 1], rho[k]
    if not np.isfinite(r0):
        return float(k * dt_s)
    return float((k - 1 + (r0 - INV_E) / (r0 - r1)) * dt_s)


# --- distributions -------------------------------------------------------------------------


def wasserstein1(a: ArrayLike, b: ArrayLike) -> float:
    """Wasserstein-1 (earth mover's) distance between two 1-D samples: integral |F_a - F_b| dx.

    The same quantity as ``scipy.stats.wasserstein_distance`` without weights; NaN dropped.

    Parameters
    ----------
    a : (n,) float, any unit
    b : (m,) float, the same unit

    Returns
    -------
    w1 : float, in the unit of the samples; NaN if either is empty
    """
    x = np.sort(np.asarray(a, dtype=float).ravel())
    y = np.sort(np.asarray(b, dtype=float).ravel())
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    if x.size == 0 or y.size == 0:
        return float("nan")
    allv = np.sort(np.concatenate([x, y]))
    deltas = np.diff(allv)
    fx = np.searchsorted(x, allv[:-1], side="right") / x.size
    fy = np.searchsorted(y, allv[:-1], side="right") / y.size
    return float(np.sum(np.abs(fx - fy) * deltas))


def distribution_summary(
    values: ArrayLike, quantiles: Sequence[float] = (0.05, 0.25, 0.75, 0.95)
) -> dict[str, float]:
    """Median, quantiles, mean and count of a sample (NaN dropped).

    Parameters
    ----------
    values : (...) float, any unit (flattened)
    quantiles : fractions in [0, 1]; each gives a key ``p05``, ``p25``, ... (percent, 2 digits)

    Returns
    -------
    {"median", "mean", "n", "p05", ...} : floats in the unit of ``values`` (``n`` a count)
    """
    x = np.asarray(values, dtype=float).ravel()
    x = x[np.isfinite(x)]
    out = {"median": float("nan"), "mean": float("nan"), "n": float(x.size)}
    out.update({f"p{round(q * 100):02d}": float("nan") for q in quantiles})
    if x.size:
        out["median"] = float(np.median(x))
        out["mean"] = float(np.mean(x))
        for q, v in zip(quantiles, np.quantile(x, quantiles), strict=True):
            out[f"p{round(q * 100):02d}"] = float(v)
    return out


def hdop_summary(hdop: ArrayLike) -> dict[str, float]:
    """HDOP distribution: median, 5/25/75/95 % quantiles, mean, count.

    Parameters
    ----------
    hdop : (n,) float, dimensionless; NaN (no fix) ignored

    Returns
    -------
    {"median", "mean", "n", "p05", "p25", "p75", "p95"} : floats
    """
    return distribution_summary(hdop)


def cn0_summary(cn0_dbhz: ArrayLike) -> dict[str, float]:
    """C/N0 distribution over all tracked satellite-epochs: median, quantiles, mean, count.

    Parameters
    ----------
    cn0_dbhz : (n_t, n_sat) float, dB-Hz; NaN where not tracked (ignored)

    Returns
    -------
    {"median", "mean", "n", "p05", "p25", "p75", "p95"} : floats, dB-Hz (``n`` a count)
    """
    return distribution_summary(cn0_dbhz)


# --- availability and satellites -----------------------------------------------------------


def fix_fraction(quality: ArrayLike) -> float:
    """Fraction of epochs with a fix (GGA quality > 0).

    Parameters
    ----------
    quality : (n,) int, GGA quality per epoch

    Returns
    -------
    fraction : float in [0, 1]; NaN for no epochs
    """
    q = np.asarray(quality)
    return float(np.mean(q > 0)) if q.size else float("nan")


def ttff_s(t_unix_s: ArrayLike, quality: ArrayLike, t_start_s: float | None = None) -> float:
    """Time to first fix: time of the first epoch with quality > 0 after the start.

    Parameters
    ----------
    t_unix_s : (n,) float, seconds, epoch times
    quality : (n,) int, GGA quality per epoch
    t_start_s : float, seconds, the power-up time; default the first epoch's time (a log's
        first output line comes some time after power-up, so a log gives a lower bound)

    Returns
    -------
    ttff_s : float, seconds; NaN if no epoch has a fix
    """
    t = np.asarray(t_unix_s, dtype=float)
    fixed = np.flatnonzero(np.asarray(quality) > 0)
    if fixed.size == 0 or t.size == 0:
        return float("nan")
    start = t[0] if t_start_s is None else t_start_s
    return float(t[fixed[0]] - start)


def count_stats(counts: ArrayLike) -> dict[str, float]:
    """Statistics of a satellite count per epoch (negative = unknown, ignored).

    Parameters
    ----------
    counts : (n,) int, satellites per epoch

    Returns
    -------
    {"median", "mean", "min", "max", "p05", "p95"} : floats, satellites; NaN with no data
    """
    c = np.asarray(counts, dtype=float).ravel()
    c = c[np.isfinite(c) & (c >= 0)]
    if c.size == 0:
        return dict.fromkeys(("median", "mean", "min", "max", "p05", "p95"), float("nan"))
    p05, p95 = np.quantile(c, (0.05, 0.95))
    return {
        "median": float(np.median(c)),
        "mean": float(np.mean(c)),
        "min": float(c.min()),
        "max": float(c.max()),
        "p05": float(p05),
        "p95": float(p95),
    }


def changes_per_minute(
    counts: ArrayLike, t_unix_s: ArrayLike, max_step_s: float | None = None
) -> float:
    """How often a count changes: changes between consecutive epochs per minute.

    Only pairs of consecutive epochs that are both known (count >= 0) and at most
    ``max_step_s`` apart count, both for the changes and for the time; a gap in the log is
    neither a change nor time observed.

    Parameters
    ----------
    counts : (n,) int, e.g. satellites used per epoch; negative = unknown
    t_unix_s : (n,) float, seconds, epoch times
    max_step_s : float, seconds; default 1.5 times the median epoch step

    Returns
    -------
    rate_per_min : float, changes per minute; NaN without any valid pair
    """
    c = np.asarray(counts, dtype=float)
    t = np.asarray(t_unix_s, dtype=float)
    if c.size < 2:
        return float("nan")
    dt = np.diff(t)
    limit = 1.5 * float(np.median(dt)) if max_step_s is None else max_step_s
    ok = (c[1:] >= 0) & (c[:-1] >= 0) & (dt > 0) & (dt <= limit)
    minutes = dt[ok].sum() / 60.0
    if minutes <= 0:
        return float("nan")
    return float(np.count_nonzero(c[1:][ok] != c[:-1][ok]) / minutes)


# --- everything at once --------------------------------------------------------------------


def _opt(epochs: object, name: str) -> np.ndarray | None:
    v = getattr(epochs, name, None)
    return None if v is None else np.asarray(v)


def summary(
    epochs: object,
    reference: str | None = "auto",
    detrend: str = "mean",
) -> dict[str, float]:
    """The calibration statistics of a run of epochs, real or simulated.

    Reads these attributes of ``epochs`` (all (n_t,) unless said otherwise; optional ones may be
    absent): ``t_unix_s``, ``lat_deg``, ``lon_deg``, ``quality`` (required); ``hdop``;
    ``alt_msl_m`` + ``geoid_sep_m`` or ``alt_hae_m``; ``sats_used`` (else ``used`` (n_t, n_sat)
    summed); ``sats_in_view`` (else ``in_view`` (n_t, n_sat) summed); ``cn0_dbhz`` (n_t, n_sat);
    ``truth_lat_deg``, ``truth_lon_deg``, ``truth_alt_hae_m``. That is
    :class:`virtualgps.receiver.records.Fixes` and the records of :mod:`mtk_logs`.

    Position, satellite, HDOP and C/N0 statistics are over the epochs with a fix (quality > 0
    and a finite position); availability over all epochs.

    Parameters
    ----------
    epochs : a record of epochs as above
    reference : where errors are measured from: ``"truth"`` (per-epoch truth), ``"median"``
        (the median fixed position: a static log without truth), ``"auto"`` (truth if any
        truth is finite, else the median) or None (no position statistics: NaN)
    detrend : for the autocorrelation time, see :func:`autocorrelation`

    Returns
    -------
    stats : dict, keys with units (``_m``, ``_s``, ``_dbhz``, ``_per_min``; counts of
        satellites are ``sats_*``, HDOP dimensionless): ``n_epochs``, ``duration_s``,
        ``fix_fraction``, ``ttff_s``, ``cep50_m``, ``r95_m``, ``bias_{h,e,n,u}_m``,
        ``sigma_{e,n,u}_m``, ``autocorr_{h,e,n,u}_s`` (h: E and N pooled), ``sats_used_*`` and
        ``sats_in_view_*`` (median, mean, min, max, p05, p95), ``sats_in_view_gps_*`` (PRN
        1-32 listed with an elevation), ``sats_tracked_*`` (finite C/N0),
        ``sats_used_changes_per_min``,
        ``hdop_*`` (median, mean, p05, p25, p75, p95), ``cn0_*_dbhz`` (same), ``cn0_n``
        (satellite-epochs with a C/N0). Counts of a record lacking them are NaN.
    """
    t = np.asarray(epochs.t_unix_s, dtype=float)  # type: ignore[attr-defined]
    lat = np.asarray(epochs.lat_deg, dtype=float)  # type: ignore[attr-defined]
    lon = np.asarray(epochs.lon_deg, dtype=float)  # type: ignore[attr-defined]
    quality = np.asarray(epochs.quality)  # type: ignore[attr-defined]
    n_t = t.size
    fixed = (quality > 0) & np.isfinite(lat) & np.isfinite(lon)
    out: dict[str, float] = {
        "n_epochs": float(n_t),
        "n_fixed": float(fixed.sum()),
        "duration_s": float(t[-1] - t[0]) if n_t else float("nan"),
        "fix_fraction": fix_fraction(quality),
        "ttff_s": ttff_s(t, quality),
    }

    # position errors
    alt_msl, sep, alt_hae = (_opt(epochs, k) for k in ("alt_msl_m", "geoid_sep_m", "alt_hae_m"))
    if alt_hae is None and alt_msl is None:
        alt_hae = np.full(n_t, np.nan)
    elif alt_hae is None:
        # a log without the geoid field: EGM96 from the bundled grid (what the receiver adds)
        sep_m = np.full(n_t, np.nan) if sep is None else np.asarray(sep, dtype=float)
        sep_m = np.where(
            np.isfinite(sep_m), sep_m, geoid_sep_m(np.nan_to_num(lat), np.nan_to_num(lon))
        )
        alt_hae = np.asarray(alt_msl, dtype=float) + sep_m
    alt_hae = np.asarray(alt_hae, dtype=float)
    truth = [_opt(epochs, k) for k in ("truth_lat_deg", "truth_lon_deg", "truth_alt_hae_m")]
    have_truth = truth[0] is not None and bool(np.any(np.isfinite(truth[0])))
    mode = reference
    if mode == "auto":
        mode = "truth" if have_truth else "median"
    enu = np.full((n_t, 3), np.nan)
    if mode == "truth" and have_truth:
        enu = errors_enu_m(lat, lon, alt_hae, *truth)  # type: ignore[arg-type]
    elif mode == "median":
        ref = median_position(lat[fixed], lon[fixed], alt_hae[fixed])
        enu = errors_enu_m(lat, lon, alt_hae, *ref)
    elif mode not in (None, "truth"):
        raise ValueError(f"reference={reference!r}: expected 'truth', 'median', 'auto' or None")
    enu[~fixed] = np.nan
    err_h = horizontal_error_m(enu)
    bias = bias_enu_m(enu)
    sig = sigma_enu_m(enu)
    out.update(
        cep50_m=cep50_m(err_h),
        r95_m=r95_m(err_h),
        bias_h_m=float(np.hypot(bias[0], bias[1])),
        bias_e_m=bias[0],
        bias_n_m=bias[1],
        bias_u_m=bias[2],
        sigma_e_m=sig[0],
        sigma_n_m=sig[1],
        sigma_u_m=sig[2],
    )
    steps = np.diff(t[fixed])
    dt_s = float(np.median(steps)) if steps.size else float("nan")
    ac = dict.fromkeys(("h", "e", "n", "u"), float("nan"))
    if np.isfinite(dt_s) and dt_s > 0 and np.isfinite(err_h).sum() > 2:
        _, grid = to_regular_grid(t[fixed], enu[fixed], dt_s)
        for key, cols in (("h", [0, 1]), ("e", [0]), ("n", [1]), ("u", [2])):
            ac[key] = autocorrelation_time_s(grid[:, cols], dt_s, detrend=detrend)
    out.update({f"autocorr_{k}_s": float(v) for k, v in ac.items()})

    # satellites
    used = _opt(epochs, "sats_used")
    if used is None and _opt(epochs, "used") is not None:
        used = _opt(epochs, "used").sum(axis=1)  # type: ignore[union-attr]
    view = _opt(epochs, "sats_in_view")
    if view is None and _opt(epochs, "in_view") is not None:
        view = _opt(epochs, "in_view").sum(axis=1)  # type: ignore[union-attr]
    # GPS satellites (PRN 1-32) listed with an elevation: what the simulator's in_view holds
    # (real MTK GSV also lists SBAS PRNs 33-51 and channels still searching, e.g. ``34,,,``)
    prn, in_view, el = (_opt(epochs, k) for k in ("prn", "in_view", "el_deg"))
    view_gps = None
    if prn is not None and in_view is not None and in_view.ndim == 2:
        listed = in_view & ((prn >= 1) & (prn <= 32))[None, :]
        if el is not None and el.shape == in_view.shape:
            listed &= np.isfinite(el)
        view_gps = listed.sum(axis=1)
    tracked = None
    cn0 = _opt(epochs, "cn0_dbhz")
    if cn0 is not None and cn0.ndim == 2 and cn0.shape[1] > 0:
        tracked = np.isfinite(cn0).sum(axis=1)
    for name, counts in (
        ("sats_used", used),
        ("sats_in_view", view),
        ("sats_in_view_gps", view_gps),
        ("sats_tracked", tracked),
    ):
        c = np.full(n_t, -1.0) if counts is None else np.asarray(counts, dtype=float)
        out.update({f"{name}_{k}": v for k, v in count_stats(c[fixed]).items()})
    c = np.full(n_t, -1.0) if used is None else np.where(fixed, used, -1.0)
    out["sats_used_changes_per_min"] = changes_per_minute(c, t)

    hdop = _opt(epochs, "hdop")
    h = hdop_summary(np.full(0, np.nan) if hdop is None else np.asarray(hdop, float)[fixed])
    out.update({f"hdop_{k}": v for k, v in h.items() if k != "n"})
    cs = cn0_summary(
        np.full(0, np.nan) if cn0 is None or cn0.ndim != 2 else np.asarray(cn0, float)[fixed]
    )
    out.update({f"cn0_{k}_dbhz": v for k, v in cs.items() if k != "n"})
    out["cn0_n"] = cs["n"]
    out.update(speed_summary(_opt(epochs, "speed_mps"), _opt(epochs, "course_deg"), fixed))
    if prn is not None and el is not None and in_view is not None and in_view.ndim == 2:
        gps = ((prn >= 1) & (prn <= 32))[None, :] & in_view & fixed[:, None]
        if cn0 is not None and cn0.shape == in_view.shape:
            out.update(elevation_bin_stats(el, cn0, gps))
        az, used_sats = _opt(epochs, "az_deg"), _opt(epochs, "used")
        if az is not None and used_sats is not None and used_sats.shape == in_view.shape:
            vdop = used_set_vdop(el, az, used_sats & gps)
            fin = np.isfinite(vdop)
            out["vdop_used_median"] = float(np.median(vdop[fin])) if fin.any() else math.nan
    return out


# Elevation bins (degrees) of the per-bin C/N0 and tracking statistics: a patch antenna's
# roll-off shows between them, and an obstructed site's losses by direction too.
ELEVATION_BINS_DEG = ((5, 15), (15, 30), (30, 60), (60, 90))


def elevation_bin_stats(el_deg: np.ndarray, cn0_dbhz: np.ndarray, listed: np.ndarray
                        ) -> dict[str, float]:
    """Per elevation bin: median C/N0 of the tracked satellites and the share tracked.

    Parameters
    ----------
    el_deg, cn0_dbhz : (n_t, n_sat) GSV elevation (degrees) and SNR (dB-Hz, NaN: not tracked)
    listed : (n_t, n_sat) bool, the satellite-epochs to count (GPS, in view, fixed epochs)

    Returns
    -------
    stats : ``cn0_el{lo}_{hi}_median_dbhz`` and ``tracked_el{lo}_{hi}_share`` for each bin of
        :data:`ELEVATION_BINS_DEG` (NaN where the bin holds no satellite-epoch)
    """
    out = {}
    el = np.where(listed, el_deg, np.nan)
    for lo, hi in ELEVATION_BINS_DEG:
        inside = (el >= lo) & (el < hi) if hi < 90 else (el >= lo)
        tracked = inside & np.isfinite(cn0_dbhz)
        key = f"el{lo}_{hi}"
        out[f"cn0_{key}_median_dbhz"] = (float(np.median(cn0_dbhz[tracked])) if tracked.any()
                                         else math.nan)
        out[f"tracked_{key}_share"] = (float(tracked.sum() / inside.sum()) if inside.any()
                                       else math.nan)
    return out


def used_set_vdop(el_deg: np.ndarray, az_deg: np.ndarray, used: np.ndarray) -> np.ndarray:
    """VDOP of each epoch's used satellites from their GSV elevation and azimuth (unit weights,
    4 states), the same for real and simulated logs whatever DOP the receiver prints.

    el_deg, az_deg : (n_t, n_sat) degrees; used : (n_t, n_sat) bool (GSA)
    Returns (n_t,) VDOP; NaN with fewer than 4 used satellites of known direction
    """
    ok = used & np.isfinite(el_deg) & np.isfinite(az_deg)
    el, az = np.radians(np.where(ok, el_deg, 0.0)), np.radians(np.where(ok, az_deg, 0.0))
    g = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el),
                  np.ones_like(el)], axis=-1) * ok[..., None]
    out = np.full(el.shape[0], math.nan)
    four = ok.sum(axis=1) >= 4
    if four.any():
        gtg = np.einsum("tsi,tsj->tij", g[four], g[four])
        cond_ok = np.linalg.cond(gtg) < 1e12
        q = np.full(gtg.shape, math.nan)
        q[cond_ok] = np.linalg.inv(gtg[cond_ok])
        out[four] = np.sqrt(q[:, 2, 2])
    return out


MPS_PER_KNOT = 1852.0 / 3600.0


def speed_summary(speed_mps: object, course_deg: object, fixed: np.ndarray
                  ) -> dict[str, float]:
    """The reported speed's median and 90th percentile (knots, as NMEA prints it) and the share
    of consecutive fixes whose course differs, over the fixed epochs (NaN where absent).

    speed_mps, course_deg : (n_t,) or None; fixed : (n_t,) bool
    """
    out = {"speed_median_kn": math.nan, "speed_p90_kn": math.nan, "course_change_share": math.nan}
    if speed_mps is not None:
        kn = np.asarray(speed_mps, dtype=float)[fixed] / MPS_PER_KNOT
        kn = kn[np.isfinite(kn)]
        if kn.size:
            out["speed_median_kn"] = float(np.median(kn))
            out["speed_p90_kn"] = float(np.percentile(kn, 90))
    if course_deg is not None:
        c = np.asarray(course_deg, dtype=float)[fixed]
        c = c[np.isfinite(c)]
        if c.size > 1:
            out["course_change_share"] = float(np.mean(np.diff(c) != 0))
    return out
