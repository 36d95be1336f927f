"""The receiver core against closed forms: the paper's sigma(n), Box-Muller noise statistics,
DOP of a known geometry, the elevation mask, and batch == epoch-by-epoch."""

from __future__ import annotations

import numpy as np
import pytest

from virtualgps import geodesy
from virtualgps.profiles import load_profile
from virtualgps.receiver import (
    Georef,
    Receiver,
    ReceiverState,
    box_muller,
    dop,
    select_used,
    simulate,
    usarsim_sigma_m,
)

GEOREF = Georef(52.14, 11.64, 100.0)


class FixedSky:
    """Satellites fixed in the sky of GEOREF's origin at given az/el, 20,000 km away."""

    def __init__(self, az_deg, el_deg, prn=None):
        self.az_deg = np.asarray(az_deg, float)
        self.el_deg = np.asarray(el_deg, float)
        self.prn = np.asarray(prn if prn is not None else np.arange(1, len(self.az_deg) + 1))
        enu = geodesy.azel_to_enu_unit(self.az_deg, self.el_deg) * 20_000e3
        self.ecef = geodesy.enu_to_ecef(enu, GEOREF.lat0_deg, GEOREF.lon0_deg, GEOREF.alt0_hae_m)

    def sat_ecef_m(self, t_unix_s):
        t = np.atleast_1d(t_unix_s)
        return np.broadcast_to(self.ecef, (t.shape[0],) + self.ecef.shape).copy()


class WallOnAzimuth:
    """Blocks every ray whose azimuth lies in [az0, az1) -- a stand-in scene for the core."""

    def __init__(self, az0, az1):
        self.az0, self.az1 = az0, az1

    def blocked(self, origins_enu_m, dirs_enu, cls="occluder"):
        az, _, _ = geodesy.enu_to_azel(dirs_enu)
        blocks = cls in ("occluder", "solid")  # "solid": occluders and foliage together
        return (az >= self.az0) & (az < self.az1) if blocks else np.zeros(len(az), bool)


def test_sigma_equals_paper_equations():
    # max 8, min 2: n = 4 -> 8/3, n = 8 -> 5/3, n = 12 -> 2/3 m (issue #2's worked values).
    np.testing.assert_allclose(
        usarsim_sigma_m(np.array([4, 8, 12]), 8.0, 2.0), [8 / 3, 5 / 3, 2 / 3], rtol=1e-12
    )


def test_box_muller_gives_standard_normals():
    rng = np.random.default_rng(7)
    z0, z1 = box_muller(rng.random(200_000), rng.random(200_000))
    for z in (z0, z1):
        assert abs(z.mean()) < 0.01
        assert z.std() == pytest.approx(1.0, rel=0.01)
    assert abs(np.corrcoef(z0, z1)[0, 1]) < 0.01


def _run(profile, sky, n_t=1, scene=None, seed=1, pos=None):
    rx = Receiver(profile=profile, ephemeris=sky, scene=scene, georef=GEOREF)
    t = 1.49e9 + np.arange(n_t, dtype=float)
    enu = np.zeros((n_t, 3)) if pos is None else pos
    return simulate(
        rx,
        t,
        enu,
        np.zeros((n_t, 3)),
        np.ones(n_t, bool),
        ReceiverState(),
        np.random.default_rng(seed),
    )


@pytest.mark.parametrize("n_sats", [4, 8, 12])
def test_empirical_sigma_matches_equation_within_5_percent(n_sats):
    prof = load_profile("usarsim", {"noise": {"max_noise_m": 8.0, "min_noise_m": 2.0}})
    sky = FixedSky(np.linspace(0, 360, n_sats, endpoint=False), np.full(n_sats, 45.0))
    fixes, _ = _run(prof, sky, n_t=20_000)
    assert (fixes.sats_used == n_sats).all()
    # Errors in metres with the paper's own flat-earth scale (the profile's conversion).
    m_per_deg = 111_319.49
    north = (fixes.lat_deg - fixes.truth_lat_deg) * m_per_deg
    east = (fixes.lon_deg - fixes.truth_lon_deg) * m_per_deg * np.cos(np.radians(GEOREF.lat0_deg))
    expected = usarsim_sigma_m(n_sats, 8.0, 2.0)
    assert north.std() == pytest.approx(expected, rel=0.05)
    assert east.std() == pytest.approx(expected, rel=0.05)
    np.testing.assert_allclose(
        fixes.alt_msl_m + fixes.geoid_sep_m, fixes.truth_alt_hae_m, atol=1e-6
    )


def test_dop_zenith_plus_three_horizon_satellites():
    # Zenith + three satellites on the horizon 120 deg apart: HDOP = VDOP = 2/sqrt(3).
    los = geodesy.azel_to_enu_unit([0.0, 0.0, 120.0, 240.0], [90.0, 0.0, 0.0, 0.0])
    hdop, vdop, pdop = dop(los, np.ones(4, bool))
    assert hdop == pytest.approx(2 / np.sqrt(3), rel=1e-9)
    assert vdop == pytest.approx(2 / np.sqrt(3), rel=1e-9)
    assert pdop == pytest.approx(np.sqrt(8 / 3), rel=1e-9)


def test_dop_needs_four_satellites_and_ignores_unused():
    los = geodesy.azel_to_enu_unit([0.0, 0.0, 120.0, 240.0, 60.0], [90.0, 0.0, 0.0, 0.0, 30.0])
    hdop, _, _ = dop(los, np.array([True, True, True, False, False]))
    assert np.isnan(hdop)
    h_all, _, _ = dop(los[:4], np.ones(4, bool))
    h_masked, _, _ = dop(los, np.array([True, True, True, True, False]))
    assert h_masked == pytest.approx(h_all)


def test_mask_blocking_and_fix_rules():
    prof = load_profile("ideal")
    #            visible  below mask  blocked (az 100-140)  visible  visible
    sky = FixedSky([10, 200, 120, 250, 300], [60, 4.9, 30, 20, 45])
    fixes, _ = _run(prof, sky, scene=WallOnAzimuth(100, 140))
    tracked = ~np.isnan(fixes.cn0_dbhz[0])  # seen satellites carry an SNR
    assert list(tracked) == [True, False, False, True, True]
    assert fixes.quality[0] == 0  # three satellites: no fix, so none is "used"
    assert not fixes.used[0].any()
    assert np.isnan(fixes.lat_deg[0]) and np.isnan(fixes.hdop[0])
    assert fixes.in_view[0].all()  # GSV still lists everything above the horizon
    fixes, _ = _run(prof, sky)  # no scene: four satellites, a fix at the true position
    assert fixes.quality[0] == 1 and fixes.mode[0] == 3
    assert list(fixes.used[0]) == [True, False, True, True, True]
    assert fixes.lat_deg[0] == pytest.approx(GEOREF.lat0_deg, abs=1e-9)
    assert fixes.alt_msl_m[0] + fixes.geoid_sep_m[0] == pytest.approx(GEOREF.alt0_hae_m, abs=1e-6)


def test_select_used_keeps_the_highest_twelve():
    el = np.arange(14, dtype=float) * 5 + 10
    used = select_used(np.ones(14, bool), el, 12)
    assert used.sum() == 12 and not used[0] and not used[1]


def test_batch_equals_epoch_by_epoch():
    prof = load_profile("holux-m1000")
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    n_t = 5
    pos = np.cumsum(np.ones((n_t, 3)), axis=0)
    batch, end_state = _run(prof, sky, n_t=n_t, pos=pos, seed=3)
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    rng = np.random.default_rng(3)
    state = ReceiverState()
    t = 1.49e9 + np.arange(n_t, dtype=float)
    for i in range(n_t):
        one, state = simulate(
            rx, t[i : i + 1], pos[i : i + 1], np.zeros((1, 3)), np.ones(1, bool), state, rng
        )
        assert one.lat_deg[0] == batch.lat_deg[i] and one.lon_deg[0] == batch.lon_deg[i]
    assert state == end_state


def test_no_pose_gives_no_fix():
    prof = load_profile("holux-m1000")
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    fixes, _ = simulate(
        rx,
        np.array([1.49e9]),
        np.full((1, 3), np.nan),
        np.zeros((1, 3)),
        np.zeros(1, bool),
        ReceiverState(),
        np.random.default_rng(0),
    )
    assert fixes.quality[0] == 0 and fixes.used.sum() == 0 and np.isnan(fixes.lat_deg[0])


def test_restart_blocks_the_fix_for_a_ttff_whose_mean_is_the_parameter():
    from virtualgps.receiver import restart

    prof = load_profile("holux-m1000", {"cold_start": {"ttff_cold_s": 35.0, "ttff_hot_s": 1.0}})
    rng = np.random.default_rng(11)
    ttff = np.array([restart(ReceiverState(), "cold", 0.0, prof, rng).no_fix_until_t_unix_s
                     for _ in range(4000)])
    assert ttff.mean() == pytest.approx(35.0, rel=0.05)
    assert ttff.std() == pytest.approx(35.0 * prof.cold_start.ttff_sd_frac, rel=0.1)
    # No fix before the TTFF, fixes after it.
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    t = 1.49e9 + np.arange(60.0)
    state = restart(ReceiverState(), "cold", t[0], prof, np.random.default_rng(1))
    fixes, _ = simulate(rx, t, np.zeros((60, 3)), np.zeros((60, 3)), np.ones(60, bool), state,
                        np.random.default_rng(0))
    has_fix = fixes.quality > 0
    assert (has_fix == (t >= state.no_fix_until_t_unix_s)).all() and has_fix.any()


def _enu_errors(fixes):
    """Reported minus true position, metres ENU (WGS-84 profiles)."""
    truth = geodesy.geodetic_to_ecef(fixes.truth_lat_deg, fixes.truth_lon_deg,
                                     fixes.truth_alt_hae_m)
    rep = geodesy.geodetic_to_ecef(fixes.lat_deg, fixes.lon_deg,
                                   fixes.alt_msl_m + fixes.geoid_sep_m)
    return geodesy.ecef_to_enu(rep, GEOREF.lat0_deg, GEOREF.lon0_deg, GEOREF.alt0_hae_m) - \
        geodesy.ecef_to_enu(truth, GEOREF.lat0_deg, GEOREF.lon0_deg, GEOREF.alt0_hae_m)


UNIT_UERE = {"sis_m": 1.0, "iono_zenith_m": 0.0, "tropo_zenith_m": 0.0, "rx_noise_m": 0.0,
             "multipath_a_m": 0.0, "multipath_b_m": 0.0}


def test_dop_error_covariance_scales_with_the_dop():
    """Equal unit range errors: the position error covariance is sigma^2 (G^T G)^-1."""
    prof = load_profile("ideal", {"dop_error": {"enabled": True, **UNIT_UERE},
                                  "sky": {"elevation_mask_deg": -1.0}})
    sky = FixedSky([0.0, 0.0, 120.0, 240.0], [90.0, 0.0, 0.0, 0.0])
    fixes, _ = _run(prof, sky, n_t=20_000, seed=2)
    err = _enu_errors(fixes)
    assert fixes.hdop[0] == pytest.approx(2 / np.sqrt(3), rel=1e-6)
    assert fixes.vdop[0] == pytest.approx(2 / np.sqrt(3), rel=1e-6)
    # Q = diag(2/3, 2/3, 4/3 ... ) for this geometry: east/north sigma sqrt(2/3), up 2/sqrt(3).
    assert err[:, 0].std() == pytest.approx(np.sqrt(2 / 3), rel=0.03)
    assert err[:, 1].std() == pytest.approx(np.sqrt(2 / 3), rel=0.03)
    assert err[:, 2].std() == pytest.approx(2 / np.sqrt(3), rel=0.03)
    # Doubling the range errors doubles the position errors: the scale is the UERE times DOP.
    prof2 = load_profile("ideal", {"dop_error": {"enabled": True, **UNIT_UERE, "sis_m": 2.0},
                                   "sky": {"elevation_mask_deg": -1.0}})
    fixes2, _ = _run(prof2, sky, n_t=20_000, seed=2)
    np.testing.assert_allclose(_enu_errors(fixes2), 2 * err, atol=1e-5)


def test_dop_error_off_is_the_ideal_receiver():
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    on, _ = _run(load_profile("ideal", {"dop_error": {"enabled": True}}), sky, n_t=50)
    off, _ = _run(load_profile("ideal"), sky, n_t=50)
    assert np.abs(_enu_errors(off)).max() < 1e-6
    assert np.abs(_enu_errors(on)).max() > 0.1
    np.testing.assert_array_equal(on.used, off.used)
    np.testing.assert_array_equal(on.hdop, off.hdop)


def test_two_d_fix_with_three_satellites_holds_the_last_altitude():
    prof = load_profile("ideal", {"dop_error": {"enabled": True}})
    four = FixedSky([0.0, 90.0, 200.0, 300.0], [70.0, 30.0, 40.0, 20.0])
    rx = Receiver(profile=prof, ephemeris=four, scene=None, georef=GEOREF)
    t = 1.49e9 + np.arange(6.0)
    # Epochs 3-5 lose the fourth satellite behind a wall (az 300).
    fixes, state = simulate(rx, t[:3], np.zeros((3, 3)), np.zeros((3, 3)), np.ones(3, bool),
                            ReceiverState(), np.random.default_rng(0))
    rx_wall = Receiver(profile=prof, ephemeris=four, scene=WallOnAzimuth(290, 310), georef=GEOREF)
    fixes2, _ = simulate(rx_wall, t[3:], np.zeros((3, 3)), np.zeros((3, 3)), np.ones(3, bool),
                         state, np.random.default_rng(1))
    assert (fixes.mode == 3).all() and (fixes2.mode == 2).all() and (fixes2.quality == 1).all()
    held_hae = fixes2.alt_msl_m + fixes2.geoid_sep_m
    np.testing.assert_allclose(held_hae, fixes.alt_msl_m[-1] + fixes.geoid_sep_m[-1], atol=1e-9)
    assert (fixes2.sats_used == 3).all()
    # Without a 3D fix before, 3 satellites give no fix.
    cold, _ = simulate(rx_wall, t[3:], np.zeros((3, 3)), np.zeros((3, 3)), np.ones(3, bool),
                       ReceiverState(), np.random.default_rng(1))
    assert (cold.quality == 0).all()


@pytest.mark.parametrize("domain", ["position", "range"])
def test_correlated_error_autocorrelation_is_1_over_e_at_tau(domain):
    """A long seeded run: the error's autocorrelation at lag tau is e^-1 within 10 %."""
    tau = 20.0
    over = {"correlated_error": {"enabled": True, "domain": domain, "tau_s": tau, "sigma_m": 2.0}}
    if domain == "range":  # only the Gauss-Markov range errors (no white receiver noise)
        over["dop_error"] = {"enabled": True, **UNIT_UERE}
    prof = load_profile("ideal", over)
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    rng = np.random.default_rng(5)
    state = ReceiverState()
    errs = []
    chunk, n = 50_000, 200_000
    for a in range(0, n, chunk):  # in chunks: the state carries the process across calls
        t = 1.49e9 + np.arange(a, a + chunk, dtype=float)
        fixes, state = simulate(rx, t, np.zeros((chunk, 3)), np.zeros((chunk, 3)),
                                np.ones(chunk, bool), state, rng)
        errs.append(_enu_errors(fixes))
    err = np.concatenate(errs)
    lag = int(tau)
    for axis in (0, 1, 2):
        x = err[:, axis] - err[:, axis].mean()
        rho = np.dot(x[:-lag], x[lag:]) / np.dot(x, x)
        assert rho == pytest.approx(np.exp(-1.0), rel=0.10), (axis, rho)
    if domain == "position":
        assert err[:, 0].std() == pytest.approx(2.0, rel=0.05)
        assert err[:, 2].std() == pytest.approx(3.0, rel=0.05)  # up_ratio 1.5


def test_effects_keep_batch_equal_to_epoch_by_epoch():
    prof = load_profile("ideal", {"dop_error": {"enabled": True},
                                  "correlated_error": {"enabled": True, "domain": "range"}})
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    batch, _ = _run(prof, sky, n_t=12, seed=9)
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    rng, state = np.random.default_rng(9), ReceiverState()
    for i in range(12):
        one, state = simulate(rx, 1.49e9 + np.array([float(i)]), np.zeros((1, 3)),
                              np.zeros((1, 3)), np.ones(1, bool), state, rng)
        assert one.lat_deg[0] == pytest.approx(batch.lat_deg[i], abs=1e-12)
        assert one.alt_msl_m[0] == pytest.approx(batch.alt_msl_m[i], abs=1e-9)


def _walk(prof, vel_east_mps, n=30, seed=0):
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    t = 1.49e9 + np.arange(float(n))
    v = np.zeros((n, 3))
    v[:, 0] = vel_east_mps
    pos = np.cumsum(v, axis=0) - v  # x = v t
    fixes, _ = simulate(rx, t, pos, v, np.ones(n, bool), ReceiverState(),
                        np.random.default_rng(seed))
    return fixes, _enu_errors(fixes)


def test_latency_reports_where_the_antenna_was():
    fixes, err = _walk(load_profile("ideal", {"latency": {"enabled": True, "latency_s": 0.3}}), 2.0)
    np.testing.assert_allclose(err[:, 0], -0.6, atol=1e-5)
    np.testing.assert_allclose(err[:, 1:], 0.0, atol=1e-5)


def test_nav_filter_lags_a_moving_antenna_by_the_first_order_steady_state():
    tau = 2.0
    _, err = _walk(load_profile("ideal", {"nav_filter": {"enabled": True, "tau_s": tau}}), 1.5)
    alpha = 1 - np.exp(-1.0 / tau)
    # A first-order low-pass following a ramp of v per step lags v (1 - alpha) / alpha.
    assert err[-1, 0] == pytest.approx(-1.5 * (1 - alpha) / alpha, abs=1e-4)
    assert err[0, 0] == pytest.approx(0.0, abs=1e-6)  # starts on the first solution
    _, err0 = _walk(load_profile("ideal", {"nav_filter": {"enabled": True, "tau_s": tau}}), 0.0)
    np.testing.assert_allclose(err0, 0.0, atol=1e-5)  # no lag at rest


def test_static_hold_freezes_the_output_below_the_threshold():
    over = {"dop_error": {"enabled": True}, "static_hold": {"enabled": True,
                                                           "threshold_mps": 0.4}}
    slow, _ = _walk(load_profile("ideal", over), 0.1)
    # Held to 0.1 mm (the output is converted by first-order offsets from the moving truth).
    assert np.ptp(slow.lat_deg) < 1e-9 and np.ptp(slow.lon_deg) < 1e-9
    fast, _ = _walk(load_profile("ideal", over), 1.0)
    assert np.ptp(fast.lon_deg) > 1e-6
    free, _ = _walk(load_profile("ideal", {"dop_error": {"enabled": True}}), 0.1)
    assert np.ptp(free.lat_deg) > 1e-6  # the same noise moves the fix without the hold


def test_sbas_gives_quality_2_and_smaller_errors():
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    base = {"dop_error": {"enabled": True, "sis_m": 1.0, "iono_zenith_m": 2.0,
                          "tropo_zenith_m": 0.0, "rx_noise_m": 0.0, "multipath_a_m": 0.0,
                          "multipath_b_m": 0.0}}
    plain, _ = _run(load_profile("ideal", base), sky, n_t=4000, seed=3)
    sbas, _ = _run(load_profile("ideal", {**base, "sbas": {"enabled": True, "sis_factor": 0.5,
                                                           "iono_factor": 0.5}}), sky,
                   n_t=4000, seed=3)
    assert (plain.quality == 1).all() and (sbas.quality == 2).all()
    # Every UERE term halves, so (same seed, same geometry) every error halves exactly.
    # (to 0.1 mm: metres become degrees by a first-order offset, good to d^2 / R)
    np.testing.assert_allclose(_enu_errors(sbas), 0.5 * _enu_errors(plain), atol=1e-4)


def test_reported_sigma_matches_the_error_scatter_and_reaches_gst():
    from pynmeagps import NMEAReader

    from virtualgps import nmea

    prof = load_profile("ideal", {"dop_error": {"enabled": True}})
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    fixes, _ = _run(prof, sky, n_t=20_000, seed=4)
    err = _enu_errors(fixes)
    np.testing.assert_allclose(err.std(axis=0), fixes.sigma_enu_m[0], rtol=0.05)
    np.testing.assert_allclose(fixes.sigma_enu_m, fixes.sigma_enu_m[:1].repeat(20_000, 0))
    fmt = nmea.NmeaFormat.from_dict({"sentences": ["GGA", "GST"]})
    text = nmea.epoch_sentences(fixes, 0, fmt).split(b"\r\n")
    gst = NMEAReader.parse(text[1] + b"\r\n", validate=1)
    assert gst.msgID == "GST"
    assert float(gst.stdLat) == pytest.approx(fixes.sigma_enu_m[0, 1], abs=0.051)
    assert float(gst.stdLong) == pytest.approx(fixes.sigma_enu_m[0, 0], abs=0.051)
    assert float(gst.stdAlt) == pytest.approx(fixes.sigma_enu_m[0, 2], abs=0.051)
    # The paper's model reports its sigma(n) horizontally and nothing vertically.
    us, _ = _run(load_profile("usarsim"), sky, n_t=3)
    np.testing.assert_allclose(us.sigma_enu_m[:, :2], usarsim_sigma_m(7, 8.0, 2.0))
    assert np.isnan(us.sigma_enu_m[:, 2]).all()


def test_cold_start_satellites_become_usable_one_by_one_and_the_error_converges():
    from virtualgps.receiver import restart

    prof = load_profile("ideal", {"cold_start": {"ttff_cold_s": 10.0, "ttff_sd_frac": 0.0,
                                                 "decode_spread_s": 20.0,
                                                 "converge_sigma_m": 30.0,
                                                 "converge_tau_s": 5.0}})
    sky = FixedSky(np.linspace(0, 330, 12), np.linspace(15, 85, 12))
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    t = 1.49e9 + np.arange(60.0)
    state = restart(ReceiverState(), "cold", t[0], prof, np.random.default_rng(2), n_sat=12)
    fixes, _ = simulate(rx, t, np.zeros((60, 3)), np.zeros((60, 3)), np.ones(60, bool), state,
                        np.random.default_rng(0))
    n = fixes.sats_used
    assert (n[:10] == 0).all() and n[10] == 4  # first fix at the TTFF with four satellites
    assert (np.diff(n[10:]) >= 0).all() and n[31:].min() == 12  # all decoded within 20 s
    err = np.linalg.norm(_enu_errors(fixes)[10:], axis=1)
    bias = np.linalg.norm(state.start_bias_enu_m)
    np.testing.assert_allclose(err, bias * np.exp(-np.arange(50) / 5.0), atol=1e-4)
    # A hot start keeps its ephemerides: every satellite and no start-up error at the fix.
    hot = restart(ReceiverState(), "hot", t[0], prof, np.random.default_rng(2), n_sat=12)
    fixes, _ = simulate(rx, t[:5], np.zeros((5, 3)), np.zeros((5, 3)), np.ones(5, bool), hot,
                        np.random.default_rng(0))
    assert fixes.sats_used[fixes.quality > 0].min() == 12
