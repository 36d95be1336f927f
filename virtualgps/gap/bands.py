"""How improbable a real statistic is under the profile's own ensemble: calibrated bands for the
``where`` table and the gap score, both in units of the seeds' own spread (DESIGN 7.1).

One statistic of one segment gives ``s`` seed values (each a whole-segment statistic of one
simulated run, so the correlation between epochs is inside them) and one real value. Under the
null, a real log made by the profile under test, the real value is one more draw of the same
distribution. On a scale where that distribution is close to normal (the logarithm of
``x + c`` for positive scales: errors, times, counts, HDOP; the value itself for shares and
levels) the predictive statistic

    t = (y_real - mean(y)) / (sd(y) * sqrt(1 + 1/s))

follows Student's t with ``s - 1`` degrees of freedom: the prediction interval for one new draw
of a normal sample (Hahn & Meeker, "Statistical Intervals", 1991, sec. 4.6; Geisser 1993). Its
two-sided p-value accounts for the finite ensemble: 8 seeds give a wider band than 50, and
neither flags more than its share under the null. Statistics whose missing value means "longer
than the segment can show" (a correlation time that never falls to 1/e, a first fix that never
comes) are judged by rank instead, missing counted as the largest: p = 2 min(k_below + 1,
k_above + 1) / (s + 1), exact under exchangeability.

Practical floor. Each metric has a difference below which it is no gap whatever the seeds'
spread (:data:`METRICS`, in the metric's units: 0.01 of fix fraction, 0.1 of HDOP, half a metre
of CEP): the distance is measured from the edge of that indifference zone around the
ensemble's centre, so 1.000 against 0.9994 is never a gap.

Many rows. A report tests one statistic per metric, segment, PRN and sky sector: a few hundred
rows. They are judged together with the Benjamini-Hochberg rule at :data:`FDR_Q` (false
discovery rate; under the null every row is null, so it is also the chance that any row of a
report is flagged). Each row's band is the prediction interval at the level that rule ends up
using (``alpha_row``; Bonferroni's ``q / m`` when no row is flagged), widened by the floor, so a
row is ``outside`` exactly when its value leaves its band.

Score. For fitting and ranking effects each metric's disagreement is ``z``, the normal quantile
of its two-sided predictive p-value (0 inside the floor, :data:`Z_CAP` at most), and its
distance ``max(0, z - DEAD_ZONE_Z)``: under the null a metric's distance averages about 0.1, and
a metric the seeds cannot tell apart from the real log adds nothing, so no effect buys a lower
score by moving a metric within the seeds' own scatter. Nor by widening that scatter: where a
candidate moves a metric's centre away from the real value, its distance is at least the one
that centre has in the spread of the profile under test (:func:`distance_against`). Nor by
moving further away a metric the profile under test already misses by more than the cap: the
per-metric distances that judge what a candidate worsens carry the further move, in that
profile's spreads, beyond the cap (at most D_CAP more).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy import special

FDR_Q = 0.05  # false-discovery rate of a report's located gaps
Z_CAP = 8.0  # a p-value of ~1e-15: beyond it nothing is more certain
DEAD_ZONE_Z = 1.0  # score distance: z beyond one predictive standard deviation
D_CAP = 5.0  # one metric's distance at most (a metric shown by the real log, by no seed);
# what a candidate worsens sees up to twice that (a centre moved further than the reference's)
MIN_SEEDS = 3  # seeds with a value a statistic needs before it is judged
GUARD_P = 0.001  # a centre that moves away by less than its noise at this level has not moved
_CAP_TAIL = float(special.ndtr(-(D_CAP + DEAD_ZONE_Z)))  # one-sided tail of the cap's z


@dataclass(frozen=True)
class MetricSpec:
    """How a metric is judged.

    kind : "log" (positive scale: judged on ln(x + c)) or "lin" (share or level: on x)
    c : the log offset, in the metric's units (keeps small values from dominating)
    floor : practical floor, the metric's units: smaller differences are no gap
    rel_floor : the floor as a share of the ensemble's centre, where larger
    nan_high : a missing seed value means "longer than the segment shows" (rank judged)
    score : part of the gap score (else located only)
    unit : for people
    share : a share of epochs or satellites, in [0, 1] (a band stops at those ends)
    """

    kind: str
    c: float = 0.0
    floor: float = 0.0
    rel_floor: float = 0.0
    nan_high: bool = False
    score: bool = True
    unit: str = ""
    share: bool = False

    def clip(self, lo: float, hi: float) -> tuple[float, float]:
        """A band within the values the metric can take: scales from 0, shares 0 to 1 (the
        prediction interval of a normal, widened by the floor, runs past them: a fix
        fraction "0.99..1.01" means "0.99 or more")."""
        if self.kind == "log" or self.share:
            lo = max(lo, 0.0)
        if self.share:
            hi = min(hi, 1.0)
        return lo, hi


# Floors: a printed digit or two, or what a user would call the same receiver. Positions print
# to 0.0001' (0.19 m of latitude) in MTK logs; GSV SNR in whole dB-Hz; HDOP to 0.01-0.1.
METRICS: dict[str, MetricSpec] = {
    "cep50_m": MetricSpec("log", 0.5, 0.5, 0.05, unit="m"),
    "r95_m": MetricSpec("log", 0.5, 1.0, 0.05, unit="m"),
    "up_p68_m": MetricSpec("log", 0.5, 0.5, 0.05, unit="m"),
    "bias_m": MetricSpec("log", 0.5, 0.5, 0.05, score=False, unit="m"),
    "autocorr_s": MetricSpec("log", 2.0, 2.0, 0.05, nan_high=True, unit="s"),
    "error_step_m": MetricSpec("log", 0.1, 0.05, 0.05, unit="m"),
    # (a tenth of itself beyond a second: the lag is measured to a few hundredths of a second,
    # and the latency and nav_filter grids' lags lie 0.25-0.5 s apart there)
    "lag_s": MetricSpec("lin", floor=0.1, rel_floor=0.1, unit="s"),
    # (estimated on ~1 Hz steps: a filter of under half a step, e^-2 of the last fix carried
    # into the next, is no smoothing one could see, and its estimate is the noise's; the
    # seeds' values pile up on the grid's 0 and 0.1 s, a spread the normal prediction
    # understates: a null log's 0.3 s on a 160 s block passed for a filter)
    "smoothing_s": MetricSpec("log", 0.5, 0.5, 0.05, unit="s"),
    "frozen_fraction": MetricSpec("lin", floor=0.02, share=True),
    "sats_used_mean": MetricSpec("log", 0.5, 0.5, 0.0, unit="satellites"),
    "used_changes_per_min": MetricSpec("log", 0.5, 0.1, 0.05, unit="/min"),
    "tracked_agreement": MetricSpec("lin", floor=0.05, share=True),
    "tracked_share": MetricSpec("lin", floor=0.03, share=True),
    "cn0_median_dbhz": MetricSpec("lin", floor=1.0, unit="dB-Hz"),
    "used_el_p05_deg": MetricSpec("lin", floor=1.0, unit="°"),
    "hdop_median": MetricSpec("log", 0.2, 0.1, 0.0),
    "fix_fraction": MetricSpec("lin", floor=0.01, share=True),
    "ttff_s": MetricSpec("log", 5.0, 2.0, 0.05, nan_high=True, unit="s"),
    "dgps_fraction": MetricSpec("lin", floor=0.02, share=True),
    "eq4_deg": MetricSpec("log", 1e-6, 5e-6, 0.05, score=False, unit="°"),
}
SCORE_METRICS = tuple(m for m, s in METRICS.items() if s.score)


def _g(spec: MetricSpec, x: np.ndarray | float) -> np.ndarray:
    """The judging scale: ln(max(x, 0) + c) for log metrics, x for linear ones."""
    x = np.asarray(x, dtype=float)
    return np.log(np.maximum(x, 0.0) + spec.c) if spec.kind == "log" else x


def _g_inv(spec: MetricSpec, y: np.ndarray | float) -> np.ndarray:
    y = np.asarray(y, dtype=float)
    return np.exp(y) - spec.c if spec.kind == "log" else y


# Scalar twins of _g and _g_inv: a diagnosis judges some 10^4-10^5 single values in its main
# process, where numpy's per-call cost on a scalar was most of judge's and the guard's time.
def _g1(spec: MetricSpec, x: float) -> float:
    return math.log(max(x, 0.0) + spec.c) if spec.kind == "log" else x


def _g1_inv(spec: MetricSpec, y: float) -> float:
    return math.exp(y) - spec.c if spec.kind == "log" else y


@functools.cache
def _t_quantile(dof: int, q: float) -> float:
    """Student's t quantile (a few seed counts and levels recur)."""
    return float(special.stdtrit(dof, q))


class Judged(NamedTuple):
    """A real value against its ensemble (a named tuple: a diagnosis makes some 10^5 of them,
    most in its workers, and unpickles their results in its main process).

    p : two-sided p-value (NaN: too few seeds with a value)
    z : signed normal-equivalent (+: real above the ensemble); 0 inside the floor
    centre : the ensemble's centre, metric units (its mean on the judging scale, or the median
        for rank-judged metrics); floor : the practical floor used, metric units
    n : seeds with a value
    rank : judged by rank (a seed's missing value counted as the largest)
    sd_g : the seeds' standard deviation on the judging scale (NaN where rank-judged)
    """

    p: float
    z: float
    centre: float
    floor: float
    n: int
    rank: bool
    sd_g: float = math.nan


def _z_of_p(p: float, sign: float) -> float:
    if not math.isfinite(p):
        return math.nan
    if p >= 1.0:
        return 0.0
    return float(sign * min(Z_CAP, -special.ndtri(max(p, 1e-300) / 2.0)))


def _predictive(spec: MetricSpec, real: float, centre: float, sd_g: float, n: int
                ) -> tuple[float, float, float]:
    """The real value against one more draw of a normal ensemble of ``n`` seeds with this
    centre (metric units) and spread (judging scale): (p, z, floor) as in :func:`judge`."""
    floor = max(spec.floor, spec.rel_floor * abs(centre))
    if abs(real - centre) <= floor:
        return 1.0, 0.0, floor
    sign = 1.0 if real > centre else -1.0
    edge = _g1(spec, centre + sign * floor)
    d = abs(_g1(spec, real) - edge)
    scale = sd_g * math.sqrt(1.0 + 1.0 / n)
    if scale <= 0.0:
        p = 0.0 if d > 0 else 1.0
    else:
        p = float(2.0 * special.stdtr(n - 1, -d / scale))
    return p, _z_of_p(p, sign), floor


def judge(metric: str, real: float, sims: Sequence[float] | np.ndarray) -> Judged:
    """Judge one real statistic against the seeds' values of it (see the module docstring).

    Parameters
    ----------
    metric : a name of :data:`METRICS`
    real : the real log's value (finite)
    sims : (s,) the seeds' values (NaN: no value; for ``nan_high`` metrics: longer than shown)

    Returns
    -------
    Judged
    """
    spec = METRICS[metric]
    y = np.asarray(sims, dtype=float).ravel()
    fin = y[np.isfinite(y)]
    s = y.size
    if spec.nan_high and fin.size < s:
        yy = np.where(np.isfinite(y), y, np.inf)
        centre = float(np.median(yy))
        floor = max(spec.floor, spec.rel_floor * abs(centre)) if math.isfinite(centre) \
            else spec.floor
        if math.isfinite(centre) and abs(real - centre) <= floor:
            return Judged(1.0, 0.0, centre, floor, s, True)
        below, above = int(np.sum(yy < real)), int(np.sum(yy > real))
        p = min(1.0, 2.0 * (min(below, above) + 1) / (s + 1))
        return Judged(p, _z_of_p(p, 1.0 if real > centre else -1.0), centre, floor, s, True)
    if fin.size < MIN_SEEDS:
        return Judged(math.nan, math.nan, math.nan, spec.floor, int(fin.size), False)
    g = _g(spec, fin)
    n = int(fin.size)
    m = float(g.sum()) / n
    sd = math.sqrt(float(np.dot(g - m, g - m)) / (n - 1))
    centre = _g1_inv(spec, m)
    p, z, floor = _predictive(spec, real, centre, sd, n)
    return Judged(p, z, centre, floor, n, False, sd)


def band(metric: str, sims: Sequence[float] | np.ndarray, alpha: float) -> tuple[float, float]:
    """The range of real values not flagged at two-sided level ``alpha``: the prediction
    interval of one more draw (or the rank interval for rank-judged metrics), widened by the
    practical floor, within the values the metric can take (:meth:`MetricSpec.clip`): all
    of them when the ensemble cannot flag at that level.

    sims : (s,) the seeds' values; returns (lo, hi) in the metric's units
    """
    spec = METRICS[metric]
    y = np.asarray(sims, dtype=float).ravel()
    fin = y[np.isfinite(y)]
    s = y.size
    if spec.nan_high and fin.size < s:
        yy = np.sort(np.where(np.isfinite(y), y, np.inf))
        k = int(math.floor(alpha / 2.0 * (s + 1)))
        if k < 1:
            return spec.clip(-math.inf, math.inf)
        centre = float(np.median(yy))
        floor = max(spec.floor, spec.rel_floor * abs(centre)) if math.isfinite(centre) \
            else spec.floor
        lo, hi = float(yy[k - 1]), float(yy[s - k])
        if math.isfinite(centre):
            lo, hi = min(lo, centre - floor), max(hi, centre + floor)
        return spec.clip(lo, hi)
    if fin.size < MIN_SEEDS:
        return spec.clip(-math.inf, math.inf)
    g = _g(spec, fin)
    m, sd = float(np.mean(g)), float(np.std(g, ddof=1))
    centre = float(_g_inv(spec, m))
    floor = max(spec.floor, spec.rel_floor * abs(centre))
    half = float(special.stdtrit(fin.size - 1, 1.0 - alpha / 2.0)) * sd * math.sqrt(
        1.0 + 1.0 / fin.size)
    hi = float(_g_inv(spec, _g(spec, centre + floor) + half))
    lo_edge = centre - floor
    lo = float(_g_inv(spec, _g(spec, lo_edge) - half)) if (
        spec.kind != "log" or lo_edge > 0) else 0.0
    return spec.clip(lo, hi)


def bh_alpha(p_values: Sequence[float] | np.ndarray, q: float = FDR_Q) -> float:
    """The per-row level of the Benjamini-Hochberg rule at false-discovery rate ``q``: the
    largest p_(k) threshold q k / m that p_(k) meets, else q / m (no row flagged).

    p_values : (m,) NaN left out; returns the level (q with no p-value at all)
    """
    p = np.sort(np.asarray(p_values, dtype=float))
    p = p[np.isfinite(p)]
    m = p.size
    if m == 0:
        return q
    k = np.flatnonzero(p <= q * np.arange(1, m + 1) / m)
    return float(q * (k[-1] + 1) / m) if k.size else q / m


def distance(z: float) -> float:
    """One metric's score distance from its signed z: max(0, |z| - DEAD_ZONE_Z), at most
    D_CAP; NaN stays NaN."""
    if not math.isfinite(z):
        return math.nan
    return float(min(D_CAP, max(0.0, abs(z) - DEAD_ZONE_Z)))


def distances_many(metric: str, reals: np.ndarray, judged: Sequence[Judged],
                   sims: Sequence[np.ndarray], ref: Judged | None = None) -> np.ndarray:
    """Score distances of many values against many ensembles of one metric at once: each
    ``reals[b]`` judged as the real value against each ensemble ``t``, as
    :func:`distance_against` with the same reference (:func:`distance` of :func:`judge`'s z
    without one).

    reals : (B,) values (NaN: none, its column NaN); judged : (T,) :func:`judge` of any value
    against each ensemble (it gives the centre, spread and path); sims : (T,) each ensemble's
    seeds' values (read where an ensemble is rank-judged); ref : :func:`judge` of any value
    against the reference's seeds (its centre and spread guard each distance). Returns
    (T, B), NaN where an ensemble cannot judge.
    """
    r_all = np.asarray(reals, dtype=float)
    fin = np.isfinite(r_all)
    out = np.full((len(judged), r_all.size), np.nan)
    if fin.any():
        out[:, fin] = _distances_finite(metric, r_all[fin], judged, sims, ref)
    return out


def _distances_finite(metric: str, r: np.ndarray, judged: Sequence[Judged],
                      sims: Sequence[np.ndarray], ref: Judged | None) -> np.ndarray:
    spec = METRICS[metric]
    out = np.full((len(judged), r.size), np.nan)
    normal = [t for t, j in enumerate(judged) if not j.rank and math.isfinite(j.sd_g)]
    for t, j in enumerate(judged):
        if j.rank:
            out[t] = [distance(judge(metric, float(x), sims[t]).z) for x in r]
    if not normal:
        return out
    own = [judged[t] for t in normal]
    centre = np.array([j.centre for j in own])[:, None]
    sd = np.array([j.sd_g for j in own])[:, None]
    n = np.array([j.n for j in own])[:, None]
    d = _predictive_distances(spec, r, centre, sd, n)
    if ref is not None and not ref.rank and math.isfinite(ref.sd_g):
        # (the guard of distance_against, for every pair at once)
        g_r = _g(spec, r)[None, :]
        miss_own = np.abs(g_r - _g(spec, centre))
        miss_ref = np.abs(g_r - _g1(spec, ref.centre))
        tol = np.array([_t_quantile(min(j.n, ref.n) - 1, 1.0 - GUARD_P) * math.sqrt(
            j.sd_g ** 2 / j.n + ref.sd_g ** 2 / ref.n) for j in own])[:, None]
        away = miss_own > miss_ref + tol
        if away.any():
            in_ref = _predictive_distances(spec, r, centre, np.full_like(sd, ref.sd_g),
                                           np.full_like(n, ref.n))
            d = np.where(away, np.maximum(d, in_ref), d)
    out[normal] = d
    return out


def _predictive_distances(spec: MetricSpec, r: np.ndarray, centre: np.ndarray, sd_g: np.ndarray,
                          n: np.ndarray) -> np.ndarray:
    """:func:`distance` of :func:`_predictive`'s z for every pair at once (its vector twin:
    :func:`judge` takes one value, a fit's refits take every seed against every grid point).

    r : (B,) finite values; centre, sd_g, n : (T, 1) the ensembles'; returns (T, B)"""
    p = _predictive_p(spec, r[None, :], centre, sd_g, n)
    z = np.where(p >= 1.0, 0.0, np.minimum(Z_CAP, -special.ndtri(np.maximum(p, 1e-300) / 2.0)))
    return np.clip(z - DEAD_ZONE_Z, 0.0, D_CAP)


def _predictive_p(spec: MetricSpec, r: np.ndarray, centre: np.ndarray, sd_g: np.ndarray,
                  n: np.ndarray) -> np.ndarray:
    """:func:`_predictive`'s two-sided p-value, its arguments broadcast against each other
    (1 inside the floor)."""
    floor = np.maximum(spec.floor, spec.rel_floor * np.abs(centre))
    sign = np.where(r > centre, 1.0, -1.0)
    d = np.abs(_g(spec, r) - _g(spec, centre + sign * floor))
    scale = sd_g * np.sqrt(1.0 + 1.0 / n)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(scale > 0, 2.0 * special.stdtr(n - 1, -d / np.where(scale > 0, scale, 1.0)),
                     np.where(d > 0, 0.0, 1.0))
    return np.where(np.abs(r - centre) <= floor, 1.0, p)


def holdout_p(metric: str, sims: Sequence[float] | np.ndarray) -> np.ndarray:
    """Each seed in turn as the real value, judged against the others (:func:`judge`, for all
    at once): the p-values a log made by the profile under test itself would get.

    sims : (s,) the seeds' values; returns (s,) p-values (NaN where the seed has no value, or
    too few others have one)
    """
    spec = METRICS[metric]
    y = np.asarray(sims, dtype=float).ravel()
    fin = np.isfinite(y)
    out = np.full(y.size, np.nan)
    if spec.nan_high and not fin.all():
        for k in np.flatnonzero(fin):
            out[k] = judge(metric, float(y[k]), np.delete(y, k)).p
        return out
    n = int(fin.sum()) - 1
    if n < MIN_SEEDS:
        return out
    g = _g(spec, y[fin])
    gc = g - g.mean()  # (centred: equal seeds give a spread of exactly 0)
    m_k = -gc / n  # the others' mean, less the mean of all
    var_k = np.maximum((float(gc @ gc) - gc ** 2 - n * m_k ** 2) / (n - 1), 0.0)
    centre = _g_inv(spec, g.mean() + m_k)
    out[fin] = _predictive_p(spec, y[fin], centre, np.sqrt(var_k), np.full(g.size, n))
    return out


def distance_against(metric: str, real: float, own: Judged, ref: Judged | None,
                     beyond: bool = False) -> float:
    """One metric's score distance for a candidate, guarded by the profile under test.

    In its own seeds' spread (:func:`distance` of ``own.z``), unless the candidate's centre
    lies further from the real value than the reference's (the profile under test, on the
    judging scale, beyond the two centres' estimation noise at one-sided level
    :data:`GUARD_P`): then it is at least
    the distance its centre has in the reference's spread. Moving a metric away from the real
    log while widening the seeds' spread thus never counts as a gain (on the GSDC drive
    ``cn0_tracking`` took the simulated HDOP from 1.0 to 3.7, further from the phone's 0.38,
    and in its own, wider spread its distance fell from 5.0 to 3.4). A centre that moves
    towards the real value, or stays, keeps the candidate's own calibrated distance.

    own, ref : :func:`judge` of the real value against the candidate's and the reference's
        seeds (ref None, or either rank-judged: the own distance)
    beyond : where the reference's own distance is at D_CAP too, add how much further the
        candidate's centre lies than the reference's (:func:`_beyond_cap`): what a metric the
        profile under test already misses beyond the cap is made worse by (the per-metric
        distances that judge what a candidate worsens; the score itself stays capped). Below
        the cap the reference's distance already counts a move up to it.
    """
    d_own = distance(own.z)
    if (ref is None or own.rank or ref.rank or not math.isfinite(d_own)
            or not (math.isfinite(own.sd_g) and math.isfinite(ref.sd_g))):
        return d_own
    spec = METRICS[metric]
    g_real = _g1(spec, real)
    miss_own = abs(g_real - _g1(spec, own.centre))
    miss_ref = abs(g_real - _g1(spec, ref.centre))
    # "further" beyond the two centres' estimation noise: the 99.9 % point of Student's t
    # (a candidate whose centre only seems to move by the seeds' luck keeps its own distance)
    tol = _t_quantile(min(own.n, ref.n) - 1, 1.0 - GUARD_P) * math.sqrt(
        own.sd_g ** 2 / own.n + ref.sd_g ** 2 / ref.n)
    if miss_own <= miss_ref + tol:
        return d_own
    _, z, _ = _predictive(spec, real, own.centre, ref.sd_g, ref.n)
    d = max(d_own, distance(z))
    if beyond and d >= D_CAP and distance(ref.z) >= D_CAP:
        d += _beyond_cap(spec, miss_own, miss_ref, tol, ref)
    return d


def distance_moved(metric: str, real: float, own: Judged, before: Judged | None,
                   ref: Judged | None) -> float:
    """One metric's distance for judging what a candidate worsens: :func:`distance_against`
    (``beyond``), but where the candidate's seeds scatter less than the model before it, no
    more than its centre's distance in that model's wider spread. A candidate worsens a metric
    by moving its centre away from the real value, not by narrowing the seeds' spread about
    the same centre: that only shows a miss the model before had too, hidden in its scatter.
    (A tau 2.99 s filter injected into the GSDC drive: after ``nav_filter``, ``noise_level``
    took the moving run's ``autocorr_s`` centre from 53.3 to 50.8 s against the log's 63.3 s,
    and its 95 % band from 36-80 s to 42-63 s: distance 0 -> 1.64 there; on the held-out
    blocks it "worsened autocorr_s by 1.28" and was refused.)
    A centre that moves away is judged in the wider spread; the score itself keeps the
    candidate's own spread.

    own, before, ref : :func:`judge` of the real value against the candidate's seeds, the
        model's before it (None: not judged there) and the profile under test's (None: none)
    """
    d = distance_against(metric, real, own, ref, beyond=True)
    if (before is None or own.rank or before.rank or not math.isfinite(d)
            or not (math.isfinite(own.sd_g) and math.isfinite(before.sd_g))
            or before.sd_g <= own.sd_g):
        return d
    p, z, floor = _predictive(METRICS[metric], real, own.centre, before.sd_g, before.n)
    wide = own._replace(p=p, z=z, floor=floor, n=before.n, sd_g=before.sd_g)
    return min(d, distance_against(metric, real, wide, ref, beyond=True))


def _beyond_cap(spec: MetricSpec, miss_own: float, miss_ref: float, tol: float, ref: Judged
                ) -> float:
    """What a guarded distance adds at D_CAP when asked (``beyond``): how much further the
    candidate's centre lies than both the reference's and the cap's reach, in the reference's
    predictive spreads (or its floors, where wider: seeds that all agree have no spread), less
    the two centres' noise ``tol``, at most D_CAP more. Without it a metric the profile under
    test already misses by more than the cap could be moved further away unseen while another
    metric gained (the GSDC SPAN reference as the real log: 11.4 satellites used against 8 in
    every seed; an elevation mask of 20 deg took the simulation to fewer still, its HDOP nearer
    the log's, and was added). It judges what a candidate worsens, not the score: added to the
    score, it made a fit's surface jump by up to D_CAP between neighbouring grid points (the
    Magdeburg waypoints' cn0_tracking). miss_own, miss_ref : distances of the centres from the
    real value on the judging scale; ref : the reference's judgment."""
    floor = max(spec.floor, spec.rel_floor * abs(ref.centre))
    floor_g = _g1(spec, ref.centre + floor) - _g1(spec, ref.centre)
    spread = ref.sd_g * math.sqrt(1.0 + 1.0 / ref.n)
    scale = max(spread, floor_g)
    if not scale > 0.0 or ref.n < 2:
        return 0.0
    # (the cap's reach: the floor, then as many predictive spreads as Student's t with the
    # reference's seeds needs for the p-value whose z is D_CAP + DEAD_ZONE_Z, 17.7 at 12
    # seeds, 38.8 at 8; so the distance grows on from the cap without a step)
    reach = max(miss_ref, floor_g + _t_quantile(ref.n - 1, 1.0 - _CAP_TAIL) * spread)
    return min(D_CAP, max(0.0, (miss_own - tol - reach) / scale))


def band_description(n_rows: int, seeds: int, alpha_row: float, holdout: dict) -> dict:
    """``report.json``'s ``band``: how the located gaps were judged, and the bands checked on
    the seeds themselves (``holdout``: :func:`virtualgps.gap.where.seed_holdout`)."""
    return {
        "method": "predictive",
        "statistic": "each row's real value against one more draw of the seeds' values of the "
                     "same statistic over the same epochs: Student's t prediction interval "
                     "with s - 1 degrees of freedom on ln(x + c) for scales and x for shares "
                     "and levels; rank among the seeds where a seed's value is 'longer than "
                     "the segment shows' (autocorr_s, ttff_s)",
        "seeds": seeds,
        "multiplicity": f"Benjamini-Hochberg false-discovery rate {FDR_Q:g} over the {n_rows} "
                        "rows (segments holding the same epochs merged first)",
        "fdr_q": FDR_Q,
        "alpha_row": alpha_row,
        "floors": {m: {"floor": s.floor, "relative": s.rel_floor, "unit": s.unit}
                   for m, s in METRICS.items()},
        "resolution": "simulated positions, HDOP and altitude rounded to the digits the real "
                      "log prints; SNR compared in whole dB-Hz",
        "seed_holdout": holdout | {
            "what": "each seed in turn taken as the real log and judged against the others "
                    "as the real log is: reports_with_any_row_outside of reports would show a "
                    f"located gap; a calibrated band gives at most {FDR_Q:g} of them"},
    }


HOLDOUT_P = 0.01  # the seed-holdout check warns when its count is this improbable


def holdout_warning(band_entry: dict) -> str | None:
    """A plain warning where the bands, checked on the seeds themselves, flag more of the seeds
    taken as the real log than a calibrated band plausibly would: k of s reports with a
    located gap when P(K >= k) < :data:`HOLDOUT_P` for K binomial(s, ``FDR_Q``) (at 50 seeds,
    8 or more; the seeds' reports share their ensemble, so the level is a rough one). None
    where the check passes or was not made."""
    h = band_entry.get("seed_holdout") or {}
    k, s = h.get("reports_with_any_row_outside", 0), h.get("reports", 0)
    if not s or k == 0 or float(special.bdtrc(k - 1, s, FDR_Q)) >= HOLDOUT_P:
        return None
    worst = ", ".join(f"{m} ({n})" for m, n in sorted(h["metrics"].items(),
                                                      key=lambda kv: -kv[1])[:3])
    return (f"the bands look too narrow for this run: {k} of {s} seeds, each taken as the "
            f"real log, would show a located gap (a calibrated band: at most "
            f"{100 * FDR_Q:.0f} %); read the located gaps in {worst} with care")


def holdout_counts(band_entry: dict) -> dict:
    """A report's seed-holdout counts alone (``band.seed_holdout`` less its wording; empty
    where the report has none): what the self-check adds up over its trials."""
    h = band_entry.get("seed_holdout") or {}
    return {k: v for k, v in h.items() if k != "what"}
