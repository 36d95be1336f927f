"""How the fixes follow a moving truth: their lag behind it, and whether they keep to its path
or cut its corners (what tells an output delay from a navigation filter, DESIGN 7.5).

All functions take the fixes' errors about the truth for ``s`` seeds over ``n`` epochs, metres
ENU, and the truth's motion at those epochs; they return one value per seed (NaN where the
motion cannot show it).
"""

from __future__ import annotations

import math

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


CUT_WINDOW_S = 20.0  # a fix is placed on the truth's path within this time of its epoch
CUT_MIN_LAT_RMS_MPS2 = 0.1  # the least lateral acceleration (rms) that shows a rounded corner
# The distance to the path less its mean over +-CUT_HIGH_PASS_S: a receiver's slow error (range
# errors of minutes) leaves the turns' seconds-long cuts alone and no longer hides them. On the
# GSDC drive against holux-m1000 it halves the seeds' spread of the slope (0.9 -> 0.3-0.4 s^2),
# and the phone's own slow cross-track wander no longer makes its fixes, delayed by 2.7 s, look
# filtered (1.10 -> 0.12 s^2; filtered with tau 2.7 s: 0.71, the simulated filter 0.74).
CUT_HIGH_PASS_S = 15.0


def path_offset_m(err_enu_m: np.ndarray, truth_lat_deg: np.ndarray, truth_lon_deg: np.ndarray,
                  t_unix_s: np.ndarray, epochs: np.ndarray) -> np.ndarray:
    """Each fix's signed distance to the truth's path (left of the direction of travel
    positive): to the nearest of the path's chords, about one second long, within
    CUT_WINDOW_S of its epoch. Unlike the error, it does not see where along the path the fix
    lies, so a delay (the fix on the path, some way back) leaves it at the receiver's own
    cross-track error.

    err_enu_m : (s, n, 3) fixes minus truth, metres; truth_lat_deg, truth_lon_deg,
    t_unix_s : (n,); epochs : (n,) bool, those to measure; returns (s, n) metres (NaN
    elsewhere)
    """
    n = t_unix_s.size
    out = np.full(err_enu_m.shape[:2], np.nan)
    idx = np.flatnonzero(epochs)
    if idx.size == 0:
        return out
    dt = epoch_step_s(t_unix_s)
    stride = max(1, int(round(1.0 / dt)))
    reach = int(math.ceil(CUT_WINDOW_S / dt))
    lat_rad, lon_rad = np.radians(truth_lat_deg), np.radians(truth_lon_deg)
    m_m, n_m = geodesy.radii_of_curvature_m(truth_lat_deg[idx])
    lat0, lon0 = lat_rad[idx], lon_rad[idx]
    east_per_rad = n_m * np.cos(lat0)

    def rel(j: int) -> np.ndarray:  # (m, 2) truth at epoch k + j less at k, local metres
        i = np.clip(idx + j, 0, n - 1)
        return np.stack([east_per_rad * (lon_rad[i] - lon0), m_m * (lat_rad[i] - lat0)], axis=1)

    f = err_enu_m[:, idx, :2]
    best = np.full(f.shape[:2], np.inf)
    signed = np.full(f.shape[:2], np.nan)
    a = rel(-reach)
    for j in range(-reach, reach, stride):
        b = rel(j + stride)
        seg = b - a
        len2 = (seg * seg).sum(axis=1)
        fa = f - a[None]
        with np.errstate(invalid="ignore", divide="ignore"):
            u = np.clip((fa * seg[None]).sum(axis=2) / len2[None], 0.0, 1.0)
        d = f - (a[None] + u[..., None] * seg[None])
        dist = np.hypot(d[..., 0], d[..., 1])
        side = np.sign(seg[None, :, 0] * fa[..., 1] - seg[None, :, 1] * fa[..., 0])
        closer = (dist < best) & (len2 > 0.01)[None]  # (a chord of under 0.1 m has no side)
        best = np.where(closer, dist, best)
        signed = np.where(closer, side * dist, signed)
        a = b
    out[:, idx] = signed
    return out


def corner_cut_s2(err_enu_m: np.ndarray, truth_lat_deg: np.ndarray, truth_lon_deg: np.ndarray,
                  t_unix_s: np.ndarray, vel_enu_mps: np.ndarray, epochs: np.ndarray
                  ) -> np.ndarray:
    """How far the fixes cut the truth's corners, per unit of lateral acceleration: the slope
    c of the fixes' distance to the truth's path (:func:`path_offset_m`, toward the centre of
    the turn positive, less its mean over +-CUT_HIGH_PASS_S) on the truth's lateral
    acceleration, in s^2. What tells a filter from a delay: a first-order filter of time
    constant tau, turning steadily, runs inside the path by a tau^2 / 2 (c = tau^2 / 2; less
    in turns of a few seconds, and after the high-pass), while a delay (or a log-vs-truth
    clock offset) keeps the fixes on it (c = 0). NaN where the truth's lateral
    acceleration is under CUT_MIN_LAT_RMS_MPS2 rms, or with fewer than 30 epochs.

    err_enu_m : (s, n, 3); truth_lat_deg, truth_lon_deg, t_unix_s : (n,); vel_enu_mps :
    (n, 3); epochs : (n,) bool; returns (s,) s^2
    """
    out = np.full(err_enu_m.shape[0], np.nan)
    speed = np.hypot(vel_enu_mps[:, 0], vel_enu_mps[:, 1])
    acc = acceleration_enu_mps2(t_unix_s, vel_enu_mps)
    with np.errstate(invalid="ignore", divide="ignore"):
        lateral = (vel_enu_mps[:, 0] * acc[:, 1] - vel_enu_mps[:, 1] * acc[:, 0]) / speed
    epochs = epochs & np.isfinite(lateral) & (speed > 0)
    if epochs.sum() < 30:
        return out
    d = path_offset_m(err_enu_m, truth_lat_deg, truth_lon_deg, t_unix_s, epochs)
    for i, di in enumerate(d):
        ok = epochs & np.isfinite(di)
        if ok.sum() < 30:
            continue
        x = lateral[ok] - lateral[ok].mean()
        sxx = float(np.sum(x * x))
        if sxx < ok.sum() * CUT_MIN_LAT_RMS_MPS2 ** 2:
            continue
        out[i] = float(np.sum(x * _high_pass(t_unix_s[ok], di[ok], CUT_HIGH_PASS_S))) / sxx
    return out


def _high_pass(t_s: np.ndarray, y: np.ndarray, half_s: float) -> np.ndarray:
    """y less its mean over the samples within +-half_s of each (t sorted)."""
    cs = np.concatenate(([0.0], np.cumsum(y)))
    lo = np.searchsorted(t_s, t_s - half_s, side="left")
    hi = np.searchsorted(t_s, t_s + half_s, side="right")
    return y - (cs[hi] - cs[lo]) / (hi - lo)


def acceleration_enu_mps2(t_unix_s: np.ndarray, vel_enu_mps: np.ndarray) -> np.ndarray:
    """(n, 3) the truth's acceleration by central differences of its velocity (NaN for a run
    of fewer than three epochs)."""
    if t_unix_s.size < 3:
        return np.full(vel_enu_mps.shape, np.nan)
    return np.gradient(vel_enu_mps, t_unix_s, axis=0)
