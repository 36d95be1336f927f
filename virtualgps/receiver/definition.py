"""What one simulated receiver is, fixed for a run: its profile, ephemeris, scene and
georeference (:class:`Receiver`), with what is derived from them once (the scene's walls, the
satellites' interpolation nodes, which scene classes its rays are cast against).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from virtualgps import geodesy
from virtualgps.receiver import walls
from virtualgps.receiver.params import Profile
from virtualgps.sky.satnodes import SatNodes


class Ephemeris(Protocol):
    """Satellite positions: a TLE constellation or the paper's lookup table."""

    prn: np.ndarray

    def sat_ecef_m(self, t_unix_s: np.ndarray) -> np.ndarray:
        """(n_t, n_sat, 3) ECEF metres at UTC times (n_t,); NaN where unknown."""
        ...


class Occluder(Protocol):
    """Line-of-sight queries in the scene's local ENU frame."""

    def blocked(
        self, origins_enu_m: np.ndarray, dirs_enu: np.ndarray, cls: str = ...
    ) -> np.ndarray:
        """(m,) bool: does the ray from each origin along each direction hit the class?"""
        ...


@dataclass(frozen=True)
class Georef:
    """The geodetic point of the scene origin (the paper's "tag").

    lat0_deg, lon0_deg : degrees, WGS-84; alt0_hae_m : metres above the ellipsoid
    """

    lat0_deg: float
    lon0_deg: float
    alt0_hae_m: float


_FACADES: dict[int, tuple[object, walls.Facades]] = {}  # scene id -> (scene, its walls)


_SAT_NODES: dict[int, tuple[object, SatNodes]] = {}  # ephemeris id -> (ephemeris, its nodes)


@dataclass(frozen=True)
class Receiver:
    """Everything fixed during a run: profile, ephemeris, scene and georeference.

    sky_shift_s : seconds subtracted from the epoch time before propagating satellites (the
        sky-time policy: 0 for the true sky; a whole number of sky-repeat periods when the
        simulated time lies far from the TLE epoch)
    origin_ecef_m : (3,) ECEF of the georeference point (derived)
    origin_rot : (3, 3) ECEF -> scene ENU rotation (derived; rows E, N, U)
    facades : the scene's reflecting walls when the profile models ``nlos`` or ``multipath``
        (derived)
    sat_nodes : the ephemeris' positions interpolated between nodes, for an ephemeris that asks
        for it (``node_interpolation``: SGP4's TLE sets); derived, shared by the receivers of
        one ephemeris; None: its positions are used as they are
    """

    profile: Profile
    ephemeris: Ephemeris
    scene: Occluder | None
    georef: Georef
    sky_shift_s: float = 0.0
    origin_ecef_m: np.ndarray = field(init=False, repr=False, compare=False)
    origin_rot: np.ndarray = field(init=False, repr=False, compare=False)
    facades: walls.Facades | None = field(init=False, repr=False, compare=False)
    sat_nodes: SatNodes | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        g = self.georef
        # Computed once: the daemon calls the core once per epoch, where numpy's per-call
        # overhead on tiny arrays dominates.
        object.__setattr__(
            self, "origin_ecef_m", geodesy.geodetic_to_ecef(g.lat0_deg, g.lon0_deg, g.alt0_hae_m)
        )
        object.__setattr__(self, "origin_rot", geodesy.ecef_to_enu_matrix(g.lat0_deg, g.lon0_deg))
        facades = None
        faces = getattr(self.scene, "faces", None)
        reflects = self.profile.nlos.enabled or self.profile.multipath.enabled
        if reflects and faces is not None and len(faces):
            from virtualgps.sky.scene import CLASS_OCCLUDER

            facades = _FACADES.get(id(self.scene), (None, None))[1]
            if facades is None:  # built once per scene (a profile change must not rebuild it)
                sel = self.scene.face_class == CLASS_OCCLUDER
                facades = walls.Facades(self.scene.vertices_enu_m, faces[sel],
                                          self.scene.face_object[sel])
                _FACADES[id(self.scene)] = (self.scene, facades)
        object.__setattr__(self, "facades", facades)
        nodes = None
        if getattr(self.ephemeris, "node_interpolation", False):
            nodes = _SAT_NODES.get(id(self.ephemeris), (None, None))[1]
            if nodes is None:  # one node cache per ephemeris (a fleet's receivers share it)
                nodes = SatNodes(self.ephemeris)
                _SAT_NODES[id(self.ephemeris)] = (self.ephemeris, nodes)
        object.__setattr__(self, "sat_nodes", nodes)
        prepare = getattr(self.scene, "prepare", None)  # (a Scene; an Occluder may lack it)
        if prepare is not None:
            prepare(sky_ray_classes(self.profile))


def sky_ray_classes(profile: Profile) -> tuple[str, ...]:
    """The scene classes :func:`compute_sky` casts rays against: the direct paths' blockers
    first (foliage blocks as the paper has it unless the foliage model attenuates), then the
    foliage (its attenuation) and the occluders (reflections off walls) where modelled.

    Parameters
    ----------
    profile : the receiver's profile

    Returns
    -------
    classes : query class names (``scene.QueryClass``), the direct paths' first
    """
    foliage_blocks = profile.sky.foliage == "block" and not profile.foliage.enabled
    classes = ["solid" if foliage_blocks else "occluder"]
    if profile.foliage.enabled:
        classes.append("foliage")
    if (profile.nlos.enabled or profile.multipath.enabled) and "occluder" not in classes:
        classes.append("occluder")
    return tuple(classes)
