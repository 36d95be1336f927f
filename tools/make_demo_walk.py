"""Plan the Magdeburg scene's demo walk: the waypoint markers of the real logs, joined by paths
that stay outside buildings, antenna 1.5 m above the ground. Prints the ``[demo]`` table for
``scenes/magdeburg-campus/scene.toml``.

Usage: python tools/make_demo_walk.py [PATH/TO/Wegpunkte/staticmap.txt]

The markers (18 map pins; the logs stand at 5-18) come from ../shared/data (xaedes/GNSS-Shadowing,
MIT). Buildings are found by casting rays upward from below the terrain: a hit on an occluder
means the point lies under a roof. Cells within 3 m of a building are avoided; paths are
shortest 8-connected paths on a 1 m grid, then thinned to the corners a walker would take.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_dilation
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from virtualgps import geodesy
from virtualgps.sky.scene import load_scene

REPO = Path(__file__).resolve().parents[1]
MARKERS = Path(sys.argv[1]) if len(sys.argv) > 1 else (
    REPO.parent / "shared/data/magdeburg-campus/nmea/Wegpunkte/staticmap.txt")
CELL_M = 1.0
CLEARANCE_M = 3.0
ANTENNA_M = 1.5


def main() -> None:
    scene = load_scene(REPO / "scenes/magdeburg-campus")
    url = MARKERS.read_text()
    markers = url.split("markers=")[1].strip().strip("|").split("|")
    pins = [tuple(map(float, m.split(","))) for m in markers]
    ll = np.array(pins)[4:18]  # markers 5-18: where the waypoint logs were recorded
    enu = geodesy.ecef_to_enu(geodesy.geodetic_to_ecef(ll[:, 0], ll[:, 1], scene.alt_hae_m),
                              scene.lat_deg, scene.lon_deg, scene.alt_hae_m)[:, :2]
    lo, hi = enu.min(axis=0) - 60.0, enu.max(axis=0) + 60.0
    xs = np.arange(lo[0], hi[0], CELL_M)
    ys = np.arange(lo[1], hi[1], CELL_M)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    origins = np.c_[gx.ravel(), gy.ravel(), np.full(gx.size, 40.0)]  # below the terrain
    up = np.tile([0.0, 0.0, 1.0], (gx.size, 1))
    building = np.isfinite(scene.hit_distance_m(origins, up, cls="occluder")).reshape(gx.shape)
    r = int(CLEARANCE_M / CELL_M)
    disk = np.hypot(*np.mgrid[-r:r + 1, -r:r + 1]) <= r
    free = ~binary_dilation(building, structure=disk)

    # 8-connected grid graph over free cells.
    idx = np.arange(gx.size).reshape(gx.shape)
    rows, cols, w = [], [], []
    for dx, dy in [(1, 0), (0, 1), (1, 1), (1, -1)]:
        a = idx[max(0, -dx):gx.shape[0] - max(0, dx), max(0, -dy):gx.shape[1] - max(0, dy)]
        b = idx[max(0, dx):, max(0, dy):][: a.shape[0], : a.shape[1]] if dy >= 0 else \
            idx[max(0, dx):, : gx.shape[1] + dy][: a.shape[0], : a.shape[1]]
        ok = free.ravel()[a.ravel()] & free.ravel()[b.ravel()]
        rows += [a.ravel()[ok]]
        cols += [b.ravel()[ok]]
        w += [np.full(ok.sum(), np.hypot(dx, dy) * CELL_M)]
    graph = coo_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(gx.size, gx.size)).tocsr()

    def cell(p: np.ndarray) -> int:
        i, j = int(round((p[0] - lo[0]) / CELL_M)), int(round((p[1] - lo[1]) / CELL_M))
        # Nearest free cell to a marker.
        fi, fj = np.nonzero(free)
        k = np.argmin((fi - i) ** 2 + (fj - j) ** 2)
        return int(idx[fi[k], fj[k]])

    def is_free_segment(a: np.ndarray, b: np.ndarray) -> bool:
        n = max(2, int(np.linalg.norm(b - a) / (CELL_M / 2)))
        s = np.linspace(0.0, 1.0, n)[:, None]
        p = a * (1 - s) + b * s
        i = np.clip(np.round((p[:, 0] - lo[0]) / CELL_M).astype(int), 0, gx.shape[0] - 1)
        j = np.clip(np.round((p[:, 1] - lo[1]) / CELL_M).astype(int), 0, gx.shape[1] - 1)
        return bool(free[i, j].all())

    loop = list(range(len(enu))) + [0]
    path: list[np.ndarray] = []
    for a, b in zip(loop[:-1], loop[1:], strict=True):
        src, dst = cell(enu[a]), cell(enu[b])
        _, pred = dijkstra(graph, directed=False, indices=src, return_predecessors=True)
        chain = [dst]
        while chain[-1] != src:
            chain.append(int(pred[chain[-1]]))
            assert chain[-1] >= 0, f"no path from marker {a + 5} to {b + 5}"
        pts = np.c_[gx.ravel()[chain[::-1]], gy.ravel()[chain[::-1]]]
        # Thin to corners: keep a point only when the straight line past it would leave free space.
        keep = [pts[0]]
        k = 0
        while k < len(pts) - 1:
            m = len(pts) - 1
            while m > k + 1 and not is_free_segment(pts[k], pts[m]):
                m -= 1
            keep.append(pts[m])
            k = m
        path.extend(keep[:-1])
    xy = np.array(path)
    ground = scene.ground_height_m(xy[:, 0], xy[:, 1])
    z = ground + ANTENNA_M
    length = np.linalg.norm(np.diff(np.vstack([xy, xy[:1]]), axis=0), axis=1).sum()
    print(f"# {len(xy)} waypoints, loop length {length:.0f} m (tools/make_demo_walk.py)")
    print("[demo]")
    print("speed_mps = 1.4")
    print("waypoints_enu_m = [")
    for (x, y), zz in zip(xy, z, strict=True):
        print(f"    [{x:.1f}, {y:.1f}, {zz:.2f}],")
    print("]")


if __name__ == "__main__":
    main()
