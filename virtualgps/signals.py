"""What reaches the antenna and what the receiver tracks (DESIGN section 6, ``cn0_tracking``):
C/N0 from elevation and losses, and tracking with acquisition/tracking thresholds, hysteresis
and a re-acquisition delay. Pure numpy, vectorised over epochs and satellites; the tracking
state machine is evaluated with running-index tricks instead of a loop over epochs.
"""

from __future__ import annotations

import numpy as np


def antenna_gain_db(el_deg: np.ndarray, horizon_loss_db: float) -> np.ndarray:
    """Gain of a zenith-pointing patch antenna relative to the zenith.

    0 dB at the zenith falling to ``-horizon_loss_db`` at the horizon, linear in 1 - sin(el):
    a patch's pattern loses ~10-15 dB towards the horizon (Kaplan & Hegarty, Understanding GPS,
    2nd ed., section 6.3.1; the MT3339's data sheet recommends such patches).

    Parameters
    ----------
    el_deg : (...) float, degrees
    horizon_loss_db : float, dB

    Returns
    -------
    gain_db : (...) float, dB (<= 0)
    """
    s = np.sin(np.radians(np.clip(np.nan_to_num(el_deg, nan=-90.0), 0.0, 90.0)))
    return -horizon_loss_db * (1.0 - s)


def run_length(cond: np.ndarray, run0: np.ndarray) -> np.ndarray:
    """Length of the current run of True along axis 0, continuing runs ``run0`` from before.

    Parameters
    ----------
    cond : (n_t, m) bool
    run0 : (m,) int, run length before the first row

    Returns
    -------
    run : (n_t, m) int; run[k] = run[k-1] + 1 where cond[k], else 0
    """
    n_t = cond.shape[0]
    k = np.arange(n_t)[:, None]
    last_false = np.maximum.accumulate(np.where(cond, -1, k), axis=0)
    return np.where(last_false >= 0, k - last_false, run0[None, :] + k + 1) * cond


def track(
    cn0_dbhz: np.ndarray,
    acq_dbhz: float,
    track_dbhz: float,
    reacq_epochs: int,
    tracked0: np.ndarray,
    run0: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Tracking with hysteresis: acquire after ``reacq_epochs`` epochs at or above the
    acquisition threshold, keep tracking down to the (lower) tracking threshold.

    Real receivers acquire at a higher C/N0 than they can track (MTK: acquisition -148 dBm,
    tracking -165 dBm), so a satellite near the threshold flickers less than a single threshold
    would make it.

    Parameters
    ----------
    cn0_dbhz : (n_t, m) float, dB-Hz (-inf or NaN: no signal)
    acq_dbhz, track_dbhz : thresholds, dB-Hz (acq >= track)
    reacq_epochs : epochs of sustained signal before (re)acquisition, >= 1
    tracked0 : (m,) bool, tracked before the first row
    run0 : (m,) int, epochs at or above the acquisition threshold before the first row

    Returns
    -------
    tracked : (n_t, m) bool
    run : (m,) int, the run after the last row (the next call's ``run0``)
    """
    c = np.nan_to_num(cn0_dbhz, nan=-np.inf)
    run = run_length(c >= acq_dbhz, run0)
    # Events: +1 acquire, -1 lose; otherwise the state carries on (hysteresis band).
    event = np.where(run >= reacq_epochs, 1, np.where(c < track_dbhz, -1, 0))
    k = np.arange(c.shape[0])[:, None]
    last = np.maximum.accumulate(np.where(event != 0, k, -1), axis=0)
    last_event = np.take_along_axis(event, np.maximum(last, 0), axis=0)
    tracked = np.where(last >= 0, last_event > 0, tracked0[None, :])
    return tracked, run[-1] if c.shape[0] else run0


# --------------------------------------------------------------------------------------------
# NLOS: specular reflections off vertical facades (image method).


class Facades:
    """The near-vertical occluder triangles of a scene, for the image method.

    Attributes
    ----------
    v0, e1, e2 : (n, 3) float, metres, scene ENU: a vertex and the two edges of each triangle
    normal : (n, 3) float, horizontal unit normals (sign arbitrary; oriented per antenna)
    tree : scipy cKDTree over the triangles' horizontal centroids
    radius_m : (n,) float, metres, horizontal distance from each centroid to its farthest vertex
    """

    def __init__(self, vertices_enu_m: np.ndarray, faces: np.ndarray, max_tilt_deg: float = 10.0):
        from scipy.spatial import cKDTree

        tri = vertices_enu_m[faces]  # (n, 3, 3)
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        nrm = np.cross(e1, e2)
        length = np.linalg.norm(nrm, axis=1)
        ok = length > 1e-9
        nrm[ok] /= length[ok, None]
        vertical = ok & (np.abs(nrm[:, 2]) < np.sin(np.radians(max_tilt_deg)))
        self.v0, self.e1, self.e2 = tri[vertical, 0], e1[vertical], e2[vertical]
        n_h = nrm[vertical].copy()
        n_h[:, 2] = 0.0
        self.normal = n_h / np.linalg.norm(n_h, axis=1, keepdims=True)
        centroid = tri[vertical].mean(axis=1)
        self.radius_m = np.linalg.norm(tri[vertical, :, :2] - centroid[:, None, :2], axis=2).max(1)
        self.tree = cKDTree(centroid[:, :2]) if len(centroid) else None
        self._max_radius_m = float(self.radius_m.max()) if len(centroid) else 0.0

    def __len__(self) -> int:
        return len(self.v0)

    def near(self, xy_m: np.ndarray, max_dist_m: float) -> list[list[int]]:
        """Indices of the triangles within ``max_dist_m`` (horizontally) of each point."""
        if self.tree is None:
            return [[] for _ in range(len(xy_m))]
        return self.tree.query_ball_point(xy_m, max_dist_m + self._max_radius_m)


def reflections(
    scene,
    facades: Facades,
    antenna_enu_m: np.ndarray,
    sat_dir_enu: np.ndarray,
    max_dist_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Specular single-bounce paths from far satellites to antennas off vertical facades.

    For a wall with unit normal n facing the antenna at distance d, a satellite in direction u
    on the antenna's side (u . n > 0) reflects to the antenna from the mirrored direction
    r = u - 2 (u . n) n, off the point P = a + r d / (-r . n); the reflected signal travels
    2 d (u . n) further than a direct one would (the image antenna a' = a - 2 d n sees the
    satellite at that extra range; far-field, plane wave). A path counts when P lies on the
    triangle, nothing blocks antenna -> P (the first occluder hit along r is P) and nothing
    blocks P -> satellite. Of several paths the shortest is kept (the strongest, usually).

    Parameters
    ----------
    scene : the Scene (occluder ray queries)
    facades : its :class:`Facades`
    antenna_enu_m : (m, 3) metres, scene ENU, one antenna per query
    sat_dir_enu : (m, 3) unit vectors antenna -> satellite, scene ENU
    max_dist_m : only walls closer than this (horizontally) reflect

    Returns
    -------
    found : (m,) bool, a reflected path exists
    excess_m : (m,) float, metres, its extra length (NaN where none)
    """
    m = len(antenna_enu_m)
    found = np.zeros(m, bool)
    excess = np.full(m, np.nan)
    if m == 0 or len(facades) == 0:
        return found, excess
    lists = facades.near(antenna_enu_m[:, :2], max_dist_m)
    q = np.repeat(np.arange(m), [len(c) for c in lists])
    if q.size == 0:
        return found, excess
    j = np.concatenate([np.asarray(c, dtype=int) for c in lists])
    a, u = antenna_enu_m[q], sat_dir_enu[q]
    n = facades.normal[j]
    d = np.einsum("ij,ij->i", a - facades.v0[j], n)
    n = n * np.sign(d)[:, None]  # face the antenna
    d = np.abs(d)
    un = np.einsum("ij,ij->i", u, n)
    ok = (un > 1e-6) & (d > 0.05) & (d <= max_dist_m)
    r = u - 2.0 * un[:, None] * n
    t = d / np.maximum(un, 1e-12)  # -r . n = u . n
    p = a + r * t[:, None]
    # Barycentric test: P on the triangle.
    w = p - facades.v0[j]
    e1, e2 = facades.e1[j], facades.e2[j]
    d11 = np.einsum("ij,ij->i", e1, e1)
    d12 = np.einsum("ij,ij->i", e1, e2)
    d22 = np.einsum("ij,ij->i", e2, e2)
    w1 = np.einsum("ij,ij->i", w, e1)
    w2 = np.einsum("ij,ij->i", w, e2)
    den = d11 * d22 - d12**2
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = (d22 * w1 - d12 * w2) / den
        b2 = (d11 * w2 - d12 * w1) / den
    tol = 1e-6
    ok &= (b1 >= -tol) & (b2 >= -tol) & (b1 + b2 <= 1 + tol)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return found, excess
    # Leg 1: the first occluder along r is this wall (nothing in between).
    hit = scene.hit_distance_m(a[idx], r[idx])
    leg1 = np.abs(hit - t[idx]) < 0.02 + 1e-4 * t[idx]
    idx = idx[leg1]
    # Leg 2: open sky from the reflection point (nudged off the wall) to the satellite.
    leg2 = ~scene.blocked(p[idx] + 0.05 * n[idx], u[idx])
    idx = idx[leg2]
    ex = 2.0 * d[idx] * un[idx]
    # Shortest path per query.
    order = np.lexsort((ex, q[idx]))
    idx, ex = idx[order], ex[order]
    first = np.ones(idx.size, bool)
    first[1:] = q[idx][1:] != q[idx][:-1]
    found[q[idx][first]] = True
    excess[q[idx][first]] = ex[first]
    return found, excess
