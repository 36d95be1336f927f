"""Sky masks: attenuation by sky direction (and place) for obstacles the scene lacks.

Owns a profile's ``[sky_mask]`` table (:class:`SkyMaskParams`) and its lookup, the learned part of
the ``foliage`` effect (DESIGN section 6): a grid of azimuth x elevation bins of attenuation in dB,
optionally one grid per square cell of the scene's east/north plane.
:func:`virtualgps.receiver.skyview.compute_sky` adds the attenuation to the foliage attenuation, and
a bin at or above ``block_db`` blocks. Pure numpy, vectorised over any leading axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Largest |cell index| a sky mask may hold (cells of 1 m reach 1000 km from the scene origin).
SKY_MASK_MAX_CELL = 1_000_000


@dataclass(frozen=True)
class SkyMaskParams:
    """``[sky_mask]``, the learned part of ``foliage``: attenuation by sky direction for
    obstacles the scene lacks (trees, buildings or vehicles missing from the mesh).

    The sky is cut into bins of ``el_bin_deg`` x ``az_bin_deg``; ``atten_db[r][c]`` is the
    attenuation (dB, >= 0) of a satellite with ``r * el_bin_deg <= el < (r + 1) * el_bin_deg``
    and ``c * az_bin_deg <= az < (c + 1) * az_bin_deg`` (azimuth from north, clockwise): rows
    from the horizon up, each with 360 / az_bin_deg values; rows above the last given are clear.
    A value >= ``block_db`` (TOML's ``inf`` too) blocks the satellite. With ``cell_m`` > 0,
    ``cells`` holds grids for square cells of the scene's east/north plane, cell ``(i, j)`` =
    ``(floor(east / cell_m), floor(north / cell_m))``, written ``"i,j"`` in TOML; a cell's grid
    replaces ``atten_db`` while the antenna is in it. ``block_db`` = 30 dB: more than the margin
    between a clear satellite's C/N0 and a receiver's tracking threshold (~25 dB with the
    ``cn0_tracking`` defaults), so a bin that strong is a wall whatever the model.

    atten_db : rows of floats; cells : ((i, j), rows) pairs in key order (from the TOML table)
    """

    enabled: bool = False
    az_bin_deg: float = 10.0
    el_bin_deg: float = 10.0
    block_db: float = 30.0
    atten_db: tuple[tuple[float, ...], ...] = ()
    cell_m: float = 0.0
    cells: tuple[tuple[tuple[int, int], tuple[tuple[float, ...], ...]], ...] = ()


# Antenna cell indices beyond the largest a profile may hold map to no cell (the default grid).
_CELL_CLIP = SKY_MASK_MAX_CELL + 1
_CELL_SPAN = 2 * _CELL_CLIP + 1  # packing (i, j) into one int64: (i + clip) * span + (j + clip)

# Compiled grids by profile table: hashing a frozen table of ~1000 floats per epoch would cost
# more than the lookup; the entry keeps its table alive, so its id cannot be reused meanwhile.
_COMPILED: dict[int, tuple[SkyMaskParams, np.ndarray, np.ndarray]] = {}


def _pack(i: np.ndarray, j: np.ndarray) -> np.ndarray:
    i = np.clip(i, -_CELL_CLIP, _CELL_CLIP).astype(np.int64)
    j = np.clip(j, -_CELL_CLIP, _CELL_CLIP).astype(np.int64)
    return (i + _CELL_CLIP) * _CELL_SPAN + (j + _CELL_CLIP)


def _compiled(mask: SkyMaskParams) -> tuple[np.ndarray, np.ndarray]:
    """The mask's grids as one array, and the packed keys of its cells.

    Returns
    -------
    grids_db : (1 + n_cells, 90 / el_bin_deg, 360 / az_bin_deg) float, dB; [0] is
        ``atten_db``, [1 + k] the k-th cell's grid in key order; rows not given are 0 (clear)
    keys : (n_cells,) int64, packed (i, j) cell indices, ascending
    """
    hit = _COMPILED.get(id(mask))
    if hit is not None and hit[0] is mask:
        return hit[1], hit[2]
    n_el = round(90.0 / mask.el_bin_deg)
    n_az = round(360.0 / mask.az_bin_deg)
    rows = [mask.atten_db] + [grid for _, grid in mask.cells]
    grids = np.zeros((len(rows), n_el, n_az))
    for k, grid in enumerate(rows):
        if grid:
            grids[k, : len(grid)] = np.array(grid, dtype=np.float64)
    ij = np.array([cell for cell, _ in mask.cells], dtype=np.int64).reshape(-1, 2)
    keys = _pack(ij[:, 0], ij[:, 1])
    order = np.argsort(keys)
    grids[1:] = grids[1:][order]
    if len(_COMPILED) >= 16:  # profiles are few; a long run of throw-away ones must not grow it
        _COMPILED.clear()
    _COMPILED[id(mask)] = (mask, grids, keys[order])
    return grids, keys[order]


def cell_of(antenna_enu_m: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The sky-mask cell an antenna is in: ``(floor(east / cell_m), floor(north / cell_m))``.

    Parameters
    ----------
    antenna_enu_m : (..., 3) float, metres, scene ENU
    cell_m : the cells' side, metres (> 0)

    Returns
    -------
    i, j : (...) int64, east and north cell indices; 0 where the position is not finite
    """
    en = np.asarray(antenna_enu_m, dtype=np.float64)[..., :2] / cell_m
    en = np.floor(np.where(np.isfinite(en), en, 0.0))
    en = np.clip(en, -_CELL_CLIP, _CELL_CLIP).astype(np.int64)
    return en[..., 0], en[..., 1]


def attenuation_db(
    mask: SkyMaskParams, az_deg: np.ndarray, el_deg: np.ndarray, antenna_enu_m: np.ndarray
) -> np.ndarray:
    """Attenuation of each satellite's signal by the sky mask.

    A satellite at azimuth ``az`` (from north, clockwise) and elevation ``el`` falls in bin
    ``(floor(el / el_bin_deg), floor((az mod 360) / az_bin_deg))``; elevations are clipped to
    [0, 90] (90 deg falls in the top row). The grid is the one of the antenna's cell
    (:func:`cell_of`) when the mask has one for it, else ``atten_db``.

    Parameters
    ----------
    mask : the profile's ``[sky_mask]`` (used whether or not ``enabled``)
    az_deg, el_deg : (..., n_t, n_sat) float, degrees, at the antenna; NaN (no ephemeris) -> 0
    antenna_enu_m : (..., n_t, 3) float, metres, scene ENU

    Returns
    -------
    atten_db : (..., n_t, n_sat) float, dB, >= 0; ``inf`` where the profile says ``inf``
    """
    grids, keys = _compiled(mask)
    _, n_el, n_az = grids.shape
    az = np.asarray(az_deg, dtype=np.float64)
    el = np.asarray(el_deg, dtype=np.float64)
    ok = np.isfinite(az) & np.isfinite(el)
    # (az mod 360) may round to 360.0 for tiny negative azimuths: clip to the last column
    col = np.minimum(np.floor(np.where(ok, az, 0.0) % 360.0 / mask.az_bin_deg), n_az - 1)
    row = np.minimum(np.floor(np.clip(np.where(ok, el, 0.0), 0.0, 90.0) / mask.el_bin_deg),
                     n_el - 1)
    grid = np.zeros(az.shape[:-1], dtype=np.intp)
    if keys.size:
        packed = _pack(*cell_of(antenna_enu_m, mask.cell_m))
        pos = np.minimum(np.searchsorted(keys, packed), keys.size - 1)
        grid = np.where(keys[pos] == packed, pos + 1, 0)
    out = grids[grid[..., None], row.astype(np.intp), col.astype(np.intp)]
    return np.where(ok, out, 0.0)
