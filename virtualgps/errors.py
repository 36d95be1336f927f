"""Range and position error models (DESIGN section 6): the UERE budget by elevation, first-order
Gauss-Markov processes, and the weighted least-squares position error of per-satellite range
errors. Pure numpy; random numbers come in as uniforms drawn by the caller, so one block of
uniforms per epoch keeps batch and epoch-by-epoch runs identical.
"""

from __future__ import annotations

import numpy as np

from virtualgps.constants import WGS84_A_M

IONO_SHELL_HEIGHT_M = 350e3  # thin-shell ionosphere height, IS-GPS-200 / Klobuchar


def normals_from_uniforms(u: np.ndarray) -> np.ndarray:
    """Standard normal deviates from uniforms by Box-Muller, pairwise along the last axis.

    Parameters
    ----------
    u : (..., 2k) float, uniform on [0, 1)

    Returns
    -------
    z : (..., 2k) float, independent standard normals
    """
    a, b = u[..., 0::2], u[..., 1::2]
    radius = np.sqrt(-2.0 * np.log1p(-a))
    angle = 2.0 * np.pi * b
    z = np.empty_like(u)
    z[..., 0::2] = radius * np.cos(angle)
    z[..., 1::2] = radius * np.sin(angle)
    return z


def iono_obliquity(el_deg: np.ndarray) -> np.ndarray:
    """Thin-shell ionospheric obliquity factor (slant/vertical delay), IS-GPS-200 20.3.3.5.2.5.

    F = 1 / sqrt(1 - (R cos(el) / (R + h))^2), h = 350 km: 1 at the zenith, ~3 at the horizon.

    Parameters
    ----------
    el_deg : (...) float, degrees

    Returns
    -------
    factor : (...) float
    """
    c = WGS84_A_M * np.cos(np.radians(el_deg)) / (WGS84_A_M + IONO_SHELL_HEIGHT_M)
    return 1.0 / np.sqrt(1.0 - c**2)


def tropo_obliquity(el_deg: np.ndarray) -> np.ndarray:
    """Tropospheric mapping function of RTCA DO-229 (A.4.2.4): 1.001 / sqrt(0.002001 + sin^2 el).

    Parameters
    ----------
    el_deg : (...) float, degrees

    Returns
    -------
    factor : (...) float (~1 at the zenith, ~10 at 5 deg)
    """
    s = np.sin(np.radians(np.clip(el_deg, 0.0, 90.0)))
    return 1.001 / np.sqrt(0.002001 + s**2)


def uere_sigma_m(
    el_deg: np.ndarray,
    sis_m: float,
    iono_zenith_m: float,
    tropo_zenith_m: float,
    rx_noise_m: float,
    multipath_a_m: float,
    multipath_b_m: float,
) -> np.ndarray:
    """One-sigma user equivalent range error of each satellite by elevation.

    sigma^2 = SIS^2 + (F_iono iono)^2 + (F_tropo tropo)^2 + noise^2 + (a + b exp(-el/10 deg))^2,
    the airborne multipath term's form from RTCA DO-229 (J.2.4); the residual ionosphere and
    troposphere scale with their obliquity factors.

    Parameters
    ----------
    el_deg : (...) float, degrees
    sis_m, iono_zenith_m, tropo_zenith_m, rx_noise_m, multipath_a_m, multipath_b_m : metres

    Returns
    -------
    sigma_m : (...) float, metres
    """
    el = np.nan_to_num(np.asarray(el_deg, dtype=float), nan=90.0)
    mp = multipath_a_m + multipath_b_m * np.exp(-el / 10.0)
    return np.sqrt(
        sis_m**2
        + (iono_obliquity(el) * iono_zenith_m) ** 2
        + (tropo_obliquity(el) * tropo_zenith_m) ** 2
        + rx_noise_m**2
        + mp**2
    )


def gauss_markov(
    x0: np.ndarray, dt_s: np.ndarray, tau_s: float, sigma: np.ndarray, z: np.ndarray
) -> np.ndarray:
    """Run first-order Gauss-Markov processes over epochs.

    x_k = phi_k x_(k-1) + sigma sqrt(1 - phi_k^2) z_k with phi_k = exp(-dt_k / tau): stationary
    with standard deviation ``sigma`` and autocorrelation exp(-lag / tau) (Brown & Hwang,
    Introduction to Random Signals and Applied Kalman Filtering, 4th ed., section 2.9).

    Parameters
    ----------
    x0 : (m,) float, the state before the first epoch
    dt_s : (n_t,) float, seconds since the previous epoch (for the first: since x0's epoch)
    tau_s : float, correlation time, seconds
    sigma : (m,) or (n_t, m) float, stationary standard deviation
    z : (n_t, m) float, standard normals

    Returns
    -------
    x : (n_t, m) float, the process at each epoch (x[-1] is the new state)
    """
    phi = np.exp(-np.asarray(dt_s, dtype=float) / tau_s)[:, None]  # (n_t, 1)
    drive = np.broadcast_to(sigma, z.shape) * np.sqrt(1.0 - phi**2) * z
    prev = np.asarray(x0, dtype=float)
    if drive.shape[0] > 8 and np.all(phi == phi[0]):
        # Constant step (every batch on the epoch grid): a first-order IIR filter, in C.
        from scipy.signal import lfilter

        p = float(phi[0, 0])
        return lfilter([1.0], [1.0, -p], drive, axis=0, zi=(p * prev)[None, :])[0]
    # A few epochs (the live loop) or variable steps: the plain recursion is cheaper.
    x = np.empty_like(drive)
    for k in range(x.shape[0]):
        prev = phi[k] * prev + drive[k]
        x[k] = prev
    return x


def wls_error(
    los_enu: np.ndarray, used: np.ndarray, sigma_m: np.ndarray, range_err_m: np.ndarray,
    n_states: int = 4,
) -> np.ndarray:
    """Position error of a weighted least-squares fix made from erroneous ranges.

    Pseudorange residual model rho_err = -u . dx + c dt + eps; the WLS estimate
    dx = (G^T W G)^-1 G^T W eps, with G rows [-e, -n, -u, 1] (3D) or [-e, -n, 1] (2D, height
    held), W = diag(1 / sigma^2) over the used satellites (Misra & Enge, section 6.1).

    Parameters
    ----------
    los_enu : (..., n_sat, 3) unit vectors to the satellites, ENU
    used : (..., n_sat) bool
    sigma_m : (..., n_sat) float, metres, range error standard deviations (weights)
    range_err_m : (..., n_sat) float, metres, the range errors
    n_states : 4 (east, north, up, clock) or 3 (east, north, clock: a 2D fix)

    Returns
    -------
    err_enu_m : (..., 3) float, metres (up is 0 for a 2D fix); NaN where the geometry does not
        determine the states
    """
    u = -np.nan_to_num(los_enu)
    ones = np.ones(los_enu.shape[:-1] + (1,))
    g = np.concatenate([u, ones] if n_states == 4 else [u[..., :2], ones], axis=-1)
    w = np.where(used, 1.0 / np.square(sigma_m), 0.0)[..., None]
    normal = np.einsum("...si,...sj->...ij", g * w, g)
    rhs = np.einsum("...si,...s->...i", g * w, np.where(used, range_err_m, 0.0))
    ok = used.sum(axis=-1) >= n_states
    eye = np.eye(n_states)
    safe = np.where(ok[..., None, None], normal, eye)
    try:
        sol = np.linalg.solve(safe, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:  # an exactly singular geometry somewhere: find it
        ok &= np.abs(np.linalg.det(safe)) > 1e-12
        sol = np.linalg.solve(np.where(ok[..., None, None], safe, eye), rhs[..., None])[..., 0]
    # A nearly singular geometry gives a huge solution: treat it as none (PDOP > 1e4).
    ok &= np.all(np.abs(sol) < 1e7, axis=-1)
    err = np.zeros(los_enu.shape[:-2] + (3,))
    err[..., :2] = sol[..., :2]
    if n_states == 4:
        err[..., 2] = sol[..., 2]
    return np.where(ok[..., None], err, np.nan)


def wls_sigma_enu_m(los_enu: np.ndarray, used: np.ndarray, sigma_m: np.ndarray) -> np.ndarray:
    """One-sigma east/north/up errors of a weighted least-squares fix: sqrt(diag (G^T W G)^-1).

    Parameters
    ----------
    los_enu : (..., n_sat, 3) unit vectors to the satellites, ENU
    used : (..., n_sat) bool
    sigma_m : (..., n_sat) float, metres, range error sigmas (W = 1 / sigma^2)

    Returns
    -------
    sigma_enu_m : (..., 3) float, metres; NaN with fewer than 4 used satellites
    """
    g = np.concatenate([-np.nan_to_num(los_enu), np.ones(los_enu.shape[:-1] + (1,))], axis=-1)
    w = np.where(used, 1.0 / np.square(sigma_m), 0.0)[..., None]
    normal = np.einsum("...si,...sj->...ij", g * w, g)
    ok = used.sum(axis=-1) >= 4
    safe = np.where(ok[..., None, None], normal, np.eye(4))
    ok &= np.abs(np.linalg.det(safe)) > 1e-12
    q = np.linalg.inv(np.where(ok[..., None, None], safe, np.eye(4)))
    diag = np.sqrt(np.abs(np.diagonal(q, axis1=-2, axis2=-1)[..., :3]))
    return np.where(ok[..., None], diag, np.nan)
