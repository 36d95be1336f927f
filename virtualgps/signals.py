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
CELL_M = 8.0  # side of the square cells whose candidate walls are cached
MAX_CACHED_CELLS = 100_000  # per radius (~100 walls each: tens of MB at most); then rebuilt


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
    along : (n, 2) float, horizontal unit vectors along each plane (perpendicular to its normal)
    ends_s : (n, 2) float, metres, the footprint's ends as positions along ``along``
    footprint_xy_m : (n, 2, 2) float, metres, scene east/north of the footprint's two ends
    index_start, index_n : (n,) int, each plane's first row in ``index_xy`` and its number of
        index steps (``index_n + 1`` points, evenly spaced from end to end)
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
        # All four corners of the bounding box: a wall running north-west to south-east spans
        # the box between the other two.
        lo, hi = self.lo_m[:, :2], self.hi_m[:, :2]
        corners = np.stack([lo, hi, np.stack([lo[:, 0], hi[:, 1]], 1),
                            np.stack([hi[:, 0], lo[:, 1]], 1)], axis=1)  # (n, 4, 2)
        s = np.einsum("ikj,ij->ik", corners, along)
        ends_s = np.stack([s.min(axis=1), s.max(axis=1)], axis=1)
        base = self.offset_m[:, None] * self.normal[:, :2]
        n_pts = np.maximum(1, np.ceil((ends_s[:, 1] - ends_s[:, 0]) / INDEX_STEP_M)).astype(int)
        owner = np.repeat(np.arange(n_planes), n_pts + 1)
        frac = np.concatenate([np.linspace(0.0, 1.0, k + 1) for k in n_pts]) if n_planes else \
            np.zeros(0)
        pos = ends_s[owner, 0] + frac * (ends_s[owner, 1] - ends_s[owner, 0])
        self.index_xy = base[owner] + pos[:, None] * along[owner]
        self.index_owner = owner
        self.tree = cKDTree(self.index_xy) if len(owner) else None
        self.along = along
        self.ends_s = ends_s
        self.footprint_xy_m = base[:, None, :] + ends_s[:, :, None] * along[:, None, :]
        # The same as contiguous columns, for the per-pair arithmetic of wall_dist_m.
        start, span = self.footprint_xy_m[:, 0], np.diff(self.footprint_xy_m, axis=1)[:, 0]
        self._x0, self._y0 = start[:, 0].copy(), start[:, 1].copy()
        self._dx, self._dy = span[:, 0].copy(), span[:, 1].copy()
        self._inv_len2 = 1.0 / np.maximum(self._dx**2 + self._dy**2, 1e-12)
        self._top_m = self.hi_m[:, 2].copy()
        self.index_n = n_pts
        self.index_start = np.cumsum(n_pts + 1) - (n_pts + 1)
        # Candidate walls per cell of the ground (see candidates): an antenna stays in a cell
        # for many epochs, and the daemon asks once per epoch.
        self._cells: dict[tuple[float, float], dict[int, np.ndarray]] = {}

    def __len__(self) -> int:
        return len(self.normal)

    def candidates(
        self, xy_m: np.ndarray, radius_m: float, plane_dist_m: float = np.inf
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (query, plane): a superset of the planes with an index point within
        ``radius_m`` of each point and a plane within ``plane_dist_m`` of it.

        The planes near each ``CELL_M`` square are found once (index point and plane within
        those distances plus half the cell's diagonal of its centre) and cached: a walking
        antenna stays in a cell for several epochs, a static one for ever. Use
        :meth:`index_dist_m` to keep the exact set.

        Parameters
        ----------
        xy_m : (m, 2) metres, scene east/north
        radius_m : metres
        plane_dist_m : metres, distance from the point to the wall's (infinite) plane

        Returns
        -------
        query, plane : (k,) int, no pair twice (grouped by cell)
        """
        m = len(xy_m)
        if self.tree is None or m == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        cell = np.floor(xy_m / CELL_M).astype(np.int64)
        key = cell[:, 0] * (1 << 32) + cell[:, 1]  # unique while |north| < 2^31 cells
        if (key == key[0]).all():  # one cell (the live loop's epoch): no grouping to do
            keys, first, inverse = key[:1], np.zeros(1, np.intp), np.zeros(m, np.intp)
        else:
            keys, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        cache = self._cells.setdefault((float(radius_m), float(plane_dist_m)), {})
        key_list = keys.tolist()
        missing = [i for i, k in enumerate(key_list) if k not in cache]
        if missing:
            if len(cache) + len(missing) > MAX_CACHED_CELLS:
                cache.clear()
                missing = list(range(len(key_list)))
            centres = (cell[first[missing]] + 0.5) * CELL_M
            half_diag = CELL_M * np.sqrt(0.5) + 1e-6  # from the centre to any point of the cell
            near = self.tree.query_ball_point(centres, radius_m + half_diag)
            for i, c, pts in zip(missing, centres, near, strict=True):
                planes = np.unique(self.index_owner[np.asarray(pts, np.intp)])
                off = np.abs(self.normal[planes, :2] @ c - self.offset_m[planes])
                cache[key_list[i]] = planes[off <= plane_dist_m + half_diag]
        if len(key_list) == 1:
            planes = cache[key_list[0]]
            return np.repeat(np.arange(m), planes.size), np.tile(planes, m)
        # Cell by cell: every query of a cell pairs with every plane of its list.
        order = np.argsort(inverse, kind="stable")
        groups = np.split(order, np.cumsum(np.bincount(inverse))[:-1])
        query = [np.repeat(g, cache[k].size) for k, g in zip(key_list, groups, strict=True)]
        plane = [np.tile(cache[k], g.size) for k, g in zip(key_list, groups, strict=True)]
        return np.concatenate(query), np.concatenate(plane)

    def index_dist_m(self, xy_m: np.ndarray, plane: np.ndarray) -> np.ndarray:
        """Distance from each point to the nearest index point of its plane (closed form).

        The index points of a plane are evenly spaced on a line, so the nearest one is the one
        whose position along the line is nearest to the point's projection.

        Parameters
        ----------
        xy_m : (k, 2) metres, scene east/north
        plane : (k,) int

        Returns
        -------
        dist_m : (k,) float, metres
        """
        s = np.einsum("ij,ij->i", xy_m, self.along[plane])
        e0, e1 = self.ends_s[plane, 0], self.ends_s[plane, 1]
        span = e1 - e0
        frac = np.clip((s - e0) / np.where(span > 0, span, 1.0), 0.0, 1.0)
        k = np.rint(frac * self.index_n[plane]).astype(np.intp)
        diff = xy_m - self.index_xy[self.index_start[plane] + k]
        return np.sqrt(np.einsum("ij,ij->i", diff, diff))

    def wall_dist_m(self, antenna_enu_m: np.ndarray, max_dist_m: float) -> np.ndarray:
        """Horizontal distance from each antenna to the nearest wall whose top is above it.

        The distance to a wall is to its footprint, the segment its triangles cover along its
        plane; walls lower than the antenna are left out, as in :func:`reflections`.

        Parameters
        ----------
        antenna_enu_m : (m, 3) metres, scene ENU
        max_dist_m : walls further than this are not searched for

        Returns
        -------
        dist_m : (m,) float, metres; inf where no wall is within ``max_dist_m``
        """
        m = len(antenna_enu_m)
        # A footprint within max_dist_m has an index point within max_dist_m + half a step
        # (the distances of reflections' search: one cache serves both when they agree).
        q, j = self.candidates(antenna_enu_m[:, :2], max_dist_m + INDEX_STEP_M,
                               max_dist_m + 1e-3)
        k = np.flatnonzero(self._top_m[j] > antenna_enu_m[q, 2])
        q, j = q[k], j[k]
        # Nearest point of each footprint segment: its start + t (end - start), t in [0, 1].
        px = antenna_enu_m[q, 0] - self._x0[j]
        py = antenna_enu_m[q, 1] - self._y0[j]
        dx, dy = self._dx[j], self._dy[j]
        t = np.clip((px * dx + py * dy) * self._inv_len2[j], 0.0, 1.0)
        px -= t * dx
        py -= t * dy
        dist2 = np.full(m, np.inf)
        np.minimum.at(dist2, q, px * px + py * py)
        dist = np.sqrt(dist2)
        return np.where(dist <= max_dist_m, dist, np.inf)


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
    # Queries come epoch by epoch: a run of queries from one antenna position shares the wall
    # search and the antenna-to-wall geometry.
    new_run = np.ones(m, bool)
    new_run[1:] = np.any(antenna_enu_m[1:] != antenna_enu_m[:-1], axis=1)
    starts = np.flatnonzero(new_run)
    counts = np.diff(np.append(starts, m))
    ant = antenna_enu_m[starts]
    xy = np.round(ant[:, :2], 3)  # the candidate rule's position (to the millimetre)
    reach_m = max_dist_m + INDEX_STEP_M  # walls with an index point this close are candidates
    ga, j_a = facades.candidates(xy, reach_m, max_dist_m + 1e-3)  # (xy is within 1 mm of ant)
    # Distance to each wall plane, its normal turned to face the antenna (the normals are
    # horizontal: east and north terms only). A satellite above the horizon reflects off a
    # wall above the antenna.
    nx, ny, off = facades.normal[j_a, 0], facades.normal[j_a, 1], facades.offset_m[j_a]
    d = ant[ga, 0] * nx + ant[ga, 1] * ny - off
    side = np.sign(d)
    d = np.abs(d)
    keep = np.flatnonzero((facades.hi_m[j_a, 2] > ant[ga, 2]) & (d > 0.05) & (d <= max_dist_m))
    ga, j_a, d = ga[keep], j_a[keep], d[keep]
    nx, ny = nx[keep] * side[keep], ny[keep] * side[keep]
    # Expand (antenna, wall) pairs to (query, wall) pairs; keep satellites on the wall's side.
    rep = counts[ga]
    pair = np.repeat(np.arange(ga.size), rep)
    q = np.repeat(starts[ga], rep) + _ranges(rep)
    ux, uy, uz = (np.ascontiguousarray(sat_dir_enu[:, i]) for i in range(3))
    un = ux[q] * nx[pair] + uy[q] * ny[pair]
    k = np.flatnonzero(un > 1e-6)
    q, pair, un = q[k], pair[k], un[k]
    # The reflection point P = a + r t, r = u - 2 (u . n) n, must lie in the wall's bounding box
    # (up first: it rules out most pairs).
    g, j, d, nx, ny = ga[pair], j_a[pair], d[pair], nx[pair], ny[pair]
    t = d / np.maximum(un, 1e-12)
    slack = 0.05
    pz = ant[g, 2] + uz[q] * t  # (r's up component is u's)
    k = np.flatnonzero((pz >= facades.lo_m[j, 2] - slack) & (pz <= facades.hi_m[j, 2] + slack))
    q, g, j, d, nx, ny, un, t, pz = q[k], g[k], j[k], d[k], nx[k], ny[k], un[k], t[k], pz[k]
    rx, ry = ux[q] - 2.0 * un * nx, uy[q] - 2.0 * un * ny
    px, py = ant[g, 0] + rx * t, ant[g, 1] + ry * t
    lo, hi = facades.lo_m[j] - slack, facades.hi_m[j] + slack
    ok = (px >= lo[:, 0]) & (px <= hi[:, 0]) & (py >= lo[:, 1]) & (py <= hi[:, 1])
    idx = np.flatnonzero(ok)
    idx = idx[facades.index_dist_m(xy[g[idx]], j[idx]) <= reach_m]
    if idx.size == 0:
        return found, excess
    r = np.stack([rx[idx], ry[idx], uz[q[idx]]], axis=1)
    # Leg 1: the first occluder along r is this wall (nothing in between, and the wall is there).
    hit = scene.hit_distance_m(ant[g[idx]], r)
    idx = idx[np.abs(hit - t[idx]) < 0.02 + 1e-4 * t[idx]]
    # Leg 2: open sky from the reflection point (nudged off the wall) to the satellite.
    p_off = np.stack([px[idx] + 0.05 * nx[idx], py[idx] + 0.05 * ny[idx], pz[idx]], axis=1)
    idx = idx[~scene.blocked(p_off, sat_dir_enu[q[idx]])]
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
