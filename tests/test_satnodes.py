"""Satellite positions between nodes: against SGP4 itself, a closed form, and batch identity."""

from __future__ import annotations

import numpy as np
import pytest

from virtualgps.sky import satnodes
from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR, load_tle
from virtualgps.sky.satnodes import NODE_STEP_S, SatNodes, lagrange_weights


@pytest.fixture(scope="module")
def c2017():
    return load_tle(BUNDLED_EPHEMERIS_DIR / "gps-ops-2017-03-26.tle")


class Quintic:
    """A made-up ephemeris of two satellites moving on degree-5 polynomials of time (which
    degree-5 interpolation reproduces exactly), and a third that is NaN after ``t_end``."""

    prn = np.array([1, 2, 3])

    def __init__(self, t0: float, t_end: float) -> None:
        self.t0, self.t_end = t0, t_end
        self.calls = 0

    def sat_ecef_m(self, t_unix_s: np.ndarray) -> np.ndarray:
        self.calls += 1
        x = (np.asarray(t_unix_s, dtype=float) - self.t0) / 1000.0  # kiloseconds
        poly = np.stack([2.0e7 + 3.0e5 * x - 4.0e3 * x**3 + 50.0 * x**5,
                         -1.0e7 + 1.0e6 * x**2 - 7.0 * x**4,
                         1.5e7 - 2.0e5 * x + 30.0 * x**5], axis=-1)  # (n, 3)
        out = np.stack([poly, -poly, poly[:, ::-1]], axis=1)  # (n, 3 sats, 3)
        out[np.asarray(t_unix_s) > self.t_end, 2] = np.nan
        return out


def test_weights_are_lagrange_basis():
    s = np.linspace(0.0, 0.999, 37)
    w = np.stack(lagrange_weights(s))  # (6, n)
    np.testing.assert_allclose(w.sum(axis=0), 1.0, rtol=0, atol=1e-14)
    # At the interval's start node the basis is the unit vector of that node (offset 0).
    np.testing.assert_allclose(w[:, 0], [0, 0, 1, 0, 0, 0], atol=1e-15)
    # It reproduces s^k exactly for k <= 5 (positions relative to the start node).
    x = np.array(satnodes.NODE_OFFSETS, float)
    for k in range(6):
        np.testing.assert_allclose((x[:, None] ** k * w).sum(axis=0), s**k, atol=1e-12)


def test_polynomial_orbits_are_reproduced_and_nan_stays_local():
    t0 = 1.49e9
    eph = Quintic(t0, t_end=t0 + 1800.0)
    nodes = SatNodes(eph)
    t = t0 + np.arange(0.0, 3600.0, 7.3)
    got = nodes.sat_ecef_m(t)
    want = eph.sat_ecef_m(t)
    np.testing.assert_allclose(got[:, :2], want[:, :2], rtol=0, atol=1e-6)
    # Satellite 3 has no position after t_end: NaN from the first epoch whose six nodes reach
    # past it (3 steps before), finite before that, and the other two are unaffected.
    nan3 = np.isnan(got[:, 2]).any(axis=-1)
    first_nan = t[np.argmax(nan3)]
    assert not nan3[t < t0 + 1800.0 - 3 * NODE_STEP_S].any() and nan3[t > t0 + 1800.0].all()
    assert t0 + 1800.0 - 3 * NODE_STEP_S <= first_nan <= t0 + 1800.0
    np.testing.assert_allclose(got[~nan3, 2], want[~nan3, 2], rtol=0, atol=1e-6)
    # Times that are not finite give NaN, and the rest of the batch is unaffected.
    t_bad = np.array([t[3], np.nan, np.inf, t[4]])
    out = nodes.sat_ecef_m(t_bad)
    assert np.isnan(out[1:3]).all()
    np.testing.assert_array_equal(out[[0, 3]], got[[3, 4]])


def test_agrees_with_sgp4_to_a_millimetre(c2017):
    # A day at odd times (the measured figure in the module's docstring: 0.46 mm at most).
    t = c2017.epoch_center_unix_s + np.arange(0.0, 86400.0, 3.7)
    err = np.linalg.norm(SatNodes(c2017).sat_ecef_m(t) - c2017.sat_ecef_m(t), axis=-1)
    assert np.nanmax(err) < 1e-3
    assert np.isfinite(err).all()


def test_a_batch_equals_its_epochs_one_by_one_to_the_bit(c2017):
    t = c2017.epoch_center_unix_s + 0.1 * np.arange(1500)  # 150 s at 10 Hz: three intervals
    batch = SatNodes(c2017).sat_ecef_m(t)
    # The live loop: one epoch at a time, its nodes cached from earlier epochs...
    live = SatNodes(c2017)
    one_by_one = np.stack([live.sat_ecef_m(t[i : i + 1])[0] for i in range(t.size)])
    np.testing.assert_array_equal(one_by_one, batch)
    # ... or made fresh for any epoch, and a batch split anywhere.
    np.testing.assert_array_equal(SatNodes(c2017).sat_ecef_m(t[777:778])[0], batch[777])
    again = np.concatenate([live.sat_ecef_m(t[:333]), live.sat_ecef_m(t[333:])])
    np.testing.assert_array_equal(again, batch)


def test_nodes_are_propagated_once_and_the_cache_is_bounded(monkeypatch):
    t0 = 1.49e9
    eph = Quintic(t0, t_end=np.inf)
    nodes = SatNodes(eph)
    t = t0 + np.arange(0.0, 600.0, 0.5)
    first = nodes.sat_ecef_m(t)
    calls = eph.calls
    np.testing.assert_array_equal(nodes.sat_ecef_m(t), first)
    assert eph.calls == calls  # every node was cached
    monkeypatch.setattr(satnodes, "MAX_CACHED_NODES", 8)
    small = SatNodes(eph)
    np.testing.assert_array_equal(np.concatenate([small.sat_ecef_m(t[i : i + 200])
                                                  for i in range(0, t.size, 200)]), first)
    assert len(small._nodes) <= 8 + len(satnodes.NODE_OFFSETS) + 1


def test_an_epoch_whose_nodes_are_partly_cached(c2017):
    # Two batches leave nodes cached around them with a gap between; an epoch whose six
    # nodes span both and the gap gets the numbers a fresh cache gives.
    t0 = np.floor(c2017.epoch_center_unix_s / NODE_STEP_S) * NODE_STEP_S
    nodes = SatNodes(c2017)
    nodes.sat_ecef_m(np.array([t0 + 10.0, t0 + 13 * NODE_STEP_S]))
    t = np.array([t0 + 5.5 * NODE_STEP_S])
    np.testing.assert_array_equal(nodes.sat_ecef_m(t), SatNodes(c2017).sat_ecef_m(t))
    assert np.isfinite(nodes.sat_ecef_m(t)).all()
