"""The sky at the antenna: satellite directions, the elevation mask, and what the scene does to
each line of sight (blocking, foliage, paths scattered off walls, the nearest wall).

It depends on the antenna's position and time only, never on the receiver's random draws or
state: the replay computes it for the next chunk in a second thread while the receiver models
run on this one (:mod:`virtualgps.run.replay`), and the gap tool computes it once for every seed of
an ensemble. :func:`virtualgps.receiver.core.simulate` turns it into fixes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from virtualgps import geodesy
from virtualgps.receiver import signals, walls
from virtualgps.receiver.definition import sky_ray_classes
from virtualgps.sky import skymask

if TYPE_CHECKING:
    from virtualgps.receiver.definition import Receiver




@dataclass(frozen=True)
class Sky:
    """What the antenna sees at each epoch, over ``n_sat`` satellites.

    Arrays have the leading shape of the antenna positions, ``(..., n_t)``, then ``n_sat``.
    lat_deg, lon_deg, alt_hae_m : (..., n_t) the antenna, geodetic
    az_deg, el_deg : (..., n_t, n_sat) degrees, at the antenna
    los_enu : (..., n_t, n_sat, 3) unit vectors antenna -> satellite, antenna ENU frame
    above_mask : (..., n_t, n_sat) bool, elevation >= the profile's mask
    blocked : (..., n_t, n_sat) bool, line of sight hits an occluder or a blocking bin of the
        profile's sky mask (False below the horizon)
    nlos : (..., n_t, n_sat) bool, blocked but received off a facade (``nlos`` effect)
    excess_m : (..., n_t, n_sat) float, metres, the reflected path's extra length (0 if direct)
    nlos_loss_db : (..., n_t, n_sat) float, dB, the loss of that path: the reflection loss, plus
        the scattering lobe's off the specular direction (0 if direct)
    foliage_db : (..., n_t, n_sat) float, dB, attenuation through foliage and by the sky mask
        (``foliage`` effect)
    wall_dist_m : (..., n_t) float, metres, horizontal distance from the antenna to the nearest
        wall rising above it, up to ``multipath.max_dist_m`` (inf: none that near; NaN: no
        scene, or ``multipath`` off)
    """

    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_hae_m: np.ndarray
    az_deg: np.ndarray
    el_deg: np.ndarray
    los_enu: np.ndarray
    above_mask: np.ndarray
    blocked: np.ndarray
    nlos: np.ndarray
    excess_m: np.ndarray
    nlos_loss_db: np.ndarray
    foliage_db: np.ndarray
    wall_dist_m: np.ndarray

    def rows(self) -> Sky:
        """The sky of a batch of antennas at one epoch each, as rows: every array's first two
        axes ``(n_rx, 1)`` merged into one (the rows :func:`virtualgps.receiver.core.simulate` takes
        with :class:`~virtualgps.receiver.state.ReceiverRows`).

        Returns
        -------
        sky : Sky, ``(n_rx, ...)`` views of this one's arrays
        """
        return Sky(*(a.reshape((-1,) + a.shape[2:]) for a in
                     (getattr(self, f.name) for f in fields(self))))


def antenna_geodetic(
    antenna_enu_m: np.ndarray, rx: Receiver
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Geodetic and ECEF position of antenna points given in the scene's ENU frame.

    Parameters
    ----------
    antenna_enu_m : (..., 3) metres, scene ENU (origin at the georeference point)
    rx : the receiver; its profile's ``georef`` is "wgs84" (exact) or "flat_earth" (the paper's
        conversion and wraps)

    Returns
    -------
    lat_deg, lon_deg, alt_hae_m : (...) float
    ecef_m : (..., 3) float, metres, ECEF
    """
    enu = np.asarray(antenna_enu_m, dtype=float)
    if rx.profile.georef == "flat_earth":
        g = rx.georef
        lat, lon = geodesy.flat_earth_to_geodetic(enu[..., 0], enu[..., 1], g.lat0_deg, g.lon0_deg)
        alt = g.alt0_hae_m + enu[..., 2]
        return lat, lon, alt, geodesy.geodetic_to_ecef(lat, lon, alt)
    ecef = rx.origin_ecef_m + enu @ rx.origin_rot  # rows of origin_rot are E, N, U in ECEF
    lat, lon, alt = geodesy.ecef_to_geodetic(ecef)
    return lat, lon, alt, ecef


def compute_sky(rx: Receiver, t_unix_s: np.ndarray, antenna_enu_m: np.ndarray) -> Sky:
    """Satellite directions, the elevation mask and line-of-sight blocking at each epoch.

    Parameters
    ----------
    rx : the receiver (ephemeris, scene, georeference, profile)
    t_unix_s : (n_t,) float, UTC seconds (the simulated clock)
    antenna_enu_m : (..., n_t, 3) float, metres, scene ENU

    Returns
    -------
    sky : Sky
    """
    t = np.atleast_1d(np.asarray(t_unix_s, dtype=float))
    ant = np.asarray(antenna_enu_m, dtype=float)
    lat, lon, alt, ant_ecef = antenna_geodetic(ant, rx)  # ant_ecef (..., n_t, 3)
    positions = rx.ephemeris.sat_ecef_m if rx.sat_nodes is None else rx.sat_nodes.sat_ecef_m
    sat_ecef = positions(t - rx.sky_shift_s)  # (n_t, n_sat, 3)
    d_ecef = sat_ecef - ant_ecef[..., None, :]  # (..., n_t, n_sat, 3)
    rng_m = np.linalg.norm(d_ecef, axis=-1, keepdims=True)
    u_ecef = d_ecef / rng_m
    rot = geodesy.ecef_to_enu_matrix(lat, lon)  # (..., n_t, 3, 3)
    los_enu = u_ecef @ np.swapaxes(rot, -1, -2)  # (matmul: einsum is 10x slower here)
    az, el, _ = geodesy.enu_to_azel(los_enu)
    with np.errstate(invalid="ignore"):
        above = el >= rx.profile.sky.elevation_mask_deg  # NaN (no ephemeris) -> False
        # Every satellite above the horizon is ray-cast, not only those above the mask: a
        # receiver tracks (and GSV lists with an SNR) satellites below its mask for use.
        risen = el >= 0.0
    blocked = np.zeros_like(above)
    foliage_db = np.zeros(above.shape)
    if rx.scene is not None and risen.any():
        # Rays are cast in the scene's frame: the ENU frame of the georeference point, whose
        # axes differ from the antenna's local ENU by the Earth's curvature (~0.009 deg per km).
        idx = np.nonzero(risen)
        dirs = u_ecef[idx] @ rx.origin_rot.T
        origins = ant[idx[:-1]]  # (the antenna of each ray's epoch)
        hit = rx.scene.blocked(origins, dirs, cls=sky_ray_classes(rx.profile)[0])
        if rx.profile.foliage.enabled:
            fol = rx.profile.foliage
            path_m = signals.foliage_path_m(rx.scene, origins, dirs, fol.billboard_m)
            foliage_db[idx] = np.minimum(fol.db_per_m * path_m, fol.max_db)
        blocked[idx] = hit
    mask = rx.profile.sky_mask
    if mask.enabled:  # obstacles the scene lacks: attenuate like foliage; a bin >= block_db
        # blocks the direct path (a reflection off a facade may still arrive: nlos)
        mask_db = np.where(risen, skymask.attenuation_db(mask, az, el, ant), 0.0)
        walled = mask_db >= mask.block_db
        blocked |= walled
        foliage_db = foliage_db + np.where(walled, 0.0, mask_db)
    nlos = np.zeros_like(blocked)
    excess = np.zeros(blocked.shape)
    nlos_loss = np.zeros(blocked.shape)
    if rx.profile.nlos.enabled and rx.facades is not None and blocked.any():
        idx = np.nonzero(blocked)
        dirs = u_ecef[idx] @ rx.origin_rot.T
        origins = ant[idx[:-1]]
        nl = rx.profile.nlos
        if nl.scattering:  # (a specular point on a wall is the lobe's centre: loss 0)
            found, ex, lobe = walls.scattered_paths(
                rx.scene, rx.facades, origins, dirs, nl.max_dist_m, nl.scattering_alpha,
                nl.scattering_max_loss_db)
            loss = np.where(found, nl.reflection_loss_db + lobe, 0.0)
        else:
            found, ex = walls.reflections(rx.scene, rx.facades, origins, dirs, nl.max_dist_m)
            loss = np.where(found, nl.reflection_loss_db, 0.0)
        nlos[idx] = found
        excess[idx] = np.where(found, ex, 0.0)
        nlos_loss[idx] = loss
    wall_dist = np.full(ant.shape[:-1], np.nan)
    if rx.profile.multipath.enabled and rx.facades is not None:
        flat = ant.reshape(-1, 3)
        # Once per run of epochs at one position (a static antenna: once per batch).
        new = np.ones(len(flat), bool)
        new[1:] = np.any(flat[1:] != flat[:-1], axis=1)
        first = np.flatnonzero(new)
        dist = rx.facades.wall_dist_m(flat[first], rx.profile.multipath.max_dist_m)
        wall_dist = dist[np.cumsum(new) - 1].reshape(ant.shape[:-1])
    return Sky(lat, lon, alt, az, el, los_enu, above, blocked, nlos, excess, nlos_loss,
               foliage_db, wall_dist)
