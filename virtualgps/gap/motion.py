"""How the fixes follow a moving truth: their lag behind it, and whether they follow its motion
delayed or smoothed (what tells an output delay from a navigation filter, DESIGN 7.5).

All functions take the fixes' errors about the truth for ``s`` seeds over ``n`` epochs, metres
ENU, and the truth's motion at those epochs; they return one value per seed (NaN where the
motion cannot show it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from virtualgps import geodesy

# The least velocity variation (rms about the mean, m/s) that separates a lag from a bias: a
# lag's standard error is about the error's sigma / (this * sqrt(epochs)), ~5 s for 3 m over 30
# epochs.
LAG_MIN_VEL_RMS_MPS = 0.2


def epoch_step_s(t: np.ndarray) -> float:
    """The median step between epochs, s (1 for fewer than two)."""
    return float(np.median(np.diff(t))) if t.size > 1 else 1.0


def lag_s(err_enu_m: np.ndarray, vel_enu_mps: np.ndarray, epochs: np.ndarray) -> np.ndarray:
    """How far the fixes lag behind the truth, in seconds: the least-squares L of
    e_k = b - L v_k over the epochs (horizontal error e, truth velocity v, a constant bias b
    per seed). A fix describing where the antenna was L seconds earlier (``latency``), or a
    low-pass filter of time constant L at constant velocity (``nav_filter``), gives L; a slowly
    varying error adds little, as the vehicle turns and stops. NaN with fewer than 30 epochs, or
    where the truth's velocity varies by less than LAG_MIN_VEL_RMS_MPS (rms about its mean): at
    a constant velocity a lag and a constant bias move the fixes alike.

    err_enu_m : (s, n, 3); vel_enu_mps : (n, 3); epochs : (n,) bool; returns (s,) seconds
    """
    out = np.full(err_enu_m.shape[0], np.nan)
    for i, e in enumerate(err_enu_m):
        ok = epochs & np.isfinite(e[:, :2]).all(axis=1)
        if ok.sum() < 30:
            continue
        v = vel_enu_mps[ok, :2]
        y = e[ok, :2]
        vc, yc = v - v.mean(axis=0), y - y.mean(axis=0)
        den = float(np.sum(vc * vc))
        if den >= ok.sum() * LAG_MIN_VEL_RMS_MPS ** 2:
            out[i] = -float(np.sum(vc * yc)) / den
    return out


# The delay and smoothing a log's fixes show (:func:`delay_smoothing_s`): the filter time
# constants tried (0.1 s apart where receivers' filters lie, coarser beyond), the longest delay
# (a log-vs-truth clock offset of seconds is a delay too), and the least acceleration of the
# truth (rms, m/s^2) that tells one from the other: at a constant velocity a first-order
# filter of tau and a delay of tau move the fixes alike.
SMOOTH_TAU_S = tuple(round(0.1 * k, 1) for k in range(21)) + (
    2.25, 2.5, 2.75, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0, 24.0)
SMOOTH_MAX_DELAY_S = 8.0
SMOOTH_MIN_ACC_RMS_MPS2 = 0.1
# Steps slower than this are left out: at walking pace a second of delay or smoothing moves a
# fix by about a metre, under a consumer receiver's noise, and errors that depend on where the
# antenna is (reflections off the walls it walks past) then pass for a response to its motion
# (a walk near the campus's buildings with nlos injected: smoothing_s 1.4 predictive sd off
# the seeds without it, and with it; a bicycle, a car or a drone runs faster).
SMOOTH_MIN_SPEED_MPS = 3.0


def lag_free_steps_m(err_enu_m: np.ndarray, truth_en_m: np.ndarray, t_unix_s: np.ndarray,
                     lag_s_: np.ndarray) -> np.ndarray:
    """How far the fixes move from one epoch to the next about the truth delayed by each
    seed's own lag (the error step of a receiver's noise alone): fix_k - truth(t_k - L).
    About the truth itself a delay L adds L times the change of velocity to every step, so
    that a delay would show as a rougher error, and adding the right ``latency`` to a
    smoother receiver's profile would widen its error-step gap (a 2 s delay injected into the
    GSDC Pixel 4 drive: its error step 0.19 m -> 0.57 m about the truth, 0.19 m about the
    delayed truth). What a filter leaves besides its lag (its rounding of the track, its
    smoothing of the noise) stays. Steps whose delayed time falls outside the known truth are
    NaN.

    err_enu_m : (s, n, 3) fixes minus truth, metres; truth_en_m : (n, 2) the truth east and
    north, metres (NaN where unknown); t_unix_s : (n,); lag_s_ : (s,) seconds (NaN: 0);
    returns (s, n - 1) metres
    """
    known = np.isfinite(truth_en_m).all(axis=1)
    lag = np.nan_to_num(np.clip(lag_s_, -SMOOTH_MAX_DELAY_S, SMOOTH_MAX_DELAY_S))
    out = np.full((err_enu_m.shape[0], t_unix_s.size - 1), np.nan)
    if known.sum() < 2:
        return out
    tk, xk = t_unix_s[known], truth_en_m[known]
    for i, (e, lag_i) in enumerate(zip(err_enu_m, lag, strict=True)):
        if lag_i == 0.0:  # (no lag measured: a static log, a slow walk)
            out[i] = np.hypot(*np.diff(e[:, :2], axis=0).T)
            continue
        td = t_unix_s - lag_i
        past = np.stack([np.interp(td, tk, xk[:, a]) for a in (0, 1)], axis=1)
        past[(td < tk[0]) | (td > tk[-1])] = np.nan
        d = np.diff(e[:, :2] + truth_en_m - past, axis=0)
        out[i] = np.hypot(d[:, 0], d[:, 1])
    return out


def local_en_m(lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """(n, 2) metres east and north in the ENU frame of the first finite point, NaN where
    unknown."""
    ok = np.isfinite(lat_deg) & np.isfinite(lon_deg)
    if not ok.any():
        return np.full((lat_deg.size, 2), np.nan)
    i = int(np.argmax(ok))
    ecef = geodesy.geodetic_to_ecef(lat_deg, lon_deg, np.zeros(lat_deg.size))
    return geodesy.ecef_to_enu(ecef, lat_deg[i], lon_deg[i], 0.0)[:, :2]


def _low_pass(x: np.ndarray, dt_s: float, tau_s: float) -> np.ndarray:
    """(m, 2) a first-order low-pass of time constant tau (0: x itself) at a fixed step."""
    if tau_s <= 0:
        return x
    from scipy.signal import lfilter

    a = math.exp(-dt_s / tau_s)
    y = lfilter([1.0 - a], [1.0, -a], x - x[0], axis=0)
    return y + x[0]


@dataclass(frozen=True)
class _TruthResponses:
    """What :func:`delay_smoothing_s` needs of a truth alone, at about 1 Hz (``m`` steps)."""

    idx: np.ndarray  # (m + 1,) the epochs kept
    step: float  # s between them
    truth: np.ndarray  # (m + 1, 2) metres, interpolated where unknown
    known: np.ndarray  # (m + 1,) bool
    usable: np.ndarray  # (m,) bool: fast, and known and regular as far back as the longest delay
    acc2: np.ndarray  # (m - 1,) squared acceleration at the steps' ends, (m/s^2)^2
    flat: np.ndarray  # (n_tau * (n_shift + 1), 2 m) each tau's steps at each whole delay
    same: np.ndarray  # (n_tau * (n_shift + 1), m) their squared lengths
    nxt: np.ndarray  # (n_tau * n_shift, m) products of neighbouring delays' steps
    n_shift: int


# The truth's responses last built, per process: the units of a run share its truth, and each
# job measures several of them (a job spent ~0.02 s per unit rebuilding it). One truth is kept
# (an hour at 1 Hz: ~37 MB, scaled from the GSDC drive's 17.6 MB; what one call held anyway).
TRUTH_CACHE_SIZE = 1
_TRUTHS: list[tuple[tuple[np.ndarray, ...], _TruthResponses | None]] = []


def _truth_responses(truth_lat_deg: np.ndarray, truth_lon_deg: np.ndarray, t_unix_s: np.ndarray
                     ) -> _TruthResponses | None:
    """The truth's low-passed steps at every tau of SMOOTH_TAU_S and whole-epoch delay, built
    once per truth (the arrays' identity); None with fewer than 31 known epochs."""
    for arrays, hit in _TRUTHS:
        if all(a is b for a, b in zip(arrays, (truth_lat_deg, truth_lon_deg, t_unix_s),
                                      strict=True)):
            return hit
    dt = epoch_step_s(t_unix_s)
    stride = max(1, int(round(1.0 / dt)))  # (about 1 Hz: the steps of a 10 Hz log are noise)
    idx = np.arange(0, t_unix_s.size, stride)
    t = t_unix_s[idx]
    step = dt * stride
    truth = local_en_m(truth_lat_deg[idx], truth_lon_deg[idx])
    known = np.isfinite(truth).all(axis=1)
    out = None
    if known.sum() >= 31:
        # the truth where unknown: interpolated (those steps are not counted; the filter runs
        # on)
        truth = np.stack([np.interp(t, t[known], truth[known, a]) for a in (0, 1)], axis=1)
        regular = known[1:] & known[:-1] & (np.abs(np.diff(t) - step) < 0.25 * step)
        n_shift = int(math.ceil(SMOOTH_MAX_DELAY_S / step)) + 1  # whole-epoch delays 0..n_shift
        # a step counts where the truth's steps as far back as the longest delay are known and
        # regular (a model of a gap in the truth would be no model)
        bad = np.concatenate((np.ones(n_shift, int), (~regular).astype(int)))
        back = np.convolve(bad, np.ones(n_shift + 1, int))[n_shift:n_shift + regular.size] == 0
        fast = np.hypot(*np.diff(truth, axis=0).T) >= SMOOTH_MIN_SPEED_MPS * step
        acc = np.diff(np.diff(truth, axis=0), axis=0) / step ** 2  # at the steps' ends
        n_tau = len(SMOOTH_TAU_S)
        m = truth.shape[0] - 1
        # each tau's model steps at every whole-epoch delay: (m, 2) columns
        shifted = np.zeros((n_tau, n_shift + 1, m, 2))
        for i, tau in enumerate(SMOOTH_TAU_S):
            steps = np.diff(_low_pass(truth, step, tau), axis=0)
            for j in range(n_shift + 1):
                shifted[i, j, j:] = steps[:m - j]
        # (the two components added by hand: a sum over a trailing axis of 2 took as long as
        # the fit)
        e, n = shifted[..., 0], shifted[..., 1]
        out = _TruthResponses(
            idx, step, truth, known, back & fast, (acc ** 2).sum(axis=1),
            shifted.reshape(n_tau * (n_shift + 1), 2 * m),
            (e * e + n * n).reshape(n_tau * (n_shift + 1), m),
            (e[:, :-1] * e[:, 1:] + n[:, :-1] * n[:, 1:]).reshape(n_tau * n_shift, m), n_shift)
    _TRUTHS.insert(0, ((truth_lat_deg, truth_lon_deg, t_unix_s), out))
    del _TRUTHS[TRUTH_CACHE_SIZE:]
    return out


def steps_show_motion(truth_lat_deg: np.ndarray, truth_lon_deg: np.ndarray,
                      t_unix_s: np.ndarray, epochs: np.ndarray) -> bool:
    """Whether the truth over these epochs lets :func:`delay_smoothing_s` measure how fixes
    follow it: 30 or more steps at SMOOTH_MIN_SPEED_MPS or faster (known and regular as far
    back as the longest delay), and an acceleration of SMOOTH_MIN_ACC_RMS_MPS2 (rms) or more
    over them. Of the truth alone: the same answer for a real log and every seed.

    truth_lat_deg, truth_lon_deg, t_unix_s : (n,); epochs : (n,) bool
    """
    tr = _truth_responses(truth_lat_deg, truth_lon_deg, t_unix_s)
    return tr is not None and bool(_steps_show_motion(_usable_steps(tr, epochs), tr.acc2))


def _usable_steps(tr: _TruthResponses, epochs: np.ndarray) -> np.ndarray:
    """(m,) bool: the truth's steps between two of ``epochs`` that the fit counts."""
    ok = epochs[tr.idx] & tr.known
    return ok[1:] & ok[:-1] & tr.usable


def _steps_show_motion(w: np.ndarray, acc2: np.ndarray) -> np.ndarray:
    """(...) bool per row of steps ``w`` (..., m): 30 or more of them, and the truth's
    acceleration at the ends of neighbouring ones SMOOTH_MIN_ACC_RMS_MPS2 (rms) or more."""
    wa = w[..., 1:] & w[..., :-1]
    acc_ms = (wa * acc2).sum(axis=-1) / np.maximum(wa.sum(axis=-1), 1)
    return (w.sum(axis=-1) >= 30) & (acc_ms >= SMOOTH_MIN_ACC_RMS_MPS2 ** 2)


def steps_lag_s(delay_s: np.ndarray, tau_s: np.ndarray, step_s: float = 1.0) -> np.ndarray:
    """The lag behind a truth at constant velocity of a delay L after a first-order filter of
    tau run at steps of ``step_s``: L + step a / (1 - a), a = exp(-step / tau) (the filter
    y_k = (1 - a) x_k + a y_(k-1) trails x_k = v k step by v step a / (1 - a); 0.58 s at
    tau 1 s, 1 Hz). The fit of :func:`delay_smoothing_s` trades a delay for a filter of like
    lag where its smoothing is under a step (a 0.63 s delay: some seeds tau 0.5-1.1 s with
    delay ~0); their lag is the same.

    delay_s, tau_s : (s,) seconds (NaN stays NaN); returns (s,) seconds
    """
    tau = np.asarray(tau_s, dtype=float)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        a = np.where(tau > 0, np.exp(-step_s / np.where(tau > 0, tau, 1.0)), 0.0)
        return np.asarray(delay_s, dtype=float) + np.where(np.isfinite(tau),
                                                           step_s * a / (1.0 - a), np.nan)


def fix_lag_s(err_enu_m: np.ndarray, vel_enu_mps: np.ndarray, truth_lat_deg: np.ndarray,
              truth_lon_deg: np.ndarray, t_unix_s: np.ndarray, epochs: np.ndarray,
              clear: np.ndarray | None = None,
              fitted: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """How far the fixes lag behind the truth, seconds, per seed. Where the truth's steps
    over the ``clear`` epochs show its motion (:func:`steps_show_motion`): the lag of the delay
    and filter that best follow it there, step to step (:func:`delay_smoothing_s`,
    :func:`steps_lag_s`): a receiver's slow error drops out of the steps, so the lag is
    pinned down some three to six times better than by :func:`lag_s` on the levels (the
    self-check's 15-minute drive against ``holux-m1000``: seeds' sd 0.021 s against 0.116 s
    under the null, 0.043 s against 0.116 s with a 0.63 s delay; the GSDC Pixel 4 drive: 0.017
    against 0.097 s). It is 0 or more there (a log ahead of its truth shows in the
    ``time_offset`` cause). Elsewhere (a slower truth, one that hardly accelerates) the
    least-squares :func:`lag_s` on the levels over all the epochs.

    ``clear``: the epochs whose errors do not depend on where the antenna is. Near buildings
    reflections come and go as it moves, and the steps read them as fixes that follow the
    motion late (a null drive on the bundled campus against ``holux-m1000``: the seeds' lag
    from the steps 0.91 s, sd 0.32 s, over all its moving epochs; 0.0 s, sd 0.04 s, over its
    open ones; on the levels -0.02 s, sd 0.17 s).

    err_enu_m : (s, n, 3) metres; vel_enu_mps : (n, 3); truth_lat_deg, truth_lon_deg,
    t_unix_s, epochs, clear : (n,), the last two bool; fitted : :func:`delay_smoothing_s` of
    these errors over ``epochs``, where already made (used where ``clear`` leaves out none
    of them); returns (s,) seconds
    """
    at = epochs if clear is None else epochs & clear
    if steps_show_motion(truth_lat_deg, truth_lon_deg, t_unix_s, at):
        delay, tau = (fitted if fitted is not None and np.array_equal(at, epochs) else
                      delay_smoothing_s(err_enu_m, truth_lat_deg, truth_lon_deg, t_unix_s, at))
        step = _truth_responses(truth_lat_deg, truth_lon_deg, t_unix_s).step
        return steps_lag_s(delay, tau, step)
    return lag_s(err_enu_m, vel_enu_mps, epochs)


def delay_smoothing_s(err_enu_m: np.ndarray, truth_lat_deg: np.ndarray,
                      truth_lon_deg: np.ndarray, t_unix_s: np.ndarray, epochs: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """How the fixes follow the truth's motion: the delay L and the first-order smoothing tau
    whose response to the truth (its positions low-passed with tau, then delayed by L) best
    matches the fixes' own motion, epoch to epoch. What tells a delay from a navigation
    filter (DESIGN 7.5): at a constant velocity both lag by their time, but through turns,
    stops and starts a delay keeps the track's shape (tau 0) and a filter rounds it (tau its
    time constant). The fit is on the fixes' steps (differences of consecutive epochs at
    about 1 Hz), so a receiver's slow error (minutes) and any bias drop out, and its white
    noise, uncorrelated with the truth's motion, widens the estimate without moving it.

    Least squares over the grid of :data:`SMOOTH_TAU_S` and every delay up to
    :data:`SMOOTH_MAX_DELAY_S` (whole epochs, and the fraction between two in closed form:
    the delayed truth is interpolated linearly between epochs, as a delay's fixes are), for
    every seed at once: sums over epochs as matrix products. Only steps at
    SMOOTH_MIN_SPEED_MPS or faster count; NaN with fewer than 30 of them, or where the
    truth's acceleration is under SMOOTH_MIN_ACC_RMS_MPS2 (rms). The truth's responses are
    built once per truth (the same arrays) and kept for the next call.

    err_enu_m : (s, n, 3) fixes minus truth, metres; truth_lat_deg, truth_lon_deg, t_unix_s :
    (n,); epochs : (n,) bool, those to measure; returns (delay (s,) s, tau (s,) s)
    """
    s = err_enu_m.shape[0]
    nan = (np.full(s, np.nan), np.full(s, np.nan))
    tr = _truth_responses(truth_lat_deg, truth_lon_deg, t_unix_s)
    if tr is None:
        return nan
    fix = tr.truth[None] + err_enu_m[:, tr.idx, :2]
    d_fix = np.diff(fix, axis=1)  # (s, m, 2)
    seen = np.isfinite(fix).all(axis=2)
    w = _usable_steps(tr, epochs)[None] & seen[:, 1:] & seen[:, :-1]
    if w.sum(axis=1).max() < 30:
        return nan
    d_fix = np.where(w[..., None], d_fix, 0.0)
    n_tau, n_shift = len(SMOOTH_TAU_S), tr.n_shift
    m = d_fix.shape[1]
    flat, same, nxt = tr.flat, tr.same, tr.nxt
    rows = np.arange(s)

    def fit(wt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tau index, whole delay, fraction) per seed minimising the weighted squares."""
        # (row by row: a product of all seeds at once rounds its last bits by how many rows
        # it holds, and a seed's lag must not depend on how the seeds were cut into jobs)
        wd = (wt[..., None] * d_fix).reshape(s, 2 * m)
        b = np.stack([r @ flat.T for r in wd]).reshape(s, n_tau, n_shift + 1)  # sum w D.P_j
        c = np.stack([r @ same.T for r in wt]).reshape(s, n_tau, n_shift + 1)  # sum w |P_j|^2
        x = np.stack([r @ nxt.T for r in wt]).reshape(s, n_tau, n_shift)  # sum w P_j.P_(j+1)
        # the fraction f between delays j and j + 1 minimising
        # -2 (1-f) B_j - 2 f B_(j+1) + (1-f)^2 C_j + 2 f (1-f) X_j + f^2 C_(j+1)
        bj, bk, cj, ck = b[..., :-1], b[..., 1:], c[..., :-1], c[..., 1:]
        curv = cj - 2 * x + ck
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.clip(np.where(curv > 0, (bk - bj + cj - x) / curv, 0.0), 0.0, 1.0)
        cost = (-2 * (1 - f) * bj - 2 * f * bk + (1 - f) ** 2 * cj + 2 * f * (1 - f) * x
                + f ** 2 * ck)  # (s, n_tau, n_shift): the sum of squares less sum w |D|^2
        i_tau, j = np.unravel_index(np.argmin(cost.reshape(s, -1), axis=1), cost.shape[1:])
        return i_tau, j, f[rows, i_tau, j]

    i_tau, j, frac = fit(w.astype(float))
    delay = (j + frac) * tr.step
    tau = np.asarray(SMOOTH_TAU_S)[i_tau]
    bad = ~_steps_show_motion(w, tr.acc2)
    return np.where(bad, np.nan, delay), np.where(bad, np.nan, tau)
