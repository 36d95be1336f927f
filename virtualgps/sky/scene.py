"""Scenes: a 3D mesh placed on the Earth by ``scene.toml``, its object classes, and batched
line-of-sight queries (Embree).

A scene is a folder holding ``scene.toml`` and a mesh file (OBJ, glTF/GLB, PLY, STL). The mesh is
kept in the scene's local ENU frame: metres East/North/Up from the georeference point (the paper's
"tag"). Rays are cast in that frame because Embree works in float32 (an ulp is 0.25 mm at 2 km
from the origin, but 1 m at 10,000 km).

``scene.toml`` (DESIGN.md section 4, plus the extras marked *extra*)::

    mesh = "campus.obj"          # path relative to the scene folder (absolute paths allowed)
    tle = "../../ephemeris/x.tle"  # extra, optional: the scene's default TLE set (relative path);
                                 #   not opened here, so a scene loads even before its TLE exists
    [georef]                     # the geodetic point of mesh coordinate (0, 0, 0)
    lat_deg = 52.1400665
    lon_deg = 11.643243
    alt_hae_m = 0.0              # or alt_msl_m (converted with the EGM96 geoid); exactly one
    [axes]                       # optional (default +x, +y, +z): mesh axes of East/North/Up,
    east = "+x"                  #   each one of "+x" "-x" "+y" "-y" "+z" "-z"; together a
    north = "-z"                 #   proper rotation (a mirror would flip the scene)
    up = "+y"
    [classes]                    # optional: object-name prefixes (case-sensitive)
    occluders = ["Building", "Wall"]
    foliage = ["Tree"]
    ignore = ["Road", "Rail"]
    default = "occluder"         # extra: class of objects matching no prefix, "occluder"
                                 #   (the default) or "ignore"
    [demo]                       # extra, optional: the scripted walk of ``--poses demo``
    waypoints_enu_m = [[0.0, 0.0, 1.5], [10.0, 0.0, 1.5]]  # antenna positions, scene ENU m
    speed_mps = 1.4              # walking speed (default 1.4)

Any other key is an error naming the key.

Object names. OBJ files are read by our own parser, because trimesh's OBJ loader drops the ``o``
and ``g`` names that carry the classes: each face remembers the last ``o`` name and the last ``g``
name before it; an object is a run of faces under one (``o``, ``g``) pair; its name is the ``o``
name (else the ``g`` name, else the file stem). Other formats are loaded by trimesh; each scene
graph node is an object named after the node (the geometry name is the fallback for
classification); a single mesh is one object named after the file stem.

Classification: the longest matching prefix over all three lists wins (so ``RoadSign`` under
occluders can override ``Road`` under ignore), trying the object's name first and its fallback
name second; objects matching nothing get ``classes.default``.

Accepted approximations:
- The mesh axes are taken as a local tangent plane at the georeference point. Over 1 km the
  Earth's curvature drops the ground by 8 cm, and a mesh made in a map projection (OSM2World uses
  an orthographic projection) has scale errors of that order: both far below a GPS receiver's
  error and below a building's height.
- Ray origins are nudged ``nudge_m`` (1 mm, or more for scenes larger than 8 km) along the ray
  before casting, so that an antenna on a surface (a roof, the ground) does not see that
  surface. A surface closer than 1 mm in front of the origin is missed.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from virtualgps.exceptions import InputFileError
from virtualgps.geodesy import geoid_sep_m
from virtualgps.sky.meshfiles import load_mesh
from virtualgps.tomlfile import toml_key_line

F64 = NDArray[np.float64]

# Class ids of faces and objects.
CLASS_OCCLUDER, CLASS_FOLIAGE, CLASS_IGNORE = 0, 1, 2
CLASS_NAMES = ("occluder", "foliage", "ignore")
# Names accepted by the queries' ``cls``: one class, or "all" (every face, ignored ones too).
# "solid" = occluders and foliage together: one query where foliage blocks (the paper's rule).
QueryClass = Literal["occluder", "foliage", "ignore", "all", "solid"]
_QUERY_CLASSES = ("occluder", "foliage", "ignore", "all", "solid")

# Ray-origin nudge (see module docstring). 1 mm is 4x the float32 spacing at 8 km from the
# origin; larger scenes scale it to 4 ulps of their extent.
NUDGE_MIN_M = 1e-3
# Coordinates farther than this from the georeference point are refused: float32 spacing there is
# 2 mm, and farther out the mesh was almost surely not made local to [georef].
MAX_EXTENT_M = 20_000.0

_AXES = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}
_KEYS = {
    "": {"mesh", "tle", "georef", "axes", "classes", "demo"},
    "georef": {"lat_deg", "lon_deg", "alt_hae_m", "alt_msl_m"},
    "axes": {"east", "north", "up"},
    "classes": {"occluders", "foliage", "ignore", "default"},
    "demo": {"waypoints_enu_m", "speed_mps"},
}


# --------------------------------------------------------------------------------------------
# Ray engines: one per class set, same API for Embree and trimesh's numpy reference.


class _EmbreeEngine:
    """Embree BVH over some triangles (float32, local frame)."""

    def __init__(self, vertices_enu_m: F64, faces: NDArray[np.int32], device: Any) -> None:
        from embreex.mesh_construction import TriangleMesh
        from embreex.rtcore_scene import EmbreeScene

        self._scene = EmbreeScene(device)
        TriangleMesh(self._scene, vertices_enu_m.astype(np.float32), faces.astype(np.int32))
        # Build the BVH now, not on the first query (embreex commits lazily in run()).
        self._scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))

    def occluded(self, org: NDArray[np.float32], unit: NDArray[np.float32], tmax: float) -> Any:
        # OCCLUDED is Embree's any-hit query: traversal stops at the first hit found.
        return self._scene.run(org, unit, dists=tmax, query="OCCLUDED") != -1

    def distance(self, org: NDArray[np.float32], unit: NDArray[np.float32]) -> F64:
        t = self._scene.run(org, unit, query="DISTANCE").astype(np.float64)
        t[t >= 1e36] = np.inf  # embreex reports a miss as its initial tfar, 1e37
        return t


class _NumpyEngine:
    """trimesh's pure-numpy ray/triangle intersector (reference backend for tests; slow)."""

    def __init__(self, vertices_enu_m: F64, faces: NDArray[np.int32]) -> None:
        import trimesh
        from trimesh.ray.ray_triangle import RayMeshIntersector

        mesh = trimesh.Trimesh(vertices_enu_m, faces, process=False, validate=False)
        self._rmi = RayMeshIntersector(mesh)

    def occluded(self, org: NDArray[np.float32], unit: NDArray[np.float32], tmax: float) -> Any:
        return self.distance(org, unit) <= tmax

    def distance(self, org: NDArray[np.float32], unit: NDArray[np.float32]) -> F64:
        o = org.astype(np.float64)
        d = np.broadcast_to(unit, org.shape).astype(np.float64)
        t = np.full(len(o), np.inf)
        if len(o) == 0:
            return t
        _, i_ray, loc = self._rmi.intersects_id(o, d, return_locations=True, multiple_hits=False)
        if len(i_ray):
            # trimesh keeps hits up to 1e-6 m behind the origin; Embree starts at t = 0.
            dist = np.einsum("ij,ij->i", loc - o[i_ray], d[i_ray])
            ok = dist >= 0.0
            np.minimum.at(t, i_ray[ok], dist[ok])
        return t


# --------------------------------------------------------------------------------------------
# The scene.


@dataclass(frozen=True, eq=False)
class Scene:
    """A georeferenced mesh with classified objects, and line-of-sight queries against it.

    Make one with :func:`load_scene` or :meth:`Scene.open_sky`. Immutable; the ray engines are
    built once, at their first query or :meth:`prepare`, and shared by :meth:`with_georef`.

    Attributes
    ----------
    lat_deg, lon_deg : float, degrees, WGS-84 geodetic position of the ENU origin
    alt_hae_m : float, metres above the WGS-84 ellipsoid of the ENU origin (mesh up = 0)
    vertices_enu_m : (n_v, 3) float64, metres, scene ENU
    faces : (n_f, 3) int32, vertex indices of each triangle
    face_object : (n_f,) int32, index into ``object_names`` of each face
    object_names : tuple of n_obj str, object names (may repeat: OSM2World names every segment of
        a road after the road)
    object_class : (n_obj,) int8, class id of each object (CLASS_OCCLUDER, CLASS_FOLIAGE,
        CLASS_IGNORE)
    path : Path or None, the scene.toml (None for open sky)
    mesh_path : Path or None, the mesh file
    tle_path : Path or None, the scene's default TLE set (absolute; may not exist)
    demo_waypoints_enu_m : (n_wp, 3) float64 or None, metres, scene ENU, antenna positions
    demo_speed_mps : float, metres per second along the demo walk
    backend : "embree" or "numpy"
    nudge_m : float, metres, how far ray origins are moved along the ray before casting
    """

    lat_deg: float
    lon_deg: float
    alt_hae_m: float
    vertices_enu_m: F64 = field(repr=False)
    faces: NDArray[np.int32] = field(repr=False)
    face_object: NDArray[np.int32] = field(repr=False)
    object_names: tuple[str, ...] = field(repr=False)
    object_class: NDArray[np.int8] = field(repr=False)
    path: Path | None = None
    mesh_path: Path | None = None
    tle_path: Path | None = None
    demo_waypoints_enu_m: F64 | None = field(default=None, repr=False)
    demo_speed_mps: float = 1.4
    backend: Literal["embree", "numpy"] = "embree"
    nudge_m: float = field(init=False, default=NUDGE_MIN_M)
    # Ray engines by query class (and, under "_device", the Embree device they share); passed
    # in only by with_georef, which shares them.
    _engines: dict[str, Any] | None = field(default=None, repr=False, compare=False)
    _top_m: float = field(init=False, repr=False, default=0.0)

    def __post_init__(self) -> None:
        if self.backend not in ("embree", "numpy"):
            raise ValueError(f"backend must be 'embree' or 'numpy', not {self.backend!r}")
        verts = self.vertices_enu_m
        extent = float(np.abs(verts).max()) if len(verts) else 0.0
        # 4 float32 ulps at the scene's extent, at least 1 mm (module docstring).
        nudge = max(NUDGE_MIN_M, 4.0 * float(np.spacing(np.float32(extent))))
        object.__setattr__(self, "nudge_m", nudge)
        object.__setattr__(self, "_top_m", float(verts[:, 2].max()) if len(verts) else 0.0)
        if self._engines is None:
            # Built on first use, class by class (a run casts against two or three of the five:
            # building them all cost a short replay ~0.1 s); with_georef shares this dict.
            object.__setattr__(self, "_engines", {})

    def prepare(self, classes: Iterable[QueryClass]) -> None:
        """Build the ray engines of these query classes now, not at their first query (a
        daemon's first epoch should not wait for a BVH).

        Parameters
        ----------
        classes : query class names (see ``QueryClass``)
        """
        for cls in classes:
            self._engine(cls)

    def _build_engine(self, name: str) -> Any:
        """The engine of one query class, None for a class without faces."""
        face_class = self.face_class
        if name == "all":
            sel = self.faces
        elif name == "solid":
            sel = self.faces[face_class != CLASS_NAMES.index("ignore")]
        else:
            sel = self.faces[face_class == CLASS_NAMES.index(name)]
        if len(sel) == 0:
            return None
        if self.backend == "numpy":
            return _NumpyEngine(self.vertices_enu_m, sel)
        device = self._engines.get("_device")
        if device is None:
            from embreex.rtcore import EmbreeDevice

            device = self._engines["_device"] = EmbreeDevice()  # shared by the class scenes
        return _EmbreeEngine(self.vertices_enu_m, sel, device)

    # -- construction ------------------------------------------------------------------------

    @classmethod
    def open_sky(cls, lat_deg: float, lon_deg: float, alt_hae_m: float) -> Scene:
        """Make a scene without a mesh: nothing blocks (``--scene none``).

        Parameters
        ----------
        lat_deg, lon_deg : float, degrees, WGS-84, the ENU origin
        alt_hae_m : float, metres above the ellipsoid, the ENU origin

        Returns
        -------
        scene : Scene with no faces
        """
        return cls(
            lat_deg=float(lat_deg),
            lon_deg=float(lon_deg),
            alt_hae_m=float(alt_hae_m),
            vertices_enu_m=np.zeros((0, 3)),
            faces=np.zeros((0, 3), np.int32),
            face_object=np.zeros(0, np.int32),
            object_names=(),
            object_class=np.zeros(0, np.int8),
        )

    def with_georef(self, lat_deg: float, lon_deg: float, alt_hae_m: float) -> Scene:
        """Return the same scene placed at another geodetic origin (``--origin``, config).

        The mesh stays in its local frame; only the ENU origin moves. Ray engines are shared.

        Parameters
        ----------
        lat_deg, lon_deg : float, degrees, WGS-84
        alt_hae_m : float, metres above the ellipsoid of mesh up = 0
        """
        return replace(
            self,
            lat_deg=float(lat_deg),
            lon_deg=float(lon_deg),
            alt_hae_m=float(alt_hae_m),
            _engines=self._engines,
        )

    # -- properties --------------------------------------------------------------------------

    @property
    def face_class(self) -> NDArray[np.int8]:
        """(n_f,) int8, class id of each face."""
        return self.object_class[self.face_object]

    @property
    def has_mesh(self) -> bool:
        """True when the scene has faces (False for open sky)."""
        return len(self.faces) > 0

    # -- queries -----------------------------------------------------------------------------

    def _rays(
        self, origins_enu_m: ArrayLike, dirs_enu: ArrayLike
    ) -> tuple[tuple[int, ...], NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_] | None]:
        """Broadcast, flatten, normalise and nudge rays for the engines.

        Returns
        -------
        shape : the broadcast shape without the xyz axis
        org : (m, 3) float32, metres, scene ENU, nudged origins
        unit : (m, 3) or (1, 3) float32, unit directions ((1, 3): one for all rays)
        valid : (m,) bool, or None when every ray is valid (the common, fast case)
        """
        o = np.asarray(origins_enu_m, dtype=np.float64)
        d = np.asarray(dirs_enu, dtype=np.float64)
        if o.shape[-1:] != (3,) or d.shape[-1:] != (3,):
            raise ValueError(f"rays need xyz on the last axis, got shapes {o.shape}, {d.shape}")
        norm = np.sqrt(np.einsum("...i,...i->...", d, d))
        # Fast path (a 32-ray epoch spends more time here than in Embree): no masks unless
        # some ray is degenerate. NaN norms fail the comparison too.
        if norm.size and norm.min() > 0.0:
            unit = d / norm[..., None]
            org = o + self.nudge_m * unit  # broadcasts origins against directions
            org32 = org.astype(np.float32).reshape(-1, 3)
            if math.isfinite(float(org32.sum())):
                if unit.shape == org.shape:
                    unit32 = unit.astype(np.float32).reshape(-1, 3)
                elif unit.size == 3:
                    unit32 = unit.astype(np.float32).reshape(1, 3)  # Embree reuses it
                else:
                    unit32 = np.broadcast_to(unit, org.shape).astype(np.float32).reshape(-1, 3)
                return org.shape[:-1], org32, unit32, None
        shape = np.broadcast_shapes(o.shape, d.shape)
        o = np.broadcast_to(o, shape).reshape(-1, 3)
        d = np.broadcast_to(d, shape).reshape(-1, 3)
        norm = np.sqrt(np.einsum("ij,ij->i", d, d))
        valid = (norm > 0.0) & np.isfinite(norm) & np.isfinite(o).all(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = d / norm[:, None]
        # Cast something harmless for invalid rays; their results are masked out afterwards.
        unit[~valid] = (0.0, 0.0, 1.0)
        o = np.where(valid[:, None], o, 0.0)
        org = o + self.nudge_m * unit
        return shape[:-1], org.astype(np.float32), unit.astype(np.float32), valid

    def _engine(self, cls: str) -> Any:
        if cls not in _QUERY_CLASSES:
            raise ValueError(f"cls must be one of {_QUERY_CLASSES}, not {cls!r}")
        engines = self._engines
        if cls not in engines:
            engines[cls] = self._build_engine(cls) if len(self.faces) else None
        return engines[cls]

    def blocked(
        self,
        origins_enu_m: ArrayLike,
        dirs_enu: ArrayLike,
        cls: QueryClass = "occluder",
        max_dist_m: float = math.inf,
    ) -> NDArray[np.bool_]:
        """Tell which rays hit a surface of a class (Embree any-hit query).

        Parameters
        ----------
        origins_enu_m : (..., 3) float, metres, scene ENU, ray origins (e.g. the antenna)
        dirs_enu : (..., 3) float, scene ENU, ray directions (unit or not; e.g. towards each
            satellite); broadcast against ``origins_enu_m``
        cls : "occluder" (default), "foliage", "ignore" or "all"
        max_dist_m : float, metres, only surfaces closer than this count (default: any)

        Returns
        -------
        blocked : (...) bool, True where the ray meets a ``cls`` surface; False for zero or
            non-finite directions and origins
        """
        shape, org, unit, valid = self._rays(origins_enu_m, dirs_enu)
        engine = self._engine(cls)
        if engine is None or len(org) == 0:
            return np.zeros(shape, dtype=bool)
        tmax = float(max_dist_m) - self.nudge_m
        if not tmax >= 0.0:  # also catches NaN
            return np.zeros(shape, dtype=bool)
        hit = engine.occluded(org, unit, min(tmax, 1e30))
        if valid is not None:
            hit &= valid
        return hit.reshape(shape)

    def hit_distance_m(
        self, origins_enu_m: ArrayLike, dirs_enu: ArrayLike, cls: QueryClass = "occluder"
    ) -> F64:
        """Measure the distance along each ray to its first ``cls`` surface.

        Parameters
        ----------
        origins_enu_m : (..., 3) float, metres, scene ENU
        dirs_enu : (..., 3) float, scene ENU (unit or not); broadcast against the origins
        cls : "occluder" (default), "foliage", "ignore" or "all"

        Returns
        -------
        dist_m : (...) float64, metres from the (un-nudged) origin; inf where nothing is hit,
            NaN for zero or non-finite rays
        """
        shape, org, unit, valid = self._rays(origins_enu_m, dirs_enu)
        engine = self._engine(cls)
        if engine is None or len(org) == 0:
            dist = np.full(len(org), np.inf)
        else:
            dist = engine.distance(org, unit) + self.nudge_m
        if valid is not None:
            dist[~valid] = np.nan
        return dist.reshape(shape)

    def ground_height_m(
        self, east_m: ArrayLike, north_m: ArrayLike, from_up_m: ArrayLike | None = None
    ) -> F64:
        """Height of the first surface straight below points (any class: ground is "ignore").

        This is the top surface: a roof where a building stands, a road deck over a tunnel.

        Parameters
        ----------
        east_m, north_m : (...) float, metres, scene ENU, broadcast together
        from_up_m : (...) float, metres, scene ENU, optional: look down from this height
            (default: from above the whole mesh)

        Returns
        -------
        up_m : (...) float64, metres, scene ENU up of the surface; NaN where there is none
            (always NaN for open sky)
        """
        top = self._top_m + 1.0 if from_up_m is None else from_up_m
        e, n, u = np.broadcast_arrays(
            np.asarray(east_m, float), np.asarray(north_m, float), np.asarray(top, float)
        )
        origins = np.stack([e, n, u], axis=-1)
        dist = self.hit_distance_m(origins, np.array([0.0, 0.0, -1.0]), cls="all")
        return np.where(np.isfinite(dist), u - dist, np.nan)


# --------------------------------------------------------------------------------------------
# Loading.


def load_scene(path: str | Path, backend: Literal["embree", "numpy"] = "embree") -> Scene:
    """Load a scene folder (or its ``scene.toml``): mesh, georeference, classes, extras.

    Parameters
    ----------
    path : str or Path, a folder holding ``scene.toml``, or the TOML file itself. (``none``,
        open sky, is the caller's: use :meth:`Scene.open_sky`.)
    backend : "embree" (default) or "numpy" (trimesh's pure-numpy intersector; a slow
        reference for tests)

    Returns
    -------
    scene : Scene

    Raises
    ------
    InputFileError
        The TOML or the mesh is missing or malformed; the message names the file, the line
        where known, and what was expected.
    """
    p = Path(path)
    toml_path = p / "scene.toml" if p.is_dir() else p
    if not toml_path.is_file():
        hint = " (for open sky use --scene none)" if str(path) == "none" else ""
        raise InputFileError(toml_path, f"scene file not found{hint}")
    raw = toml_path.read_bytes()
    try:
        text = raw.decode("utf-8")
        doc = tomllib.loads(text)
    except UnicodeDecodeError as exc:
        raise InputFileError(toml_path, f"not UTF-8 text ({exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"at line (\d+)", str(exc))
        raise InputFileError(
            toml_path, f"TOML syntax error: {exc}", int(m.group(1)) if m else None
        ) from None
    cfg = _SceneToml(toml_path, text, doc)

    mesh_rel = cfg.get("", "mesh", str, required=True)
    mesh_path = (toml_path.parent / mesh_rel).resolve()
    if not mesh_path.is_file():
        cfg.fail("", "mesh", f"mesh file {mesh_rel!r} not found (looked for {mesh_path})")

    lat = cfg.get("georef", "lat_deg", float, required=True)
    lon = cfg.get("georef", "lon_deg", float, required=True)
    if not -90.0 <= lat <= 90.0:
        cfg.fail("georef", "lat_deg", f"lat_deg = {lat} is outside [-90, 90]")
    if not -180.0 <= lon <= 360.0:
        cfg.fail("georef", "lon_deg", f"lon_deg = {lon} is outside [-180, 360]")
    georef = doc.get("georef", {})
    if ("alt_hae_m" in georef) == ("alt_msl_m" in georef):
        cfg.fail("georef", None, "[georef] needs exactly one of alt_hae_m and alt_msl_m")
    if "alt_hae_m" in georef:
        alt_hae = cfg.get("georef", "alt_hae_m", float)
    else:
        # h_ellipsoid = h_msl + N (EGM96 geoid separation at the georef point).
        alt_hae = cfg.get("georef", "alt_msl_m", float) + float(geoid_sep_m(lat, lon))

    rot = _axes_matrix(cfg)
    prefixes, default_cls = _class_rules(cfg)

    tle_rel = cfg.get("", "tle", str)
    tle_path = (toml_path.parent / tle_rel).resolve() if tle_rel is not None else None

    waypoints, speed = None, 1.4
    if "demo" in doc:
        waypoints, speed = _demo(cfg)

    verts, faces, face_object, names = load_mesh(mesh_path)
    verts_enu = verts @ rot.T
    extent = float(np.abs(verts_enu).max())
    if extent > MAX_EXTENT_M:
        raise InputFileError(
            mesh_path,
            f"mesh coordinates reach {extent:.0f} m from the georef point; Embree casts in "
            f"float32, so keep the mesh within {MAX_EXTENT_M:.0f} m of its origin (re-centre it "
            "and move [georef] there)",
        )
    object_class = np.array([_classify(n, prefixes, default_cls) for n in names], np.int8)
    return Scene(
        lat_deg=lat,
        lon_deg=lon,
        alt_hae_m=alt_hae,
        vertices_enu_m=verts_enu,
        faces=faces,
        face_object=face_object,
        object_names=tuple(n[0] for n in names),
        object_class=object_class,
        path=toml_path,
        mesh_path=mesh_path,
        tle_path=tle_path,
        demo_waypoints_enu_m=waypoints,
        demo_speed_mps=speed,
        backend=backend,
    )


class _SceneToml:
    """Typed access to a parsed scene.toml with errors that name the file, line and key."""

    def __init__(self, path: Path, text: str, doc: dict[str, Any]) -> None:
        self.path, self.doc, self.text = path, doc, text
        for section, allowed in _KEYS.items():
            table = doc if section == "" else doc.get(section, {})
            if not isinstance(table, dict):
                self.fail("", section, f"{section} must be a table [{section}]")
            for key in table:
                if key not in allowed:
                    where = f"[{section}]" if section else "the top level"
                    self.fail(
                        section,
                        key,
                        f"unknown key {key!r} in {where} (allowed: {', '.join(sorted(allowed))})",
                    )

    def line_of(self, section: str, key: str | None) -> int | None:
        """1-based line of ``key`` in ``[section]`` (or of a table header), None if not found."""
        return toml_key_line(self.text, section, key)

    def fail(self, section: str, key: str | None, message: str) -> Any:
        raise InputFileError(self.path, message, self.line_of(section, key))

    def get(self, section: str, key: str, kind: type, required: bool = False) -> Any:
        table = self.doc if section == "" else self.doc.get(section, {})
        name = f"{section}.{key}" if section else key
        if key not in table:
            if required:
                where = f"[{section}]" if section else "the top level"
                self.fail(section, None, f"missing {key!r} in {where}")
            return None
        value = table[key]
        if kind is float and isinstance(value, int | float) and not isinstance(value, bool):
            if not math.isfinite(value):
                self.fail(section, key, f"{name} must be a finite number, got {value}")
            return float(value)
        if kind is str and isinstance(value, str):
            return value
        expected = "a number" if kind is float else "a string"
        return self.fail(section, key, f"{name} must be {expected}, got {value!r}")


def _axes_matrix(cfg: _SceneToml) -> F64:
    """(3, 3) matrix whose rows are East, North, Up in mesh coordinates: enu = rot @ xyz."""
    names = {"east": "+x", "north": "+y", "up": "+z"}
    for k in names:
        v = cfg.get("axes", k, str)
        if v is not None:
            if v not in _AXES:
                cfg.fail(
                    "axes",
                    k,
                    f"axes.{k} = {v!r}; expected one of {', '.join(repr(a) for a in _AXES)}",
                )
            names[k] = v
    rot = np.array([_AXES[names[k]] for k in ("east", "north", "up")])
    det = np.linalg.det(rot)
    if abs(det) < 0.5:
        cfg.fail(
            "axes",
            None,
            f"[axes] east/north/up = {names['east']}/{names['north']}/"
            f"{names['up']} use one mesh axis twice; each must be a different axis",
        )
    if det < 0.0:
        cfg.fail(
            "axes",
            None,
            f"[axes] east/north/up = {names['east']}/{names['north']}/"
            f"{names['up']} is a mirror image (left-handed); flip the sign of one axis",
        )
    return rot


def _class_rules(cfg: _SceneToml) -> tuple[dict[str, int], int]:
    """Prefix -> class id, and the default class id."""
    prefixes: dict[str, int] = {}
    for key, cls_id in (
        ("occluders", CLASS_OCCLUDER),
        ("foliage", CLASS_FOLIAGE),
        ("ignore", CLASS_IGNORE),
    ):
        values = cfg.doc.get("classes", {}).get(key, [])
        if not isinstance(values, list) or not all(isinstance(v, str) and v for v in values):
            cfg.fail("classes", key, f"classes.{key} must be a list of non-empty name prefixes")
        for v in values:
            if v in prefixes and prefixes[v] != cls_id:
                cfg.fail("classes", key, f"prefix {v!r} is listed under two classes")
            prefixes[v] = cls_id
    default = cfg.get("classes", "default", str)
    if default is None:
        default = "occluder"
    if default not in ("occluder", "ignore"):
        cfg.fail(
            "classes", "default", f"classes.default = {default!r}; expected 'occluder' or 'ignore'"
        )
    return prefixes, CLASS_NAMES.index(default)


def _classify(names: tuple[str, ...], prefixes: dict[str, int], default: int) -> int:
    """Class of an object: longest matching prefix of its first name that matches any."""
    for name in names:
        best = -1
        cls_id = default
        for prefix, c in prefixes.items():
            if len(prefix) > best and name.startswith(prefix):
                best, cls_id = len(prefix), c
        if best >= 0:
            return cls_id
    return default


def _demo(cfg: _SceneToml) -> tuple[F64, float]:
    wp = cfg.doc["demo"].get("waypoints_enu_m")
    if wp is None:
        cfg.fail("demo", None, "[demo] needs waypoints_enu_m = [[x, y, z], ...]")
    try:
        arr = np.array(wp, dtype=float)
    except (TypeError, ValueError):
        arr = np.zeros((0,))
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) < 2 or not np.isfinite(arr).all():
        cfg.fail(
            "demo",
            "waypoints_enu_m",
            "demo.waypoints_enu_m must list at least two [east, north, up] points in metres",
        )
    speed = cfg.get("demo", "speed_mps", float)
    if speed is None:
        speed = 1.4
    if not speed > 0.0:
        cfg.fail("demo", "speed_mps", f"demo.speed_mps = {speed}; expected > 0")
    return arr, speed
