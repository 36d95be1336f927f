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
    err = position_errors(prof, sky, used, used.sum(axis=1), z, layout, {}, PRN)
    assert (bool(err.three_d[0]), bool(err.two_d[0])) == (fix == "3d", fix == "2d")


def _two_systems(**constellations):
    from virtualgps.receiver.profiles import build_profile, load_profile_dict

    table, _ = load_profile_dict("holux-m1000")
    table["constellations"] = {"enabled": True, "systems": ["GPS", "GLONASS"], **constellations}
    table["correlated_error"] = {"enabled": False}
    return build_profile(table)


def test_each_system_has_its_signal_in_space_error():
    from virtualgps.receiver.solution import position_errors
    from virtualgps.receiver.state import draw_layout

    used = np.ones((1, PRN.size), bool)
    sky = _sky(used.shape)
    for prof, glo_factor in ((_two_systems(), 2.7), (_two_systems(sis_factor={"GLONASS": 1.5}),
                                                     1.5)):
        d = prof.dop_error
        layout = draw_layout(prof, PRN.size)
        z = np.zeros((1, max(layout.values()) + PRN.size))
        err = position_errors(prof, sky, used, used.sum(axis=1), z, layout, {}, PRN)
        sis = np.where(GLO, d.sis_m * glo_factor, d.sis_m)
        want = np.sqrt(sis**2 + (errors.iono_obliquity(EL) * d.iono_zenith_m) ** 2
                       + (errors.tropo_obliquity(EL) * d.tropo_zenith_m) ** 2 + d.rx_noise_m**2
                       + (d.multipath_a_m + d.multipath_b_m * np.exp(-EL / 10.0)) ** 2)
        np.testing.assert_allclose(err.uere_sigma_m[0], want, rtol=1e-12)
    # the GPS-only profile: GPS's sigma for every satellite, whatever their numbers
    from dataclasses import replace

    from virtualgps.receiver.profiles import load_profile

    plain = load_profile("holux-m1000")
    plain = replace(plain, correlated_error=replace(plain.correlated_error, enabled=False))
    err = position_errors(plain, sky, used, used.sum(axis=1), z, draw_layout(plain, PRN.size),
                          {}, PRN)
    assert np.ptp(err.uere_sigma_m[0] - errors.uere_sigma_m(EL, plain.dop_error.sis_m, 2.0,
                                                           0.2, 0.5, 0.13, 0.53)) < 1e-12


def test_a_per_system_table_overrides_the_defaults_system_by_system():
    prof = _two_systems(sis_factor={"GLONASS": 1.5})
    assert dict(prof.constellations.sis_factor) == {"GLONASS": 1.5, "Galileo": 2.3,
                                                    "BeiDou": 2.1, "QZSS": 0.86}


def test_each_system_has_its_signal_level():
    from virtualgps.receiver.core import tracked_cn0
    from virtualgps.receiver.state import ReceiverState

    prof = _two_systems(cn0_offset_db={"GLONASS": -2.5})
    off = prof.constellations.per_satellite(PRN, "cn0_offset_db", 0.0)
    np.testing.assert_array_equal(off, np.where(GLO, -2.5, 0.0))
    sky = _sky((1, PRN.size))
    fade = np.zeros((1, PRN.size))
    procs = {"fade": (fade, np.zeros(PRN.size))}
    state = ReceiverState()
    a = tracked_cn0(prof, sky, np.array([np.inf]), state, procs)[0]
    b = tracked_cn0(prof, sky, np.array([np.inf]), state, procs, off)[0]
    np.testing.assert_allclose((b - a)[np.isfinite(a) & np.isfinite(b)],
                               off[np.isfinite(a[0]) & np.isfinite(b[0])])


@pytest.mark.parametrize("table, key, message", [
    ({"sis_factor": {"Glonas": 2.0}}, "sis_factor", "unknown satellite system 'Glonas'"),
    ({"sis_factor": {"GLONASS": 0.0}}, "sis_factor", r"each factor must be in \(0, 100\]"),
    ({"sis_factor": [2.0]}, "sis_factor", "must be a table of numbers by name"),
    ({"cn0_offset_db": {"SBAS": 1.0}}, "cn0_offset_db", "SBAS is not a system tracked"),
])
def test_a_wrong_per_system_setting_names_its_key(table, key, message):
    from virtualgps.exceptions import ConfigError

    with pytest.raises(ConfigError, match=message) as e:
        _two_systems(**table)
    assert e.value.key == key


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
