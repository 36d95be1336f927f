"""Scenes: loading with object names and classes, and line-of-sight queries against closed-form
geometry (the test scene's wall) and against trimesh's independent pure-numpy ray backend."""

from __future__ import annotations

import numpy as np
import pytest

from virtualgps import geodesy
from virtualgps.exceptions import InputFileError
from virtualgps.run.config import BUNDLED_SCENES_DIR
from virtualgps.sky.scene import CLASS_FOLIAGE, CLASS_IGNORE, CLASS_OCCLUDER, Scene, load_scene

TEST_SCENE = BUNDLED_SCENES_DIR / "test-wall"
# Wall1 of the test scene (tools/make_test_scene.py): east -20..20, north 30..30.5, up 0..12.
WALL_E = (-20.0, 20.0)
WALL_N = 30.0
WALL_H = 12.0


@pytest.fixture(scope="module")
def wall_scene() -> Scene:
    return load_scene(TEST_SCENE)


@pytest.fixture(scope="module")
def wall_scene_numpy() -> Scene:
    return load_scene(TEST_SCENE, backend="numpy")


def test_analytic_wall_blocks_exactly_below_its_edge(wall_scene):
    """A wall of height h at distance d blocks exactly the elevations below atan(h/d)."""
    origin = np.array([3.0, -5.0, 1.5])  # not the scene origin
    d = WALL_N - origin[1]
    h = WALL_H - origin[2]
    edge_deg = np.degrees(np.arctan2(h, d))  # straight north (az 0): the wall's nearest point
    el = np.array([edge_deg - 0.05, edge_deg + 0.05, 1.0, 60.0])
    dirs = geodesy.azel_to_enu_unit(np.zeros(4), el)
    blocked = wall_scene.blocked(np.broadcast_to(origin, (4, 3)), dirs)
    assert blocked.tolist() == [True, False, True, False]

    # In other azimuths inside the span the edge is lower: atan(h / (d / cos(az))).
    az = np.array([-25.0, 10.0, 25.0])
    edge = np.degrees(np.arctan2(h, d / np.cos(np.radians(az))))
    for sign, expect in ((-0.05, True), (+0.05, False)):
        dirs = geodesy.azel_to_enu_unit(az, edge + sign)
        assert wall_scene.blocked(np.broadcast_to(origin, (3, 3)), dirs).tolist() == [expect] * 3

    # Outside the wall's azimuth span nothing blocks, even at low elevation.
    span = np.degrees(np.arctan2(np.array(WALL_E) - origin[0], d))
    az_out = np.array([span[0] - 1.0, span[1] + 1.0])
    dirs = geodesy.azel_to_enu_unit(az_out, np.full(2, 2.0))
    assert not wall_scene.blocked(np.broadcast_to(origin, (2, 3)), dirs).any()
    az_in = np.array([span[0] + 1.0, span[1] - 1.0])
    dirs = geodesy.azel_to_enu_unit(az_in, np.full(2, 2.0))
    assert wall_scene.blocked(np.broadcast_to(origin, (2, 3)), dirs).all()


def test_hit_distance_is_the_distance_to_the_wall(wall_scene):
    origin = np.array([[0.0, 0.0, 2.0]])
    dist = wall_scene.hit_distance_m(origin, np.array([[0.0, 1.0, 0.0]]))
    assert dist[0] == pytest.approx(WALL_N, abs=1e-3)
    assert np.isinf(wall_scene.hit_distance_m(origin, np.array([[0.0, -1.0, 0.0]]))[0])


def test_embree_and_numpy_backends_agree(wall_scene, wall_scene_numpy):
    rng = np.random.default_rng(2)
    n = 3000
    origins = np.c_[rng.uniform(-40, 50, n), rng.uniform(-40, 40, n), rng.uniform(0.5, 10, n)]
    dirs = geodesy.azel_to_enu_unit(rng.uniform(0, 360, n), rng.uniform(-30, 90, n))
    for cls in ("occluder", "foliage"):
        a = wall_scene.blocked(origins, dirs, cls=cls)
        b = wall_scene_numpy.blocked(origins, dirs, cls=cls)
        assert a.any() and (a == b).mean() > 0.999, cls  # grazing rays may differ in float32
    da = wall_scene.hit_distance_m(origins, dirs)
    db = wall_scene_numpy.hit_distance_m(origins, dirs)
    both = np.isfinite(da) & np.isfinite(db)
    np.testing.assert_allclose(da[both], db[both], atol=1e-3)


def test_ray_starting_on_a_surface_does_not_hit_it(wall_scene):
    # An antenna standing on the wall's top, looking up and sideways: only the nudge keeps the
    # top face from blocking every ray.
    top = np.array([[0.0, 30.25, WALL_H]])
    dirs = geodesy.azel_to_enu_unit(np.array([90.0, 0.0, 200.0]), np.array([80.0, 5.0, 1.0]))
    assert not wall_scene.blocked(np.repeat(top, 3, axis=0), dirs).any()


def test_classes_foliage_and_ignore(wall_scene):
    names = dict(zip(wall_scene.object_names, wall_scene.object_class.tolist(), strict=True))
    assert names["Wall1"] == CLASS_OCCLUDER and names["Kiosk1"] == CLASS_OCCLUDER  # default
    assert names["Tree1"] == CLASS_FOLIAGE
    assert names["Road1"] == CLASS_IGNORE and names["Ground"] == CLASS_IGNORE
    # Through the tree canopy (east 20..26, north -20..-14, up 3..9): foliage, not occluder.
    o = np.array([[23.0, -30.0, 6.0]])
    north = np.array([[0.0, 1.0, 0.0]])
    assert wall_scene.blocked(o, north, cls="foliage")[0]
    assert not wall_scene.blocked(o, north, cls="occluder")[0]
    # Along the raised road slab (ignore) nothing blocks.
    o = np.array([[-40.0, -27.5, 1.0]])
    assert not wall_scene.blocked(o, np.array([[1.0, 0.0, 0.0]]))[0]


def test_magdeburg_objects_and_classes(shared_data):
    scene = load_scene(BUNDLED_SCENES_DIR / "magdeburg-campus")
    names = np.array(scene.object_names)
    cls = scene.object_class
    is_building = np.char.startswith(names, "Building") & ~np.char.startswith(
        names, "BuildingEntrance")
    # SOURCES.md: 40 buildings, 138 trees, 42 benches, 21 street lamps.
    assert len(set(names[is_building])) <= 40 <= is_building.sum()
    assert np.char.startswith(names, "Tree").sum() == 138
    assert (cls[np.char.startswith(names, "Tree")] == CLASS_FOLIAGE).all()
    assert (cls[is_building] == CLASS_OCCLUDER).all()
    for ignored in ("Road", "Rail", "Tunnel", "SurfaceArea"):
        assert (cls[np.char.startswith(names, ignored)] == CLASS_IGNORE).all(), ignored
    # The georeference: MSL 0 becomes the EGM96 geoid height above the ellipsoid.
    assert scene.alt_hae_m == pytest.approx(float(geodesy.geoid_sep_m(scene.lat_deg,
                                                                       scene.lon_deg)))
    # Demo waypoints are outside buildings: an upward ray from below the terrain hits no roof.
    w = scene.demo_waypoints_enu_m
    below = np.c_[w[:, :2], np.full(len(w), 40.0)]
    up = np.tile([0.0, 0.0, 1.0], (len(w), 1))
    assert not np.isfinite(scene.hit_distance_m(below, up, cls="occluder")).any()
    # Ground 1.5 m below each waypoint.
    np.testing.assert_allclose(scene.ground_height_m(w[:, 0], w[:, 1]), w[:, 2] - 1.5, atol=0.05)


def test_open_sky_blocks_nothing():
    sky = Scene.open_sky(52.0, 11.0, 100.0)
    dirs = geodesy.azel_to_enu_unit(np.arange(0, 360, 30.0), np.full(12, 1.0))
    assert not sky.blocked(np.zeros((12, 3)), dirs).any()


@pytest.mark.parametrize(
    ("text", "expect"),
    [
        ('mesh = "nope.obj"\n[georef]\nlat_deg = 1.0\nlon_deg = 2.0\nalt_hae_m = 0.0\n',
         "nope.obj"),
        ('mesh = "m.obj"\n[georef]\nlat_deg = 1.0\nlon_deg = 2.0\nalt_hae_m = 0.0\n'
         '[axes]\neast = "+x"\nnorth = "+x"\nup = "+z"\n', "axes"),
        ('mesh = "m.obj"\n[georef]\nlat_deg = 1.0\nlon_deg = 2.0\nalt_hae_m = 0.0\n'
         '[classes]\nshrubs = ["Bush"]\n', "shrubs"),
        ('mesh = "m.obj"\n[georef\n', "line 2"),
        # A mirror (left-handed) axis mapping, named with its line.
        ('mesh = "m.obj"\n[georef]\nlat_deg = 1.0\nlon_deg = 2.0\nalt_hae_m = 0.0\n'
         '[axes]\neast = "+x"\nnorth = "+y"\nup = "-z"\n', "scene.toml:6: [axes]"),
        ('mesh = "m.obj"\n[georef]\nlat_deg = 1.0\nlon_deg = 2.0\nalt_hae_m = 0.0\n'
         'alt_msl_m = 0.0\n', "exactly one of"),
        ('mesh = "m.obj"\nmesh_scale = 2\n[georef]\nlat_deg = 1.0\nlon_deg = 2.0\n'
         'alt_hae_m = 0.0\n', "scene.toml:2: unknown key 'mesh_scale'"),
    ],
)
def test_bad_scene_toml_names_the_file(tmp_path, text, expect):
    (tmp_path / "m.obj").write_text("o Wall1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "scene.toml").write_text(text)
    with pytest.raises(InputFileError) as err:
        load_scene(tmp_path)
    msg = str(err.value)
    assert "scene.toml" in msg or "nope.obj" in msg
    assert expect in msg


def test_bad_obj_names_the_line(tmp_path):
    (tmp_path / "m.obj").write_text("o Wall1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n")
    (tmp_path / "scene.toml").write_text(
        'mesh = "m.obj"\n[georef]\nlat_deg = 1.0\nlon_deg = 2.0\nalt_hae_m = 0.0\n'
    )
    with pytest.raises(InputFileError, match=r"m\.obj:5: face index '4' is out of range"):
        load_scene(tmp_path)


def test_parsed_meshes_are_cached_by_content(tmp_path, monkeypatch):
    """Issue #9: the parsed mesh is kept in the user cache, keyed by the file's content; a
    cached load gives the same arrays, an edited file is parsed afresh, a broken cache file is
    rebuilt."""
    from virtualgps.sky import meshfiles

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    obj = tmp_path / "m.obj"
    obj.write_text("o Wall1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n"
                   "o Tree2\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf 5 6 7\n")
    first = meshfiles.load_mesh(obj)
    (cached,) = (tmp_path / "cache" / "virtualgps" / "mesh").glob("*.npz")
    monkeypatch.setattr(meshfiles, "_read_obj", lambda p: pytest.fail("parsed again"))
    again = meshfiles.load_mesh(obj)
    for a, b in zip(first[:3], again[:3], strict=True):
        np.testing.assert_array_equal(a, b)
        assert a.dtype == b.dtype
    assert again[3] == first[3] == [("Wall1", "m"), ("Tree2", "m")]
    monkeypatch.undo()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    obj.write_text(obj.read_text().replace("v 1 1 0", "v 2 2 0"))  # edited: a new key
    assert meshfiles.load_mesh(obj)[0][3, 0] == 2.0
    cached.write_bytes(b"not a cache")
    obj.write_text(obj.read_text().replace("v 2 2 0", "v 1 1 0"))
    np.testing.assert_array_equal(meshfiles.load_mesh(obj)[0], first[0])


def test_glb_and_stl_take_object_names_from_the_scene_graph(tmp_path, wall_scene):
    """The test scene exported through trimesh (GLB with named nodes) loads with the same
    classes and blocks the same rays; a single-mesh STL is one object named after its file."""
    import trimesh

    verts_mesh = wall_scene.vertices_enu_m[:, [0, 2, 1]] * [1.0, 1.0, -1.0]  # back to y-up
    graph = trimesh.Scene()
    for i, name in enumerate(wall_scene.object_names):
        faces = wall_scene.faces[wall_scene.face_object == i]
        part = trimesh.Trimesh(verts_mesh, faces, process=False)
        part.remove_unreferenced_vertices()
        graph.add_geometry(part, node_name=name, geom_name=f"{name}-mesh")
    graph.export(tmp_path / "walls.glb")
    toml = (TEST_SCENE / "scene.toml").read_text().replace("test-wall.obj", "walls.glb")
    (tmp_path / "scene.toml").write_text(toml)
    glb = load_scene(tmp_path)
    classes = dict(zip(wall_scene.object_names, wall_scene.object_class.tolist(), strict=True))
    assert dict(zip(glb.object_names, glb.object_class.tolist(), strict=True)) == classes

    rng = np.random.default_rng(5)
    n = 500
    origins = np.c_[rng.uniform(-40, 50, n), rng.uniform(-40, 40, n), rng.uniform(0.5, 10, n)]
    dirs = geodesy.azel_to_enu_unit(rng.uniform(0, 360, n), rng.uniform(-10, 60, n))
    for cls in ("occluder", "foliage", "all"):
        assert (glb.blocked(origins, dirs, cls) == wall_scene.blocked(origins, dirs, cls)).all()

    wall = wall_scene.object_names.index("Wall1")
    faces = wall_scene.faces[wall_scene.face_object == wall]
    trimesh.Trimesh(verts_mesh, faces).export(tmp_path / "Wall1.stl")
    (tmp_path / "scene.toml").write_text(toml.replace("walls.glb", "Wall1.stl"))
    stl = load_scene(tmp_path)
    assert stl.object_names == ("Wall1",) and stl.object_class.tolist() == [CLASS_OCCLUDER]


def test_magdeburg_class_engines_partition_the_faces(shared_data):
    """Each face is in its own class's ray engine and in no other: a ray aimed at a face from
    0.5 m in front of it meets it at 0.5 m in its class, never in another class (so trees are
    not occluders, and roads, rails, surfaces and the tunnel never block)."""
    scene = load_scene(BUNDLED_SCENES_DIR / "magdeburg-campus")
    tri = scene.vertices_enu_m[scene.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    normal /= area2[:, None]
    rng = np.random.default_rng(3)
    for k, name in enumerate(("occluder", "foliage", "ignore")):
        # Bottoms of objects standing on the ground coincide with ground faces: leave them out.
        faces = np.flatnonzero((scene.face_class == k) & (area2 > 0.04) & (normal[:, 2] > -0.99))
        faces = rng.choice(faces, min(2000, len(faces)), replace=False)
        origins = tri[faces].mean(axis=1) + 0.5 * normal[faces]
        for other in ("occluder", "foliage", "ignore"):
            dist = scene.hit_distance_m(origins, -normal[faces], cls=other)
            at_face = np.abs(dist - 0.5) < 1e-3
            if other == name:
                # Most faces are met first; the rest lie behind overlapping (coplanar) layers.
                assert at_face.mean() > 0.75, name
            else:
                assert not at_face.any(), (name, other)
