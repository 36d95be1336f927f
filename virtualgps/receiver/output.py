"""The receiver's output stage, after the solution: latency, the navigation filter's smoothing,
static hold, and the height held while the fix is 2D.

Pure numpy over time; what carries across epochs (the filter's last output, the held height)
comes in and goes out through :class:`virtualgps.receiver.state.ReceiverState`.
"""

from __future__ import annotations

import numpy as np

from virtualgps.receiver import errors
from virtualgps.receiver.params import Profile
from virtualgps.receiver.solution import (
    PositionErrors,
)
from virtualgps.receiver.state import (
    ReceiverRows,
    ReceiverState,
)


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


def delayed_enu_m(
    t_unix_s: np.ndarray,
    truth_enu_m: np.ndarray,
    vel_enu_mps: np.ndarray,
    known: np.ndarray,
    latency_s: float,
    state: ReceiverState,
) -> tuple[np.ndarray, dict[str, np.ndarray | None]]:
    """Where the antenna was ``latency_s`` before each epoch: the truth's positions (those of
    the batch and those the state carries from before it) interpolated linearly at t - L, as
    the poses themselves are. A pure output delay keeps the fix on the path, through turns and
    stops alike (the second-order expansion x - v L + a L^2 / 2 it replaces did not: with the
    velocity of the pose segment ahead and the acceleration of the one behind, a 0.9 s delay
    on a 1 Hz drive responded to the turns like a 0.7 s delay behind a 0.6 s filter). Before
    the first known position: that position, moved back along the epoch's velocity.

    Parameters
    ----------
    t_unix_s : (n_t,) UTC seconds
    truth_enu_m : (n_t, 3) metres, the true antenna positions
    vel_enu_mps : (n_t, 3) metres per second, the true velocity (0 where unknown)
    known : (n_t,) bool, epochs whose truth is known (a valid pose)
    latency_s : the delay L, seconds
    state : the receiver state before the batch (:class:`ReceiverState`: ``past_t_unix_s``,
        ``past_enu_m`` the known positions before it; :class:`ReceiverRows`: (n_t, K) and
        (n_t, K, 3) per receiver, NaN where none)

    Returns
    -------
    delayed_enu_m : (n_t, 3) metres
    state_update : the new ``past_t_unix_s`` and ``past_enu_m``
    """
    t = np.asarray(t_unix_s, dtype=float)
    td = t - latency_s
    if isinstance(state, ReceiverRows):  # receivers side by side, one epoch each
        ht = np.concatenate((state.past_t_unix_s, np.where(known, t, np.nan)[:, None]), axis=1)
        hx = np.concatenate((state.past_enu_m, truth_enu_m[:, None, :]), axis=1)
        # (the known times of a row increase along it, with NaN where none)
        before = ht <= td[:, None]
        k = ht.shape[1]
        a = np.where(before.any(axis=1), k - 1 - np.argmax(before[:, ::-1], axis=1), -1)
        after = ht > td[:, None]
        b = np.where(after.any(axis=1), np.argmax(after, axis=1), -1)
        rows = np.arange(t.size)
        ta, tb = ht[rows, a], ht[rows, b]
        xa, xb = hx[rows, a], hx[rows, b]
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.clip((td - ta) / (tb - ta), 0.0, 1.0)[:, None]
        has_a, has_b = (a >= 0)[:, None], (b >= 0)[:, None]
        out = np.select(
            [has_a & has_b, has_b, has_a],
            [xa + w * (xb - xa),  # between two known positions
             xb + vel_enu_mps * (td - tb)[:, None],  # before the first known one
             xa],  # (the epoch's own pose unknown: no fix is output)
            truth_enu_m - vel_enu_mps * latency_s)
        keep = np.where(known[:, None], np.arange(1, k), np.arange(k - 1))
        return out, {"past_t_unix_s": np.take_along_axis(ht, keep, axis=1),
                     "past_enu_m": np.take_along_axis(hx, keep[..., None], axis=1)}
    past_t = state.past_t_unix_s if state.past_t_unix_s is not None else np.empty(0)
    past_x = state.past_enu_m if state.past_enu_m is not None else np.empty((0, 3))
    ht = np.concatenate((past_t, t[known]))
    hx = np.concatenate((past_x, np.asarray(truth_enu_m, dtype=float)[known]))
    if ht.size == 0:
        return truth_enu_m - vel_enu_mps * latency_s, {"past_t_unix_s": None,
                                                        "past_enu_m": None}
    out = np.stack([np.interp(td, ht, hx[:, j]) for j in range(3)], axis=1)
    early = td < ht[0]
    if early.any():
        out[early] = hx[0] + vel_enu_mps[early] * (td[early] - ht[0])[:, None]
    # what the next batch needs: the positions after ht[-1] - L, and the one before
    first = max(0, int(np.searchsorted(ht, ht[-1] - latency_s, side="right")) - 1)
    return out, {"past_t_unix_s": ht[first:], "past_enu_m": hx[first:]}


def output_stage(
    prof: Profile,
    t_unix_s: np.ndarray,
    truth_enu_m: np.ndarray,
    err_enu_m: np.ndarray,
    vel_enu_mps: np.ndarray,
    dt_s: np.ndarray,
    has_fix: np.ndarray,
    known: np.ndarray,
    state: ReceiverState,
) -> tuple[np.ndarray, dict[str, np.ndarray | None]]:
    """What the receiver does to its solution before output: ``latency``, ``nav_filter``,
    ``static_hold`` (in that order).

    Parameters
    ----------
    prof : profile
    t_unix_s : (n_t,) UTC seconds
    truth_enu_m : (n_t, 3) metres, true antenna positions, scene ENU
    err_enu_m : (n_t, 3) metres, the solution's error
    vel_enu_mps : (n_t, 3) metres per second, true velocity
    dt_s : (n_t,) seconds since the previous epoch (inf for the very first)
    has_fix : (n_t,) bool
    known : (n_t,) bool, epochs whose truth is known (a valid pose)
    state : receiver state before the batch

    Returns
    -------
    err_enu_m : (n_t, 3) metres, error of the position output
    state_update : new ``nav_enu_m``, ``hold_enu_m`` and (with ``latency``) the truth's
        past positions
    """
    out = truth_enu_m + err_enu_m
    update: dict[str, np.ndarray | None] = {}
    if prof.latency.enabled:
        then, past = delayed_enu_m(t_unix_s, truth_enu_m, vel_enu_mps, known,
                                   prof.latency.latency_s, state)
        update.update(past)
        out = out - truth_enu_m + then
    if prof.nav_filter.enabled and prof.nav_filter.velocity_aided:
        # (the state carries the filtered error: the motion itself is not filtered)
        smooth, update["nav_enu_m"] = nav_filter(
            err_enu_m, dt_s, has_fix, prof.nav_filter.tau_s, state.nav_enu_m
        )
        out = out - err_enu_m + smooth
    elif prof.nav_filter.enabled:
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
