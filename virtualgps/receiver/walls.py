"""Signals off the scene's walls: the reflecting facades of the mesh, indexed by cell, and the
paths a blocked satellite's signal takes to the antenna off them (specular reflections, the
``nlos`` effect, and paths scattered off a wall's surface, ``multipath``), with their extra
length and loss.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

INDEX_STEP_M = 5.0


CELL_M = 8.0  # side of the square cells whose candidate walls are cached


MAX_CACHED_CELLS = 100_000  # per radius (~100 walls each: tens of MB at most); then rebuilt


NEAR_WALLS = 16  # walls per cell that wall_dist_m tries first (the nearest is ~7 m away)


SCATTER_WALLS = 16  # walls nearest an antenna's cell that scattered_paths tries (see there)


HEIGHT_BAND_M = 0.5  # wall_dist_m's cell lists leave out walls below the antennas' band


def _cell_groups(
    cell: np.ndarray, band: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group queries by their ``CELL_M`` ground cell (and height band).

    Parameters
    ----------
    cell : (m,) + (2,) int64, cell indices east and north (|index| < 2^23: 67,000 km of cells)
    band : (m,) int64, height band indices (|index| < 2^15), optional

    Returns
    -------
    key : (m,) int64, one number per cell (and band)
    first : (g,) int, the first query of each group
    inverse : (m,) int, each query's group
    """
    key = cell[:, 0] * (1 << 24) + cell[:, 1]
    if band is not None:
        key = key * (1 << 16) + band
    if (key == key[0]).all():  # one group (the live loop's epoch): np.unique costs more
        return key, np.zeros(1, np.intp), np.zeros(len(key), np.intp)
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    return key, first, inverse


@dataclass(frozen=True, eq=False)
class _NearWalls:
    """One ground cell's walls for :meth:`Facades.wall_dist_m`, nearest to the cell's centre
    first.

    Attributes
    ----------
    planes : (k,) int, the walls that can be within the search distance of a point in the cell
    centre_dist_m : (k,) float, metres, ascending, their footprints' distances from the centre
    head : (6, NEAR_WALLS) float, the first walls' columns of ``Facades._segments`` (padded
        with its last column, no wall)
    next_dist_m : metres, the centre distance of the first wall after the head (inf: none)
    """

    planes: np.ndarray
    centre_dist_m: np.ndarray
    head: np.ndarray
    next_dist_m: float


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
        plane
    along : (n, 2) float, horizontal unit vectors along each plane (perpendicular to its normal)
    ends_s : (n, 2) float, metres, the footprint's ends as positions along ``along``
    footprint_xy_m : (n, 2, 2) float, metres, scene east/north of the footprint's two ends
    index_start, index_n : (n,) int, each plane's first row in ``index_xy`` and its number of
        index steps (``index_n + 1`` points, evenly spaced from end to end)
    padded_rows : four (n + 1,) float arrays: normal east, normal north, offset (metres) and top
        height (metres); entry n is a padding wall without a top
    """

    def __init__(
        self,
        vertices_enu_m: np.ndarray,
        faces: np.ndarray,
        face_object: np.ndarray | None = None,
        max_tilt_deg: float = 10.0,
    ) -> None:
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
        # np.linspace(0, 1, k + 1) of each plane, at once (the same numbers: i * (1 / k), the
        # last exactly 1; a plane at a time cost a replay's start-up 0.03 s)
        i_pt = _ranges(n_pts + 1)
        frac = i_pt * (1.0 / n_pts[owner])
        frac[np.cumsum(n_pts + 1) - 1] = 1.0
        pos = ends_s[owner, 0] + frac * (ends_s[owner, 1] - ends_s[owner, 0])
        self.index_xy = base[owner] + pos[:, None] * along[owner]
        self.index_owner = owner
        self.along = along
        self.ends_s = ends_s
        self.footprint_xy_m = base[:, None, :] + ends_s[:, :, None] * along[:, None, :]
        # The same as rows of one table, for the arithmetic of wall_dist_m (one gather): start
        # east and north, span east and north, 1 / length^2, top height; a last column that
        # plane -1 picks, a wall without a top (never counted).
        start, span = self.footprint_xy_m[:, 0], np.diff(self.footprint_xy_m, axis=1)[:, 0]
        self._segments = np.zeros((6, n_planes + 1))
        self._segments[:4, :-1] = np.concatenate([start, span], axis=1).T
        self._segments[4, :-1] = 1.0 / np.maximum(span[:, 0] ** 2 + span[:, 1] ** 2, 1e-12)
        self._segments[5] = np.append(self.hi_m[:, 2], -np.inf)
        self.index_n = n_pts
        self.index_start = np.cumsum(n_pts + 1) - (n_pts + 1)
        # Normal east and north, offset and top height, with a last entry (plane n) for a
        # padding wall that never counts: no top (scattered_paths' rows of walls).
        self.padded_rows = (np.append(self.normal[:, 0], 0.0), np.append(self.normal[:, 1], 0.0),
                            np.append(self.offset_m, 0.0), np.append(self.hi_m[:, 2], -np.inf))
        # Candidate walls per cell of the ground (see candidates): an antenna stays in a cell
        # for many epochs, and the daemon asks once per epoch.
        self._cells: dict[tuple[float, float], dict[int, np.ndarray]] = {}
        # Per max_dist_m, cell and height band: its walls, nearest first (wall_dist_m).
        self._near_cells: dict[float, dict[tuple[tuple[float, float], float], _NearWalls]] = {}

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
        if len(self.index_owner) == 0 or m == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        cell = np.floor(xy_m / CELL_M).astype(np.int64)
        key, first, inverse = _cell_groups(cell)
        keys = key[first]
        cache = self._cells.setdefault((float(radius_m), float(plane_dist_m)), {})
        key_list = keys.tolist()
        missing = [i for i, k in enumerate(key_list) if k not in cache]
        if missing:
            if len(cache) + len(missing) > MAX_CACHED_CELLS:
                cache.clear()
                missing = list(range(len(key_list)))
            centres = (cell[first[missing]] + 0.5) * CELL_M
            half_diag = CELL_M * np.sqrt(0.5) + 1e-6  # from the centre to any point of the cell
            near = self._index_within(centres, radius_m + half_diag)
            for i, c, pts in zip(missing, centres, near, strict=True):
                planes = np.unique(self.index_owner[pts])
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

    def _index_within(self, centres_m: np.ndarray, radius_m: float) -> list[np.ndarray]:
        """Per centre ((c, 2) metres), the index points within ``radius_m`` of it (brute force
        in blocks: a few cells at a time against some thousand index points is cheaper than
        importing and building a k-d tree)."""
        out = []
        r2 = radius_m * radius_m
        for a in range(0, len(centres_m), 256):
            d = centres_m[a : a + 256, None, :] - self.index_xy[None, :, :]
            within = np.einsum("cij,cij->ci", d, d) <= r2
            out += [np.flatnonzero(w) for w in within]
        return out

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

        Each ``CELL_M`` cell of the ground keeps its walls sorted by their distance from the
        cell's centre, per ``HEIGHT_BAND_M`` band of antenna height (cached, see
        :meth:`_near_walls`). An antenna r metres from the centre measures the ``NEAR_WALLS``
        nearest first; a wall d metres from the centre is at least d - r from the antenna, so
        only the walls with d - r below the nearest distance found (few, and rarely any) are
        measured after them.

        Parameters
        ----------
        antenna_enu_m : (m, 3) metres, scene ENU
        max_dist_m : walls further than this are not searched for

        Returns
        -------
        dist_m : (m,) float, metres; inf where no wall is within ``max_dist_m``
        """
        ant = np.asarray(antenna_enu_m, dtype=float)
        m = len(ant)
        if len(self.index_owner) == 0 or m == 0:
            return np.full(m, np.inf)
        cell = np.floor(ant[:, :2] / CELL_M)
        if (cell == cell[0]).all():  # one cell (the live loop's epoch): no grouping to do
            inverse = np.zeros(m, np.intp)
            near = self._near_walls(cell[:1], [float(ant[:, 2].min())], max_dist_m)
            head = near[0].head[:, None, :]  # (6, 1, NEAR_WALLS): the same for every antenna
            nxt: float | np.ndarray = near[0].next_dist_m
        else:
            _, first, inverse = _cell_groups(cell.astype(np.int64))
            z_min = np.full(len(first), np.inf)
            np.minimum.at(z_min, inverse, ant[:, 2])
            near = self._near_walls(cell[first], z_min, max_dist_m)
            head = np.stack([w.head for w in near], axis=1)[:, inverse]  # (6, m, NEAR_WALLS)
            nxt = np.array([w.next_dist_m for w in near])[inverse]
        dist2 = self._footprint_dist2(ant, head).min(axis=1)
        # The walls that may be nearer than the head's nearest (or than max_dist_m): centre
        # distance below that plus the antenna's distance from the centre (and a margin for
        # round-off); none after the head where nxt is inf.
        off = ant[:, :2] - (cell + 0.5) * CELL_M
        reach = np.minimum(np.sqrt(dist2), max_dist_m) + np.hypot(off[:, 0], off[:, 1]) + 1e-6
        todo = np.flatnonzero(reach >= nxt)
        if todo.size:
            # Each antenna's walls after the head, those within its reach, -1 after them.
            rows = [near[c] for c in inverse[todo].tolist()]
            n_more = [int(np.searchsorted(w.centre_dist_m, r, side="right")) - NEAR_WALLS
                      for w, r in zip(rows, reach[todo].tolist(), strict=True)]
            rest = np.full((todo.size, max(n_more)), -1, np.intp)
            for r, (w, n) in enumerate(zip(rows, n_more, strict=True)):
                rest[r, :n] = w.planes[NEAR_WALLS : NEAR_WALLS + n]
            dist2[todo] = np.minimum(
                dist2[todo], self._footprint_dist2(ant[todo], self._segments[:, rest]).min(axis=1)
            )
        dist = np.sqrt(dist2)
        return np.where(dist <= max_dist_m, dist, np.inf)

    def _footprint_dist2(self, antenna_enu_m: np.ndarray, seg: np.ndarray) -> np.ndarray:
        """Squared horizontal distances from antennas to wall footprints.

        Parameters
        ----------
        antenna_enu_m : (m, 3) metres, scene ENU
        seg : (6, m or 1, k) float, the walls' columns of ``_segments``, a row per antenna

        Returns
        -------
        dist2_m2 : (m, k) float, square metres; inf for walls whose top is not above the
            antenna
        """
        x0, y0, dx, dy, inv_len2, top = seg
        # Nearest point of each footprint segment: its start + t (end - start), t in [0, 1].
        px = antenna_enu_m[:, 0, None] - x0
        py = antenna_enu_m[:, 1, None] - y0
        t = np.minimum(np.maximum((px * dx + py * dy) * inv_len2, 0.0), 1.0)
        px -= t * dx
        py -= t * dy
        return np.where(top > antenna_enu_m[:, 2, None], px * px + py * py, np.inf)

    def _near_walls(
        self, cells: np.ndarray, z_min_m: Sequence[float], max_dist_m: float
    ) -> list[_NearWalls]:
        """The walls that can be within ``max_dist_m`` of a point in each cell and rise above
        the height band of ``z_min_m``, nearest to the cell's centre first (cached per cell
        and band).

        Parameters
        ----------
        cells : (n, 2) float, whole numbers, the cells' east/north indices
        z_min_m : n heights, metres: walls whose top is below the band of this height (a
            multiple of ``HEIGHT_BAND_M``) are left out
        max_dist_m : metres

        Returns
        -------
        near : n :class:`_NearWalls`
        """
        cache = self._near_cells.setdefault(float(max_dist_m), {})
        band = np.floor(np.asarray(z_min_m) / HEIGHT_BAND_M)
        wanted = list(zip(map(tuple, cells.tolist()), band.tolist(), strict=True))
        missing = [i for i, kb in enumerate(wanted) if kb not in cache]
        if missing:
            if len(cache) + len(missing) > MAX_CACHED_CELLS:
                cache.clear()
                missing = list(range(len(wanted)))
            centres = (cells[missing] + 0.5) * CELL_M
            # A footprint within max_dist_m has an index point within max_dist_m + half a step
            # (the distances of reflections' search: one cache serves both when they agree).
            q, j = self.candidates(centres, max_dist_m + INDEX_STEP_M, max_dist_m + 1e-3)
            floor_m = band[missing] * HEIGHT_BAND_M  # every antenna is at least this high
            dc = np.sqrt(self._footprint_dist2(np.c_[centres[q], floor_m[q]],
                                               self._segments[:, j, None])[:, 0])
            # Walls further than max_dist_m from every point of the cell never count (nor
            # those dc marks inf: not above the band).
            keep = np.flatnonzero(dc - (CELL_M * np.sqrt(0.5) + 1e-6) <= max_dist_m)
            keep = keep[np.lexsort((dc[keep], q[keep]))]  # by cell, then nearest first
            ends = np.cumsum(np.bincount(q[keep], minlength=len(missing))).tolist()
            for i, a, b in zip(missing, [0, *ends[:-1]], ends, strict=True):
                planes, dist = j[keep[a:b]], dc[keep[a:b]]
                head = np.full(NEAR_WALLS, -1, np.intp)
                head[: min(planes.size, NEAR_WALLS)] = planes[:NEAR_WALLS]
                nxt = float(dist[NEAR_WALLS]) if planes.size > NEAR_WALLS else np.inf
                cache[wanted[i]] = _NearWalls(planes, dist, self._segments[:, head], nxt)
        return [cache[kb] for kb in wanted]


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
    best = _best_per_query(q[idx], ex)  # the shortest path
    found[q[idx][best]] = True
    excess[q[idx][best]] = ex[best]
    return found, excess


def scattered_paths(
    scene,
    facades: Facades,
    antenna_enu_m: np.ndarray,
    sat_dir_enu: np.ndarray,
    max_dist_m: float,
    lobe_alpha: float,
    max_lobe_loss_db: float,
    max_walls: int = SCATTER_WALLS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Single-bounce paths off rough walls: diffuse scattering in a lobe around the specular.

    Real facades (windows, ledges, rough plaster) scatter part of the signal away from the
    specular direction, so a blocked satellite is received off walls that have no specular
    point for it. We use the directive scattering model of Degli-Esposti et al. ("Measurement
    and modelling of scattering from buildings", IEEE Trans. Antennas Propag. 55(1), 2007): the
    scattered power falls off as ((1 + cos psi) / 2) ** alpha_R, psi the angle between the
    scattered direction and the specular one, i.e. a loss of
    -10 alpha_R log10((1 + cos psi) / 2) dB relative to the specular reflection (alpha_R of a
    few for building walls in their measurements).

    For each of the ``max_walls`` walls nearest the antenna's ground cell (``CELL_M``; nearer
    walls scatter more power to it, and the cap keeps the search to a few hundred rays per
    epoch) that faces the antenna within ``max_dist_m`` and is lit by the satellite on that
    side, two scattering points P are tried: the wall point nearest the specular point (the
    specular point clamped into the wall's extent, 0.1 m inside its edges; where the specular
    point lies on the wall, P is it and the lobe loss 0), and the point straight above it
    below the wall's top. A path counts when the first occluder from the antenna towards P is
    at P and nothing blocks P -> satellite (both legs ray-checked); of several, the least
    lossy, then the shortest, is kept. Its excess length over the direct path is
    |a - P| - (P - a) . u (plane wave from direction u).

    Parameters
    ----------
    scene : the Scene (occluder ray queries)
    facades : its :class:`Facades`
    antenna_enu_m : (m, 3) metres, scene ENU, one antenna per query
    sat_dir_enu : (m, 3) unit vectors antenna -> satellite, scene ENU
    max_dist_m : only walls closer than this scatter
    lobe_alpha : alpha_R, the lobe's exponent (larger: narrower lobe, more like a mirror)
    max_lobe_loss_db : paths scattered further off the specular (more loss) are ignored
    max_walls : walls tried per antenna, nearest to its cell's centre first

    Returns
    -------
    found : (m,) bool, a scattered path exists
    excess_m : (m,) float, metres, its extra length (NaN where none)
    lobe_loss_db : (m,) float, dB, the loss relative to a specular reflection (NaN where none)
    """
    m = len(antenna_enu_m)
    found = np.zeros(m, bool)
    excess = np.full(m, np.nan)
    loss = np.full(m, np.nan)
    if m == 0 or len(facades) == 0:
        return found, excess, loss
    ant = np.asarray(antenna_enu_m, dtype=float)
    u = np.asarray(sat_dir_enu, dtype=float)
    # The walls nearest each antenna's ground cell (cached per cell and height band).
    cell = np.floor(ant[:, :2] / CELL_M).astype(np.int64)
    band = np.floor(ant[:, 2] / HEIGHT_BAND_M).astype(np.int64)
    _, first, inverse = _cell_groups(cell, band)
    near = facades._near_walls(cell[first].astype(float), (band[first] * HEIGHT_BAND_M).tolist(),
                               max_dist_m)
    # Each query's walls as a row (padded with a wall that never counts: no top): the first
    # tests run on (query, wall) arrays that broadcast the antenna and the satellite, and only
    # the pairs that pass (about two in five) are gathered.
    table = np.full((len(near), max_walls), len(facades), np.intp)
    for r, w in enumerate(near):
        planes = w.planes[:max_walls]
        table[r, : planes.size] = planes
    jj = table[inverse]  # (m, max_walls)
    east, north, offset, top = facades.padded_rows
    nrm_x, nrm_y = east[jj], north[jj]
    d = ant[:, 0, None] * nrm_x + ant[:, 1, None] * nrm_y - offset[jj]
    side = np.sign(d)
    nx, ny = nrm_x * side, nrm_y * side  # facing the antenna
    un = u[:, 0, None] * nx + u[:, 1, None] * ny  # > 0: the satellite lights the side it sees
    d = np.abs(d)
    k = np.flatnonzero((un > 1e-6) & (d > 0.05) & (d <= max_dist_m)
                       & (top[jj] > ant[:, 2, None]))
    q, j = k // max_walls, jj.ravel()[k]
    d, nx, ny, un = d.ravel()[k], nx.ravel()[k], ny.ravel()[k], un.ravel()[k]
    ax, ay, az = ant[q, 0], ant[q, 1], ant[q, 2]
    ux, uy, uz = u[q, 0], u[q, 1], u[q, 2]
    # Specular point, then clamped onto the wall (its footprint and height, 0.1 m inside).
    t = d / un
    rx, ry = ux - 2.0 * un * nx, uy - 2.0 * un * ny  # (r's up component is u's)
    along = facades.along[j]
    e0, e1 = facades.ends_s[j, 0], facades.ends_s[j, 1]
    inset = np.minimum(0.1, 0.5 * (e1 - e0))
    s_al = np.clip((ax + rx * t) * along[:, 0] + (ay + ry * t) * along[:, 1], e0 + inset,
                   e1 - inset)
    lo_z, hi_z = facades.lo_m[j, 2], facades.hi_m[j, 2]
    z_in = np.minimum(0.1, 0.5 * (hi_z - lo_z))
    px = facades.offset_m[j] * facades.normal[j, 0] + s_al * along[:, 0]
    py = facades.offset_m[j] * facades.normal[j, 1] + s_al * along[:, 1]
    vx, vy = ax - px, ay - py  # P -> antenna, horizontal
    # Two points per wall: the one nearest the specular point, and the one below the wall's
    # top edge, which the satellite still sees over the buildings in front of it more often.
    # Where the specular point lies above the wall's top the first is the second (the same
    # point, ray and loss): it is tried once (a fifth of the candidates on the hour's walk).
    top = hi_z - z_in
    pz_near = np.clip(az + uz * t, lo_z + z_in, top)
    other = np.flatnonzero(pz_near != top)
    pz = np.concatenate([pz_near, top[other]])
    two = np.concatenate([np.arange(q.size), other])
    vz = az[two] - pz
    h2 = vx * vx + vy * vy
    dist = np.sqrt(h2[two] + vz * vz)
    cos_psi = -((vx * rx + vy * ry)[two] + vz * uz[two]) / dist  # vs the specular (-r)
    lobe = -10.0 * lobe_alpha * np.log10(np.clip(0.5 * (1.0 + cos_psi), 1e-12, 1.0))
    k = np.flatnonzero(lobe <= max_lobe_loss_db)
    if k.size == 0:
        return found, excess, loss
    # Leg 2 first: open sky from P (nudged off the wall) to the satellite. (Both legs must
    # hold, so their order changes nothing but the cost: this any-hit query rules out more
    # candidates than the nearest-hit one below, and costs less per ray.)
    i = two[k]
    p_off = np.empty((k.size, 3))
    p_off[:, 0], p_off[:, 1], p_off[:, 2] = px[i] + 0.05 * nx[i], py[i] + 0.05 * ny[i], pz[k]
    k = k[~scene.blocked(p_off, u[q[i]])]
    # Leg 1: the first occluder from the antenna towards P is the wall at P.
    i = two[k]
    to_p = np.empty((k.size, 3))  # (filled by column: np.stack costs more on a few rows)
    to_p[:, 0], to_p[:, 1], to_p[:, 2] = vx[i], vy[i], vz[k]
    to_p = -to_p / dist[k, None]
    hit = scene.hit_distance_m(ant[q[i]], to_p)
    k = k[np.abs(hit - dist[k]) < 0.02 + 1e-4 * dist[k]]
    if k.size == 0:
        return found, excess, loss
    i = two[k]
    # Excess over the direct path: |a - P| - (P - a) . u = dist + v . u.
    ex = dist[k] + vx[i] * ux[i] + vy[i] * uy[i] + vz[k] * uz[i]
    best = least_loss_then_shortest(q[i], ex, lobe[k])
    found[q[i][best]] = True
    excess[q[i][best]] = ex[best]
    loss[q[i][best]] = lobe[k][best]
    return found, excess, loss


def least_loss_then_shortest(
    query: np.ndarray, excess_m: np.ndarray, loss_db: np.ndarray
) -> np.ndarray:
    """Each query's path with the least loss, of those the shortest.

    Losses compare to a micro-dB: a path at a specular point has loss 0 only up to round-off
    (~1e-10 dB), and which of several such paths is kept must not be left to the round-off (on
    the hour's walk at 10 Hz, a 1e-9 deg change in a satellite's direction picked paths 46 m
    apart).

    Parameters
    ----------
    query : (k,) int, each candidate path's query
    excess_m : (k,) float, metres, its excess length
    loss_db : (k,) float, dB, its loss

    Returns
    -------
    best : (n_q,) int, indices into the candidates, one per query that has any
    """
    return _best_per_query(query, excess_m, np.round(loss_db, 6))


def _best_per_query(query: np.ndarray, *keys: np.ndarray) -> np.ndarray:
    """The best candidate of each query: the smallest by ``keys``, the last most significant
    (``np.lexsort``'s order; ties keep the first candidate).

    Parameters
    ----------
    query : (k,) int, each candidate's query
    keys : (k,) arrays, the criteria

    Returns
    -------
    best : (n_q,) int, indices into the candidates, one per query that has any
    """
    order = np.lexsort((*keys, query))
    qo = query[order]
    first = np.ones(order.size, bool)
    first[1:] = qo[1:] != qo[:-1]
    return order[first]


def _ranges(counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges: [0..c0), [0..c1), ... for counts c."""
    ends = np.cumsum(counts)
    return np.arange(ends[-1] if len(ends) else 0) - np.repeat(ends - counts, counts)
