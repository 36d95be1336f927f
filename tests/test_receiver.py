"""The receiver core against closed forms: the paper's sigma(n), Box-Muller noise statistics,
DOP of a known geometry, the elevation mask, and batch == epoch-by-epoch."""

from __future__ import annotations

import numpy as np
import pynmeagps
import pytest

from virtualgps import geodesy
from virtualgps.device import nmea
from virtualgps.receiver.core import simulate
from virtualgps.receiver.definition import Georef, Receiver
from virtualgps.receiver.profiles import SettingError, load_profile
from virtualgps.receiver.solution import dop, select_used, usarsim_sigma_m
from virtualgps.receiver.state import ReceiverRows, ReceiverState

GEOREF = Georef(52.14, 11.64, 100.0)


class FixedSky:
    """Satellites fixed in the sky of a georeference's origin (GEOREF unless given) at given
    az/el, 20,000 km away."""

    def __init__(self, az_deg, el_deg, prn=None, georef=GEOREF):
        self.az_deg = np.asarray(az_deg, float)
        self.el_deg = np.asarray(el_deg, float)
        self.prn = np.asarray(prn if prn is not None else np.arange(1, len(self.az_deg) + 1))
        enu = geodesy.azel_to_enu_unit(self.az_deg, self.el_deg) * 20_000e3
        self.ecef = geodesy.enu_to_ecef(enu, georef.lat0_deg, georef.lon0_deg,
                                        georef.alt0_hae_m)

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


def test_normals_from_uniforms_are_standard_normals():
    from virtualgps.receiver.errors import normals_from_uniforms

    rng = np.random.default_rng(7)
    z = normals_from_uniforms(rng.random((100_000, 4)))
    z0, z1 = z[:, 0::2].ravel(), z[:, 1::2].ravel()  # each pair's two deviates
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


def test_dop_needs_three_satellites_and_ignores_unused():
    los = geodesy.azel_to_enu_unit([0.0, 0.0, 120.0, 240.0, 60.0], [90.0, 0.0, 0.0, 0.0, 30.0])
    hdop, _, _ = dop(los, np.array([True, True, False, False, False]))
    assert np.isnan(hdop)
    h_all, _, _ = dop(los[:4], np.ones(4, bool))
    h_masked, _, _ = dop(los, np.array([True, True, True, True, False]))
    assert h_masked == pytest.approx(h_all)


def test_dop_of_a_2d_fix_three_horizon_satellites():
    """Three satellites on the horizon 120 deg apart plus the held height's row [0, 0, 1, 0]:
    rows [-sin az, -cos az, 0, 1] give G^T G = diag(3/2, 3/2, 1, 3) (the sums of sin az, cos az
    and sin az cos az vanish), so Q = diag(2/3, 2/3, 1, 1/3): HDOP = sqrt(4/3) (the 3-state
    east/north/clock value, as no satellite sees the height), VDOP = 1, PDOP = sqrt(7/3)."""
    los = geodesy.azel_to_enu_unit([0.0, 120.0, 240.0, 60.0], [0.0, 0.0, 0.0, 30.0])
    hdop, vdop, pdop = dop(los, np.array([True, True, True, False]))
    assert hdop == pytest.approx(np.sqrt(4 / 3), rel=1e-9)
    assert vdop == pytest.approx(1.0, rel=1e-9)
    assert pdop == pytest.approx(np.sqrt(7 / 3), rel=1e-9)


def test_dop_of_a_2d_fix_is_what_mtk_firmware_prints():
    """gpsd-mtk/mtk-3301.log:72-73, an MT3301 in a 2D fix: ``$GPGSA,A,2,21,28,08,...,3.05,2.88,
    1.00`` with GSV ``08,63,065 28,42,144 21,13,320`` (el, az in whole degrees)."""
    los = geodesy.azel_to_enu_unit([65.0, 144.0, 320.0], [63.0, 42.0, 13.0])
    hdop, vdop, pdop = dop(los, np.ones(3, bool))
    assert f"{pdop:.2f},{hdop:.2f},{vdop:.2f}" == "3.05,2.88,1.00"
    # vectorised: a batch of 2, 3 and 4 used satellites equals the epochs one by one
    los5 = geodesy.azel_to_enu_unit([65.0, 144.0, 320.0, 200.0, 10.0], [63.0, 42.0, 13.0, 30, 5])
    used = np.array([[1, 1, 0, 0, 0], [1, 1, 1, 0, 0], [1, 1, 1, 1, 0]], bool)
    batch = np.stack(dop(np.broadcast_to(los5, (3, 5, 3)), used))
    one = np.array([dop(los5, u) for u in used]).T
    np.testing.assert_array_equal(batch, one)
    assert np.isnan(batch[:, 0]).all() and np.isfinite(batch[:, 1:]).all()


def test_dop_is_the_inverse_of_the_normal_matrix_at_any_geometry():
    """The closed form (a Schur complement and cofactors) against numpy's inverse of G^T G,
    built epoch by epoch, over random skies of one and of two systems, 3D and 2D fixes."""
    from virtualgps.receiver.solution import clock_columns

    rng = np.random.default_rng(7)
    n, k = 400, 12
    los = geodesy.azel_to_enu_unit(rng.uniform(0, 360, (n, k)), rng.uniform(5, 90, (n, k)))
    used = rng.uniform(size=(n, k)) < 0.6
    used[:40] = False
    used[:40, :3] = True  # 2D fixes (one clock)
    prn = np.array([1, 2, 3, 4, 5, 6, 66, 67, 68, 69, 70, 71])  # GPS, then GLONASS
    for clocks in (None, clock_columns(prn)):
        h, v, p = dop(los, used, clocks)
        for i in range(n):
            u = used[i]
            cl = np.ones((k, 1)) if clocks is None else clocks[:, (clocks[u] > 0).any(axis=0)]
            g = np.concatenate([-los[i][u], cl[u]], axis=1)
            if u.sum() == 2 + cl.shape[1]:  # the held height's row
                g = np.vstack([g, np.r_[0.0, 0.0, 1.0, np.zeros(cl.shape[1])]])
            if u.sum() < 2 + cl.shape[1]:
                assert np.isnan(h[i])
                continue
            q = np.linalg.inv(g.T @ g)
            assert h[i] == pytest.approx(np.sqrt(q[0, 0] + q[1, 1]), rel=1e-9)
            assert v[i] == pytest.approx(np.sqrt(q[2, 2]), rel=1e-9)
            assert p[i] == pytest.approx(np.sqrt(np.trace(q[:3, :3])), rel=1e-9)


def test_dop_of_a_singular_geometry_is_nan():
    # every satellite at one elevation: the height and the clock cannot be told apart
    los = geodesy.azel_to_enu_unit([0.0, 90.0, 180.0, 270.0, 45.0], [30.0] * 5)
    assert np.isnan(dop(los, np.ones(5, bool))).all()


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


def test_a_pdop_mask_refuses_a_fix_over_a_geometry_worse_than_it():
    """Four satellites at 30 deg elevation, one of them 2 deg higher: up and the clock are
    nearly one unknown (PDOP 46.96 in closed form, :func:`dop`). Without a mask (the default,
    MTK's) the fix is made; a mask under that PDOP (u-blox's 25) refuses it, one over it keeps
    it, and a mask never touches a good geometry."""
    az, el = [0.0, 120.0, 240.0, 60.0], [30.0, 30.0, 30.0, 32.0]
    want = dop(geodesy.azel_to_enu_unit(az, el), np.ones(4, bool))[2]
    assert 46.0 < want < 48.0
    flat = FixedSky(az, el)
    fixes, _ = _run(load_profile("ideal"), flat)
    assert fixes.quality[0] == 1 and fixes.pdop[0] == pytest.approx(want, rel=1e-6)
    for mask, has_fix in ((25.0, False), (want * 0.99, False), (want * 1.01, True)):
        fixes, _ = _run(load_profile("ideal", {"sky": {"pdop_mask": mask}}), flat)
        assert bool(fixes.quality[0] == 1) is has_fix, mask
        assert bool(np.isfinite(fixes.lat_deg[0])) is has_fix
        assert bool(fixes.used[0].any()) is has_fix
        assert fixes.in_view[0].all()  # GSV still lists what is tracked
    good = FixedSky([0.0, 0.0, 120.0, 240.0], [90.0, 10.0, 10.0, 10.0])  # PDOP 1.82
    fixes, _ = _run(load_profile("ideal", {"sky": {"pdop_mask": 25.0}}), good)
    assert fixes.quality[0] == 1 and fixes.pdop[0] < 25.0
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(SettingError, match="pdop_mask"):
            load_profile("ideal", {"sky": {"pdop_mask": bad}})


def test_satellites_below_the_mask_are_ray_cast_too():
    """A receiver tracks satellites below its mask (GSV lists them with an SNR); one behind a
    building is not received, whatever its elevation."""
    prof = load_profile("ideal", {"cn0_tracking": {"enabled": True, "cn0_zenith_dbhz": 45.0,
                                                   "horizon_loss_db": 5.0}})
    #                  2 deg behind the wall (az 100-140), 2 deg clear, and three high ones
    sky = FixedSky([120, 200, 10, 250, 300], [2.0, 2.0, 60, 40, 45])
    walled, _ = _run(prof, sky, n_t=30, scene=WallOnAzimuth(100, 140))
    assert prof.sky.elevation_mask_deg > 2.0
    assert np.isnan(walled.cn0_dbhz[:, 0]).all()  # behind the wall: never an SNR
    assert np.isfinite(walled.cn0_dbhz[:, 1]).any()  # the clear one at 2 deg is tracked
    assert not walled.used[:, :2].any()  # (neither is used: below the mask)
    open_sky, _ = _run(prof, sky, n_t=30)
    assert np.isfinite(open_sky.cn0_dbhz[:, 0]).any()  # without the wall it is tracked


def test_select_used_keeps_the_highest_twelve():
    el = np.arange(14, dtype=float) * 5 + 10
    used = select_used(np.ones(14, bool), el, 12)
    assert used.sum() == 12 and not used[0] and not used[1]


def test_batch_equals_epoch_by_epoch():
    prof = load_profile("holux-m1000")
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    n_t = 12
    pos = np.cumsum(np.ones((n_t, 3)), axis=0)
    batch, end_state = _run(prof, sky, n_t=n_t, pos=pos, seed=3)
    assert (batch.quality > 0).sum() >= n_t // 2  # (tracking first acquires the satellites)
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    rng = np.random.default_rng(3)
    state = ReceiverState()
    t = 1.49e9 + np.arange(n_t, dtype=float)
    for i in range(n_t):
        one, state = simulate(
            rx, t[i : i + 1], pos[i : i + 1], np.zeros((1, 3)), np.ones(1, bool), state, rng
        )
        for name in ("lat_deg", "lon_deg", "alt_msl_m", "cn0_dbhz", "used", "hdop"):
            np.testing.assert_array_equal(getattr(one, name)[0], getattr(batch, name)[i])
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
    from virtualgps.receiver.state import restart

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


def test_two_d_fix_with_three_satellites_holds_the_last_altitude_and_reports_dops():
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
    # GGA and GSA carry the 2D fix's DOPs (see test_dop_of_a_2d_fix_*)
    want = dop(geodesy.azel_to_enu_unit([0.0, 90.0, 200.0], [70.0, 30.0, 40.0]), np.ones(3, bool))
    got = np.stack([fixes2.hdop, fixes2.vdop, fixes2.pdop], axis=-1)
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=1e-6)
    msgs = {}
    for line in nmea.epoch_sentences(fixes2, 0, nmea.NmeaFormat()).decode().splitlines():
        m = pynmeagps.NMEAReader.parse(line, validate=pynmeagps.VALCKSUM, msgmode=pynmeagps.GET)
        msgs[m.msgID] = m
    gga, gsa = msgs["GGA"], msgs["GSA"]
    assert gga.quality == 1 and gga.HDOP == pytest.approx(want[0], abs=0.005)
    assert gsa.navMode == 2 and gsa.HDOP == pytest.approx(want[0], abs=0.005)
    assert gsa.VDOP == 1.0  # printed 1.00, as MTK firmware prints it
    assert gsa.PDOP == pytest.approx(want[2], abs=0.005)
    # GST carries the 2D fix's own sigmas (issue #9: ROS turns empty ones into NaN covariances)
    assert np.isfinite(fixes2.sigma_enu_m).all()
    fmt = nmea.NmeaFormat.from_dict({"sentences": ["GGA", "GST"]})
    for line in nmea.epoch_sentences(fixes2, 0, fmt).decode().splitlines()[1::2]:
        gst = pynmeagps.NMEAReader.parse(line, validate=pynmeagps.VALCKSUM)
        assert gst.msgID == "GST" and min(gst.stdLat, gst.stdLong, gst.stdAlt) > 0
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


@pytest.mark.parametrize("extra", [
    {"correlated_error": {"enabled": True, "domain": "range"}},
    {"multipath": {"enabled": True, "open_sky_factor": 1.0}},
])
def test_switching_one_effect_leaves_the_others_random_numbers_alone(extra):
    """Common random numbers: a profile with one more effect, run with the same seed, draws
    every other model's numbers as before (the gap tool's fits compare such profiles; one
    shared row of uniforms reshuffled all of them when a model's columns joined it)."""
    base = {"dop_error": {"enabled": True}, "cn0_tracking": {"enabled": True}}
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    ref, _ = _run(load_profile("ideal", base), sky, n_t=60, seed=4)
    more, _ = _run(load_profile("ideal", {**base, **extra}), sky, n_t=60, seed=4)
    assert np.isfinite(ref.cn0_dbhz).sum() > 100
    np.testing.assert_array_equal(more.cn0_dbhz, ref.cn0_dbhz)  # the same fades
    np.testing.assert_array_equal(more.used, ref.used)
    assert not np.array_equal(more.lat_deg, ref.lat_deg)  # and the effect itself acts


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


def test_latency_keeps_the_fix_on_the_path_of_a_turn_and_runs_epoch_by_epoch_alike():
    """A delay puts the fix where the antenna was, on its path: circling at 10 m/s on 50 m
    (2 m/s^2), 2.5 s late, the fix stays within 0.3 m of the circle (the chords between 1 Hz
    poses sag 0.25 m; to first order in the velocity alone it ran 6.2 m outside), 25 m back
    along it, and after a gap in the poses too (on the chord across it before). Epochs whose
    t - L precedes the first pose are moved back along their velocity. One epoch at a time,
    alone or as a row of receivers side by side, gives the same fixes."""
    radius, speed, lat_s, n = 50.0, 10.0, 2.5, 40
    prof = load_profile("ideal", {"latency": {"enabled": True, "latency_s": lat_s}})
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    t = 1.49e9 + np.arange(float(n))
    w = speed / radius
    ang = w * np.arange(float(n))
    pos = np.stack([radius * np.cos(ang), radius * np.sin(ang), 0 * ang], 1)
    vel = np.stack([-speed * np.sin(ang), speed * np.cos(ang), 0 * ang], 1)
    valid = np.ones(n, bool)
    valid[20] = False
    batch, _ = simulate(rx, t, pos, vel, valid, ReceiverState(), np.random.default_rng(3))
    fix = pos + _enu_errors(batch)
    off_path = np.abs(np.hypot(fix[:, 0], fix[:, 1]) - radius)
    known = valid & (t - lat_s >= t[0])
    across = (t - lat_s > t[19]) & (t - lat_s < t[21])  # on the chord over the missing pose
    assert known[21] and off_path[known & ~across].max() < 0.3
    assert off_path[known & across].max() < radius * (1 - np.cos(w))  # its sag
    assert off_path[0] == pytest.approx(radius * (np.hypot(1.0, w * lat_s) - 1.0), abs=1e-3)
    back = np.hypot(*(fix - pos)[known, :2].T)
    np.testing.assert_allclose(back, 2 * radius * np.sin(w * lat_s / 2), rtol=0.02)
    state, rng = ReceiverState(), np.random.default_rng(3)
    rows = ReceiverRows.stack([ReceiverState()], [np.random.default_rng(3)], prof, 7)
    for i in range(n):
        one, state = simulate(rx, t[i:i + 1], pos[i:i + 1], vel[i:i + 1], valid[i:i + 1],
                              state, rng)
        row, rows = simulate(rx, t[i:i + 1], pos[i:i + 1], vel[i:i + 1], valid[i:i + 1],
                             rows, rng)
        if valid[i]:
            for got in (one, row):
                assert got.lat_deg[0] == pytest.approx(batch.lat_deg[i], abs=1e-12)
                assert got.lon_deg[0] == pytest.approx(batch.lon_deg[i], abs=1e-12)


def test_nav_filter_lags_a_moving_antenna_by_the_first_order_steady_state():
    tau = 2.0
    _, err = _walk(load_profile("ideal", {"nav_filter": {"enabled": True, "tau_s": tau}}), 1.5)
    alpha = 1 - np.exp(-1.0 / tau)
    # A first-order low-pass following a ramp of v per step lags v (1 - alpha) / alpha.
    assert err[-1, 0] == pytest.approx(-1.5 * (1 - alpha) / alpha, abs=1e-4)
    assert err[0, 0] == pytest.approx(0.0, abs=1e-6)  # starts on the first solution
    _, err0 = _walk(load_profile("ideal", {"nav_filter": {"enabled": True, "tau_s": tau}}), 0.0)
    np.testing.assert_allclose(err0, 0.0, atol=1e-5)  # no lag at rest


def test_a_velocity_aided_nav_filter_smooths_the_error_and_follows_the_motion():
    """Aided by its own velocity the filter follows a moving antenna without lag, and what it
    low-passes is the solution's error: the same errors as without it, filtered (its first
    fix on the first solution), however fast the antenna moves."""
    tau = 2.0
    aided = {"nav_filter": {"enabled": True, "tau_s": tau, "velocity_aided": True}}
    _, err = _walk(load_profile("ideal", aided), 1.5)
    np.testing.assert_allclose(err, 0.0, atol=1e-5)  # no lag (unaided: 2.3 m)
    noisy = {"dop_error": {"enabled": True}}
    _, raw = _walk(load_profile("ideal", noisy), 1.5, n=60, seed=2)
    for speed in (0.0, 1.5, 20.0):
        _, smooth = _walk(load_profile("ideal", {**noisy, **aided}), speed, n=60, seed=2)
        want = raw.copy()
        a = 1 - np.exp(-1.0 / tau)
        for k in range(1, want.shape[0]):
            want[k] = want[k - 1] + a * (raw[k] - want[k - 1])
        np.testing.assert_allclose(smooth[:, :2], want[:, :2], atol=2e-3)
    steps = np.hypot(*np.diff(smooth[:, :2], axis=0).T)
    assert np.median(steps) < 0.5 * np.median(np.hypot(*np.diff(raw[:, :2], axis=0).T))


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


def test_two_d_sigmas_with_equal_weights_are_the_2d_dops():
    """The held height as a measurement weighted like a range: with equal range sigmas the
    sigmas are sigma x the 2D DOPs MTK firmware prints (HDOP horizontally, VDOP = 1)."""
    from virtualgps.receiver.errors import wls_fix

    los = geodesy.azel_to_enu_unit([0.0, 90.0, 200.0], [70.0, 30.0, 40.0])
    used = np.ones(3, bool)
    sig = wls_fix(los, used, np.full(3, 2.5), np.zeros(3), held_height=True)[1]
    hdop, vdop, _ = dop(los, used)
    assert np.hypot(sig[0], sig[1]) == pytest.approx(2.5 * hdop, rel=1e-9)
    assert sig[2] == pytest.approx(2.5 * vdop, rel=1e-9)


def test_reported_sigma_matches_the_error_scatter_and_reaches_gst():
    from pynmeagps import NMEAReader

    from virtualgps.device import nmea

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


@pytest.mark.parametrize("extra", [
    {"correlated_error": {"enabled": True, "domain": "range", "tau_s": 3.0, "sigma_m": 3.5}},
    {"multipath": {"enabled": True, "open_sky_factor": 1.0, "sigma_m": 8.0, "tau_s": 3.0}},
])
def test_reported_sigma_is_that_of_the_errors_made(extra):
    """Weights from the textbook UERE, errors carrying more (correlated range errors,
    multipath): GST's sigma must still be the errors' (issue #11: actual/reported 1.5-1.7
    before). Short correlation times, so 20,000 epochs hold thousands of samples."""
    prof = load_profile("ideal", {"dop_error": {"enabled": True}, **extra})
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    fixes, _ = _run(prof, sky, n_t=20_000, seed=5)
    err = _enu_errors(fixes)
    rms = np.sqrt(np.mean(err**2, axis=0))
    np.testing.assert_allclose(rms / fixes.sigma_enu_m[0], 1.0, atol=0.06)
    plain = load_profile("ideal", {"dop_error": {"enabled": True}})
    assert (fixes.sigma_enu_m[0] > _run(plain, sky, n_t=1)[0].sigma_enu_m[0]).all()


def test_a_static_receiver_prints_doppler_speed_noise_and_a_wandering_course():
    """Range-rate errors (sigma at the zenith x the UERE's elevation shape, sigma_i / sigma_z)
    through the same WLS (weights 1 / sigma_i^2): the velocity error's covariance is
    (sigma_rr / sigma_z)^2 (G^T W G)^-1 (issue #11: speeds were 0.00 kn, the course fixed)."""
    from virtualgps.device import nmea
    from virtualgps.receiver import errors

    prof = load_profile("ideal", {"dop_error": {"enabled": True, "range_rate_sigma_mps": 0.05,
                                                "range_rate_tau_s": 1.0}})
    az, el = np.linspace(0, 300, 7), np.linspace(10, 80, 7)
    fixes, _ = _run(prof, FixedSky(az, el), n_t=20_000, seed=3)
    assert (fixes.speed_mps > 0).all()
    assert np.mean(np.diff(fixes.course_deg) != 0) > 0.99
    # the east/north velocity error's spread from the speed and course
    ve = fixes.speed_mps * np.sin(np.radians(fixes.course_deg))
    vn = fixes.speed_mps * np.cos(np.radians(fixes.course_deg))
    d = prof.dop_error
    uere = (d.sis_m, d.iono_zenith_m, d.tropo_zenith_m, d.rx_noise_m, d.multipath_a_m,
            d.multipath_b_m)
    sigma_i = errors.uere_sigma_m(el, *uere)
    los = geodesy.azel_to_enu_unit(az, el)
    g = np.column_stack([-los, np.ones(7)])
    q = np.linalg.inv(g.T @ (g / sigma_i[:, None] ** 2))
    want = 0.05 / errors.uere_sigma_m(90.0, *uere) * np.sqrt(np.diag(q)[:2])
    np.testing.assert_allclose([ve.std(), vn.std()], want, rtol=0.05)
    # RMC and VTG print the same speed and course
    fmt = nmea.NmeaFormat.from_dict({"sentences": ["RMC", "VTG"]})
    rmc, vtg = (pynmeagps.NMEAReader.parse(line + b"\r\n") for line in
                nmea.epoch_sentences(fixes, 5, fmt).split(b"\r\n")[:2])
    assert float(rmc.spd) == float(vtg.sogn) and float(rmc.cog) == float(vtg.cogt)


def test_cold_start_satellites_become_usable_one_by_one_and_the_error_converges():
    from virtualgps.receiver.state import restart

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


# --------------------------------------------------------------------------------------------
# multipath: line-of-sight Gauss-Markov range errors near walls and at low elevation.

QUIET_UERE = {**UNIT_UERE, "sis_m": 1e-9}  # dop_error's own range errors vanish


def test_a_2d_fix_carries_its_held_heights_error_into_east_north():
    """Three satellites (70, 35, 50 deg), ranges without error, a held height 8 m above the
    antenna: the 3-state solution with the height fixed is G3^-1 (u_up x 8 m), G3 rows
    [-e, -n, 1] (exact: three equations, three unknowns); the printed height is the held one."""
    from dataclasses import replace as dc_replace

    prof = load_profile("ideal", {"dop_error": {"enabled": True, **QUIET_UERE}})
    az, el = [20.0, 140.0, 260.0], [70.0, 35.0, 50.0]
    sky = FixedSky(az, el)
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    state = dc_replace(ReceiverState(), last_alt_hae_m=GEOREF.alt0_hae_m + 8.0)
    fixes, _ = simulate(rx, 1.49e9 + np.arange(2.0), np.zeros((2, 3)), np.zeros((2, 3)),
                        np.ones(2, bool), state, np.random.default_rng(0))
    assert (fixes.mode == 2).all()
    los = geodesy.azel_to_enu_unit(az, el)
    g3 = np.column_stack([-los[:, 0], -los[:, 1], np.ones(3)])
    want = np.linalg.solve(g3, los[:, 2] * 8.0)[:2]
    err = _enu_errors(fixes)
    np.testing.assert_allclose(err[:, :2], np.tile(want, (2, 1)), atol=1e-4)  # (0.1 mm)
    np.testing.assert_allclose(err[:, 2], 8.0, atol=1e-6)
    assert np.hypot(*want) > 1.0  # (a shift the fix used to miss: it moved by 0)


def test_multipath_sigma_decays_with_elevation_and_wall_distance():
    from virtualgps.receiver.errors import multipath_sigma_m

    el = np.array([0.0, 15.0, 30.0, 60.0])
    # Next to a wall (d = 0): sigma_m exp(-el / el0).
    np.testing.assert_allclose(multipath_sigma_m(el, np.array(0.0), 4.0, 15.0, 30.0, 0.0),
                               4.0 * np.exp(-el / 15.0), rtol=1e-12)
    # At the horizon, falling linearly with the distance to 0 at max_dist_m and beyond it
    # (inf: no wall near); without a scene (NaN) the open-sky factor stands in.
    d = np.array([0.0, 7.5, 15.0, 30.0, 45.0, np.inf, np.nan])
    got = multipath_sigma_m(np.zeros((7, 1)), d, 4.0, 15.0, 30.0, 0.25)[:, 0]
    np.testing.assert_allclose(got, 4.0 * np.array([1.0, 0.75, 0.5, 0.0, 0.0, 0.0, 0.25]),
                               rtol=1e-12)


def _mp_sky(wall_dist_m, blocked):
    """A handmade Sky of six satellites for position_errors, the antenna wall_dist_m from a wall."""
    from virtualgps.receiver.skyview import Sky

    az = np.array([0.0, 70.0, 140.0, 210.0, 280.0, 330.0])
    el = np.array([80.0, 10.0, 25.0, 40.0, 15.0, 55.0])
    los = geodesy.azel_to_enu_unit(az, el)[None]
    one = np.ones((1, 6))
    return Sky(np.zeros(1), np.zeros(1), np.zeros(1), az[None], el[None], los,
               one.astype(bool), np.asarray(blocked)[None], np.zeros((1, 6), bool),
               np.zeros((1, 6)), np.zeros((1, 6)), np.zeros((1, 6)), np.array([wall_dist_m]))


@pytest.mark.parametrize("wall_dist_m", [6.0, 29.0, 30.0, 80.0, np.inf])
def test_multipath_moves_only_line_of_sight_ranges_near_a_wall(wall_dist_m):
    """The fix error is the WLS solution of sigma(el, d) z on the unblocked satellites (the
    first epoch draws the stationary process: x = z), and nothing beyond max_dist_m."""
    from virtualgps.receiver import errors
    from virtualgps.receiver.solution import error_processes, position_errors
    from virtualgps.receiver.state import draw_layout

    mp = {"enabled": True, "sigma_m": 4.0, "el0_deg": 15.0, "max_dist_m": 30.0}
    on = load_profile("ideal", {"dop_error": {"enabled": True, **QUIET_UERE}, "multipath": mp})
    off = load_profile("ideal", {"dop_error": {"enabled": True, **QUIET_UERE}})
    blocked = np.array([False, False, True, False, False, False])  # received off a wall: nlos
    sky = _mp_sky(wall_dist_m, blocked)
    used = np.ones((1, 6), bool)
    layout_on, layout_off = draw_layout(on, 6), draw_layout(off, 6)
    # The effect's uniforms come after every other block (its own stream: see
    # test_switching_one_effect_leaves_the_others_random_numbers_alone).
    others = ("multipath", "velocity", "total")
    assert {k: v for k, v in layout_on.items() if k not in others} == \
        {k: v for k, v in layout_off.items() if k not in others}
    u = np.random.default_rng(3).random((1, layout_on["total"]))
    z_row = errors.normals_from_uniforms(u)  # (as simulate gives them)
    dt, start = np.array([np.inf]), ReceiverState()
    args = (sky, used, used.sum(axis=1), z_row)
    e_on = position_errors(on, *args, layout_on,
                           error_processes(on, start, dt, z_row, layout_on, 6))
    e_off = position_errors(off, *args[:3], z_row[:, : layout_off["total"]], layout_off,
                            error_processes(off, start, dt, z_row, layout_off, 6))
    assert np.abs(e_off.enu_m).max() < 1e-6
    c = layout_on["multipath"]
    z = errors.normals_from_uniforms(u[:, c : c + 6])  # the block's own Box-Muller pairs
    prox = max(0.0, 1.0 - wall_dist_m / 30.0)
    eps = np.where(blocked, 0.0, 4.0 * np.exp(-sky.el_deg / 15.0) * prox * z)
    sigma_i = errors.uere_sigma_m(sky.el_deg, *QUIET_UERE.values())
    want, _ = errors.wls_fix(sky.los_enu, used, sigma_i, eps)
    np.testing.assert_allclose(e_on.enu_m, want, atol=1e-9)
    np.testing.assert_array_equal(e_on.mp_m, z[0])
    if wall_dist_m >= 30.0:  # far from any wall: exactly the receiver without the effect
        np.testing.assert_array_equal(e_on.enu_m, e_off.enu_m)
    else:
        assert np.abs(e_on.enu_m).max() > 0.01
    # The reported sigma is that of the errors made: the multipath variance joins the ranges'
    # (the sandwich covariance of the WLS weighted by the UERE alone).
    r = sigma_i**2 + np.where(blocked, 0.0, (4.0 * np.exp(-sky.el_deg / 15.0) * prox) ** 2)
    _, want_sigma = errors.wls_fix(sky.los_enu, used, sigma_i, eps, error_sigma_m=np.sqrt(r))
    np.testing.assert_allclose(e_on.sigma_enu_m, want_sigma, rtol=1e-12)
    if wall_dist_m >= 30.0:
        np.testing.assert_allclose(e_on.sigma_enu_m, e_off.sigma_enu_m, rtol=1e-12)
    else:
        assert (e_on.sigma_enu_m > e_off.sigma_enu_m).all()


def _mp_run(prof, sky, n, chunk, seed):
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    rng, state, out = np.random.default_rng(seed), ReceiverState(), []
    for a in range(0, n, chunk):  # the state carries the processes across calls
        t = 1.49e9 + np.arange(a, min(a + chunk, n), dtype=float)
        fixes, state = simulate(rx, t, np.zeros((t.size, 3)), np.zeros((t.size, 3)),
                                np.ones(t.size, bool), state, rng)
        out.append(fixes)
    return out, state


def test_multipath_autocorrelation_is_1_over_e_at_tau_and_its_spread_the_sigma():
    """Open sky with open_sky_factor 1: constant sigma_m exp(-el / el0) per satellite, so each
    axis of the fix error is a fixed mix of first-order Gauss-Markov processes."""
    from virtualgps.receiver import errors

    tau = 20.0
    prof = load_profile("ideal", {"dop_error": {"enabled": True, **QUIET_UERE},
                                  "multipath": {"enabled": True, "tau_s": tau, "sigma_m": 3.0,
                                                "el0_deg": 20.0, "open_sky_factor": 1.0}})
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    chunks, _ = _mp_run(prof, sky, 200_000, 50_000, seed=6)
    err = np.concatenate([_enu_errors(f) for f in chunks])
    # Expected spread: K diag(sigma^2) K^T with K the WLS gain of this geometry.
    los = geodesy.azel_to_enu_unit(sky.az_deg, sky.el_deg)
    sigma = 3.0 * np.exp(-sky.el_deg / 20.0)
    w = 1.0 / errors.uere_sigma_m(sky.el_deg, *QUIET_UERE.values()) ** 2
    g = np.c_[-los, np.ones(7)]
    gain = np.linalg.solve(g.T @ (w[:, None] * g), g.T * w)[:3]
    np.testing.assert_allclose(err.std(axis=0), np.sqrt((gain**2 * sigma**2).sum(axis=1)),
                               rtol=0.05)
    lag = int(tau)
    for axis in range(3):
        x = err[:, axis] - err[:, axis].mean()
        rho = np.dot(x[:-lag], x[lag:]) / np.dot(x, x)
        assert rho == pytest.approx(np.exp(-1.0), rel=0.10), (axis, rho)


def test_multipath_keeps_batch_equal_to_epoch_by_epoch():
    prof = load_profile("ideal", {"dop_error": {"enabled": True},
                                  "correlated_error": {"enabled": True},
                                  "multipath": {"enabled": True, "open_sky_factor": 0.7}})
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    (batch,), end = _mp_run(prof, sky, 12, 12, seed=9)
    ones, state = _mp_run(prof, sky, 12, 1, seed=9)
    for i, one in enumerate(ones):
        for name in ("lat_deg", "lon_deg", "alt_msl_m"):
            assert getattr(one, name)[0] == pytest.approx(getattr(batch, name)[i], abs=1e-9)
    np.testing.assert_allclose(state.mp_m, end.mp_m, rtol=1e-12)
    off, _ = _mp_run(load_profile("ideal", {"dop_error": {"enabled": True},
                                            "correlated_error": {"enabled": True}}),
                     sky, 12, 12, seed=9)
    assert np.abs(off[0].lat_deg - batch.lat_deg).max() > 1e-8  # and it does something


def test_multipath_needs_dop_error():
    from virtualgps.exceptions import ConfigError

    with pytest.raises(ConfigError, match="multipath needs dop_error"):
        load_profile("ideal", {"multipath": {"enabled": True}})
    with pytest.raises(ConfigError, match=r"multipath.open_sky_factor must be in \[0, 1\]"):
        load_profile("ideal", {"dop_error": {"enabled": True},
                               "multipath": {"enabled": True, "open_sky_factor": 2.0}})


def test_nav_filter_keeps_batch_equal_to_epoch_by_epoch_across_a_gap():
    # A batch filters each run of fixes in C (scipy's lfilter), one epoch at a time loops in
    # Python: the same products and sums, so the same bits, restarts after the gap included.
    prof = load_profile("ideal", {"dop_error": {"enabled": True},
                                  "correlated_error": {"enabled": True},
                                  "nav_filter": {"enabled": True, "tau_s": 3.0}})
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    n = 40
    t = 1.49e9 + np.arange(float(n))
    vel = np.tile([1.5, -0.5, 0.0], (n, 1))
    pos = np.cumsum(vel, axis=0)
    valid = np.ones(n, bool)
    valid[15:18] = False  # no pose: no fix, and the filter restarts after it
    batch, end = simulate(rx, t, pos, vel, valid, ReceiverState(), np.random.default_rng(2))
    assert np.isnan(batch.lat_deg[15:18]).all() and np.isfinite(batch.lat_deg[18:]).all()
    state, rng = ReceiverState(), np.random.default_rng(2)
    for i in range(n):
        one, state = simulate(rx, t[i : i + 1], pos[i : i + 1], vel[i : i + 1],
                              valid[i : i + 1], state, rng)
        for name in ("lat_deg", "lon_deg", "alt_msl_m"):
            np.testing.assert_array_equal(getattr(one, name)[0], getattr(batch, name)[i])
    np.testing.assert_array_equal(state.nav_enu_m, end.nav_enu_m)


@pytest.mark.parametrize("lfilter", [False, True], ids=["recursion", "lfilter"])
def test_gauss_markov_processes_together_equal_the_plain_recursion_to_the_bit(
    monkeypatch, lfilter
):
    """Sets with their own correlation times and widths, run in one pass (the receiver's
    fades, range errors and range rates), give each set's plain recursion to the bit, in a
    batch with a gap (runs of one coefficient) and epoch by epoch (the live loop)."""
    from virtualgps.receiver import errors

    monkeypatch.setattr(errors, "_loop_epochs",
                        errors.LOOP_EPOCHS_BEFORE_LFILTER + 1 if lfilter else 0)
    rng = np.random.default_rng(11)
    n = 300
    dt = np.full(n, 0.1)
    dt[0] = np.inf  # the first epoch: stationary start
    dt[120:123] = 0.7  # a gap in the log
    sets = [(np.zeros(5), 2.0, np.full(5, 1.5), rng.standard_normal((n, 5))),
            (rng.standard_normal(3), 30.0, np.array([1.0, 1.0, 2.0]), rng.standard_normal((n, 3))),
            (rng.standard_normal(4), 600.0, np.ones(4), rng.standard_normal((n, 4)))]
    together = errors.gauss_markov_processes(sets, dt)
    for (x0, tau_s, sigma, z), x in zip(sets, together, strict=True):
        phi = np.exp(-dt / tau_s)
        drive = sigma * np.sqrt(1.0 - phi[:, None] ** 2) * z
        want, prev = np.empty_like(z), x0.tolist()
        for k in range(n):  # Python floats, one multiply and one add per value
            prev = [float(phi[k]) * a + float(b) for a, b in zip(prev, drive[k], strict=True)]
            want[k] = prev
        np.testing.assert_array_equal(x, want)
        np.testing.assert_array_equal(x, errors.gauss_markov(x0, dt, tau_s, sigma, z))
    state = [s[0] for s in sets]
    for k in range(n):  # the live loop: one epoch a call
        one = errors.gauss_markov_processes(
            [(x0, s[1], s[2], s[3][k : k + 1]) for x0, s in zip(state, sets, strict=True)],
            dt[k : k + 1])
        state = [x[0] for x in one]
        for x, x_batch in zip(state, together, strict=True):
            np.testing.assert_array_equal(x, x_batch[k])


def test_first_order_recursion_batch_equals_its_epochs_to_the_bit():
    from virtualgps.receiver.errors import first_order_recursion

    rng = np.random.default_rng(4)
    u = rng.standard_normal((500, 3))
    p = np.full(500, 0.97)
    p[0] = 0.0  # the very first epoch's infinite step
    y0 = rng.standard_normal(3)
    batch = first_order_recursion(y0, p, u)  # the IIR filter (constant coefficient)
    prev, one = y0, []
    for k in range(500):  # the live loop: one epoch per call, the plain recursion
        prev = first_order_recursion(prev, p[k : k + 1], u[k : k + 1])[0]
        one.append(prev)
    np.testing.assert_array_equal(batch, np.array(one))
    # Closed form: y_k = sum_j p^(k - j) u_j from the first epoch on (y0 weighs p[0] = 0).
    k = np.arange(500)
    w = np.tril(0.97 ** (k[:, None] - k[None, :]).clip(0))
    np.testing.assert_allclose(batch, w @ u, rtol=0, atol=1e-9)
