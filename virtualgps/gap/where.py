"""Where the gap lies: the DESIGN section 7.1 metrics of a real run against its ensemble, per
segment, and the scalar gap score.

A run is judged as a whole, never epoch by epoch: epochs are strongly correlated (an error
decorrelates over minutes, a satellite is tracked or not for a whole pass), so each statistic
is computed over a segment of the real run and over the same segment of every simulated seed,
and the real value is judged against the seeds' values (:mod:`.bands`: a prediction interval
for a finite ensemble, a practical floor per metric, the false-discovery rate over a report's
rows). Satellite statistics are per PRN over a segment, so a pass counts once. Segments that
hold the same epochs (``steady`` when the log starts with a fix, ``open`` in open sky) are one
row, the other names listed in ``same_as``.

The scalar gap score of a unit of data (a run, or a time block of a single run) is the mean
over the score metrics it supports of each metric's distance in units of the seeds' own spread,
guarded by the profile under test's (:func:`virtualgps.gap.bands.distance_against`); lower is
better, about 0.1 under the null.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from virtualgps.gap.bands import (
    D_CAP,
    METRICS,
    SCORE_METRICS,
    Judged,
    band,
    bh_alpha,
    distance,
    distance_against,
    distance_moved,
    holdout_p,
    judge,
)
from virtualgps.gap.metrics import (
    INV_E,
    autocorrelation,
    changes_per_minute,
    errors_enu_m,
    to_regular_grid,
)
from virtualgps.gap.motion import (
    delay_smoothing_s,
    epoch_step_s,
    fix_lag_s,
    lag_free_steps_m,
)
from virtualgps.gap.observed import Obs, RunView

STARTUP_S = 120.0  # the start-up segment: this long after power-on
MOVING_MPS = 0.3  # truth speed above which an epoch is "moving"
SECTOR_AZ_DEG = (0, 90, 180, 270, 360)
SECTOR_EL_DEG = (0, 30, 60, 90)
MIN_AUTOCORR_EPOCHS = 120  # a 1/e time needs a record several times longer than itself


def errors_enu(view: RunView, obs: Obs) -> np.ndarray:
    """(s, n, 3) ENU error of each fix, metres: about the truth, or about the seed's (the
    log's) own median fix for a static run at an unknown point."""
    fixed = obs.fixed
    if view.reference == "truth":
        ref = (view.truth_lat_deg, view.truth_lon_deg, view.truth_alt_hae_m)
    else:
        # each seed's component-wise median fix (metrics.median_position, for all rows at
        # once); a seed without a fix is measured from (0, 0, 0): its errors are all NaN
        ref = tuple(np.where(fixed.any(axis=1), row_quantile(np.where(fixed, x, np.nan), 0.5),
                             0.0)[:, None] for x in (obs.lat_deg, obs.lon_deg, obs.alt_hae_m))
    out = errors_enu_m(obs.lat_deg, obs.lon_deg, obs.alt_hae_m, *ref)
    out[~fixed] = np.nan
    return out


def row_quantile(x: np.ndarray, q: float) -> np.ndarray:
    """Quantile ``q`` (0-1, linear interpolation as ``numpy.quantile``) of each row of (s, m)
    data, NaN left out; NaN for empty rows. (``numpy.nanquantile`` along an axis loops over the
    rows in Python: 100x slower on ensembles.)"""
    x = np.asarray(x, dtype=float)
    n = np.isfinite(x).sum(axis=1)
    xs = np.sort(x, axis=1)  # NaN sort last
    pos = q * np.maximum(n - 1, 0)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
    r = np.arange(x.shape[0])
    v = xs[r, lo] + (pos - lo) * (xs[r, hi] - xs[r, lo]) if x.shape[1] else np.zeros(len(n))
    return np.where(n > 0, v, np.nan)


def binned_quantile(x: np.ndarray, mask: np.ndarray, q: float, step: float, top: float,
                    span: slice = slice(None), cols: np.ndarray | None = None) -> np.ndarray:
    """Quantile ``q`` of each row's masked values of (s, ...) data in [0, top], to ``step``
    (a histogram per row: ensembles of C/N0 or elevations hold ~10^5 values a seed).

    x : (..., n, k) data (e.g. (s, n, k) C/N0, or (n, k) elevations for every seed)
    mask : (s, n', k') bool, the values that count, over rows ``span`` and columns ``cols``
        ((k,) bool; None: all) of ``x``'s last two axes (their bins are made once per ``x``)

    Returns (s,) float, NaN for rows without a value (the lower of the two middle values'
    bins for an even count, like an order statistic, not interpolated)."""
    s = mask.shape[0]
    nb = int(round(top / step)) + 1
    b = _bins(x, step, nb)[..., span, :]
    b = np.broadcast_to(b if cols is None else b[..., cols], mask.shape)
    if mask.ndim == 3:  # only the satellites the mask holds (one PRN, a sky sector)
        held = mask.any(axis=(0, 1))
        if not held.all():
            b, mask = b[..., held], mask[..., held]
    # one bincount over every row: masked-out values go to an extra bin past the last
    idx = np.where(mask, b, nb).reshape(s, -1)
    idx = idx + (np.arange(s, dtype=np.int32) * (nb + 1))[:, None]
    counts = np.bincount(idx.ravel(), minlength=s * (nb + 1)).reshape(s, nb + 1)[:, :nb]
    cum = np.cumsum(counts, axis=1)
    n = cum[:, -1]
    k = np.floor(q * np.maximum(n - 1, 0))
    pos = (cum <= k[:, None]).sum(axis=1)
    return np.where(n > 0, np.minimum(pos, nb - 1) * step, np.nan)


# The last few (data, step, bins) per thread: a where table bins the same arrays (the real
# log's, the ensemble's, the elevations) for every segment, PRN and sky sector, in turn (and
# may be judged in a thread beside the selection's own scoring).
_BINS = threading.local()
_BINS_KEPT = 4


def _bins(x: np.ndarray, step: float, nb: int) -> np.ndarray:
    """int32 bin of each value of ``x`` (NaN: bin 0), cached for the thread's last arrays."""
    kept = getattr(_BINS, "kept", None)
    if kept is None:
        kept = _BINS.kept = []
    for arr, key, b in kept:
        if arr is x and key == (step, nb):
            return b
    # in place, fmax first: NaN goes to bin 0 (a where table's ensemble is some 40 MB a copy,
    # and each fresh copy is paid again in page faults)
    b = np.divide(x, step, dtype=float)  # (float32 C/N0 of an ensemble: no copy before)
    np.rint(b, out=b)
    np.fmax(b, 0.0, out=b)
    np.fmin(b, nb - 1, out=b)
    b = b.astype(np.int32)
    kept.insert(0, (x, (step, nb), b))
    del kept[_BINS_KEPT:]
    return b


def _rowmean(x: np.ndarray) -> np.ndarray:
    n = np.isfinite(x).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.nansum(x, axis=1) / n, np.nan)


def autocorr_time_s(t: np.ndarray, err_h: np.ndarray) -> float:
    """1/e time of a (m, 2) east/north error series (m epochs at times t), NaN if too short;
    0 for an error that never changes (fixes that are their truth, or a constant offset from
    it): no error carries over from one block to the next."""
    ok = np.isfinite(err_h).all(axis=1)
    if ok.sum() < MIN_AUTOCORR_EPOCHS:
        return float("nan")
    if np.ptp(err_h[ok], axis=0).max() == 0.0:
        return 0.0
    steps = np.diff(t[ok])
    dt = float(np.median(steps))
    _, grid = to_regular_grid(t[ok], err_h[ok], dt)
    max_lag = max(1, min(grid.shape[0] // 2, grid.shape[0] - 1))
    rho = autocorrelation(grid, max_lag)
    below = np.flatnonzero(rho[1:] < INV_E)
    if below.size == 0:
        return float("nan")
    k = int(below[0]) + 1
    r0, r1 = rho[k - 1], rho[k]
    return float((k - 1 + (r0 - INV_E) / (r0 - r1)) * dt) if np.isfinite(r0) else k * dt


def tracked_fractions(view: RunView, tracked: np.ndarray, sat_mask: np.ndarray) -> tuple:
    """Per-PRN tracked share over a segment.

    Parameters
    ----------
    tracked : (s, n, k) bool
    sat_mask : (n, k) bool, the satellite-epochs compared

    Returns
    -------
    frac : (s, k) float, tracked share of each PRN's compared epochs (NaN: none)
    weight : (k,) int, compared epochs per PRN
    """
    w = sat_mask.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = (tracked & sat_mask[None]).sum(axis=1) / w[None, :]
    return np.where(w[None, :] > 0, frac, np.nan), w


def _row_span(m: np.ndarray) -> slice:
    """The rows of an (n, k) bool mask from its first to its last with a True (empty: none)."""
    rows = np.flatnonzero(m.any(axis=1))
    return slice(rows[0], rows[-1] + 1) if rows.size else slice(0, 0)


def _compared(view: RunView, epochs: np.ndarray, memo: dict | None
              ) -> tuple[slice, np.ndarray]:
    """A segment's compared satellite-epochs: the rows of the run that hold them and the
    (n', k) bool mask over those rows (kept in ``memo`` where given)."""
    hit = memo.get("compared") if memo else None
    if hit is None:
        m = view.sat_ok & (epochs & view.valid)[:, None]
        span = _row_span(m)
        hit = (span, m[span])
        if memo is not None:
            memo["compared"] = hit
    return hit


def prn_tracking(view: RunView, sims: Obs, epochs: np.ndarray, memo: dict | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per PRN over a segment: compared satellite-epochs and those tracked by the real
    receiver, (2, k); tracked by each seed, (s, k). :func:`tracking_means` makes of them the
    (3, k) counts that, pooled over held-out units, give the per-PRN tracking disagreement
    (:func:`pooled_tracking_disagreement`). Zeros without GSV/SNR in the real log. ``memo``:
    as :func:`segment_stats`'s (the real log's part kept)."""
    per_seed = np.zeros((sims.tracked.shape[0], view.prn.size))
    if not (view.assess.get("gsv") and view.assess.get("cn0")):
        return np.zeros((2, view.prn.size)), per_seed
    span, m = _compared(view, epochs, memo)
    fixed = memo.get("prn") if memo else None
    if fixed is None:
        fixed = np.zeros((2, view.prn.size))
        fixed[0] = m.sum(axis=0)
        fixed[1] = (view.real.tracked[0, span] & m).sum(axis=0)
        if memo is not None:
            memo["prn"] = fixed
    per_seed[:] = (sims.tracked[:, span] & m[None]).sum(axis=1)
    return fixed.copy(), per_seed


SKY_BIN_AZ_DEG = 30.0  # the sky bins a learned sky mask is made of
SKY_BIN_EL_DEG = 15.0


def bin_tracking(view: RunView, sims: Obs, epochs: np.ndarray, memo: dict | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per sky bin (SKY_BIN_EL_DEG x SKY_BIN_AZ_DEG, rows from the horizon up, azimuth from
    north): compared satellite-epochs, tracked by the real receiver, the real tracked
    satellites' SNR sum, (3, n_el * n_az); and per seed the tracked satellite-epochs and their
    SNR sum, (2, s, n_el * n_az). :func:`tracking_means` makes of them what a learned sky mask
    is made from. Zeros without GSV/SNR in the real log. ``memo``: as :func:`segment_stats`'s
    (the bins and the real log's part kept)."""
    n_az, n_el = int(360 / SKY_BIN_AZ_DEG), int(90 / SKY_BIN_EL_DEG)
    nb = n_el * n_az
    s = sims.tracked.shape[0]
    per_seed = np.zeros((2, s, nb))
    if not (view.assess.get("gsv") and view.assess.get("cn0")):
        return np.zeros((3, nb)), per_seed
    span, m = _compared(view, epochs, memo)
    hit = memo.get("bins") if memo else None
    if hit is None:
        el, az = view.el_deg[span], view.az_deg[span]
        r = np.clip((np.nan_to_num(el) // SKY_BIN_EL_DEG).astype(int), 0, n_el - 1)
        c = np.clip((np.nan_to_num(az) % 360.0 // SKY_BIN_AZ_DEG).astype(int), 0, n_az - 1)
        b = (r * n_az + c)[m]
        fixed = np.zeros((3, nb))
        tr, cn0 = view.real.tracked[0, span][m], view.real.cn0_dbhz[0, span][m]
        for row, w in enumerate((None, tr, np.nan_to_num(np.where(tr, cn0, 0.0)))):
            fixed[row] = np.bincount(b, weights=w, minlength=nb)
        hit = (b, fixed)
        if memo is not None:
            memo["bins"] = hit
    b, fixed = hit
    seed_b = (np.arange(s)[:, None] * nb + b[None, :]).ravel()  # one bincount for all seeds
    tr = sims.tracked[:, span][:, m]
    sim_cn0 = np.nan_to_num(np.where(tr, sims.cn0_dbhz[:, span][:, m], 0.0))
    for row, w in enumerate((tr.astype(float), sim_cn0)):
        per_seed[row] = np.bincount(seed_b, weights=w.ravel(), minlength=s * nb).reshape(s, nb)
    return fixed.copy(), per_seed


def tracking_means(fixed: np.ndarray, per_seed: np.ndarray) -> np.ndarray:
    """The counts of :func:`prn_tracking` ((3, k): compared, real, mean over seeds) or of
    :func:`bin_tracking` ((5, n_bins): compared, real tracked, simulated tracked, real SNR sum,
    simulated SNR sum, the simulated ones means over seeds) from their parts."""
    if fixed.shape[0] == 2:
        return np.vstack([fixed, per_seed.mean(axis=0)[None]])
    mean = per_seed.mean(axis=1)
    return np.vstack([fixed[:2], mean[:1], fixed[2:], mean[1:]])


def pooled_tracking_disagreement(counts: list[np.ndarray], cols: np.ndarray | None = None
                                 ) -> float:
    """Per-PRN tracking disagreement: sum over PRNs of |real - simulated tracked epochs| over
    the compared satellite-epochs, pooled over units ((3, k) arrays of :func:`prn_tracking`;
    ``cols``: (k,) bool, only those satellites, e.g. one system's). NaN without any compared
    satellite-epoch."""
    c = np.sum(counts, axis=0)
    if cols is not None:
        c = c[:, cols]
    return float(np.abs(c[1] - c[2]).sum() / c[0].sum()) if c[0].sum() > 0 else float("nan")


def _disagreement(fa: np.ndarray, fb: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Epoch-weighted mean |fa - fb| over PRNs; (s,) from (s, k) pairs."""
    ok = (w > 0) & np.isfinite(fa).all(axis=0) & np.isfinite(fb).all(axis=0)
    if not ok.any():
        return np.full(fa.shape[0], np.nan)
    return (np.abs(fa - fb)[:, ok] * w[ok]).sum(axis=1) / w[ok].sum()


def _eq4_deg(a_lat, a_lon, b_lat, b_lon) -> np.ndarray:
    """The paper's Eq. 4 per epoch: sqrt(dlat^2 + dlon^2), degrees; (s, m)."""
    return np.hypot(a_lat - b_lat, a_lon - b_lon)


@dataclass(frozen=True)
class SegmentStats:
    """The metrics of one segment: real value and per-seed values (s,).

    real : {metric: float}; sim : {metric: (s,) float}; pair : the real-vs-simulated values of
    the pairwise metrics ({metric: (s,)}); for those ``sim`` holds simulated-vs-simulated
    values (seed i against seed i - 1); fractions : ``tracked_agreement``'s per-seed tracked
    fractions (s, k) and weights (k,), from which :func:`merge_stats` pairs the seeds again
    """

    real: dict[str, float]
    sim: dict[str, np.ndarray]
    pair: dict[str, np.ndarray]
    fractions: tuple[np.ndarray, np.ndarray] | None = None

    def __reduce__(self) -> tuple:
        return (_stats_unpacked, (self.real, *pack_vectors(self.sim), *pack_vectors(self.pair),
                                  self.fractions))


def _stats_unpacked(real: dict, sim_names: Any, sim: np.ndarray | None, pair_names: Any,
                    pair: np.ndarray | None, fractions: Any) -> SegmentStats:
    return SegmentStats(real, unpack_vectors(sim_names, sim), unpack_vectors(pair_names, pair),
                        fractions)


def pack_vectors(d: dict[str, np.ndarray]) -> tuple[Any, np.ndarray | None]:
    """{name: (s,) float64} as (names, (m, s) array), to pickle: a job's result is unpickled in
    the main process, some 3 us an array, tens of arrays a result (a sixth of the serial rest
    of the benchmark hour at 16 workers went to it). Other dicts: (the dict, None).
    :func:`unpack_vectors` undoes it."""
    vals = list(d.values())
    if vals and all(isinstance(v, np.ndarray) and v.dtype == np.float64 and v.ndim == 1
                    and v.shape == vals[0].shape for v in vals):
        return tuple(d), np.stack(vals)
    return d, None


def unpack_vectors(names: Any, rows: np.ndarray | None) -> dict[str, np.ndarray]:
    """The dict :func:`pack_vectors` packed (each value a row of one array)."""
    return names if rows is None else dict(zip(names, rows, strict=True))


def merge_stats(parts: list[SegmentStats]) -> SegmentStats:
    """One segment's statistics over the seeds of several jobs (seed groups, in seed order):
    the same, to the bit, as one job over all the seeds (per-seed values are joined; the
    seed-against-seed values are paired again over all of them, and a pairwise metric's real
    value is its median against all of them)."""
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    sim = {m: np.concatenate([p.sim[m] for p in parts]) for m in first.sim}
    pair = {m: np.concatenate([p.pair[m] for p in parts]) for m in first.pair}
    # a pairwise metric's real value is its median against every seed
    real = dict(first.real) | {m: float(np.nanmedian(v)) for m, v in pair.items()}
    fractions = None
    if first.fractions is not None:
        fs = np.concatenate([p.fractions[0] for p in parts])
        fractions = (fs, first.fractions[1])
        sim["tracked_agreement"] = 1.0 - _disagreement(fs, np.roll(fs, 1, 0), fractions[1])
    return SegmentStats(real, sim, pair, fractions)


# The order of a segment's metrics (its rows in the report), pairwise ones in their places.
_ORDER = ("cep50_m", "r95_m", "up_p68_m", "bias_m", "autocorr_s", "sats_used_mean",
          "used_changes_per_min", "hdop_median", "fix_fraction", "dgps_fraction", "ttff_s",
          "error_step_m", "frozen_fraction", "lag_s", "smoothing_s", "eq4_deg",
          "tracked_agreement", "tracked_share", "cn0_median_dbhz", "used_el_p05_deg")


@dataclass(frozen=True)
class _Segment:
    """What one segment's statistics need besides a side's output (the same for the real log
    and every seed)."""

    view: RunView
    epochs: np.ndarray  # (n,) bool, the segment's valid epochs
    position: bool  # position metrics (a segment of epochs, not of satellites)
    starts: bool  # the segment holds the power-on
    moving: np.ndarray  # (n,) bool, epochs moving fast enough for lag and smoothing
    steady: np.ndarray  # (n - 1,) bool, no gap between two epochs
    # The compared satellite-epochs lie in rows ``span`` and columns ``cols`` of the run's
    # (n, k) arrays: a time block's or a PRN's statistics read only those (a job scores some
    # ten blocks of a run, each of which was read whole before: a quarter of its job time).
    sat_mask: np.ndarray | None  # (n', k') the compared satellite-epochs (None: no GSV)
    span: slice  # the rows n' of the epochs that hold them
    cols: np.ndarray | None  # (k,) bool, the satellites kept (None: all k)
    gsa: bool  # used_el_p05_deg is assessed

    def sats(self, x: np.ndarray) -> np.ndarray:
        """A side's (s, n, k) array over the compared rows and satellites, (s, n', k')."""
        x = x[:, self.span]
        return x if self.cols is None else x[..., self.cols]


def _side_stats(g: _Segment, o: Obs, e: np.ndarray, wanted: Callable[[str], bool]
                ) -> dict[str, np.ndarray]:
    """The per-row metrics of one side (the real log, s = 1, or the seeds; its output over
    the segment's satellites, :meth:`_Segment.sats`) over a segment: {metric: (s,)}; the
    pairwise metrics (eq4_deg, tracked_agreement) are not here."""
    out: dict[str, np.ndarray] = {}
    view, epochs = g.view, g.epochs
    t = view.t_unix_s
    if g.position:
        f = o.fixed[:, epochs]
        eh = np.hypot(e[:, epochs, 0], e[:, epochs, 1])
        if wanted("cep50_m"):
            out["cep50_m"] = row_quantile(eh, 0.5)
        if wanted("r95_m"):
            out["r95_m"] = row_quantile(eh, 0.95)
        if wanted("up_p68_m"):
            # The vertical scatter about its own median: a receiver's vertical error (DOP-driven
            # in most; none in the paper's model, smoothed in MTK's) without the truth's height
            # offset (an antenna height, a geoid model), which no effect of a receiver explains.
            up = e[:, epochs, 2]
            out["up_p68_m"] = row_quantile(np.abs(up - row_quantile(up, 0.5)[:, None]), 0.68)
        if view.reference == "truth" and wanted("bias_m"):
            m = np.stack([_rowmean(e[:, epochs][:, :, j]) for j in (0, 1)], axis=-1)
            out["bias_m"] = np.hypot(m[:, 0], m[:, 1])
        if wanted("autocorr_s"):
            te = t[epochs]
            out["autocorr_s"] = np.array([autocorr_time_s(te, row[epochs, :2]) for row in e])
        if wanted("sats_used_mean"):
            out["sats_used_mean"] = _rowmean(np.where(f, o.sats_used[:, epochs], np.nan))
        if wanted("used_changes_per_min"):
            c = np.where(f & np.isfinite(o.sats_used[:, epochs]), o.sats_used[:, epochs], -1)
            out["used_changes_per_min"] = np.array([changes_per_minute(row, t[epochs])
                                                    for row in c])
        if wanted("hdop_median"):
            out["hdop_median"] = row_quantile(np.where(f, o.hdop[:, epochs], np.nan), 0.5)
        if wanted("fix_fraction"):
            out["fix_fraction"] = f.mean(axis=1)
        if wanted("dgps_fraction") and view.assess.get("gga", True):
            out["dgps_fraction"] = (o.quality[:, epochs] == 2).mean(axis=1)
        if wanted("ttff_s") and g.starts:
            first = np.argmax(f, axis=1)
            out["ttff_s"] = np.where(f.any(axis=1), t[epochs][first] - view.power_on_unix_s,
                                     np.nan)
        # (the lag first: the error step is measured about the truth delayed by it; the fit
        # of the fixes' steps gives the smoothing, and the lag where no building is near)
        moving = g.moving.sum() >= 30
        fitted = (delay_smoothing_s(e, view.truth_lat_deg, view.truth_lon_deg, t, g.moving)
                  if moving and wanted("smoothing_s") else None)
        lag = (fix_lag_s(e, view.vel_enu_mps, view.truth_lat_deg, view.truth_lon_deg, t,
                         g.moving, ~view.near_building, fitted)
               if moving and (wanted("error_step_m") or wanted("lag_s"))
               else np.full(e.shape[0], np.nan))
        if wanted("error_step_m"):
            d = lag_free_steps_m(e, view.truth_en_m, t, lag)
            ok = o.fixed[:, 1:] & o.fixed[:, :-1] & epochs[1:] & g.steady
            out["error_step_m"] = row_quantile(np.where(ok, d, np.nan), 0.5)
        if wanted("frozen_fraction"):
            same = (np.diff(o.lat_deg, axis=1) == 0) & (np.diff(o.lon_deg, axis=1) == 0)
            m = epochs[1:] & o.fixed[:, 1:] & o.fixed[:, :-1]
            out["frozen_fraction"] = (same & m).sum(axis=1) / np.maximum(m.sum(axis=1), 1)
        if moving and wanted("lag_s"):
            out["lag_s"] = lag
        if fitted is not None:
            out["smoothing_s"] = fitted[1]
    if g.sat_mask is not None and view.assess.get("cn0"):
        tracked = g.sats(o.tracked) & g.sat_mask[None]
        if wanted("tracked_share"):
            out["tracked_share"] = tracked.sum(axis=(1, 2)) / g.sat_mask.sum()
        if wanted("cn0_median_dbhz"):  # (GSV SNR: whole dB-Hz)
            out["cn0_median_dbhz"] = binned_quantile(o.cn0_dbhz, tracked, 0.5, 1.0, 99.0,
                                                     g.span, g.cols)
    if g.sat_mask is not None and g.gsa and wanted("used_el_p05_deg"):
        out["used_el_p05_deg"] = binned_quantile(view.el_deg, g.sats(o.used) & g.sat_mask[None],
                                                 0.05, 0.1, 90.0, g.span, g.cols)
    return out


def segment_stats(
    view: RunView,
    sims: Obs,
    err_real: np.ndarray,
    err_sim: np.ndarray,
    epochs: np.ndarray,
    sats: np.ndarray | None = None,
    metrics: Iterable[str] | None = None,
    memo: dict | None = None,
) -> SegmentStats:
    """Every metric of DESIGN 7.1 that the segment and the real log support.

    Parameters
    ----------
    view : the run; sims : its ensemble (s seeds)
    err_real : (1, n, 3), err_sim : (s, n, 3) ENU errors (:func:`errors_enu`)
    epochs : (n,) bool, the segment's epochs
    sats : (n, k) bool or None, the segment's satellite-epochs (sky sectors, one PRN);
        None: every comparable one in the segment's epochs
    metrics : restrict to these names (None: all)
    memo : a dict kept by the caller for this run, segment and metrics (empty at first): what
        the real log shows there is computed once and kept in it (an ensemble job measures
        the same units of a run for table after table; a job of one seed spent half its
        statistics' time on the real log)

    Returns
    -------
    SegmentStats (metrics the data cannot support are left out)
    """
    want = set(metrics) if metrics is not None else None

    def wanted(name: str) -> bool:
        return want is None or name in want

    g = memo.get("segment") if memo else None
    if g is None:
        epochs = epochs & view.valid
        sat_mask = view.sat_ok & epochs[:, None] if sats is None else view.sat_ok & sats
        has_sats = bool(view.assess.get("gsv") and sat_mask.any())
        # only the satellites the segment holds where they are few (one PRN, a sky sector):
        # copying most columns of every seed's arrays costs more than it saves
        cols = sat_mask.any(axis=0) if has_sats else None
        if cols is not None and 2 * cols.sum() > cols.size:
            cols = None
        span = _row_span(sat_mask) if has_sats else slice(None)
        if has_sats:
            sat_mask = sat_mask[span] if cols is None else sat_mask[span][:, cols]
        t = view.t_unix_s
        g = _Segment(
            view, epochs, position=sats is None and bool(epochs.any()),
            starts=bool(view.started and epochs[0] and t[0] - view.power_on_unix_s < STARTUP_S),
            moving=epochs & (view.speed_mps >= MOVING_MPS),
            steady=np.diff(t) < 1.5 * epoch_step_s(t),  # (no gap between the two)
            sat_mask=sat_mask if has_sats else None, span=span, cols=cols,
            gsa=bool(view.assess.get("gsa")) and sats is None)
    real_rows = memo.get("real") if memo else None
    if real_rows is None:
        real_rows = _side_stats(g, view.real, err_real, wanted)
    have = {m for m, v in real_rows.items() if np.isfinite(v[0])}
    sim_rows = _side_stats(g, sims, err_sim, lambda m: m in have)
    if memo is not None:
        memo.update(segment=g, real=real_rows)
    real, sim, pair = {}, {}, {}
    fractions = None
    for name in _ORDER:
        if name in sim_rows:
            real[name], sim[name] = float(real_rows[name][0]), sim_rows[name]
        elif name == "eq4_deg" and g.position and wanted(name):
            def eq4(a_lat, a_lon, b_lat, b_lon) -> np.ndarray:
                return row_quantile(_eq4_deg(a_lat, a_lon, b_lat, b_lon), 0.5)
            lat_s, lon_s = sims.lat_deg[:, g.epochs], sims.lon_deg[:, g.epochs]
            rp = eq4(view.real.lat_deg[:, g.epochs], view.real.lon_deg[:, g.epochs], lat_s, lon_s)
            if np.isfinite(rp).any():
                real[name] = float(np.nanmedian(rp))
                pair[name] = rp
                sim[name] = eq4(lat_s, lon_s, np.roll(lat_s, 1, 0), np.roll(lon_s, 1, 0))
        elif (name == "tracked_agreement" and g.sat_mask is not None and view.assess.get("cn0")
              and wanted(name)):
            fr, w = tracked_fractions(view, g.sats(view.real.tracked), g.sat_mask)
            fs, _ = tracked_fractions(view, g.sats(sims.tracked), g.sat_mask)
            rp = 1.0 - _disagreement(np.broadcast_to(fr, fs.shape), fs, w)
            if np.isfinite(rp).any():
                real[name] = float(np.nanmedian(rp))
                pair[name] = rp
                sim[name] = 1.0 - _disagreement(fs, np.roll(fs, 1, 0), w)
                fractions = (fs, w)
    return SegmentStats(real, sim, pair, fractions)


def judge_scored(stats: SegmentStats) -> dict[str, tuple[float, Judged]]:
    """Each score metric a unit of data supports: its real value and how the seeds judge it
    (:func:`virtualgps.gap.bands.judge`)."""
    return {m: (stats.real[m], judge(m, stats.real[m], stats.sim[m]))
            for m in SCORE_METRICS if m in stats.real}


def gap_score(judged: dict[str, tuple[float, Judged]],
              ref: dict[str, tuple[float, Judged]] | None = None
              ) -> tuple[float, dict[str, float]]:
    """The scalar gap of a unit of data: the mean distance, in units of the seeds' spread, over
    the score metrics it supports (:func:`virtualgps.gap.bands.distance_against`, guarded by
    the reference's judgments of the same unit where given).

    judged, ref : :func:`judge_scored` of a candidate's and of the profile under test's seeds
    Returns
    -------
    gap : float (NaN when no score metric is assessed)
    parts : {metric: distance}, a metric the reference already misses beyond D_CAP with what
        the candidate moves it further beyond (``distance_against(..., beyond=True)``: what it
        worsens); the gap takes each at most D_CAP
    """
    parts = {}
    total = 0.0
    for m, (real, j) in judged.items():
        r = ref.get(m) if ref is not None else None
        d = distance_against(m, real, j, r[1] if r is not None else None, beyond=True)
        if math.isfinite(d):
            parts[m] = d
            total += min(d, D_CAP)
    return (total / len(parts) if parts else float("nan")), parts


def moved_parts(judged: dict[str, tuple[float, Judged]],
                before: dict[str, tuple[float, Judged]],
                ref: dict[str, tuple[float, Judged]] | None = None) -> dict[str, float]:
    """A candidate's per-metric distances for judging what it worsens against the model
    before it: :func:`gap_score`'s parts, each no more than its centre's distance in the
    before-model's spread where that is wider (:func:`virtualgps.gap.bands.distance_moved`).

    judged, before, ref : :func:`judge_scored` of the candidate's, the model-before's and the
        profile under test's seeds over one unit
    Returns {metric: distance} (uncapped, as :func:`gap_score`'s parts)
    """
    parts = {}
    for m, (real, j) in judged.items():
        b, r = before.get(m), ref.get(m) if ref is not None else None
        d = distance_moved(m, real, j, b[1] if b is not None else None,
                           r[1] if r is not None else None)
        if math.isfinite(d):
            parts[m] = d
    return parts


def judged_rows(stats: SegmentStats, segment: str) -> list[dict]:
    """One segment's ``where`` entries before the rows are judged together
    (:func:`finish_rows`): real value, the ensemble's centre and median, p-value, signed z
    and score distance. The seeds' values travel in ``_sims``."""
    rows = []
    for metric, r in stats.real.items():
        j = judge(metric, r, stats.sim[metric])
        sims = np.asarray(stats.sim[metric], dtype=float)
        row = {"metric": metric, "segment": segment, "real": r,
               "sim_median": float(np.nanmedian(sims)) if np.isfinite(sims).any()
               else float("nan"),
               "p_value": j.p, "z": j.z, "floor": j.floor, "seeds_with_value": j.n,
               "_sims": sims}
        if METRICS[metric].score:
            row["distance"] = distance(j.z)
        rows.append(row)
    return rows


def finish_rows(rows: list[dict], holdout: bool = True) -> tuple[list[dict], float, dict]:
    """Judge a report's rows together: the Benjamini-Hochberg level over their p-values, each
    row's band at that level and whether the real value leaves it (``outside``); with
    ``holdout``, the bands checked on the seeds themselves too.

    Returns
    -------
    rows : the rows with ``sim_lo``, ``sim_hi`` (the band at ``alpha_row``), ``outside``,
        ``q_value`` and ``band95`` (one row's own 95 % prediction band, for reading; ``_sims``
        dropped)
    alpha_row : the per-row level used
    holdout : :func:`seed_holdout` of the rows ({} without ``holdout``)
    """
    checked = seed_holdout(rows) if holdout else {}
    p = np.array([r["p_value"] for r in rows], dtype=float)
    alpha = bh_alpha(p)
    fin = np.isfinite(p)
    q = np.full(p.size, np.nan)
    if fin.any():  # BH-adjusted p-values (the smallest FDR at which each row would be flagged)
        order = np.argsort(p[fin])
        m = order.size
        adj = np.minimum.accumulate((p[fin][order] * m / np.arange(1, m + 1))[::-1])[::-1]
        qf = np.empty(m)
        qf[order] = np.minimum(adj, 1.0)
        q[fin] = qf
    out = []
    for r, qv in zip(rows, q, strict=True):
        sims = r.pop("_sims")
        lo, hi = band(r["metric"], sims, alpha)
        outside = bool(np.isfinite(r["p_value"]) and (r["real"] < lo or r["real"] > hi))
        out.append(r | {"sim_lo": lo, "sim_hi": hi, "outside": outside, "q_value": qv,
                        "band95": list(band(r["metric"], sims, 0.05))})
    return out, alpha, checked


def seed_holdout(rows: list[dict]) -> dict:
    """The bands checked on the seeds themselves: each seed in turn taken as the real log and
    every row judged against the other seeds, together, as :func:`finish_rows` judges the real
    log's (:func:`virtualgps.gap.bands.holdout_p`, then the Benjamini-Hochberg level over that
    seed's rows). A seed is a log made by the profile under test along the same truth, so under
    a calibrated band at most ``FDR_Q`` of these reports show a located gap; a larger share says
    the band is too narrow for this run (a statistic whose seeds' values are heavy-tailed or
    pile up on a few levels), and which metrics those rows belong to. A pairwise metric's seed
    value is seed k against seed k - 1, as in its band.

    rows : :func:`judged_rows` entries (with ``_sims``, each (s,) over the same seeds)
    Returns
    -------
    {"reports": s, "reports_with_any_row_outside", "share", "rows", "rows_outside",
     "metrics": {metric: rows outside over the s reports}}
    """
    if not rows:
        return {"reports": 0, "reports_with_any_row_outside": 0, "share": math.nan,
                "rows": 0, "rows_outside": 0, "metrics": {}}
    s = max(np.asarray(r["_sims"]).size for r in rows)
    p = np.full((len(rows), s), np.nan)
    for i, r in enumerate(rows):
        sims = np.asarray(r["_sims"], dtype=float).ravel()
        p[i, :sims.size] = holdout_p(r["metric"], sims)
    flagged = np.zeros(p.shape, bool)
    for k in range(s):
        col = p[:, k]
        flagged[:, k] = np.isfinite(col) & (col <= bh_alpha(col))
    any_k = flagged.any(axis=0)
    metrics: dict[str, int] = {}
    for i in np.flatnonzero(flagged.any(axis=1)):
        metrics[rows[i]["metric"]] = metrics.get(rows[i]["metric"], 0) + int(flagged[i].sum())
    return {"reports": s, "reports_with_any_row_outside": int(any_k.sum()),
            "share": float(any_k.mean()), "rows": int(np.isfinite(p).sum()),
            "rows_outside": int(flagged.sum()), "metrics": metrics}


def merged_segments(named: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, list[str]]]:
    """Segments holding the same epochs as one: name -> (mask, the other names), first name
    kept (a log that starts with a fix has ``steady`` equal to ``all``)."""
    out: dict[str, tuple[np.ndarray, list[str]]] = {}
    for name, m in named.items():
        same = next((k for k, (mm, _) in out.items()
                     if mm.shape == m.shape and np.array_equal(mm, m)), None)
        if same is None:
            out[name] = (m, [])
        else:
            out[same][1].append(name)
    return out


def segments(view: RunView) -> dict[str, np.ndarray]:
    """The epoch segments of a run: name -> (n,) bool (empty ones left out)."""
    t = view.t_unix_s
    startup = (t - view.power_on_unix_s < STARTUP_S) & view.started
    speed = view.speed_mps  # (NaN where unknown: in neither)
    seg = {
        "all": np.ones(t.size, bool),
        "startup": startup,
        "steady": ~startup,
        "stationary": speed < MOVING_MPS,
        "moving": speed >= MOVING_MPS,
        "near_buildings": view.near_building,
        "open": ~view.near_building,
    }
    return {k: v & view.valid for k, v in seg.items() if (v & view.valid).any()}


def sky_sectors(view: RunView) -> dict[str, np.ndarray]:
    """Sky sectors: name -> (n, k) bool over the comparable satellite-epochs."""
    out = {}
    az, el = view.az_deg, view.el_deg
    for a0, a1 in zip(SECTOR_AZ_DEG[:-1], SECTOR_AZ_DEG[1:], strict=True):
        for e0, e1 in zip(SECTOR_EL_DEG[:-1], SECTOR_EL_DEG[1:], strict=True):
            m = view.sat_ok & (az >= a0) & (az < a1) & (el >= e0) & (el < e1)
            if m.any():
                out[f"sky:az{a0}-{a1}:el{e0}-{e1}"] = m
    return out
