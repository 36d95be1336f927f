"""A receiver of several systems solves one clock per system (issue 23): closed-form cases of
the least squares and the DOP with inter-system clock offsets."""

from __future__ import annotations

import numpy as np
import pytest

from virtualgps.geodesy import azel_to_enu_unit
from virtualgps.receiver import errors
from virtualgps.receiver.solution import clock_columns, dop

# GPS 3, 9, 17, 22, 28 and GLONASS slots 2, 11, 20 (numbers 66, 75, 84)
PRN = np.array([3, 9, 17, 22, 28, 66, 75, 84])
AZ = np.array([10.0, 95.0, 180.0, 260.0, 320.0, 45.0, 140.0, 220.0])
EL = np.array([70.0, 35.0, 20.0, 50.0, 15.0, 60.0, 25.0, 40.0])
LOS = azel_to_enu_unit(AZ, EL)
GLO = PRN > 64


def test_one_clock_per_system_in_order_of_appearance_and_none_for_gps_alone():
    c = clock_columns(PRN)
    assert c.shape == (8, 2)
    assert (c[:, 0] == ~GLO).all() and (c[:, 1] == GLO).all()
    assert clock_columns(PRN[~GLO]) is None
    # SBAS ranges share GPS time: no clock of their own
    assert clock_columns(np.array([3, 9, 123])) is None


def test_an_offset_between_systems_is_absorbed_by_its_clock_and_moves_a_one_clock_fix():
    rng = np.random.default_rng(1)
    eps = rng.normal(0.0, 2.0, PRN.size)
    sigma = np.full(PRN.size, 2.0)
    used = np.ones(PRN.size, bool)
    clocks = clock_columns(PRN)
    offset = np.where(GLO, 30.0, 0.0)  # GLONASS time 100 ns off the receiver's GPS time
    e0 = errors.wls_fix(LOS, used, sigma, eps, clocks=clocks)[0]
    e1 = errors.wls_fix(LOS, used, sigma, eps + offset, clocks=clocks)[0]
    np.testing.assert_allclose(e1, e0, atol=1e-9)
    one = errors.wls_fix(LOS, used, sigma, eps + offset)[0]
    assert np.linalg.norm(one - e0) > 1.0


def test_a_system_with_one_satellite_adds_nothing_to_the_position():
    # its one range only fixes its own clock: the fix and the DOP are the other system's
    rng = np.random.default_rng(2)
    eps = rng.normal(0.0, 2.0, PRN.size)
    sigma = np.full(PRN.size, 1.5)
    gps = ~GLO
    one_glo = gps.copy()
    one_glo[5] = True
    clocks = clock_columns(PRN)
    e = errors.wls_fix(LOS, one_glo, sigma, eps, clocks=clocks)
    g = errors.wls_fix(LOS[gps], np.ones(5, bool), sigma[gps], eps[gps])
    np.testing.assert_allclose(e[0], g[0], atol=1e-9)
    np.testing.assert_allclose(e[1], g[1], atol=1e-9)
    np.testing.assert_allclose(dop(LOS, one_glo, clocks), dop(LOS[gps], np.ones(5, bool)),
                               atol=1e-12)
    # no GLONASS satellite used at all: its clock is left out, nothing else changes
    np.testing.assert_allclose(dop(LOS, gps, clocks), dop(LOS[gps], np.ones(5, bool)),
                               atol=1e-12)


def test_the_dop_of_two_clocks_is_that_of_the_larger_design_matrix():
    # (the closed form: Q = (G^T G)^-1 with G = [-los, one-hot system], Misra & Enge 6.1)
    used = np.ones(PRN.size, bool)
    c = clock_columns(PRN)
    g = np.concatenate([-LOS, c], axis=1)
    q = np.linalg.inv(g.T @ g)
    h, v, p = dop(LOS, used, c)
    assert h == pytest.approx(np.sqrt(q[0, 0] + q[1, 1]))
    assert v == pytest.approx(np.sqrt(q[2, 2]))
    assert p == pytest.approx(np.sqrt(np.trace(q[:3, :3])))
    # an extra unknown can only lose precision
    assert h >= dop(LOS, used)[0] and p >= dop(LOS, used)[2]


@pytest.mark.parametrize("n_gps, n_glo, fix", [(3, 2, "3d"), (4, 0, "3d"), (3, 1, "2d"),
                                               (2, 2, "2d"), (2, 1, "none"), (4, 1, "3d")])
def test_a_fix_needs_one_satellite_more_for_each_system_used(n_gps, n_glo, fix):
    from virtualgps.receiver.profiles import load_profile
    from virtualgps.receiver.solution import position_errors
    from virtualgps.receiver.state import draw_layout

    used = np.zeros((1, PRN.size), bool)
    used[0, :n_gps] = True
    used[0, 5:5 + n_glo] = True
    clocks = clock_columns(PRN)
    h = dop(LOS[None], used, clocks)[0]
    assert np.isfinite(h[0]) == (fix != "none")
    prof = load_profile("holux-m1000")
    from dataclasses import replace

    prof = replace(prof, correlated_error=replace(prof.correlated_error, enabled=False))
    sky = _sky(used.shape)
    layout = draw_layout(prof, PRN.size)
    z = np.random.default_rng(0).normal(size=(1, max(layout.values()) + PRN.size))
    err = position_errors(prof, sky, used, used.sum(axis=1), z, layout, {}, clocks)
    assert (bool(err.three_d[0]), bool(err.two_d[0])) == (fix == "3d", fix == "2d")


def _sky(shape):
    from virtualgps.receiver.skyview import Sky

    n_t, n_sat = shape
    full = lambda v: np.broadcast_to(v, (n_t, n_sat)).copy()  # noqa: E731
    return Sky(lat_deg=np.zeros(n_t), lon_deg=np.zeros(n_t), alt_hae_m=np.zeros(n_t),
               az_deg=full(AZ), el_deg=full(EL), los_enu=np.broadcast_to(LOS, (n_t, n_sat, 3)),
               above_mask=np.ones(shape, bool), blocked=np.zeros(shape, bool),
               nlos=np.zeros(shape, bool), excess_m=np.zeros(shape),
               nlos_loss_db=np.zeros(shape), foliage_db=np.zeros(shape),
               wall_dist_m=np.full(n_t, np.nan))
