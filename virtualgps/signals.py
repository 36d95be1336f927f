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
    el = np.asarray(el_deg, dtype=float)
    s = np.sin(np.radians(np.clip(np.where(np.isnan(el), 0.0, el), 0.0, 90.0)))
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


INDEX_STEP_M = 5.0


class Facades:
    """The near-vertical occluder walls of a scene, merged into planes, for the image method.

    Triangles are grouped by object and plane (normal azimuth to 0.5 deg, offset to 0.1 m): a
    building side made of many triangles is one reflector. Whether the reflection point really
    lies on a wall is checked by a ray (the first occluder along the reflected direction must
    be at the plane), so the grouping only has to be generous, never exact.

    Attributes
    ----------
    normal : (n, 3) float, horizontal unit normals (sign arbitrary; oriented per antenna)
    offset_m : (n,) float, metres, plane offsets: normal . x = offset on the plane
    lo_m, hi_m : (n, 3) float, metres, scene ENU bounding box of each plane's triangles
    index_xy, index_owner : points every INDEX_STEP_M along the planes' footprints, and their
        plane; tree : scipy cKDTree over ``index_xy``
    """

    def __init__(
        self,
        vertices_enu_m: np.ndarray,
        faces: np.ndarray,
        face_object: np.ndarray | None = None,
        max_tilt_deg: float = 10.0,
    ) -> None:
        from scipy.spatial import cKDTree

        tri = vertices_enu_m[faces]  # (n, 3, 3)
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(nrm, axis=1)
        ok = length > 1e-9
        nrm[ok] /= length[ok, None]
        vertical = ok & (np.abs(nrm[:, 2]) < np.sin(np.radians(max_tilt_deg)))
        tri, nrm = tri[vertical], nrm[vertical]
        obj = (np.zeros(len(faces), int) if face_object is None else face_object)[vertical]
        az = np.degrees(np.arctan2(nrm[:, 0], nrm[:, 1])) % 180.0  # one sign per plane
        nh = np.stack([np.sin(np.radians(az)), np.cos(np.radians(az)), np.zeros_like(az)], 1)
        off = np.einsum("ij,ij->i", tri[:, 0], nh)
        key = np.stack([obj, np.round(az / 0.5) % 360, np.round(off / 0.1)], axis=1)
        _, plane, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        n_planes = len(counts)
        self.normal = np.zeros((n_planes, 3))
        np.add.at(self.normal, plane, nh)
        self.normal /= np.maximum(np.linalg.norm(self.normal, axis=1, keepdims=True), 1e-12)
        self.offset_m = np.zeros(n_planes)
        np.add.at(self.offset_m, plane, off)
        self.offset_m /= np.maximum(counts, 1)
        self.lo_m = np.full((n_planes, 3), np.inf)
        self.hi_m = np.full((n_planes, 3), -np.inf)
        np.minimum.at(self.lo_m, plane, tri.min(axis=1))
        np.maximum.at(self.hi_m, plane, tri.max(axis=1))
        # Index the planes by points along their footprints (a long wall is found from anywhere
        # along it); the footprint runs along the wall, perpendicular to its normal.
        along = np.stack([self.normal[:, 1], -self.normal[:, 0]], axis=1)
        corners = np.stack([self.lo_m[:, :2], self.hi_m[:, :2]], axis=1)  # (n, 2, 2)
        s = np.einsum("ikj,ij->ik", corners, along)
        ends_s = np.sort(s, axis=1)
        base = self.offset_m[:, None] * self.normal[:, :2]
        n_pts = np.maximum(1, np.ceil((ends_s[:, 1] - ends_s[:, 0]) / INDEX_STEP_M)).astype(int)
        owner = np.repeat(np.arange(n_planes), n_pts + 1)
        frac = np.concatenate([np.linspace(0.0, 1.0, k + 1) for k in n_pts]) if n_planes else \
            np.zeros(0)
        pos = ends_s[owner, 0] + frac * (ends_s[owner, 1] - ends_s[owner, 0])
        self.index_xy = base[owner] + pos[:, None] * along[owner]
        self.index_owner = owner
        self.tree = cKDTree(self.index_xy) if len(owner) else None

    def __len__(self) -> int:
        return len(self.normal)

    def near(self, xy_m: np.ndarray, max_dist_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (query, plane) of walls within about ``max_dist_m`` of each point.

        Parameters
        ----------
        xy_m : (m, 2) metres, scene east/north
        max_dist_m : metres

        Returns
        -------
        query, plane : (k,) int, unique pairs
        """
        from scipy.spatial import cKDTree

        if self.tree is None or len(xy_m) == 0:
            return np.zeros(0, int), np.zeros(0, int)
        pairs = cKDTree(xy_m).sparse_distance_matrix(
            self.tree, max_dist_m + INDEX_STEP_M, output_type="ndarray"
        )
        key = np.unique(pairs["i"].astype(np.int64) * len(self) + self.index_owner[pairs["j"]])
        return key // len(self), key % len(self)


def reflections(
    scene,
    facades: Facades,
    antenna_enu_m: np.ndarray,
    sat_dir_enu: np.ndarray,
    max_dist_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Specular single-bounce paths from far satellites to antennas off vertical walls.

    For a wall with unit normal n facing the antenna at distance d, a satellite in direction u
    on the antenna's side (u . n > 0) reflects to the antenna from the mirrored direction
    r = u - 2 (u . n) n, off the point P = a + r d / (u . n); the reflected signal travels
    2 d (u . n) further than a direct one would (the image antenna a' = a - 2 d n sees the
    satellite at that extra range; far field, plane wave). A path counts when P lies in the
    wall's bounding box, the first occluder along r is at P (the wall is really there and
    nothing blocks antenna -> P) and nothing blocks P -> satellite. Of several paths the
    shortest is kept (usually the strongest).

    Parameters
    ----------
    scene : the Scene (occluder ray queries)
    facades : its :class:`Facades`
    antenna_enu_m : (m, 3) metres, scene ENU, one antenna per query
    sat_dir_enu : (m, 3) unit vectors antenna -> satellite, scene ENU
    max_dist_m : only walls closer than this reflect

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
    # Spatial query once per distinct antenna position (many satellites share one).
    xy, inverse = np.unique(np.round(antenna_enu_m[:, :2], 3), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    qa, j_a = facades.near(xy, max_dist_m)
    # A satellite above the horizon reflects off a wall above the antenna: drop walls whose top
    # is below the lowest antenna at that position.
    z_min = np.full(len(xy), np.inf)
    np.minimum.at(z_min, inverse, antenna_enu_m[:, 2])
    keep = facades.hi_m[j_a, 2] > z_min[qa]
    qa, j_a = qa[keep], j_a[keep]
    if qa.size == 0:
        return found, excess
    # Expand (antenna, plane) pairs to (query, plane) pairs.
    order = np.argsort(inverse, kind="stable")
    starts = np.searchsorted(inverse[order], np.arange(len(xy)))
    counts = np.bincount(inverse, minlength=len(xy))
    rep = counts[qa]
    q = order[np.repeat(starts[qa], rep) + _ranges(rep)]
    j = np.repeat(j_a, rep)
    a, u = antenna_enu_m[q], sat_dir_enu[q]
    n = facades.normal[j]
    d = np.einsum("ij,ij->i", a, n) - facades.offset_m[j]
    n = n * np.sign(d)[:, None]  # face the antenna
    d = np.abs(d)
    un = np.einsum("ij,ij->i", u, n)
    ok = (un > 1e-6) & (d > 0.05) & (d <= max_dist_m)
    t = d / np.maximum(un, 1e-12)
    r = u - 2.0 * un[:, None] * n
    p = a + r * t[:, None]
    slack = 0.05
    ok &= np.all((p >= facades.lo_m[j] - slack) & (p <= facades.hi_m[j] + slack), axis=1)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return found, excess
    # Leg 1: the first occluder along r is this wall (nothing in between, and the wall is there).
    hit = scene.hit_distance_m(a[idx], r[idx])
    idx = idx[np.abs(hit - t[idx]) < 0.02 + 1e-4 * t[idx]]
    # Leg 2: open sky from the reflection point (nudged off the wall) to the satellite.
    idx = idx[~scene.blocked(p[idx] + 0.05 * n[idx], u[idx])]
    ex = 2.0 * d[idx] * un[idx]
    order = np.lexsort((ex, q[idx]))  # shortest path per query first
    idx, ex = idx[order], ex[order]
    first = np.ones(idx.size, bool)
    first[1:] = q[idx][1:] != q[idx][:-1]
    found[q[idx][first]] = True
    excess[q[idx][first]] = ex[first]
    return found, excess


def _ranges(counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges: [0..c0), [0..c1), ... for counts c."""
    ends = np.cumsum(counts)
    return np.arange(ends[-1] if len(ends) else 0) - np.repeat(ends - counts, counts)


# --------------------------------------------------------------------------------------------
# Foliage: attenuation by the path length through tree crowns.


def foliage_path_m(
    scene, origins_enu_m: np.ndarray, dirs_enu: np.ndarray, billboard_m: float,
    max_crossings: int = 8,
) -> np.ndarray:
    """Length of each ray's path through foliage-class surfaces.

    Successive hits along the ray are paired as entry/exit of closed crowns; a crossing left
    unpaired (an open "billboard" tree, as OSM2World writes them) counts ``billboard_m``.

    Parameters
    ----------
    scene : the Scene (``hit_distance_m`` with cls="foliage")
    origins_enu_m : (m, 3) metres, scene ENU
    dirs_enu : (m, 3) unit directions
    billboard_m : metres of foliage per unpaired crossing
    max_crossings : surfaces followed along one ray at most

    Returns
    -------
    length_m : (m,) float, metres (0 where the ray meets no foliage)
    """
    m = len(origins_enu_m)
    length = np.zeros(m)
    start = np.zeros(m)  # distance along the ray already searched
    entry = np.full(m, np.nan)  # distance of an open crossing, awaiting its exit
    active = np.arange(m)
    for _ in range(max_crossings):
        if active.size == 0:
            break
        o = origins_enu_m[active] + dirs_enu[active] * start[active, None]
        d = scene.hit_distance_m(o, dirs_enu[active], cls="foliage")
        hit = np.isfinite(d)
        a_hit, a_miss = active[hit], active[~hit]
        # Rays that leave the foliage scene: an open crossing was a billboard.
        length[a_miss] += np.where(np.isnan(entry[a_miss]), 0.0, billboard_m)
        dist = start[a_hit] + d[hit]
        open_ = ~np.isnan(entry[a_hit])
        length[a_hit[open_]] += dist[open_] - entry[a_hit[open_]]
        entry[a_hit[open_]] = np.nan
        entry[a_hit[~open_]] = dist[~open_]
        start[a_hit] = dist + 1e-3
        active = a_hit
    length[active] += np.where(np.isnan(entry[active]), 0.0, billboard_m)
    return length
