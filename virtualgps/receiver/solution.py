"""The position solution and its errors: which satellites are used, their geometry (DOP), and
the error of each fix, from the paper's satellite-count noise to per-satellite range errors
correlated over minutes and solved by least squares; velocity errors beside them.

Pure numpy over ``(n_t, n_sat)`` epochs; the random numbers come in from
:mod:`virtualgps.receiver.state`, so that a chunked replay and the live daemon draw the same.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from virtualgps.receiver import errors
from virtualgps.receiver.params import CorrelatedErrorParams, Profile
from virtualgps.receiver.skyview import Sky
from virtualgps.receiver.state import ReceiverState
from virtualgps.sky import systems


def usarsim_sigma_m(n_sats: np.ndarray, max_noise_m: float, min_noise_m: float) -> np.ndarray:
    """The paper's noise sigma as a function of the satellites seen (Eq. 1-3).

    m = (maxNoise - minNoise) / (4 - 12), b = maxNoise - 4 m, sigma = (m n + b) / 3:
    maxNoise/3 at 4 satellites, minNoise/3 at 12. We clip n to [4, 12]: fewer than 4 gives no
    fix, and a 12-channel receiver (GSA has 12 fields) uses at most 12.

    Parameters
    ----------
    n_sats : (...) int, satellites used
    max_noise_m, min_noise_m : float, metres

    Returns
    -------
    sigma_m : (...) float, metres, per horizontal axis
    """
    slope = (max_noise_m - min_noise_m) / (4.0 - 12.0)  # Eq. 1
    intercept = max_noise_m - 4.0 * slope  # Eq. 2
    n = np.clip(np.asarray(n_sats, dtype=float), 4.0, 12.0)
    return (slope * n + intercept) / 3.0  # Eq. 3


@functools.lru_cache(maxsize=16)
def _clock_columns(prn: tuple[int, ...]) -> np.ndarray | None:
    letters = systems.letters(np.asarray(prn, dtype=np.int64))
    # (SBAS ranges, where used, share GPS time; a number of no known system counts as GPS)
    letters = np.where(np.isin(letters, ("S", "?")), "G", letters)
    kinds = list(dict.fromkeys(letters.tolist()))
    if len(kinds) < 2:
        return None
    return (letters[:, None] == np.array(kinds)[None, :]).astype(float)


def clock_columns(prn: np.ndarray) -> np.ndarray | None:
    """Each satellite's receiver-clock unknown: one per satellite system of the constellation
    (:func:`virtualgps.receiver.errors.clock_states`).

    Parameters
    ----------
    prn : (n_sat,) int, the satellites' numbers (:mod:`virtualgps.sky.systems`)

    Returns
    -------
    clocks : (n_sat, k) float 0/1, one column per system in order of first appearance; None
        for a single system (one clock, as before)
    """
    return _clock_columns(tuple(np.asarray(prn, dtype=np.int64).tolist()))


def dop(los_enu: np.ndarray, used: np.ndarray, clocks: np.ndarray | None = None
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dilutions of precision of the used satellites' geometry, as an MTK receiver reports them.

    G has a row [-e, -n, -u, 1] per used satellite (unit line of sight, receiver clock);
    Q = (G^T G)^-1 in the local ENU frame; HDOP = sqrt(Qee + Qnn), VDOP = sqrt(Quu),
    PDOP = sqrt(Qee + Qnn + Quu) (Misra & Enge, Global Positioning System, section 6.1.3).

    With exactly 3 used satellites (a 2D fix: the height is held) the held height counts as one
    more measurement, a row [0, 0, 1, 0] with the weight of a range. G is then square and only
    that row sees the height, so VDOP = 1 and PDOP^2 = HDOP^2 + 1; HDOP^2 is the 3-state (east,
    north, clock) HDOP^2 plus the horizontal variance a unit height error causes (nothing for
    satellites on the horizon). This is what MTK firmware prints: the 2D fixes of
    gpsd-mtk/mtk-3301.log:72 (3 satellites, ``3.05,2.88,1.00``) and mtk-3329.log:11 (4
    satellites, ``1.62,1.31,0.95``) come out to the printed digits from their GSV azimuths and
    elevations; the 3-state HDOP with the height taken as exact (2.75 for mtk-3301) does not.

    A receiver of several systems solves one clock per system (``clocks``; a system with no
    satellite used leaves its clock out): each used system's clock takes one satellite, so the
    3D fix needs 3 + (systems used) satellites and the DOP is that of the larger G.

    Parameters
    ----------
    los_enu : (..., n_sat, 3) unit vectors to the satellites, ENU
    used : (..., n_sat) bool
    clocks : (n_sat, k) 0/1, each satellite's system (:func:`clock_columns`); None: one clock

    Returns
    -------
    hdop, vdop, pdop : (...) float; NaN with fewer than 2 + (systems used) satellites or a
        singular geometry
    """
    # Q's position block in closed form, (A - B C^-1 B^T)^-1 (the Schur complement of the
    # clocks' block C), its diagonal by cofactors: each satellite belongs to one system, so C
    # is diagonal (the used satellites per clock; a clock none determines drops out). 2.8x
    # (one clock) to 3.6x (two) the speed of stacked 4 x 4 products and inverses over an
    # ensemble's epochs (the benchmark hour's jobs spent 14 % of their time in them); equal
    # to 1e-15 relative but at geometries with HDOP in the thousands (1e-8 there, no further
    # from the exact value).
    # The sums over satellites are matrix products, one per epoch as before: an epoch's DOP
    # does not depend on the batch it is computed in, to the last bit.
    w = used.astype(float)
    u = np.where(np.isnan(los_enu), 0.0, los_enu)  # (nan_to_num is slow on tiny arrays)
    uw_t = np.swapaxes(u * w[..., None], -1, -2)  # (..., 3, n_sat); G's rows are -u: signs
    a = uw_t @ u  # cancel in pairs
    cols = np.ones((used.shape[-1], 1)) if clocks is None else np.asarray(clocks, dtype=float)
    b = uw_t @ cols  # (..., 3, k_clocks)
    c = w @ cols  # (..., k_clocks) used satellites per clock
    n_used = used.sum(axis=-1)
    n_clocks = (c > 0).sum(axis=-1)
    with np.errstate(divide="ignore"):
        inv_c = np.where(c > 0, 1.0 / c, 0.0)

    def m(i: int, j: int) -> np.ndarray:
        return a[..., i, j] - (b[..., i, :] * b[..., j, :] * inv_c).sum(axis=-1)

    m00, m01, m02, m11, m12 = m(0, 0), m(0, 1), m(0, 2), m(1, 1), m(1, 2)
    m22 = m(2, 2) + (n_used == 2 + n_clocks)  # the held height's row [0, 0, 1, 0] (2D fix)
    c00, c11, c22 = m11 * m22 - m12 * m12, m00 * m22 - m02 * m02, m00 * m11 - m01 * m01
    det = m00 * c00 - m01 * (m01 * m22 - m12 * m02) + m02 * (m01 * m12 - m11 * m02)
    ok = n_used >= 2 + n_clocks
    with np.errstate(divide="ignore", invalid="ignore"):
        diag = np.stack([c00, c11, c22], axis=-1) / det[..., None]
    # A nearly singular geometry (e.g. every satellite at one elevation: up and clock can't be
    # told apart) inverts to huge or negative variances (an exactly singular one to inf or
    # NaN); a real one has PDOP < 1e4.
    ok &= np.all((diag >= 0.0) & (diag < 1e8), axis=-1)
    diag = np.where(ok[..., None], diag, np.nan)
    qe, qn, qu = diag[..., 0], diag[..., 1], diag[..., 2]
    return np.sqrt(qe + qn), np.sqrt(qu), np.sqrt(qe + qn + qu)


def select_used(seen: np.ndarray, el_deg: np.ndarray, max_channels: int) -> np.ndarray:
    """The satellites a receiver with ``max_channels`` channels uses: the highest seen ones.

    Parameters
    ----------
    seen : (..., n_sat) bool, satellites the receiver could use
    el_deg : (..., n_sat) float, degrees
    max_channels : int

    Returns
    -------
    used : (..., n_sat) bool, at most ``max_channels`` True per epoch
    """
    if seen.shape[-1] <= max_channels:
        return seen.copy()
    key = np.where(seen, el_deg, -np.inf)  # a seen satellite has a finite elevation
    order = np.argsort(-key, axis=-1, kind="stable")
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(seen.shape[-1]), axis=-1)
    return seen & (rank < max_channels)


@dataclass(frozen=True)
class PositionErrors:
    """Output of :func:`position_errors`.

    enu_m : (n_t, 3) metres, error of the reported position (up 0 for the paper's model)
    three_d, two_d : (n_t,) bool, a 3D / 2D solution exists (enough used satellites)
    gm_m : the Gauss-Markov state after the batch (None when the effect is off)
    mp_m : the ``multipath`` Gauss-Markov state after the batch (None when the effect is off)
    sigma_enu_m : (n_t, 3) metres, the model's 1-sigma of each axis (what GST reports); NaN
        where the model has none
    range_rms_m : (n_t,) metres, RMS range error sigma of the used satellites (NaN: none)
    held_gain_en : (n_t, 2) metres of east/north error per metre of error in a 2D fix's held
        height (0 where the fix is not 2D): the 3-state solution's response to the ranges'
        residual u_up x dh (:func:`carry_held_height`)
    uere_sigma_m : (n_t, n_sat) metres, the UERE sigmas weighting the fix (None without
        ``dop_error``)
    wls_3d : the 4-state least squares' geometry of every epoch, and ``wls_2d`` the 3-state
        one of the epochs with three used satellites (``two_d_rows``): the Doppler solution
        (:func:`velocity_errors`) has the same weights (None without ``dop_error``)
    """

    enu_m: np.ndarray
    three_d: np.ndarray
    two_d: np.ndarray
    gm_m: np.ndarray | None
    mp_m: np.ndarray | None
    sigma_enu_m: np.ndarray
    range_rms_m: np.ndarray
    held_gain_en: np.ndarray
    uere_sigma_m: np.ndarray | None = None
    wls_3d: errors.WlsGeometry | None = None
    wls_2d: errors.WlsGeometry | None = None
    two_d_rows: np.ndarray | None = None


def error_processes(
    prof: Profile, state: ReceiverState, dt_s: np.ndarray, z: np.ndarray, layout: dict[str, int],
    n_sat: int,
) -> Processes:
    """The first-order Gauss-Markov processes of the profile's error models over a batch, run
    together (:func:`virtualgps.receiver.errors.gauss_markov_processes`: each epoch's step costs the
    same however many processes it carries).

    Parameters
    ----------
    prof : profile
    state : receiver state before the batch (the processes' carried values)
    dt_s : (n_t,) seconds since the previous epoch (inf for the very first)
    z : (n_t, total) standard normals, one row per epoch
    layout : from :func:`~virtualgps.receiver.state.draw_layout`
    n_sat : number of satellites

    Returns
    -------
    processes : {name: (x, x0)}, x (n_t, m) the process at each epoch and x0 the value it
        started from, for each model that is on: "fade" (``cn0_tracking``: C/N0 fades, dB,
        per satellite), "gm" (``correlated_error``: unit range processes per satellite, or
        east/north/up metres in the position domain), "mp" (``multipath`` with ``dop_error``:
        unit, per satellite), "rr" (``dop_error``'s range rates: unit, per satellite)
    """
    sets: dict[str, tuple[np.ndarray, float, np.ndarray, np.ndarray]] = {}
    ct = prof.cn0_tracking
    if ct.enabled:
        c = layout["fade"]
        fade0 = state.fade_db if state.fade_db is not None else np.zeros(n_sat)
        sets["fade"] = (fade0, ct.fade_tau_s, np.full(n_sat, ct.fade_sigma_db),
                        z[:, c : c + n_sat])
    ce = prof.correlated_error
    if ce.enabled:
        c = layout["gm"]
        if ce.domain == "range":
            sets["gm"] = (_gm_start(state.gm_m, n_sat), ce.tau_s, np.ones(n_sat),
                          z[:, c : c + n_sat])
        else:
            sets["gm"] = (_gm_start(state.gm_m, 3), ce.tau_s, _gm_enu_sigma_m(ce), z[:, c : c + 3])
    if prof.dop_error.enabled and prof.multipath.enabled:
        c = layout["multipath"]
        sets["mp"] = (_gm_start(state.mp_m, n_sat), prof.multipath.tau_s, np.ones(n_sat),
                      z[:, c : c + n_sat])
    if "velocity" in layout:
        c = layout["velocity"]
        sets["rr"] = (_gm_start(state.rr_mps, n_sat), prof.dop_error.range_rate_tau_s,
                      np.ones(n_sat), z[:, c : c + n_sat])
    xs = errors.gauss_markov_processes(list(sets.values()), dt_s)
    return {name: (x, args[0]) for (name, args), x in zip(sets.items(), xs, strict=True)}


def _gm_enu_sigma_m(ce: CorrelatedErrorParams) -> np.ndarray:
    """(3,) metres: the east/north/up sigmas of ``correlated_error`` in the position domain."""
    return np.array([ce.sigma_m, ce.sigma_m, ce.sigma_m * ce.up_ratio])


def position_errors(
    prof: Profile,
    sky: Sky,
    used: np.ndarray,
    n_used: np.ndarray,
    z: np.ndarray,
    layout: dict[str, int],
    processes: Processes,
    prn: np.ndarray | None = None,
) -> PositionErrors:
    """The position error of each epoch under the profile's error model.

    The paper's model (``noise.model = "usarsim"``): white horizontal noise with sigma(n).
    ``dop_error``: per-satellite range errors with the UERE sigma of their elevation (white, or
    Gauss-Markov with ``correlated_error`` in the range domain plus white receiver noise),
    solved by weighted least squares over the used satellites: 3D with >= 4, 2D (height held)
    with 3 (one more for each further system's clock, ``prn``); ``nlos`` adds the reflected
    path's excess, ``multipath`` a Gauss-Markov error on each satellite received directly (its
    sigma from the elevation and the distance to the nearest wall:
    :func:`virtualgps.receiver.errors.multipath_sigma_m`). ``correlated_error`` in the position
    domain adds Gauss-Markov E/N/U errors.

    Parameters
    ----------
    prof : profile
    sky : the epochs' sky, (n_t, n_sat)
    used : (n_t, n_sat) bool, used satellites
    n_used : (n_t,) int
    z : (n_t, total) standard normals, one row per epoch (the row of uniforms through
        :func:`virtualgps.receiver.errors.normals_from_uniforms`)
    layout : from :func:`~virtualgps.receiver.state.draw_layout`
    processes : the batch's Gauss-Markov processes, from :func:`error_processes`
    prn : (n_sat,) the satellites' numbers: with several systems, one clock per system
        (:func:`clock_columns`) and each system's signal-in-space error
        (``constellations.sis_factor``); None: GPS alone

    Returns
    -------
    errors : PositionErrors
    """
    n_t, n_sat = used.shape
    enu = np.zeros((n_t, 3))
    var = np.zeros((n_t, 3))  # variance of each axis under the model
    modelled = np.zeros(3, bool)  # axes the model says something about
    range_rms = np.full(n_t, np.nan)
    gm_state = mp_state = None
    geom3 = geom2 = k = None
    clocks = clock_columns(prn) if prn is not None else None
    _, idle = errors.clock_states(used, clocks)
    n_clocks = 1 if idle is None else (~idle).sum(axis=-1)
    three_d = n_used >= 3 + n_clocks
    two_d = np.zeros(n_t, bool)
    held_gain = np.zeros((n_t, 2))
    # The UERE sigma of each satellite (dop_error's weights; correlated_error's shape)
    sigma_i = (errors.uere_sigma_m(sky.el_deg, _sat_sis_m(prof, prn), *_uere_args(prof)[1:])
               if prof.dop_error.enabled else None)
    if prof.noise.model == "usarsim":
        sigma = usarsim_sigma_m(n_used, prof.noise.max_noise_m, prof.noise.min_noise_m)
        # (Box-Muller from the paper's two uniforms: the paper draws its noise this way, and
        # a seed then gives the same numbers whatever numpy's own normal sampler does.)
        z_north, z_east = z[:, 0], z[:, 1]
        enu[:, 0], enu[:, 1] = sigma * z_east, sigma * z_north
        var[:, :2] += (sigma**2)[:, None]
        modelled[:2] = True
    ce = prof.correlated_error
    if ce.enabled:
        gm, x0 = processes["gm"]
        gm_state = _carried(gm, x0)
        if ce.domain == "range":
            el_shape = sigma_i / _uere_zenith_m(_uere_args(prof))
            corr_range = ce.sigma_m * el_shape * gm  # unit process, scaled per satellite
        else:
            enu += gm
            var += _gm_enu_sigma_m(ce) ** 2
            modelled[:] = True
    if sigma_i is not None:  # dop_error
        c = layout["white"]
        z_white = z[:, c : c + n_sat]
        # The errors' own variance where it differs from the weights' (the receiver weights
        # by its textbook budget): the reported sigma must be that of the errors it makes.
        err_var = None
        if ce.enabled and ce.domain == "range":
            eps = corr_range + prof.dop_error.rx_noise_m * z_white
            err_var = (ce.sigma_m * el_shape) ** 2 + prof.dop_error.rx_noise_m**2
        else:
            eps = sigma_i * z_white
        eps = eps + np.where(sky.nlos, sky.excess_m, 0.0)  # reflected: longer path, positive bias
        mp = prof.multipath
        if mp.enabled:
            # Unit processes, one per satellite, running whether or not it is seen; the sigma
            # follows the elevation and the antenna's distance to the walls epoch by epoch.
            x, x0 = processes["mp"]
            mp_state = _carried(x, x0)
            sigma_mp = errors.multipath_sigma_m(sky.el_deg, sky.wall_dist_m, mp.sigma_m,
                                                mp.el0_deg, mp.max_dist_m, mp.open_sky_factor)
            # Line of sight only: a blocked satellite arrives, if at all, off a wall (nlos).
            eps = eps + np.where(sky.blocked, 0.0, sigma_mp * x)
            err_var = (sigma_i**2 if err_var is None else err_var) \
                + np.where(sky.blocked, 0.0, sigma_mp**2)
        err_sigma = None if err_var is None else np.sqrt(err_var)
        geom3 = errors.wls_geometry(sky.los_enu, used, sigma_i, n_states=4, clocks=clocks)
        e3, sigma_enu = errors.wls_solve(geom3, used, eps, error_sigma_m=err_sigma)
        three_d = three_d & np.isfinite(e3[:, 0])
        two_d = n_used == 2 + n_clocks
        e2 = np.zeros_like(e3)
        k = np.flatnonzero(two_d)  # solve 2D (height held) only where one is missing
        if k.size:
            geom2 = errors.wls_geometry(sky.los_enu[k], used[k], sigma_i[k], n_states=3,
                                        clocks=clocks)
            e2[k] = errors.wls_solve(geom2, used[k], eps[k])[0]
            # A held height off by dh leaves u_up dh in each range's residual (rows [-e, -n,
            # -u, 1]), which the 3-state solution moves into east/north: its response to 1 m.
            up = np.where(np.isnan(sky.los_enu[k][..., 2]), 0.0, sky.los_enu[k][..., 2])
            held_gain[k] = errors.wls_solve(geom2, used[k], up)[0][:, :2]
            # The 2D fix's own sigmas (GST), the held height counted as a measurement.
            sigma_enu[k] = errors.wls_fix(
                sky.los_enu[k], used[k], sigma_i[k], eps[k], held_height=True,
                error_sigma_m=None if err_sigma is None else err_sigma[k], clocks=clocks)[1]
        two_d &= np.isfinite(e2[:, 0])
        enu = enu + np.where(three_d[:, None], e3, np.where(two_d[:, None], e2, 0.0))
        var += np.square(sigma_enu)
        modelled[:] = True
        n = used.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            range_var = sigma_i**2 if err_var is None else err_var
            range_rms = np.sqrt(np.where(used, range_var, 0.0).sum(axis=1) / n)
    sigma = np.where(modelled, np.sqrt(var), np.nan)
    held_gain = np.where(np.isfinite(held_gain), held_gain, 0.0)
    return PositionErrors(enu, three_d, two_d, gm_state, mp_state, sigma, range_rms, held_gain,
                          sigma_i, geom3, geom2, k)


def velocity_errors(
    prof: Profile, used: np.ndarray, processes: Processes, pos_err: PositionErrors,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The reported velocity's error: Doppler range-rate errors solved like the ranges.

    Each satellite's range-rate error is a unit first-order Gauss-Markov process times
    ``dop_error.range_rate_sigma_mps`` scaled with elevation like the UERE; the weighted least
    squares of the position (4 states; 3 for a 2D fix) turns them into east/north/up velocity
    errors, so they grow with the DOP and jump when the used set changes.

    Parameters
    ----------
    prof, used, processes : as :func:`position_errors`
    pos_err : its result for these epochs (the UERE sigmas and least-squares geometry, shared)

    Returns
    -------
    vel_err_enu_mps : (n_t, 3) metres per second (0 without ``dop_error`` or a fix)
    rr_mps : (n_sat,) the processes after the batch (None when off)
    """
    n_t = used.shape[0]
    d = prof.dop_error
    if "rr" not in processes:
        return np.zeros((n_t, 3)), None
    x, x0 = processes["rr"]
    # (The velocity needs dop_error, so the position's weights and geometry exist: the same
    # UERE sigmas, used satellites and epochs with three of them.)
    sigma_i = pos_err.uere_sigma_m
    eps = d.range_rate_sigma_mps * (sigma_i / _uere_zenith_m(_uere_args(prof))) * x
    e = errors.wls_solve(pos_err.wls_3d, used, eps)[0]
    k = pos_err.two_d_rows
    if k is not None and k.size:  # a 2D fix: east/north/clock drift
        e[k] = errors.wls_solve(pos_err.wls_2d, used[k], eps[k])[0]
    return np.where(np.isfinite(e), e, 0.0), _carried(x, x0)


def _gm_start(carried: np.ndarray | None, n: int) -> np.ndarray:
    """The (n,) Gauss-Markov state to continue from: the one carried in the receiver state,
    or zeros at the start (the first epoch's infinite step then draws it from the stationary
    distribution)."""
    if carried is not None and carried.shape[-1:] == (n,):
        return carried  # ((rows, n): receivers side by side, ReceiverRows)
    return np.zeros(n)


def _uere_args(prof: Profile) -> tuple[float, ...]:
    d = prof.dop_error
    sis_k, iono_k = (prof.sbas.sis_factor, prof.sbas.iono_factor) if prof.sbas.enabled else (1, 1)
    return (d.sis_m * sis_k, d.iono_zenith_m * iono_k, d.tropo_zenith_m, d.rx_noise_m,
            d.multipath_a_m, d.multipath_b_m)


def _sat_sis_m(prof: Profile, prn: np.ndarray | None) -> float | np.ndarray:
    """The signal-in-space range error sigma of each satellite, metres: GPS's (with SBAS's
    factor) for GPS, ``constellations.sis_factor`` times ``dop_error.sis_m`` for the other
    systems; a float when every satellite has GPS's."""
    gps = _uere_args(prof)[0]
    if prn is None:
        return gps
    f = prof.constellations.per_satellite(prn, "sis_factor", 0.0)  # (0: GPS's own)
    if np.ndim(f) == 0:
        return gps
    return np.where(f > 0.0, prof.dop_error.sis_m * f, gps)


@functools.lru_cache(maxsize=64)
def _uere_zenith_m(uere_args: tuple[float, ...]) -> np.ndarray:
    """The UERE sigma at the zenith, metres (a 0-d array), for :func:`_uere_args`' budget
    (cached: a profile's budget is fixed, and the live loop runs one epoch per call)."""
    return errors.uere_sigma_m(np.array(90.0), *uere_args)


def _dop_shared(sky: Sky, used: np.ndarray, clocks: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`dop` for an ensemble sharing one sky: seeds that use the same satellites at
    every epoch (the paper's model, any model without tracking noise) share the result."""
    last = _LAST_DOP[0]
    if last is not None and last[0] is sky and np.array_equal(last[1], used):
        return last[2]
    out = dop(sky.los_enu, used, clocks)
    _LAST_DOP[0] = (sky, used.copy(), out)
    return out


Processes = dict[str, tuple[np.ndarray, np.ndarray]]  # name -> (x (n_t, m), its start x0)


def _carried(x: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """The state a batch leaves for the next: its last epoch's row, or, for receivers side by
    side (``x0`` one row per receiver, :class:`ReceiverRows`), every row."""
    return x if x0.ndim == 2 else x[-1]


_LAST_DOP: list = [None]  # (sky, used, dops) of the last ensemble call
