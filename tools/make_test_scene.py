"""Write the synthetic test scene scenes/test-wall/ (an OBJ and its scene.toml).

The scene is small and its geometry is closed-form, so tests can check ray casting against
trigonometry. All numbers below are scene ENU metres (east, north, up); the OBJ is written in the
y-up convention of OSM2World and Blender (mesh x = east, y = up, z = south), so loading it also
exercises the [axes] mapping.

Objects (prefix -> class in scene.toml):
- ``Ground``: a convex hexagon at up = 0 spanning +-220 m (ignore); one polygon face, so the
  loader's fan triangulation is exercised.
- ``Wall1``: a box east -20..20, north 30..30.5, up 0..12 (occluder); quads written as
  ``f v/vt/vn``.
- ``Tree1``: a box canopy east 20..26, north -20..-14, up 3..9 (foliage); ``f v//vn`` faces
  with negative (relative) indices.
- ``Road1``: a raised slab east -30..-10, north -30..-25, up 0..2 (ignore).
- ``Kiosk1``: a box east 40..44, north 0..4, up 0..3, matching no prefix (default: occluder);
  plain ``f v`` triangles.

Run from the repository root: ``python tools/make_test_scene.py``.
"""

from __future__ import annotations

from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "scenes" / "test-wall"

WALL1 = ((-20.0, 20.0), (30.0, 30.5), (0.0, 12.0))
TREE1 = ((20.0, 26.0), (-20.0, -14.0), (3.0, 9.0))
ROAD1 = ((-30.0, -10.0), (-30.0, -25.0), (0.0, 2.0))
KIOSK1 = ((40.0, 44.0), (0.0, 4.0), (0.0, 3.0))
GROUND = [
    (-200.0, -200.0),
    (200.0, -200.0),
    (220.0, 0.0),
    (200.0, 200.0),
    (-200.0, 200.0),
    (-220.0, 0.0),
]

# Box corners in ENU, indexed by (ix, iy, iz) bits; quads listed counter-clockwise seen from
# outside (outward normals), each with its normal.
_CORNERS = [(ix, iy, iz) for iz in (0, 1) for iy in (0, 1) for ix in (0, 1)]
_QUADS = [
    ((0, 2, 3, 1), (0, 0, -1)),  # bottom
    ((4, 5, 7, 6), (0, 0, 1)),  # top
    ((0, 1, 5, 4), (0, -1, 0)),  # south
    ((2, 6, 7, 3), (0, 1, 0)),  # north
    ((0, 4, 6, 2), (-1, 0, 0)),  # west
    ((1, 3, 7, 5), (1, 0, 0)),  # east
]


def mesh_xyz(e: float, n: float, u: float) -> tuple[float, float, float]:
    """ENU -> the OBJ's y-up axes (x = east, y = up, z = -north)."""
    return e, u, 0.0 - n  # 0.0 - n avoids writing "-0.000000"


def box_vertices(box: tuple[tuple[float, float], ...]) -> list[tuple[float, float, float]]:
    (e0, e1), (n0, n1), (u0, u1) = box
    return [mesh_xyz((e0, e1)[ix], (n0, n1)[iy], (u0, u1)[iz]) for ix, iy, iz in _CORNERS]


def vline(p: tuple[float, float, float]) -> str:
    return f"v {p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"


def main() -> None:
    lines = [
        "# Synthetic test scene for virtualgps (tools/make_test_scene.py).",
        "# Axes: x = east, y = up, z = south.",
        "",
    ]
    n_v = 0

    # Normals, shared by every box (OBJ vn indices 1..6), in mesh axes; and one texture vertex.
    for _, (ne, nn, nu) in _QUADS:
        x, y, z = mesh_xyz(ne, nn, nu)
        lines.append(f"vn {x:g} {y:g} {z:g}")
    lines.append("vt 0 0")

    lines += ["g Terrain", "o Ground", "usemtl grass"]
    for e, n in GROUND:
        lines.append(vline(mesh_xyz(e, n, 0.0)))
    lines.append("f " + " ".join(str(n_v + k + 1) for k in range(len(GROUND))))
    n_v += len(GROUND)

    lines += ["", "g Walls", "o Wall1", "usemtl brick", "s off"]
    lines += [vline(p) for p in box_vertices(WALL1)]
    for k, (quad, _) in enumerate(_QUADS):
        lines.append("f " + " ".join(f"{n_v + i + 1}/1/{k + 1}" for i in quad))
    n_v += 8

    lines += ["", "g Vegetation", "o Tree1", "usemtl leaves"]
    lines += [vline(p) for p in box_vertices(TREE1)]
    for k, (quad, _) in enumerate(_QUADS):
        lines.append("f " + " ".join(f"{i - 8}//{k + 1}" for i in quad))  # relative indices
    n_v += 8

    lines += ["", "g Roads", "o Road1", "usemtl asphalt"]
    lines += [vline(p) for p in box_vertices(ROAD1)]
    for quad, _ in _QUADS:
        lines.append("f " + " ".join(str(n_v + i + 1) for i in quad))
    n_v += 8

    lines += ["", "g Misc", "o Kiosk1", "usemtl wood"]
    lines += [vline(p) for p in box_vertices(KIOSK1)]
    for quad, _ in _QUADS:  # as triangles
        a, b, c, d = (n_v + i + 1 for i in quad)
        lines += [f"f {a} {b} {c}", f"f {a} {c} {d}"]
    n_v += 8

    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "test-wall.obj").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (OUT / "scene.toml").write_text(
        """\
# Synthetic test scene, written by tools/make_test_scene.py (geometry documented there).
mesh = "test-wall.obj"

[georef]
lat_deg = 52.0
lon_deg = 11.0
alt_hae_m = 100.0

[axes]
east = "+x"
north = "-z"
up = "+y"

[classes]
occluders = ["Wall"]
foliage = ["Tree"]
ignore = ["Ground", "Road"]
default = "occluder"

[demo]
waypoints_enu_m = [[0.0, 0.0, 1.5], [10.0, 0.0, 1.5], [10.0, 10.0, 1.5], [0.0, 10.0, 1.5],
                   [0.0, 0.0, 1.5]]
speed_mps = 1.4
""",
        encoding="utf-8",
    )
    print(f"wrote {OUT / 'test-wall.obj'} and {OUT / 'scene.toml'}")


if __name__ == "__main__":
    main()
