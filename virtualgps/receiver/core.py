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
antenna's position and time only, are :mod:`virtualgps.receiver.skyview`; tracking (C/N0 against
the thresholds) is here; the solution and its errors :mod:`virtualgps.receiver.solution`; the
output stage :mod:`virtualgps.receiver.output`; the state carried from epoch to epoch and the
layout of each epoch's random draws :mod:`virtualgps.receiver.state`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from virtualgps import geodesy
from virtualgps.receiver import errors, signals
from virtualgps.receiver.definition import Receiver
from virtualgps.receiver.output import carry_held_height, hold_altitude, output_stage
from virtualgps.receiver.params import Profile
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
from virtualgps.receiver.solution import (
    Processes,
    _carried,
    _dop_shared,
    clock_columns,
    dop,
    error_processes,
    position_errors,
    select_used,
    velocity_errors,
)
from virtualgps.receiver.state import (
    ReceiverRows,
    ReceiverState,
    draw_layout,
    draw_plan,
    draw_uniforms,
    model_streams,
)


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
    cn0_offset_db: float | np.ndarray = 0.0,
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """C/N0 and tracking of every satellite (``cn0_tracking``).

    Parameters
    ----------
    prof : profile
    sky : the epochs' sky, (n_t, n_sat)
    dt_s : (n_t,) seconds since the previous epoch (inf for the very first)
    state : receiver state before the batch
    processes : the batch's Gauss-Markov processes (the fades), from :func:`error_processes`
    cn0_offset_db : (n_sat,) or scalar, dB added per satellite (its system's signal level)

    Returns
    -------
    cn0_dbhz : (n_t, n_sat) dB-Hz of tracked satellites, NaN elsewhere
    usable : (n_t, n_sat) bool, tracked and (``use_dbhz``) strong enough to use in the fix
    state_update : the new ``fade_db``, ``tracked`` and ``acq_run`` for the receiver state
    """
    ct = prof.cn0_tracking
    n_t, n_sat = sky.el_deg.shape
    fade, fade0 = processes["fade"]
    cn0 = (ct.cn0_zenith_dbhz + cn0_offset_db
           + signals.antenna_gain_db(sky.el_deg, ct.horizon_loss_db) + fade)
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
        u = state.uniforms(draw_plan(tuple(layout.items())))
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
    # each satellite's system's C/N0 offset (constellations.cn0_offset_db; 0.0 for GPS alone)
    cn0_offset_db = prof.constellations.per_satellite(rx.ephemeris.prn, "cn0_offset_db", 0.0)
    if prof.cn0_tracking.enabled:
        cn0, usable, track_state = tracked_cn0(prof, sky, dt_s, state, processes,
                                               cn0_offset_db)
        seen = usable & sky.above_mask & pose_valid[:, None]
    else:
        track_state = {}
        seen = sky.above_mask & (~sky.blocked | sky.nlos) & pose_valid[:, None]
        cn0 = cn0_from_elevation_dbhz(
            sky.el_deg, prof.signal.cn0_horizon_dbhz, prof.signal.cn0_zenith_dbhz
        ) + cn0_offset_db
        cn0 = np.where(seen, cn0, np.nan)
    # systems switched off since the ephemeris was loaded (a u-blox client's CFG-GNSS): neither
    # tracked nor listed
    off = prof.constellations.untracked(rx.ephemeris.prn)
    if off is not None:
        seen = seen & ~off
        cn0 = np.where(off, np.nan, cn0)
    if state.usable_from_t_unix_s is not None:  # start-up: ephemerides still being decoded
        decoded = t[:, None] >= (state.usable_from_t_unix_s if rows
                                 else state.usable_from_t_unix_s[None, :])
        # The four highest satellites (the strongest signals) are decoded first: the first fix.
        first = select_used(seen, sky.el_deg, 4) & (t >= state.no_fix_until_t_unix_s)[:, None]
        seen = seen & (decoded | first)
    used = select_used(seen, sky.el_deg, prof.sky.max_channels)
    n_used = used.sum(axis=-1)
    starting = t < state.no_fix_until_t_unix_s
    clocks = clock_columns(rx.ephemeris.prn)  # (one clock per system tracked)
    hdop, vdop, pdop = (dop(sky.los_enu, used, clocks) if not shared_sky
                        else _dop_shared(sky, used, clocks))

    err = position_errors(prof, sky, used, n_used, z, layout, processes, rx.ephemeris.prn)
    mode = np.where(err.three_d, MODE_3D, np.where(err.two_d, MODE_2D, MODE_NONE))
    # A receiver with a PDOP mask declares no fix over a geometry worse than it (u-blox's
    # default 25): four nearly coplanar satellites would put the least squares kilometres off.
    # (A NaN PDOP leaves the mode as it is: the solution already said whether it has a fix.)
    has_fix = pose_valid & (mode > MODE_NONE) & ~starting & ~(pdop > prof.sky.pdop_mask)
    mode = np.where(has_fix, mode, MODE_NONE)
    vel = np.asarray(vel_enu_mps, dtype=float)
    vel = np.where(np.isnan(vel), 0.0, vel)
    err_m = carry_held_height(err.enu_m, err, has_fix, sky.alt_hae_m, state.last_alt_hae_m)
    if state.start_bias_enu_m is not None:  # start-up error converging after the first fix
        since = np.maximum(t - state.no_fix_until_t_unix_s, 0.0)
        decay = np.exp(-since / prof.cold_start.converge_tau_s)[:, None]
        biased = err_m + decay * state.start_bias_enu_m
        err_m = np.where(state.has_start_bias[:, None], biased, err_m) if rows else biased
    err_enu, out_state = output_stage(prof, t, ant, err_m, vel, dt_s, has_fix, pose_valid,
                                      state)
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
    if off is not None:
        in_view = in_view & ~off
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
