"""Range and position error models (DESIGN section 6): the UERE budget by elevation, first-order
Gauss-Markov processes, and the weighted least-squares position error of per-satellite range
errors. Pure numpy; random numbers come in as uniforms drawn by the caller, so one block of
uniforms per epoch keeps batch and epoch-by-epoch runs identical.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from virtualgps.constants import WGS84_A_M

LOOP_EPOCHS_BEFORE_LFILTER = 400_000  # see first_order_recursion
_loop_epochs = 0  # epochs this process has run through the plain recursion
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
    el = np.asarray(el_deg, dtype=float)
    el = np.where(np.isnan(el), 90.0, el)  # (nan_to_num is slow on the live loop's tiny arrays)
    mp = multipath_a_m + multipath_b_m * np.exp(-el / 10.0)
    return np.sqrt(
        sis_m**2
        + (iono_obliquity(el) * iono_zenith_m) ** 2
        + (tropo_obliquity(el) * tropo_zenith_m) ** 2
        + rx_noise_m**2
        + mp**2
    )


def multipath_sigma_m(
    el_deg: np.ndarray,
    wall_dist_m: np.ndarray,
    sigma_m: float,
    el0_deg: float,
    max_dist_m: float,
    open_sky_factor: float,
) -> np.ndarray:
    """One-sigma line-of-sight multipath range error (``multipath``; see MultipathParams).

    sigma = sigma_m exp(-el / el0) p, with the proximity p = max(0, 1 - d / max_dist) for the
    distance d to the nearest wall, or ``open_sky_factor`` where no scene tells (d NaN).

    Parameters
    ----------
    el_deg : (..., n_sat) float, degrees (negative counts as 0; NaN gives NaN)
    wall_dist_m : (...) float, metres, horizontal distance from the antenna to the nearest wall
        rising above it (inf: none near; NaN: no scene)
    sigma_m : metres, at the horizon next to a wall
    el0_deg : degrees, the elevation scale of the decay
    max_dist_m : metres, walls at this distance or further add nothing
    open_sky_factor : the proximity without a scene, 0..1

    Returns
    -------
    sigma_m : (..., n_sat) float, metres
    """
    d = np.asarray(wall_dist_m, dtype=float)
    proximity = np.where(np.isnan(d), open_sky_factor,
                         np.clip(1.0 - d / max_dist_m, 0.0, 1.0))  # (inf: 0)
    el = np.maximum(np.asarray(el_deg, dtype=float), 0.0)
    return sigma_m * np.exp(-el / el0_deg) * proximity[..., None]


def gauss_markov(
    x0: np.ndarray, dt_s: np.ndarray, tau_s: float, sigma: np.ndarray, z: np.ndarray
) -> np.ndarray:
    """Run first-order Gauss-Markov processes over epochs.

    x_k = phi_k x_(k-1) + sigma sqrt(1 - phi_k^2) z_k with phi_k = exp(-dt_k / tau): stationary
    with standard deviation ``sigma`` and autocorrelation exp(-lag / tau) (Brown & Hwang,
    Introduction to Random Signals and Applied Kalman Filtering, 4th ed., section 2.9).

    Parameters
    ----------
    x0 : (m,) float, the state before the first epoch (or (n_t, m): independent rows, see
        :func:`first_order_recursions`)
    dt_s : (n_t,) float, seconds since the previous epoch (for the first: since x0's epoch)
    tau_s : float, correlation time, seconds
    sigma : (m,) or (n_t, m) float, stationary standard deviation
    z : (n_t, m) float, standard normals

    Returns
    -------
    x : (n_t, m) float, the process at each epoch (x[-1] is the new state)
    """
    return gauss_markov_processes([(x0, tau_s, sigma, z)], dt_s)[0]


def gauss_markov_processes(
    processes: Sequence[tuple[np.ndarray, float, np.ndarray, np.ndarray]], dt_s: np.ndarray
) -> list[np.ndarray]:
    """Run several sets of Gauss-Markov processes (each as :func:`gauss_markov`, with its own
    correlation time) over the same epochs, in one recursion.

    Parameters
    ----------
    processes : (x0, tau_s, sigma, z) of each set, as :func:`gauss_markov` takes them
    dt_s : (n_t,) float, seconds since the previous epoch

    Returns
    -------
    x : (n_t, m_i) float for each set, in order (the same numbers as :func:`gauss_markov`
        gives it alone)
    """
    dt = np.asarray(dt_s, dtype=float)
    series = []
    for x0, tau_s, sigma, z in processes:
        phi = np.exp(-dt / tau_s)
        drive = sigma * np.sqrt(1.0 - phi[:, None] ** 2) * z  # (n_t, m)
        series.append((np.asarray(x0, dtype=float), phi, drive))
    return first_order_recursions(series)


def prefer_lfilter() -> None:
    """Filter long runs with scipy.signal's lfilter from now on (a process that will simulate
    millions of epochs: its import pays at once)."""
    global _loop_epochs
    _loop_epochs = LOOP_EPOCHS_BEFORE_LFILTER + 1


def first_order_recursion(y0: np.ndarray, p: np.ndarray, u: np.ndarray) -> np.ndarray:
    """y_k = p_k y_(k-1) + u_k over epochs, for several series at once.

    Rows that are independent series (receivers side by side, one epoch each) come with one
    starting value per row: ``y0`` of shape (n_t, m) gives y_k = p_k y0_k + u_k, the same
    products and sums as one epoch of the recursion.

    Parameters
    ----------
    y0 : (m,) float, the value before the first epoch; or (n_t, m), one per row
    p : (n_t,) float, each epoch's coefficient
    u : (n_t, m) float, each epoch's input

    Returns
    -------
    y : (n_t, m) float
    """
    return first_order_recursions([(y0, p, u)])[0]


def first_order_recursions(
    series: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]
) -> list[np.ndarray]:
    """:func:`first_order_recursion` for several sets of series with coefficients of their
    own, over the same epochs: one pass over the epochs for all of them, where each epoch's
    step costs the same few microseconds however many series it carries (three or four sets
    in the receiver: one pass instead of three saved ~0.14 s of the 10 Hz hour's replay).

    Parameters
    ----------
    series : (y0, p, u) of each set, as :func:`first_order_recursion` takes them (the same
        n_t)

    Returns
    -------
    y : (n_t, m_i) float for each set, in order
    """
    out: list[np.ndarray | None] = [None] * len(series)
    run_ix = []
    for i, (y0, p, u) in enumerate(series):
        if y0.ndim == 2 or u.shape[0] == 1:
            # Independent rows, or one epoch (the live loop's: the recursion's one step,
            # without its run bookkeeping, ~25 us an epoch for each set): y0 p + u.
            out[i] = p[:, None] * y0 + u
        else:
            run_ix.append(i)
    if not run_ix:
        return out
    sets = [series[i] for i in run_ix]
    n = sets[0][2].shape[0]
    cols = np.cumsum([0] + [u.shape[1] for _, _, u in sets]).tolist()
    u = sets[0][2] if len(sets) == 1 else np.concatenate([u_i for _, _, u_i in sets], axis=1)
    y = np.empty_like(u)
    # Runs of one coefficient in every set (a batch on the epoch grid has one run after its
    # first epoch; a real log's epochs, a few, split by its gaps): a first-order IIR filter
    # per long run and set, in C, computing the same products and sums in the same order as
    # the plain recursion, so a batch equals its epochs one by one to the bit.
    new_run = np.zeros(n, bool)
    new_run[0] = True
    for _, p, _ in sets:
        new_run[1:] |= p[1:] != p[:-1]
    bounds = np.append(np.flatnonzero(new_run), n)
    prev = sets[0][0] if len(sets) == 1 else np.concatenate([y0 for y0, _, _ in sets])
    # scipy.signal costs 0.3-0.5 s to import, the plain recursion ~1.2 us an epoch: a process
    # keeps to the recursion (live epochs, replays of an hour at 10 Hz) until it has run
    # LOOP_EPOCHS_BEFORE_LFILTER epochs of it, or is told it will run many
    # (:func:`prefer_lfilter`, the gap tool's ensembles).
    global _loop_epochs
    fast = _loop_epochs > LOOP_EPOCHS_BEFORE_LFILTER
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        if fast and b - a > 8:
            from scipy.signal import lfilter

            for (_, p, _), lo, hi in zip(sets, cols[:-1], cols[1:], strict=True):
                y[a, lo:hi] = p[a] * prev[lo:hi] + u[a, lo:hi]
                c = float(p[a])
                y[a + 1 : b, lo:hi] = lfilter([1.0], [1.0, -c], u[a + 1 : b, lo:hi], axis=0,
                                              zi=(c * y[a, lo:hi])[None, :])[0]
        else:
            _loop_epochs += (b - a) * len(sets)
            # The same products and sums into the output rows in place (no temporaries, one
            # coefficient per set for the run, a Python float where there is one set, else
            # each column's): ~1/3 less time per epoch than prev = p[k] * prev + u[k].
            if len(sets) == 1:
                c = float(sets[0][1][a])
            else:
                c = np.repeat([float(p[a]) for _, p, _ in sets], np.diff(cols))
            mul, add = np.multiply, np.add
            for row, u_k in zip(list(y[a:b]), list(u[a:b]), strict=True):
                mul(prev, c, out=row)
                add(row, u_k, out=row)
                prev = row
            continue
        prev = y[b - 1]
    for i, lo, hi in zip(run_ix, cols[:-1], cols[1:], strict=True):
        out[i] = y[:, lo:hi]
    return out


@dataclass(frozen=True, eq=False)
class WlsGeometry:
    """The part of a weighted least-squares fix that depends on the geometry and weights alone
    (:func:`wls_geometry`): several sets of range errors (position, Doppler) share it.

    g : (..., n_sat, n_states) rows [-e, -n, -u, 1] (3D) or [-e, -n, 1] (2D); with several
        systems' clocks, the 1 is the satellite's row of ``clocks``
    w : (..., n_sat) weights 1 / sigma^2 of the used satellites, 0 for the others
    gw_t : (..., n_states, n_sat) G^T W
    q : (..., n_states, n_states) (G^T W G)^-1 (of the identity where ``ok`` is False)
    ok : (...) bool, enough used satellites (and an invertible normal matrix)
    regular : (...) bool, |det(G^T W G)| > 1e-12
    n_used : (...) int, used satellites
    w_held : (...) float, the held height's weight (``held_height``), else None
    n_pos : position states, 3 (3D) or 2 (2D); the rest are clocks
    """

    g: np.ndarray
    w: np.ndarray
    gw_t: np.ndarray
    q: np.ndarray
    ok: np.ndarray
    regular: np.ndarray
    n_used: np.ndarray
    w_held: np.ndarray | None
    n_pos: int = 3


def clock_states(used: np.ndarray, clocks: np.ndarray | None
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """The clock columns of G and which of them the used satellites determine.

    One receiver clock per satellite system: ranges of different systems differ by an
    inter-system time offset (system time scales, receiver biases), which a multi-system
    receiver solves as one more unknown per extra system (Misra & Enge, section 6.1; RTKLIB
    solves one clock per system alike). A system none of whose satellites is used leaves its
    clock undetermined: it is left out (a unit diagonal in the normal matrix, nothing else in
    its row), so the other states come out as without it.

    Parameters
    ----------
    used : (..., n_sat) bool
    clocks : (n_sat, k) 0/1, each satellite's system
        (:func:`virtualgps.receiver.solution.clock_columns`); None: one clock

    Returns
    -------
    columns : (..., n_sat, k) the clock columns (k = 1 without ``clocks``)
    idle : (..., k) bool, clocks no used satellite determines (None without ``clocks``)
    """
    if clocks is None:
        return np.ones(used.shape + (1,)), None
    idle = ~(used[..., None] & (clocks > 0)).any(axis=-2)
    return np.broadcast_to(clocks, used.shape + clocks.shape[-1:]), idle


def wls_geometry(
    los_enu: np.ndarray, used: np.ndarray, sigma_m: np.ndarray, n_states: int = 4,
    held_height: bool = False, clocks: np.ndarray | None = None,
) -> WlsGeometry:
    """The geometry part of :func:`wls_fix` (the same parameters), for :func:`wls_solve`."""
    u = -np.where(np.isnan(los_enu), 0.0, los_enu)  # (nan_to_num: slow on tiny arrays)
    n_pos = 3 if n_states == 4 else 2
    clk, idle = clock_states(used, clocks)
    g = np.concatenate([u[..., :n_pos], clk], axis=-1)
    w = np.where(used, 1.0 / np.square(sigma_m), 0.0)
    gw_t = np.swapaxes(g * w[..., None], -1, -2)
    # matmul, not einsum: the same sums, ten times faster over thousands of epochs
    normal = gw_t @ g
    n_used = used.sum(axis=-1)
    n_need = n_states
    if idle is not None:
        c = n_pos + np.arange(idle.shape[-1])
        normal[..., c, c] += idle
        n_need = n_pos + (~idle).sum(axis=-1)
    ok = n_used >= n_need
    w_held = None
    if held_height and n_states == 4:
        with np.errstate(invalid="ignore", divide="ignore"):
            w_held = np.trace(normal[..., :3, :3], axis1=-2, axis2=-1) / n_used
        normal[..., 2, 2] += w_held
        ok = n_used >= n_need - 1
    eye = np.eye(g.shape[-1])
    safe = np.where(ok[..., None, None], normal, eye)
    regular = np.abs(np.linalg.det(safe)) > 1e-12
    try:
        q = np.linalg.inv(safe)
    except np.linalg.LinAlgError:  # an exactly singular geometry somewhere: leave it out
        ok &= regular
        q = np.linalg.inv(np.where(ok[..., None, None], safe, eye))
    return WlsGeometry(g, w, gw_t, q, ok, regular, n_used, w_held, n_pos)


def wls_solve(
    geom: WlsGeometry, used: np.ndarray, range_err_m: np.ndarray,
    error_sigma_m: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The fix's error and sigma for one set of range errors (see :func:`wls_fix`).

    Parameters
    ----------
    geom : from :func:`wls_geometry`
    used : (..., n_sat) bool, as given to it
    range_err_m : (..., n_sat) float, metres
    error_sigma_m : (..., n_sat) float, metres, the errors' own standard deviations for the
        covariance (None: the weights')

    Returns
    -------
    err_enu_m, sigma_enu_m : (..., 3) float, metres, as :func:`wls_fix`
    """
    g, w, q, ok = geom.g, geom.w, geom.q, geom.ok
    rhs = geom.gw_t @ np.where(used, range_err_m, 0.0)[..., None]
    sol = (q @ rhs)[..., 0]
    # A nearly singular geometry gives a huge solution: treat it as none (PDOP > 1e4).
    ok_err = ok & np.all(np.abs(sol) < 1e7, axis=-1)
    err = np.zeros(g.shape[:-2] + (3,))
    err[..., :2] = sol[..., :2]
    sigma = np.full(g.shape[:-2] + (3,), np.nan)
    cov = q
    if error_sigma_m is not None:
        wr = w * np.where(used, np.square(error_sigma_m), 0.0)  # r_i / sigma_i^2
        mid = np.swapaxes(g * (w * wr)[..., None], -1, -2) @ g  # G^T W R W G
        if geom.w_held is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                mid[..., 2, 2] += geom.w_held * wr.sum(axis=-1) / geom.n_used
        cov = q @ mid @ q
    diag = np.sqrt(np.abs(np.diagonal(cov, axis1=-2, axis2=-1)))
    sigma[..., :2] = diag[..., :2]
    if geom.n_pos == 3:
        err[..., 2] = sol[..., 2]
        sigma[..., 2] = diag[..., 2]
    return (np.where(ok_err[..., None], err, np.nan),
            np.where((ok & geom.regular)[..., None], sigma, np.nan))


def wls_fix(
    los_enu: np.ndarray, used: np.ndarray, sigma_m: np.ndarray, range_err_m: np.ndarray,
    n_states: int = 4, held_height: bool = False, error_sigma_m: np.ndarray | None = None,
    clocks: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Position error of a weighted least-squares fix made from erroneous ranges, and its sigma.

    Pseudorange residual model rho_err = -u . dx + c dt + eps; the WLS estimate
    dx = Q G^T W eps with Q = (G^T W G)^-1, G rows [-e, -n, -u, 1] (3D) or [-e, -n, 1] (2D,
    height held), W = diag(1 / sigma^2) over the used satellites; the estimate's covariance is
    Q (Misra & Enge, section 6.1). One normal matrix and one inverse serve both. Where the range
    errors' own standard deviations differ from the weights' (``error_sigma_m``: a receiver
    weighting by its textbook budget while its errors carry more), the covariance is the
    sandwich Q G^T W R W G Q, R = diag(error_sigma^2).

    Parameters
    ----------
    los_enu : (..., n_sat, 3) unit vectors to the satellites, ENU
    used : (..., n_sat) bool
    sigma_m : (..., n_sat) float, metres, range error standard deviations (weights)
    range_err_m : (..., n_sat) float, metres, the range errors
    n_states : 4 (east, north, up, clock) or 3 (east, north, clock: a 2D fix)
    held_height : with n_states 4, the held height of a 2D fix counts as one more measurement,
        a row [0, 0, 1, 0] weighted as the mean of the used ranges' weights (as in
        :func:`virtualgps.receiver.solution.dop`; its error is 0 here): 3 satellites then determine
        the states, and the sigmas are a 2D fix's own (what GST reports); with ``error_sigma_m`` its
        variance is the used ranges' mean error-to-weight variance ratio over its weight
    error_sigma_m : (..., n_sat) float, metres, the range errors' standard deviations for the
        covariance (None: ``sigma_m``)
    clocks : (n_sat, k) 0/1, one receiver clock per satellite system (:func:`clock_states`):
        the clock column becomes k, each state then needs one more used satellite; None: one
        clock (``n_states`` as given)

    Returns
    -------
    err_enu_m : (..., 3) float, metres (up is 0 for a 2D fix); NaN where the geometry does not
        determine the states
    sigma_enu_m : (..., 3) float, metres, sqrt(diag Q) of east, north and up (up NaN for a 2D
        fix); NaN with fewer than ``n_states`` used satellites or a singular geometry
    """
    geom = wls_geometry(los_enu, used, sigma_m, n_states, held_height, clocks)
    return wls_solve(geom, used, range_err_m, error_sigma_m)
