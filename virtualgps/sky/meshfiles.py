"""Mesh files: OBJ read by our own fast reader (with its groups and materials, which classify
faces), glTF/PLY/STL through trimesh, and a cache of parsed meshes in the user's cache folder
keyed by the file's path, size and time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from virtualgps.exceptions import InputFileError
from virtualgps.usercache import user_cache_dir

F64 = NDArray[np.float64]


def load_mesh(
    path: Path,
) -> tuple[F64, NDArray[np.int32], NDArray[np.int32], list[tuple[str, ...]]]:
    """Read a mesh file into mesh-axis vertices, triangles, per-face object and object names.

    Returns
    -------
    vertices_m : (n_v, 3) float64, metres, mesh axes
    faces : (n_f, 3) int32, without degenerate (zero-area) triangles, which cannot be hit
    face_object : (n_f,) int32, index into names
    names : list of n_obj tuples (name, fallback names for classification...)
    """
    cached = _cached_mesh(path)
    if cached is not None:
        return cached
    if path.suffix.lower() == ".obj":
        verts, faces, face_object, names = _read_obj(path)
    elif path.suffix.lower() in _TRIMESH_FORMATS:
        verts, faces, face_object, names = _read_trimesh(path)
    else:
        raise InputFileError(
            path,
            f"unsupported mesh format {path.suffix!r}; expected .obj, .gltf, .glb, .ply or .stl",
        )
    if len(faces) == 0:
        raise InputFileError(path, "mesh has no faces")
    tri = verts[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    keep = area2 > 0.0
    faces, face_object = faces[keep], face_object[keep]
    # Drop objects left without faces so that object counts mean something.
    used = np.unique(face_object)
    remap = np.full(len(names), -1, np.int32)
    remap[used] = np.arange(len(used), dtype=np.int32)
    mesh = verts, faces, remap[face_object], [names[i] for i in used]
    _cache_mesh(path, mesh)
    return mesh


# Parsed meshes are cached by the file's content (parsing the bundled campus's 2.9 MB OBJ takes
# ~0.3 s, reading the cache ~5 ms). Bump the version when the parsing changes what it returns.
MESH_CACHE_VERSION = 1


def _mesh_cache_path(path: Path) -> Path | None:
    """The cache file of a mesh file's content, or None if the file cannot be read."""
    import hashlib

    try:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None
    tag = f"{digest[:40]}-{path.suffix.lower().lstrip('.')}-v{MESH_CACHE_VERSION}"
    return user_cache_dir("mesh") / f"{tag}.npz"


def _cached_mesh(path: Path):
    """The cached result of :func:`_load_mesh` for this content, or None."""
    import json

    cache = _mesh_cache_path(path)
    if cache is None or not cache.is_file():
        return None
    try:
        with np.load(cache, allow_pickle=False) as z:
            names = [tuple(n) for n in json.loads(str(z["names"]))]
            return (z["vertices"].astype(np.float64), z["faces"].astype(np.int32),
                    z["face_object"].astype(np.int32), names)
    except (OSError, ValueError, KeyError):  # a broken cache file is rebuilt
        return None


def _cache_mesh(path: Path, mesh) -> None:
    """Keep a parsed mesh for the next run (silently not, where the cache is not writable)."""
    import json
    import os

    cache = _mesh_cache_path(path)
    if cache is None:
        return
    verts, faces, face_object, names = mesh
    try:
        cache.parent.mkdir(parents=True, exist_ok=True)
        tmp = cache.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(tmp, vertices=verts, faces=faces, face_object=face_object,
                 names=np.array(json.dumps([list(n) for n in names])))
        os.replace(tmp, cache)
    except OSError:
        pass


def _read_obj(
    path: Path,
) -> tuple[F64, NDArray[np.int32], NDArray[np.int32], list[tuple[str, ...]]]:
    """Parse a Wavefront OBJ keeping ``o``/``g`` names (module docstring).

    Handles ``f v``, ``f v/vt``, ``f v//vn``, ``f v/vt/vn``, negative (relative) indices, and
    polygons (fan-triangulated, as OBJ polygons are convex by the format's definition).
    Text is UTF-8, or Latin-1 when it is not valid UTF-8 (OSM2World writes Latin-1).
    """
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    stem = path.stem
    vert_lines: list[str] = []
    tris: list[tuple[int, int, int]] = []
    tri_obj: list[int] = []
    names: list[tuple[str, ...]] = []
    o_name, g_name = "", ""
    current = -1  # object index of the current (o, g) run; created on its first face
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        i += 1
        lineno = i
        while line.endswith("\\") and i < len(lines):  # OBJ line continuation
            line = line[:-1] + " " + lines[i]
            i += 1
        s = line.strip()
        if not s or s[0] == "#":
            continue
        head, _, rest = s.partition(" ")
        if head == "v":
            vert_lines.append(rest)
            parts = rest.split()
            if len(parts) < 3:
                raise InputFileError(path, f"vertex needs x y z, got {s!r}", lineno)
        elif head == "f":
            n_v = len(vert_lines)
            idx = []
            for tok in rest.split():
                try:
                    k = int(tok.split("/", 1)[0])
                except ValueError:
                    raise InputFileError(
                        path,
                        f"face index {tok!r} is not an integer (v, v/vt, v//vn, v/vt/vn)",
                        lineno,
                    ) from None
                k = k - 1 if k > 0 else n_v + k  # 1-based, or relative to the last vertex
                if not 0 <= k < n_v:
                    raise InputFileError(
                        path, f"face index {tok!r} is out of range (1..{n_v} or -1..-{n_v})", lineno
                    )
                idx.append(k)
            if len(idx) < 3:
                raise InputFileError(path, f"face needs at least 3 vertices, got {s!r}", lineno)
            if current < 0:
                # Each run of faces under one (o, g) pair is an object, so repeated OSM2World
                # names (every segment of a road) stay separate objects.
                current = len(names)
                names.append(tuple(n for n in (o_name, g_name, stem) if n) or (stem,))
            for j in range(1, len(idx) - 1):  # fan triangulation
                tris.append((idx[0], idx[j], idx[j + 1]))
                tri_obj.append(current)
        elif head == "o":
            o_name, current = rest.strip(), -1
        elif head == "g":
            g_name, current = rest.strip(), -1
    if not vert_lines:
        raise InputFileError(path, "OBJ has no vertices (v lines)")
    try:
        verts = np.array([v.split()[:3] for v in vert_lines], dtype=np.float64)
    except ValueError:
        bad = next(k for k, v in enumerate(lines, 1) if v.startswith("v ") and not _floats(v))
        raise InputFileError(path, "vertex coordinates must be numbers", bad) from None
    return (
        verts,
        np.array(tris, dtype=np.int32).reshape(-1, 3),
        np.array(tri_obj, dtype=np.int32),
        names,
    )


def _floats(v_line: str) -> bool:
    try:
        [float(x) for x in v_line.split()[1:4]]
    except ValueError:
        return False
    return True


def _read_trimesh(
    path: Path,
) -> tuple[F64, NDArray[np.int32], NDArray[np.int32], list[tuple[str, ...]]]:
    """Load glTF/GLB/PLY/STL with trimesh; one object per scene-graph node (module docstring)."""
    import trimesh

    try:
        loaded = trimesh.load(str(path))
    except Exception as exc:  # trimesh raises many kinds; report them as one file error
        raise InputFileError(path, f"trimesh could not load the mesh: {exc}") from None
    parts: list[tuple[tuple[str, ...], F64, NDArray[np.int64]]] = []
    if isinstance(loaded, trimesh.Trimesh):
        parts.append(((path.stem,), np.asarray(loaded.vertices), np.asarray(loaded.faces)))
    elif isinstance(loaded, trimesh.Scene):
        for node in loaded.graph.nodes_geometry:
            transform, geom_name = loaded.graph[node]
            geom = loaded.geometry[geom_name]
            if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
                continue  # point clouds and paths cannot block rays
            v = trimesh.transform_points(np.asarray(geom.vertices), transform)
            parts.append(((str(node), str(geom_name)), v, np.asarray(geom.faces)))
    else:
        raise InputFileError(path, f"expected a triangle mesh, got {type(loaded).__name__}")
    if not parts:
        raise InputFileError(path, "mesh has no faces")
    verts, faces, face_obj, offset = [], [], [], 0
    for k, (_, v, f) in enumerate(parts):
        verts.append(v)
        faces.append(f + offset)
        face_obj.append(np.full(len(f), k, np.int32))
        offset += len(v)
    return (
        np.concatenate(verts).astype(np.float64),
        np.concatenate(faces).astype(np.int32),
        np.concatenate(face_obj),
        [p[0] for p in parts],
    )


_TRIMESH_FORMATS = {".gltf", ".glb", ".ply", ".stl"}
