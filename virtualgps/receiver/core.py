"""The pure receiver core: antenna poses + sky + profile + state + random generator -> fixes.

One code path serves the live daemon (batches of one epoch), replay (thousands of epochs) and the
gap tool. Nothing here touches files, clocks or sockets; the random generator and the receiver
state are passed in and the new state is returned, so running N epochs at once gives the same
numbers as running them one at a time (the generator is consumed identically: one row of
uniforms per epoch, whether or not there is a fix).

Per-epoch pipeline (DESIGN section 1): georeference -> satellite ECEF (SGP4) -> az/el ->
elevation mask -> line of sight against the scene (NLOS reflections, foliage) -> C/N0 and tracking
-> used satellites -> DOP -> errors (the paper's, or per-satellite ranges solved by least squares)
-> output stage (latency, smoothing, static hold) -> Fixes. The effects of DESIGN section 6 are
switched on and set by the profile. The stages up to the line of sight, which depend on the
antenna's position and time only, are :mod:`virtualgps.receiver.skyview`; the state carried from
epoch to epoch and the layout of each epoch's random draws are :mod:`virtualgps.receiver.state`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from virtualgps import geodesy
from virtualgps.receiver import errors, signals
from virtualgps.receiver.definition import Receiver
from virtualgps.receiver.profiles import CorrelatedErrorParams, Profile
from virtualgps.receiver.records import (
    MODE_2D,
    MODE_3D,
    MODE_NONE,
    QUALITY_DGPS,
    QUALITY_GPS,
    QUALITY_NONE,
    Fixes,
)
from virtualgps.receiver.skyview import Sky, compute_sky
from virtualgps.receiver.state import (
    ReceiverRows,
    ReceiverState,
    draw_layout,
    draw_plan,
    draw_uniforms,
    model_streams,
)


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


def dop(los_enu: np.ndarray, used: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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

    Parameters
    ----------
    los_enu : (..., n_sat, 3) unit vectors to the satellites, ENU
    used : (..., n_sat) bool

    Returns
    -------
    hdop, vdop, pdop : (...) float; NaN with fewer than 3 used satellites or a singular geometry
    """
    w = used.astype(float)[..., None]
    los = np.where(np.isnan(los_enu), 0.0, los_enu)  # (nan_to_num is slow on tiny arrays)
    g = np.concatenate([-los, np.ones(los_enu.shape[:-1] + (1,))], axis=-1)
    normal = np.swapaxes(g * w, -1, -2) @ g  # G^T W G (a matrix product: ~6x einsum's speed)
    n_used = used.sum(axis=-1)
    normal[..., 2, 2] += n_used == 3  # the held height's row [0, 0, 1, 0] (2D fix)
    ok = n_used >= 3
    safe = np.where(ok[..., None, None], normal, np.eye(4))
    try:
        q = np.linalg.inv(safe)
    except np.linalg.LinAlgError:  # an exactly singular geometry somewhere: find it
        ok &= np.abs(np.linalg.det(safe)) > 1e-9
        q = np.linalg.inv(np.where(ok[..., None, None], safe, np.eye(4)))
    # A nearly singular geometry (e.g. every satellite at one elevation: up and clock can't be
    # told apart) inverts to huge or negative variances; a real one has PDOP < 1e4.
    diag = np.diagonal(q, axis1=-2, axis2=-1)[..., :3]
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


def cn0_from_elevation_dbhz(
    el_deg: np.ndarray, horizon_dbhz: float, zenith_dbhz: float
) -> np.ndarray:
    """C/N0 of a directly received satellite: linear in sin(elevation).

    Parameters
    ----------
    el_deg : (...) float, degrees
    horizon_dbhz, zenith_dbhz : float, dB-Hz at 0 and 90 deg

    Returns
    -------
    cn0_dbhz : (...) float, dB-Hz
    """
    s = np.sin(np.radians(np.clip(el_deg, 0.0, 90.0)))
    return horizon_dbhz + (zenith_dbhz - horizon_dbhz) * s


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


Processes = dict[str, tuple[np.ndarray, np.ndarray]]  # name -> (x (n_t, m), its start x0)


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
) -> PositionErrors:
    """The position error of each epoch under the profile's error model.

    The paper's model (``noise.model = "usarsim"``): white horizontal noise with sigma(n).
    ``dop_error``: per-satellite range errors with the UERE sigma of their elevation (white, or
    Gauss-Markov with ``correlated_error`` in the range domain plus white receiver noise),
    solved by weighted least squares over the used satellites: 3D with >= 4, 2D (height held)
    with 3; ``nlos`` adds the reflected path's excess, ``multipath`` a Gauss-Markov error on
    each satellite received directly (its sigma from the elevation and the distance to the
    nearest wall: :func:`virtualgps.receiver.errors.multipath_sigma_m`). ``correlated_error`` in the
    position domain adds Gauss-Markov E/N/U errors.

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
    three_d = n_used >= 4
    two_d = np.zeros(n_t, bool)
    held_gain = np.zeros((n_t, 2))
    # The UERE sigma of each satellite (dop_error's weights; correlated_error's shape)
    sigma_i = errors.uere_sigma_m(sky.el_deg, *_uere_args(prof)) if prof.dop_error.enabled \
        else None
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
        geom3 = errors.wls_geometry(sky.los_enu, used, sigma_i, n_states=4)
        e3, sigma_enu = errors.wls_solve(geom3, used, eps, error_sigma_m=err_sigma)
        three_d = three_d & np.isfinite(e3[:, 0])
        two_d = n_used == 3
        e2 = np.zeros_like(e3)
        k = np.flatnonzero(two_d)  # solve 2D (height held) only where three are used
        if k.size:
            geom2 = errors.wls_geometry(sky.los_enu[k], used[k], sigma_i[k], n_states=3)
            e2[k] = errors.wls_solve(geom2, used[k], eps[k])[0]
            # A held height off by dh leaves u_up dh in each range's residual (rows [-e, -n,
            # -u, 1]), which the 3-state solution moves into east/north: its response to 1 m.
            up = np.where(np.isnan(sky.los_enu[k][..., 2]), 0.0, sky.los_enu[k][..., 2])
            held_gain[k] = errors.wls_solve(geom2, used[k], up)[0][:, :2]
            # The 2D fix's own sigmas (GST), the held height counted as a measurement.
            sigma_enu[k] = errors.wls_fix(
                sky.los_enu[k], used[k], sigma_i[k], eps[k], held_height=True,
                error_sigma_m=None if err_sigma is None else err_sigma[k])[1]
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


def carry_held_height(
    err_enu_m: np.ndarray, err: PositionErrors, has_fix: np.ndarray, truth_alt_hae_m: np.ndarray,
    last_alt_hae_m: float,
) -> np.ndarray:
    """2D fixes carry their held height's error into east/north.

    A 2D fix holds the altitude of the last 3D fix; where that is off the antenna's true
    height by dh (the 3D fix's vertical error, plus any climb since), the 3-state solution
    moves by ``held_gain_en`` x dh horizontally (Misra & Enge 6.1 with the height fixed).

    Parameters
    ----------
    err_enu_m : (n_t, 3) metres, the fix errors (up meaningless on 2D epochs)
    err : the epochs' :class:`PositionErrors`
    has_fix : (n_t,) bool, epochs with a fix
    truth_alt_hae_m : (n_t,) metres, the antenna's true height
    last_alt_hae_m : the altitude of the last 3D fix before the batch (NaN: none)

    Returns
    -------
    err_enu_m : (n_t, 3) with the 2D epochs' east/north moved
    """
    two = has_fix & err.two_d & ~err.three_d
    if not two.any():
        return err_enu_m
    held, _ = hold_altitude(truth_alt_hae_m + err_enu_m[:, 2], has_fix & err.three_d, two,
                            last_alt_hae_m)
    dh = np.where(two, held - truth_alt_hae_m, 0.0)
    dh = np.where(np.isfinite(dh), dh, 0.0)  # (no 3D altitude to hold yet: no fix anyway)
    out = err_enu_m.copy()
    out[:, :2] += err.held_gain_en * dh[:, None]
    return out


def expected_cn0_dbhz(prof: Profile, sky: Sky) -> np.ndarray:
    """C/N0 each satellite's signal arrives with, without random fading (``virtualgps sky``).

    Parameters
    ----------
    prof : profile
    sky : (..., n_sat) sky

    Returns
    -------
    cn0_dbhz : (..., n_sat) dB-Hz; NaN where no signal arrives (below the horizon, blocked
        without a reflection)
    """
    above = sky.el_deg >= 0.0  # NaN (no ephemeris): False
    arrives = above & (~sky.blocked | sky.nlos)
    if prof.cn0_tracking.enabled:
        ct = prof.cn0_tracking
        cn0 = ct.cn0_zenith_dbhz + signals.antenna_gain_db(sky.el_deg, ct.horizon_loss_db)
    else:
        sig = prof.signal
        cn0 = cn0_from_elevation_dbhz(sky.el_deg, sig.cn0_horizon_dbhz, sig.cn0_zenith_dbhz)
    cn0 = cn0 - sky.nlos_loss_db - sky.foliage_db
    return np.where(arrives, cn0, np.nan)


def tracked_cn0(
    prof: Profile, sky: Sky, dt_s: np.ndarray, state: ReceiverState, processes: Processes,
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """C/N0 and tracking of every satellite (``cn0_tracking``).

    Parameters
    ----------
    prof : profile
    sky : the epochs' sky, (n_t, n_sat)
    dt_s : (n_t,) seconds since the previous epoch (inf for the very first)
    state : receiver state before the batch
    processes : the batch's Gauss-Markov processes (the fades), from :func:`error_processes`

    Returns
    -------
    cn0_dbhz : (n_t, n_sat) dB-Hz of tracked satellites, NaN elsewhere
    usable : (n_t, n_sat) bool, tracked and (``use_dbhz``) strong enough to use in the fix
    state_update : the new ``fade_db``, ``tracked`` and ``acq_run`` for the receiver state
    """
    ct = prof.cn0_tracking
    n_t, n_sat = sky.el_deg.shape
    fade, fade0 = processes["fade"]
    cn0 = ct.cn0_zenith_dbhz + signals.antenna_gain_db(sky.el_deg, ct.horizon_loss_db) + fade
    above = sky.el_deg >= 0.0  # NaN (no ephemeris): False
    # Blocked: no signal, unless a reflection brings it in, weaker by the reflection loss.
    cn0 = cn0 - sky.nlos_loss_db - sky.foliage_db
    cn0 = np.where(above & (~sky.blocked | sky.nlos), cn0, -np.inf)
    rows = isinstance(state, ReceiverRows)
    finite_dt = dt_s[np.isfinite(dt_s)]
    if rows:  # each receiver's own step (its first epoch: the profile's)
        step = np.where(np.isfinite(dt_s), dt_s, 1.0 / prof.rate_hz)
        reacq = np.maximum(1, np.ceil(ct.reacq_s / step - 1e-9).astype(int))[:, None]
    elif finite_dt.size > 1:
        step_s = float(np.median(finite_dt))
    else:  # (the live loop's one epoch: np.median costs more than the rest of the tracking)
        step_s = float(finite_dt[0]) if finite_dt.size else 1.0 / prof.rate_hz
    if not rows:
        reacq = max(1, int(np.ceil(ct.reacq_s / step_s - 1e-9)))
    tracked0 = state.tracked if state.tracked is not None else np.zeros(n_sat, bool)
    run0 = state.acq_run if state.acq_run is not None else np.zeros(n_sat, int)
    tracked, run = signals.track(cn0, ct.acq_dbhz, ct.track_dbhz, reacq, tracked0, run0)
    out = np.where(tracked, cn0, np.nan)
    usable = tracked & (cn0 - fade >= ct.use_dbhz) if ct.use_dbhz > 0.0 else tracked
    return out, usable, {"fade_db": _carried(fade, fade0), "tracked": _carried(tracked, tracked0),
                         "acq_run": run}


def nav_filter(
    pos_enu_m: np.ndarray,
    dt_s: np.ndarray,
    has_fix: np.ndarray,
    tau_s: float,
    y0_enu_m: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Smooth output positions with a first-order low-pass filter that restarts after gaps.

    y_k = a_k x_k + (1 - a_k) y_(k-1) with a_k = 1 - exp(-dt_k / tau) over each run of epochs
    with a fix; the first epoch of a run restarts the filter (y = x) unless it continues the
    state carried in; epochs without a fix pass their input through.

    Parameters
    ----------
    pos_enu_m : (n_t, 3) metres, the positions to smooth, scene ENU
    dt_s : (n_t,) seconds since the previous epoch (inf for the very first: a = 1)
    has_fix : (n_t,) bool
    tau_s : the filter's time constant, seconds
    y0_enu_m : (3,) metres, the filter output at the epoch before the batch, or None (restart);
        (n_t, 3) for rows that are receivers at one epoch each (NaN rows: restart)

    Returns
    -------
    filt_enu_m : (n_t, 3) metres, the filter output
    y_enu_m : (3,) metres, the output at the last epoch to carry on, or None (no fix there)
    """
    a = 1.0 - np.exp(-np.asarray(dt_s, dtype=float) / tau_s)
    keep = 1.0 - a
    filt = np.array(pos_enu_m, dtype=float)
    if y0_enu_m is not None and y0_enu_m.ndim == 2:  # rows: receivers, one epoch each; NaN
        # rows of y0 restart (as None does)
        cont = has_fix & ~np.isnan(y0_enu_m[:, 0])
        filt = np.where(cont[:, None], a[:, None] * filt + keep[:, None] * y0_enu_m, filt)
        return filt, np.where(has_fix[:, None], filt, np.nan)
    fix = np.asarray(has_fix, dtype=bool).tolist()
    if len(fix) > 8:  # runs of fixes [start, stop): the recursion only restarts at a run's start
        edges = np.flatnonzero(np.diff(np.concatenate(([False], fix, [False])).astype(int)))
        runs = zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True)
    else:  # a few epochs (the live loop): each fix a run of its own, no bookkeeping
        runs = ((k, k + 1) for k, f in enumerate(fix) if f)
    y = y0_enu_m
    for start, stop in runs:
        if y is None or (start > 0 and not fix[start - 1]):  # restart
            y = filt[start]
        else:
            y = a[start] * filt[start] + keep[start] * y
            filt[start] = y
        k = start + 1
        if stop > k:
            filt[k:stop] = errors.first_order_recursion(y, keep[k:stop],
                                                        a[k:stop, None] * filt[k:stop])
            y = filt[stop - 1]
    if fix and not fix[-1]:  # the next epoch with a fix restarts
        y = None
    return filt, y


def output_stage(
    prof: Profile,
    truth_enu_m: np.ndarray,
    err_enu_m: np.ndarray,
    vel_enu_mps: np.ndarray,
    dt_s: np.ndarray,
    has_fix: np.ndarray,
    state: ReceiverState,
) -> tuple[np.ndarray, dict[str, np.ndarray | None]]:
    """What the receiver does to its solution before output: ``latency``, ``nav_filter``,
    ``static_hold`` (in that order).

    Parameters
    ----------
    prof : profile
    truth_enu_m : (n_t, 3) metres, true antenna positions, scene ENU
    err_enu_m : (n_t, 3) metres, the solution's error
    vel_enu_mps : (n_t, 3) metres per second, true velocity
    dt_s : (n_t,) seconds since the previous epoch (inf for the very first)
    has_fix : (n_t,) bool
    state : receiver state before the batch

    Returns
    -------
    err_enu_m : (n_t, 3) metres, error of the position output
    state_update : new ``nav_enu_m`` and ``hold_enu_m``
    """
    out = truth_enu_m + err_enu_m
    update: dict[str, np.ndarray | None] = {}
    if prof.latency.enabled:  # the position latency_s ago, to first order in the velocity
        out = out - vel_enu_mps * prof.latency.latency_s
    if prof.nav_filter.enabled:
        out, update["nav_enu_m"] = nav_filter(
            out, dt_s, has_fix, prof.nav_filter.tau_s, state.nav_enu_m
        )
    if prof.static_hold.enabled and prof.static_hold.threshold_mps > 0:
        slow = has_fix & (np.hypot(vel_enu_mps[:, 0], vel_enu_mps[:, 1])
                          < prof.static_hold.threshold_mps)
        if isinstance(state, ReceiverRows):  # receivers, one epoch each (NaN: none held)
            carried = slow & ~np.isnan(state.hold_enu_m[:, 0])
            out = np.where(carried[:, None], state.hold_enu_m, out)
            update["hold_enu_m"] = np.where(slow[:, None], out, np.nan)
            return out - truth_enu_m, update
        # Each slow run holds the output of its first epoch (or the held position carried in).
        k = np.arange(out.shape[0])
        start = np.maximum.accumulate(np.where(~slow, k + 1, 0))  # first epoch of the run
        carry = state.hold_enu_m is not None
        held = out[np.minimum(start, out.shape[0] - 1)]
        if carry:
            held = np.where((start == 0)[:, None], state.hold_enu_m, held)
        out = np.where(slow[:, None], held, out)
        update["hold_enu_m"] = out[-1].copy() if slow.size and slow[-1] else None
    return out - truth_enu_m, update


def _carried(x: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """The state a batch leaves for the next: its last epoch's row, or, for receivers side by
    side (``x0`` one row per receiver, :class:`ReceiverRows`), every row."""
    return x if x0.ndim == 2 else x[-1]


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


@functools.lru_cache(maxsize=64)
def _uere_zenith_m(uere_args: tuple[float, ...]) -> np.ndarray:
    """The UERE sigma at the zenith, metres (a 0-d array), for :func:`_uere_args`' budget
    (cached: a profile's budget is fixed, and the live loop runs one epoch per call)."""
    return errors.uere_sigma_m(np.array(90.0), *uere_args)


def hold_altitude(
    alt_hae_m: np.ndarray, fix_3d: np.ndarray, fix_2d: np.ndarray, last_alt_hae_m: float
) -> tuple[np.ndarray, float]:
    """A 2D fix reports the altitude of the last 3D fix (MTK and most receivers hold it).

    Parameters
    ----------
    alt_hae_m : (n_t,) metres, the 3D solution's altitude (meaningless on 2D epochs)
    fix_3d, fix_2d : (n_t,) bool
    last_alt_hae_m : altitude of the last 3D fix before the batch (NaN if none); (n_t,) for
        rows that are receivers side by side at one epoch each

    Returns
    -------
    alt_hae_m : (n_t,) metres, with 2D epochs holding the last 3D altitude (NaN if none yet)
    last_alt_hae_m : the last 3D altitude after the batch ((n_t,) for rows)
    """
    if np.ndim(last_alt_hae_m) == 1:  # rows: each its own one epoch
        return (np.where(fix_2d, last_alt_hae_m, alt_hae_m),
                np.where(fix_3d, alt_hae_m, last_alt_hae_m))
    if not fix_2d.any():
        last = alt_hae_m[fix_3d][-1] if fix_3d.any() else last_alt_hae_m
        return alt_hae_m, float(last)
    vals = np.concatenate([[last_alt_hae_m], np.where(fix_3d, alt_hae_m, np.nan)])
    idx = np.where(np.isfinite(vals), np.arange(vals.size), 0)
    held = vals[np.maximum.accumulate(idx)][:-1]  # last 3D altitude strictly before each epoch
    out = np.where(fix_2d, held, alt_hae_m)
    return out, float(vals[np.maximum.accumulate(idx)][-1])


_LAST_DOP: list = [None]  # (sky, used, dops) of the last ensemble call


def _dop_shared(sky: Sky, used: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`dop` for an ensemble sharing one sky: seeds that use the same satellites at
    every epoch (the paper's model, any model without tracking noise) share the result."""
    last = _LAST_DOP[0]
    if last is not None and last[0] is sky and np.array_equal(last[1], used):
        return last[2]
    out = dop(sky.los_enu, used)
    _LAST_DOP[0] = (sky, used.copy(), out)
    return out


def simulate(
    rx: Receiver,
    t_unix_s: np.ndarray,
    antenna_enu_m: np.ndarray,
    vel_enu_mps: np.ndarray,
    pose_valid: np.ndarray,
    state: ReceiverState,
    rng: np.random.Generator,
    sky: Sky | None = None,
) -> tuple[Fixes, ReceiverState]:
    """Run the receiver over ``n_t`` epochs.

    Parameters
    ----------
    rx : the receiver
    t_unix_s : (n_t,) float, epoch times, UTC seconds (the simulated clock)
    antenna_enu_m : (n_t, 3) float, metres, true antenna position in the scene's ENU frame
    vel_enu_mps : (n_t, 3) float, metres per second, ENU (NaN where unknown: speed 0)
    pose_valid : (n_t,) bool, False where no recent pose exists (no-fix epochs)
    state : the receiver state after the previous epoch
    rng : the random generator (consumed: two uniforms per epoch, the paper's; every other
        model draws from its own stream,
        :func:`~virtualgps.receiver.state.model_streams`, kept in the state)
    sky : the sky of these epochs and positions, from :func:`compute_sky` with this receiver
        (None: computed here). An ensemble of seeds over one run shares it: the sky holds
        everything that does not depend on the random numbers (satellites, rays, reflections).

    Returns
    -------
    fixes : Fixes over the n_t epochs
    state : the receiver state after the last epoch
    """
    prof = rx.profile
    t = np.atleast_1d(np.asarray(t_unix_s, dtype=float))
    n_t = t.shape[0]
    ant = np.where(pose_valid[:, None], antenna_enu_m, 0.0)
    shared_sky = sky is not None
    if sky is None:
        sky = compute_sky(rx, t, ant)
    layout = draw_layout(prof, len(rx.ephemeris.prn))
    # All random numbers of an epoch come as one row per stream, so batch and epoch-by-epoch
    # runs consume the generators identically (the paper's model uses the first two columns,
    # from ``rng`` itself).
    rows = isinstance(state, ReceiverRows)  # receivers side by side, one epoch each
    if rows:
        streams = state.streams
        u = np.empty((n_t, layout["total"]))
        plan = draw_plan(tuple(layout.items()))
        for i, (r, st) in enumerate(zip(state.rngs, streams, strict=True)):
            for name, a, b in plan:  # (draw_uniforms' one row, written in place)
                (r if name == "usarsim" else st[name]).random(out=u[i, a:b])
        dt_s = t - state.last_t_unix_s
    else:
        streams = state.streams if state.streams is not None else model_streams(rng)
        u = draw_uniforms(rng, streams, layout, n_t)
        dt_s = t - np.concatenate(([state.last_t_unix_s], t[:-1]))  # (np.diff: slow on one)
    dt_s = np.where(np.isfinite(dt_s), dt_s, np.inf)  # first epoch ever: stationary start
    # Steps to the microsecond: epochs k / rate far from 1970 differ from 1 / rate in their last
    # bits; equal steps keep the Gauss-Markov recursions on their one-coefficient fast path.
    dt_s = np.round(dt_s, 6)
    # Every model takes standard normals (Box-Muller pairs: each model's block starts at an
    # even column), made in one pass over the row: the live epoch's per-call costs add up.
    z = errors.normals_from_uniforms(u)
    processes = error_processes(prof, state, dt_s, z, layout, len(rx.ephemeris.prn))
    if prof.cn0_tracking.enabled:
        cn0, usable, track_state = tracked_cn0(prof, sky, dt_s, state, processes)
        seen = usable & sky.above_mask & pose_valid[:, None]
    else:
        track_state = {}
        seen = sky.above_mask & (~sky.blocked | sky.nlos) & pose_valid[:, None]
        cn0 = cn0_from_elevation_dbhz(
            sky.el_deg, prof.signal.cn0_horizon_dbhz, prof.signal.cn0_zenith_dbhz
        )
        cn0 = np.where(seen, cn0, np.nan)
    if state.usable_from_t_unix_s is not None:  # start-up: ephemerides still being decoded
        decoded = t[:, None] >= (state.usable_from_t_unix_s if rows
                                 else state.usable_from_t_unix_s[None, :])
        # The four highest satellites (the strongest signals) are decoded first: the first fix.
        first = select_used(seen, sky.el_deg, 4) & (t >= state.no_fix_until_t_unix_s)[:, None]
        seen = seen & (decoded | first)
    used = select_used(seen, sky.el_deg, prof.sky.max_channels)
    n_used = used.sum(axis=-1)
    starting = t < state.no_fix_until_t_unix_s
    hdop, vdop, pdop = dop(sky.los_enu, used) if not shared_sky else _dop_shared(sky, used)

    err = position_errors(prof, sky, used, n_used, z, layout, processes)
    mode = np.where(err.three_d, MODE_3D, np.where(err.two_d, MODE_2D, MODE_NONE))
    has_fix = pose_valid & (mode > MODE_NONE) & ~starting
    mode = np.where(has_fix, mode, MODE_NONE)
    vel = np.asarray(vel_enu_mps, dtype=float)
    vel = np.where(np.isnan(vel), 0.0, vel)
    err_m = carry_held_height(err.enu_m, err, has_fix, sky.alt_hae_m, state.last_alt_hae_m)
    if state.start_bias_enu_m is not None:  # start-up error converging after the first fix
        since = np.maximum(t - state.no_fix_until_t_unix_s, 0.0)
        decay = np.exp(-since / prof.cold_start.converge_tau_s)[:, None]
        biased = err_m + decay * state.start_bias_enu_m
        err_m = np.where(state.has_start_bias[:, None], biased, err_m) if rows else biased
    err_enu, out_state = output_stage(prof, ant, err_m, vel, dt_s, has_fix, state)
    north_m, east_m, up_m = err_enu[:, 1], err_enu[:, 0], err_enu[:, 2]
    if prof.georef == "flat_earth":
        lat, lon = geodesy.flat_earth_offset_deg(sky.lat_deg, sky.lon_deg, east_m, north_m)
    else:
        lat, lon = geodesy.offset_geodetic_deg(
            sky.lat_deg, sky.lon_deg, sky.alt_hae_m, east_m, north_m
        )
    # The paper's model perturbs latitude and longitude only (up_m is 0 there). A 2D fix holds
    # the altitude of the last 3D fix.
    alt_hae = sky.alt_hae_m + up_m
    alt_hae, last_alt = hold_altitude(
        alt_hae, has_fix & (mode == MODE_3D), has_fix & (mode == MODE_2D), state.last_alt_hae_m
    )
    lost_2d = has_fix & ~np.isfinite(alt_hae)  # a 2D fix with no 3D altitude to hold: none
    has_fix &= ~lost_2d
    mode = np.where(has_fix, mode, MODE_NONE)
    geoid = geodesy.geoid_sep_m(lat, lon)

    # Speed and course from the Doppler-derived velocity: the truth plus its error.
    vel_err, rr_state = velocity_errors(prof, used, processes, err)
    v_rep = vel + vel_err
    speed = np.hypot(v_rep[:, 0], v_rep[:, 1])
    course = np.degrees(np.arctan2(v_rep[:, 0], v_rep[:, 1])) % 360.0

    in_view = (sky.el_deg >= 0.0) & pose_valid[:, None]  # NaN elevation: False
    nofix = np.where(has_fix, 1.0, np.nan)
    truth_nan = np.where(pose_valid, 1.0, np.nan)
    fixes = Fixes(
        t_unix_s=t,
        lat_deg=lat * nofix,
        lon_deg=lon * nofix,
        alt_msl_m=(alt_hae - geoid) * nofix,
        geoid_sep_m=geoid,
        quality=np.where(
            has_fix, QUALITY_DGPS if prof.sbas.enabled else QUALITY_GPS, QUALITY_NONE
        ).astype(np.int8),
        mode=mode.astype(np.int8),
        hdop=hdop * nofix,
        vdop=vdop * nofix,
        pdop=pdop * nofix,
        speed_mps=speed * nofix,
        course_deg=course * nofix,
        prn=np.asarray(rx.ephemeris.prn),
        az_deg=sky.az_deg,
        el_deg=sky.el_deg,
        cn0_dbhz=cn0,
        in_view=in_view,
        used=used & has_fix[:, None],
        truth_lat_deg=sky.lat_deg * truth_nan,
        truth_lon_deg=sky.lon_deg * truth_nan,
        truth_alt_hae_m=sky.alt_hae_m * truth_nan,
        sigma_enu_m=err.sigma_enu_m * nofix[:, None],
        range_rms_m=err.range_rms_m * nofix,
    )
    new_state = replace(
        state,
        n_epochs=state.n_epochs + (1 if rows else n_t),
        last_t_unix_s=t if rows else (float(t[-1]) if n_t else state.last_t_unix_s),
        gm_m=err.gm_m,
        mp_m=err.mp_m,
        rr_mps=rr_state,
        streams=streams,
        last_alt_hae_m=last_alt,
        **track_state,
        **out_state,
    )
    return fixes, new_state
