"""Satellite positions between propagated nodes.

Owns the interpolation of satellite ECEF positions from nodes on a fixed grid in time. SGP4
with its TEME -> ECEF rotation costs about a microsecond per satellite and epoch, and a replay
at 10 Hz asks for the same smooth orbits 600 times a minute. Here each satellite is propagated
once per node, every ``NODE_STEP_S`` on a grid fixed in absolute time (multiples of the step
since the Unix epoch), and an epoch's position is the degree-5 Lagrange polynomial through the
six nodes around it (two before its interval, four from its start).

Accuracy: a GPS orbit seen from the rotating Earth turns by at most ~2.2e-4 rad/s, so the
sixth derivative of a coordinate is below r w^6 ~ 3e-15 m/s^6 and the interpolation error
below ~h^6 r w^6 / 100 ~ 1 um at h = 60 s. Measured against SGP4 at every 0.7 s over a day
(2017-03-26 set): 0.46 mm at most, 0.08 mm on average -- the same at 30 s and 120 s steps, so
that is SGP4's own round-off jitter (its Julian date split), not the interpolation's; SGP4's
model error is ~1 km. The nodes are a function of the time grid alone, and the weights and sums
are elementwise in a fixed order, so a batch of epochs gets the same numbers as its epochs one
by one: the live daemon and a replay print the same bytes.
"""

from __future__ import annotations

import math

import numpy as np

NODE_STEP_S = 60.0
NODE_OFFSETS = (-2, -1, 0, 1, 2, 3)  # nodes around an epoch, in steps from its interval start
MAX_CACHED_NODES = 20_000  # (2 weeks of 60 s nodes, ~15 MB at 32 satellites); then rebuilt


def lagrange_weights(s: np.ndarray | float) -> list:
    """Weights of the nodes at ``NODE_OFFSETS`` for positions ``s`` steps from the interval's
    start.

    w_j(s) = prod over m != j of (s - x_m) / (x_j - x_m), the x the offsets; products taken in
    a fixed order, each an IEEE operation on one element: an array and a Python float give
    each value the same bits.

    Parameters
    ----------
    s : (n,) float array, or a float; in [0, 1) for the interpolation interval

    Returns
    -------
    weights : len(NODE_OFFSETS) arrays (n,) (or floats), summing to 1 up to round-off
    """
    x = NODE_OFFSETS
    factors = [s - xm for xm in x]
    weights = []
    for j, xj in enumerate(x):
        others = [m for m in range(len(x)) if m != j]
        w = factors[others[0]]
        denom = float(xj - x[others[0]])
        for m in others[1:]:
            w = w * factors[m]
            denom *= xj - x[m]
        weights.append(w * (1.0 / denom))
    return weights


class SatNodes:
    """An ephemeris' satellite positions interpolated between cached nodes.

    Parameters
    ----------
    ephemeris : anything with ``sat_ecef_m(t_unix_s)`` -> (n_t, n_sat, 3) and ``prn`` (n_sat,)
        (the receiver uses it for TLE sets: see ``Constellation.node_interpolation``)
    step_s : node spacing, seconds
    """

    def __init__(self, ephemeris, step_s: float = NODE_STEP_S) -> None:
        self.ephemeris = ephemeris
        self.step_s = float(step_s)
        self._nodes: dict[int, np.ndarray] = {}  # node index -> (n_sat, 3) ECEF metres

    def _fetch(self, keys: np.ndarray) -> np.ndarray:
        """The nodes ``keys`` (sorted unique (k,) int), propagating those not cached.

        Returns
        -------
        nodes : (k, n_sat, 3) float, metres, ECEF (NaN where the ephemeris has none)
        """
        key_list = keys.tolist()
        cache = self._nodes
        got = {k: cache.get(k) for k in key_list}
        missing = [k for k, v in got.items() if v is None]
        if missing:
            pos = self.ephemeris.sat_ecef_m(np.asarray(missing, dtype=float) * self.step_s)
            new = dict(zip(missing, pos, strict=True))
            got.update(new)
            if len(cache) + len(new) > MAX_CACHED_NODES:
                cache = self._nodes = {}
            # (Read into ``got`` and rebound, never cleared under a reader: receivers sharing
            # an ephemeris may compute skies in several threads.)
            cache.update(new)
        return np.stack([got[k] for k in key_list])

    def sat_ecef_m(self, t_unix_s: np.ndarray) -> np.ndarray:
        """Satellite positions at the given times.

        Parameters
        ----------
        t_unix_s : (n_t,) float, UTC Unix seconds (of the ephemeris' sky)

        Returns
        -------
        sat_ecef_m : (n_t, n_sat, 3) float, metres, ECEF; NaN where a time is not finite or
            the ephemeris has no position at one of its six nodes
        """
        t = np.asarray(t_unix_s, dtype=float).reshape(-1)
        if t.size == 1 and math.isfinite(t[0]):  # the live epoch: Python floats, same bits
            t0 = float(t[0])
            start = math.floor(t0 / self.step_s)
            s = (t0 - start * self.step_s) / self.step_s  # (see below)
            keys = range(start + NODE_OFFSETS[0], start + NODE_OFFSETS[-1] + 1)
            try:
                nodes = [self._nodes[k] for k in keys]
            except KeyError:
                nodes = list(self._fetch(np.asarray(keys)))
            return _weighted_sum(lagrange_weights(s), nodes)[None]
        out = np.full((t.size, len(self.ephemeris.prn), 3), np.nan)
        ok = np.flatnonzero(np.isfinite(t))
        if ok.size == 0:
            return out
        start = np.floor(t[ok] / self.step_s)
        # Steps since the interval's start node, in [0, 1) (-1e-16 where t / step rounded up
        # to a whole number). start * step is a whole number far below 2^53, so exact, and
        # within a step of t, so t - start * step is exact too (Sterbenz): s keeps t's own
        # precision. t / step - start would carry the round-off of t / step, up to 0.1 us
        # in these years (0.4 mm at 4 km/s).
        s = (t[ok] - start * self.step_s) / self.step_s
        first = start.astype(np.int64) + NODE_OFFSETS[0]  # each epoch's first node
        starts = np.unique(first)
        keys = np.unique((starts[:, None] + np.arange(len(NODE_OFFSETS))).ravel())
        nodes = self._fetch(keys)
        # The six nodes of an epoch are consecutive keys, so consecutive rows of ``nodes``.
        row = np.searchsorted(keys, first)
        weights = [w[:, None, None] for w in lagrange_weights(s)]
        out[ok] = _weighted_sum(weights, [nodes[row + j] for j in range(len(NODE_OFFSETS))])
        return out


def _weighted_sum(weights: list, nodes: list) -> np.ndarray:
    """sum_j weights[j] * nodes[j], added in order (the same bits for one epoch or many)."""
    pos = weights[0] * nodes[0]
    for w, node in zip(weights[1:], nodes[1:], strict=True):
        pos = pos + w * node
    return pos
