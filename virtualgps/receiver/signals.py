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
    tracked0 : (m,) bool, tracked before the first row (or (n_t, m): rows that are
        independent receivers at one epoch each, ``reacq_epochs`` then (n_t, 1) or a number)
    run0 : (m,) int, epochs at or above the acquisition threshold before the first row (or
        (n_t, m) with ``tracked0``)

    Returns
    -------
    tracked : (n_t, m) bool
    run : (m,) int, the run after the last row (the next call's ``run0``; (n_t, m) for rows)
    """
    c = np.where(np.isnan(cn0_dbhz), -np.inf, cn0_dbhz)  # (nan_to_num: slow on tiny arrays)
    rows = np.ndim(run0) == 2
    if c.shape[0] == 1 or rows:  # one epoch (of each receiver): what the running-index
        # tricks reduce to
        run = np.where(c >= acq_dbhz, run0 + 1, 0)
        event = np.where(run >= reacq_epochs, 1, np.where(c < track_dbhz, -1, 0))
        return np.where(event != 0, event > 0, tracked0), run if rows else run[-1]
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
