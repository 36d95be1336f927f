"""cn0_tracking: the hysteresis state machine against a hand-worked sequence, chunk invariance,
and its effect in the receiver (SNR, used = tracked and above the mask, blocked = lost)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_receiver import GEOREF, FixedSky, WallOnAzimuth
from virtualgps.receiver import signals, walls
from virtualgps.receiver.core import simulate
from virtualgps.receiver.definition import Receiver
from virtualgps.receiver.profiles import load_profile
from virtualgps.receiver.state import ReceiverState


def test_tracking_hysteresis_by_hand():
    # acquisition 30, tracking 20 dB-Hz, acquisition needs 2 epochs at >= 30.
    cn0 = np.array([35, 35, 25, 25, 15, 25, 35, 35, 19, -np.inf, 31], float)[:, None]
    expect = [0, 1, 1, 1, 0, 0, 0, 1, 0, 0, 0]
    tracked, run = signals.track(cn0, 30.0, 20.0, 2, np.zeros(1, bool), np.zeros(1, int))
    assert tracked[:, 0].astype(int).tolist() == expect
    assert run.tolist() == [1]


def test_tracking_is_the_same_in_chunks():
    rng = np.random.default_rng(3)
    cn0 = rng.normal(25, 6, (500, 8))
    whole, run_w = signals.track(cn0, 28.0, 20.0, 3, np.zeros(8, bool), np.zeros(8, int))
    parts, tr, run = [], np.zeros(8, bool), np.zeros(8, int)
    for a in range(0, 500, 37):
        part, run = signals.track(cn0[a : a + 37], 28.0, 20.0, 3, tr, run)
        tr = part[-1]
        parts.append(part)
    np.testing.assert_array_equal(np.vstack(parts), whole)
    np.testing.assert_array_equal(run, run_w)


def test_run_length_continues_runs():
    cond = np.array([[1, 0], [1, 1], [0, 1], [1, 1]], bool)
    run = signals.run_length(cond, np.array([5, 0]))
    assert run.tolist() == [[6, 0], [7, 1], [0, 2], [1, 3]]


def test_antenna_gain_is_zero_at_zenith_and_the_loss_at_the_horizon():
    g = signals.antenna_gain_db(np.array([90.0, 0.0, 30.0, -5.0]), 12.0)
    np.testing.assert_allclose(g, [0.0, -12.0, -6.0, -12.0])


def _cn0_profile(**kw):
    params = {"enabled": True, "fade_sigma_db": 0.0, "reacq_s": 2.0, **kw}
    return load_profile("ideal", {"cn0_tracking": params})


def test_receiver_snr_used_and_blocked_with_cn0_tracking():
    prof = _cn0_profile(cn0_zenith_dbhz=45.0, horizon_loss_db=20.0, acq_dbhz=30.0,
                        track_dbhz=25.0)
    # el 80 and 40 strong; el 10 weak (45 - 20 (1 - sin 10) = 28.5: below acquisition);
    # az 120 behind a wall.
    sky = FixedSky([0.0, 90.0, 200.0, 120.0, 300.0, 250.0], [80.0, 40.0, 10.0, 50.0, 60.0, 30.0])
    rx = Receiver(profile=prof, ephemeris=sky, scene=WallOnAzimuth(100, 140), georef=GEOREF)
    n = 6
    fixes, state = simulate(rx, 1.49e9 + np.arange(float(n)), np.zeros((n, 3)),
                            np.zeros((n, 3)), np.ones(n, bool), ReceiverState(),
                            np.random.default_rng(0))
    expected_cn0 = 45.0 - 20.0 * (1 - np.sin(np.radians(sky.el_deg)))
    tracked = ~np.isnan(fixes.cn0_dbhz)
    assert not tracked[0].any()  # acquisition takes 2 epochs
    assert tracked[1:].tolist() == [[True, True, False, False, True, True]] * (n - 1)
    np.testing.assert_allclose(fixes.cn0_dbhz[1:, tracked[1]], np.broadcast_to(
        expected_cn0[tracked[1]], (n - 1, tracked[1].sum())))
    np.testing.assert_array_equal(fixes.used[1:], tracked[1:])
    assert (fixes.quality[1:] == 1).all() and fixes.quality[0] == 0
    assert state.tracked.tolist() == tracked[-1].tolist()


def test_weak_satellites_are_tracked_but_left_out_of_the_fix():
    # use_dbhz: el 10 arrives at 45 - 20 (1 - sin 10) = 28.5 dB-Hz, tracked (>= 25) and printed
    # in GSV, but below the use threshold of 30 it stays out of GSA and the fix; the state keeps
    # it tracked.
    prof = _cn0_profile(cn0_zenith_dbhz=45.0, horizon_loss_db=20.0, acq_dbhz=26.0,
                        track_dbhz=25.0, use_dbhz=30.0)
    sky = FixedSky([0.0, 90.0, 200.0, 300.0, 250.0], [80.0, 40.0, 10.0, 60.0, 30.0])
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    n = 5
    fixes, state = simulate(rx, 1.49e9 + np.arange(float(n)), np.zeros((n, 3)),
                            np.zeros((n, 3)), np.ones(n, bool), ReceiverState(),
                            np.random.default_rng(0))
    tracked = ~np.isnan(fixes.cn0_dbhz)
    assert tracked[1:].all()
    assert fixes.used[1:].tolist() == [[True, True, False, True, True]] * (n - 1)
    assert state.tracked.all()


def test_cn0_tracking_off_leaves_the_receiver_as_it_was():
    sky = FixedSky(np.linspace(0, 300, 7), np.linspace(10, 80, 7))
    rx_on = Receiver(profile=_cn0_profile(acq_dbhz=0.0, track_dbhz=0.0, reacq_s=0.0),
                     ephemeris=sky, scene=None, georef=GEOREF)
    rx_off = Receiver(profile=load_profile("ideal"), ephemeris=sky, scene=None, georef=GEOREF)
    args = (1.49e9 + np.arange(5.0), np.zeros((5, 3)), np.zeros((5, 3)), np.ones(5, bool),
            ReceiverState())
    on, _ = simulate(rx_on, *args, np.random.default_rng(0))
    off, _ = simulate(rx_off, *args, np.random.default_rng(0))
    np.testing.assert_array_equal(on.used, off.used)  # everything tracked with zero thresholds
    np.testing.assert_array_equal(on.lat_deg, off.lat_deg)
    assert not np.array_equal(np.nan_to_num(on.cn0_dbhz), np.nan_to_num(off.cn0_dbhz))


@pytest.mark.parametrize("sigma", [0.0, 3.0])
def test_fading_has_the_set_spread(sigma):
    prof = _cn0_profile(fade_sigma_db=sigma, fade_tau_s=5.0, acq_dbhz=0.0, track_dbhz=0.0)
    sky = FixedSky([0.0, 90.0, 200.0, 300.0], [80.0, 60.0, 45.0, 30.0])
    rx = Receiver(profile=prof, ephemeris=sky, scene=None, georef=GEOREF)
    n = 20_000
    fixes, _ = simulate(rx, 1.49e9 + np.arange(float(n)), np.zeros((n, 3)), np.zeros((n, 3)),
                        np.ones(n, bool), ReceiverState(), np.random.default_rng(1))
    spread = np.nanstd(fixes.cn0_dbhz[10:], axis=0)
    np.testing.assert_allclose(spread, sigma, atol=0.1 * max(sigma, 0.1))


# Two parallel walls running east-west: A (the blocker) at north 0..0.5, 12 m high; B (the
# reflector) at north 20..20.5, 30 m high. The antenna stands between them at north 10, 1.5 m
# up. A satellite due south at 30 deg is blocked by A (its ray is 7 m up at A) but its
# reflection off B's south face (d = 9.5 m... from the face at north 20) comes back over A
# (its leg from B passes A 17 m up).
TWO_WALLS_OBJ = """o WallA
v -50 0 0
v 50 0 0
v 50 0 12
v -50 0 12
v -50 0.5 0
v 50 0.5 0
v 50 0.5 12
v -50 0.5 12
f 1 2 3 4
f 5 6 7 8
o WallB
v -50 20 0
v 50 20 0
v 50 20 30
v -50 20 30
v -50 20.5 0
v 50 20.5 0
v 50 20.5 30
v -50 20.5 30
f 9 10 11 12
f 13 14 15 16
"""


def _walls_scene(tmp_path_factory, name: str, obj: str):
    """A scene of the given OBJ text with east/north/up axes near Magdeburg."""
    from virtualgps.sky.scene import load_scene

    d = tmp_path_factory.mktemp(name)
    (d / "walls.obj").write_text(obj)
    (d / "scene.toml").write_text(
        'mesh = "walls.obj"\n[georef]\nlat_deg = 52.14\nlon_deg = 11.64\nalt_hae_m = 100.0\n'
        '[axes]\neast = "+x"\nnorth = "+y"\nup = "+z"\n')
    return load_scene(d)


def _facades(scene):
    from virtualgps.sky.scene import CLASS_OCCLUDER

    sel = scene.face_class == CLASS_OCCLUDER
    return walls.Facades(scene.vertices_enu_m, scene.faces[sel], scene.face_object[sel])


@pytest.fixture(scope="module")
def two_walls(tmp_path_factory):
    return _walls_scene(tmp_path_factory, "two-walls", TWO_WALLS_OBJ)


def test_nlos_excess_path_equals_the_image_method(two_walls):
    from virtualgps import geodesy

    facades = _facades(two_walls)
    antenna = np.array([[3.0, 10.0, 1.5]])
    el = 30.0
    u = geodesy.azel_to_enu_unit(180.0, el)[None, :]
    assert two_walls.blocked(antenna, u)[0]  # the direct path hits wall A
    found, excess = walls.reflections(two_walls, facades, antenna, u, 50.0)
    # Image antenna 2 d behind wall B's face (d = 20 - 10 = 10 m): excess 2 d cos(el).
    assert found[0]
    assert excess[0] == pytest.approx(2 * 10.0 * np.cos(np.radians(el)), abs=0.01)
    # A satellite with its reflection point above wall B (too low a wall) or coming in
    # from the north (behind the reflector) has no such path.
    u_north = geodesy.azel_to_enu_unit(0.0, el)[None, :]
    found_n, _ = walls.reflections(two_walls, facades, antenna, u_north, 50.0)
    assert not found_n[0]
    high = geodesy.azel_to_enu_unit(180.0, 75.0)[None, :]  # reflection point 38 m up: off B
    assert not walls.reflections(two_walls, facades, antenna, high, 50.0)[0][0]
    # Walls further than max_dist_m do not reflect.
    assert not walls.reflections(two_walls, facades, antenna, u, 5.0)[0][0]


def test_nlos_in_the_receiver_biases_the_range_and_weakens_the_signal(two_walls):
    from virtualgps import geodesy
    from virtualgps.receiver.definition import Georef

    g = Georef(two_walls.lat_deg, two_walls.lon_deg, two_walls.alt_hae_m)

    # One satellite due south at 30 deg (blocked by A, reflected by B), four clear ones high.
    sky = FixedSky([180.0, 0.0, 90.0, 200.0, 300.0], [30.0, 80.0, 70.0, 75.0, 72.0], georef=g)
    tiny = {k: 0.0 for k in ("iono_zenith_m", "tropo_zenith_m", "rx_noise_m", "multipath_a_m",
                             "multipath_b_m")}
    base = {"cn0_tracking": {"enabled": True, "fade_sigma_db": 0.0, "acq_dbhz": 20.0,
                             "track_dbhz": 15.0, "reacq_s": 0.0, "cn0_zenith_dbhz": 45.0,
                             "horizon_loss_db": 10.0},
            "dop_error": {"enabled": True, "sis_m": 1e-9, **tiny}}  # errors: the NLOS bias only
    with_nlos = load_profile("ideal", {**base, "nlos": {"enabled": True,
                                                        "reflection_loss_db": 7.0}})
    without = load_profile("ideal", base)
    ant = np.array([[3.0, 10.0, 1.5]] * 3)
    args = (1.49e9 + np.arange(3.0), ant, np.zeros((3, 3)), np.ones(3, bool), ReceiverState())
    on, _ = simulate(Receiver(with_nlos, sky, two_walls, g), *args, np.random.default_rng(0))
    off, _ = simulate(Receiver(without, sky, two_walls, g), *args, np.random.default_rng(0))
    assert np.isnan(off.cn0_dbhz[:, 0]).all() and not off.used[:, 0].any()
    los_cn0 = 45.0 - 10.0 * (1 - np.sin(np.radians(30.0)))
    np.testing.assert_allclose(on.cn0_dbhz[:, 0], los_cn0 - 7.0, atol=1e-3)
    assert on.used[:, 0].all()
    # The fix moves by the least-squares solution of a bias of 2 d cos(el) on that satellite.
    excess = 2 * 10.0 * np.cos(np.radians(30.0))
    los = geodesy.azel_to_enu_unit(sky.az_deg, sky.el_deg)
    gmat = np.c_[-los, np.ones(5)]
    expect = np.linalg.lstsq(gmat, np.r_[excess, 0, 0, 0, 0], rcond=None)[0][:3]
    truth = geodesy.geodetic_to_ecef(on.truth_lat_deg, on.truth_lon_deg, on.truth_alt_hae_m)
    rep = geodesy.geodetic_to_ecef(on.lat_deg, on.lon_deg, on.alt_msl_m + on.geoid_sep_m)
    err = geodesy.ecef_to_enu(rep, g.lat0_deg, g.lon0_deg, g.alt0_hae_m) - geodesy.ecef_to_enu(
        truth, g.lat0_deg, g.lon0_deg, g.alt0_hae_m)
    np.testing.assert_allclose(err, np.broadcast_to(expect, err.shape), atol=0.01)


# A wide blocker A (12 m high, north 0..0.5) and a narrow reflector B (east -5..5, 30 m high,
# north 20..20.5). From (3, 10, 1.5) a satellite at azimuth 160, elevation 30 is blocked by A;
# its specular point on B's face lies at east 6.64, beyond B's edge, so only a scattered path
# off B exists.
NARROW_OBJ = TWO_WALLS_OBJ.replace("v -50 20 ", "v -5 20 ").replace("v 50 20 ", "v 5 20 ") \
    .replace("v -50 20.5 ", "v -5 20.5 ").replace("v 50 20.5 ", "v 5 20.5 ")


@pytest.fixture(scope="module")
def narrow_reflector(tmp_path_factory):
    return _walls_scene(tmp_path_factory, "narrow", NARROW_OBJ)


def _scatter_expect(a, u, p, alpha):
    """Closed form: lobe loss and excess path of scattering at P (wall B's face, normal -north)."""
    r = u * np.array([1.0, -1.0, 1.0])  # u mirrored in the east-up plane of the face
    v = (a - p) / np.linalg.norm(a - p)
    cos_psi = float(v @ -r)
    return -10 * alpha * np.log10((1 + cos_psi) / 2), np.linalg.norm(a - p) - (p - a) @ u


def test_scattering_off_a_wall_without_a_specular_point(narrow_reflector):
    from virtualgps import geodesy

    facades = _facades(narrow_reflector)
    a = np.array([3.0, 10.0, 1.5])
    u = geodesy.azel_to_enu_unit(160.0, 30.0)
    assert narrow_reflector.blocked(a[None], u[None])[0]
    assert not walls.reflections(narrow_reflector, facades, a[None], u[None], 50.0)[0][0]
    found, excess, lobe = walls.scattered_paths(narrow_reflector, facades, a[None], u[None],
                                                  50.0, 4.0, 30.0)
    assert found[0]
    # The specular point (east 6.64, up 7.64) clamped 0.1 m inside B's edge, or the point
    # below B's top at that east: the one with the least loss.
    t = 10.0 / (-u[1])
    spec = a + u * np.array([1.0, -1.0, 1.0]) * t
    assert spec[0] > 5.0
    options = [_scatter_expect(a, u, np.array([4.9, 20.0, z]), 4.0) for z in (spec[2], 29.9)]
    best = min(options)
    assert lobe[0] == pytest.approx(best[0], abs=1e-6) and 0 < lobe[0] < 3
    assert excess[0] == pytest.approx(best[1], abs=1e-6)
    # Loss grows with alpha_R (a narrower lobe) and a cap below it drops the path.
    narrow = walls.scattered_paths(narrow_reflector, facades, a[None], u[None], 50.0, 8.0,
                                     30.0)[2][0]
    assert narrow == pytest.approx(2 * lobe[0], rel=1e-9)
    assert not walls.scattered_paths(narrow_reflector, facades, a[None], u[None], 50.0, 4.0,
                                       0.5 * lobe[0])[0][0]
    # No wall within max_dist_m: nothing.
    assert not walls.scattered_paths(narrow_reflector, facades, a[None], u[None], 5.0, 4.0,
                                       30.0)[0][0]
    # A satellite in the north lights B's far side, which the antenna can't see, but A's north
    # face, which mirrors it with no lobe loss: excess 2 d (u . n), d = 9.5 m.
    u_n = geodesy.azel_to_enu_unit(20.0, 30.0)
    f_n, ex_n, lobe_n = walls.scattered_paths(narrow_reflector, facades, a[None], u_n[None],
                                                50.0, 4.0, 30.0)
    assert f_n[0] and lobe_n[0] == pytest.approx(0.0, abs=1e-9)
    assert ex_n[0] == pytest.approx(2 * 9.5 * u_n[1], abs=1e-6)


def test_scattering_at_the_specular_point_is_the_reflection(two_walls):
    from virtualgps import geodesy

    facades = _facades(two_walls)
    a = np.array([[3.0, 10.0, 1.5]])
    u = geodesy.azel_to_enu_unit(180.0, 30.0)[None, :]
    found, excess, lobe = walls.scattered_paths(two_walls, facades, a, u, 50.0, 4.0, 30.0)
    assert found[0] and lobe[0] == pytest.approx(0.0, abs=1e-9)
    assert excess[0] == pytest.approx(walls.reflections(two_walls, facades, a, u, 50.0)[1][0],
                                      abs=1e-6)


def test_scattering_in_the_receiver_adds_its_lobe_loss(narrow_reflector):
    from virtualgps.receiver.core import expected_cn0_dbhz
    from virtualgps.receiver.definition import Georef
    from virtualgps.receiver.skyview import compute_sky

    g = Georef(narrow_reflector.lat_deg, narrow_reflector.lon_deg, narrow_reflector.alt_hae_m)

    sky = FixedSky([160.0, 0.0], [30.0, 80.0], georef=g)
    ant = np.array([[3.0, 10.0, 1.5]])
    cn0 = {"enabled": True, "cn0_zenith_dbhz": 45.0, "horizon_loss_db": 10.0}
    out = {}
    for scattering in (False, True):
        prof = load_profile("ideal", {"cn0_tracking": cn0, "nlos": {
            "enabled": True, "reflection_loss_db": 7.0, "scattering": scattering}})
        rx = Receiver(prof, sky, narrow_reflector, g)
        out[scattering] = (compute_sky(rx, np.array([1.49e9]), ant), prof)
    plain, _ = out[False]
    sky_s, prof = out[True]
    assert plain.blocked[0, 0] and not plain.nlos[0, 0]  # no specular path
    assert sky_s.nlos[0, 0] and not sky_s.nlos[0, 1]
    u = sky_s.los_enu[0, 0] @ np.eye(3)
    _, _, lobe = walls.scattered_paths(narrow_reflector, _facades(narrow_reflector), ant,
                                         u[None], 30.0, 4.0, 10.0)
    assert sky_s.nlos_loss_db[0, 0] == pytest.approx(7.0 + lobe[0], abs=1e-3)
    direct = 45.0 - 10.0 * (1 - np.sin(np.radians(30.0)))
    assert expected_cn0_dbhz(prof, sky_s)[0, 0] == pytest.approx(direct - 7.0 - lobe[0],
                                                                  abs=1e-3)
    assert sky_s.nlos_loss_db[0, 1] == 0.0


def test_foliage_attenuation_is_the_length_through_the_crown_times_the_rate():
    from virtualgps import geodesy
    from virtualgps.receiver.definition import Georef
    from virtualgps.receiver.skyview import compute_sky
    from virtualgps.run.config import BUNDLED_SCENES_DIR
    from virtualgps.sky.scene import load_scene

    scene = load_scene(BUNDLED_SCENES_DIR / "test-wall")
    # Tree1's crown: east 20..26, north -20..-14, up 3..9 (tools/make_test_scene.py).
    origin = np.array([[23.0, -30.0, 6.0]])
    north = np.array([[0.0, 1.0, 0.0]])
    np.testing.assert_allclose(signals.foliage_path_m(scene, origin, north, 4.0), 6.0, atol=1e-3)
    # Slanted at 10 deg it stays between up 3 and 9 across the 6 m crown: 6 / cos(10 deg).
    el = 10.0
    d = geodesy.azel_to_enu_unit(0.0, el)[None, :]
    np.testing.assert_allclose(signals.foliage_path_m(scene, origin, d, 4.0),
                               6.0 / np.cos(np.radians(el)), atol=1e-3)
    assert signals.foliage_path_m(scene, origin, -north, 4.0)[0] == 0.0

    g = Georef(scene.lat_deg, scene.lon_deg, scene.alt_hae_m)

    sky = FixedSky([0.0, 180.0], [el, 60.0], georef=g)
    prof = load_profile("ideal", {"foliage": {"enabled": True, "db_per_m": 1.5, "max_db": 20.0}})
    out = compute_sky(Receiver(prof, sky, scene, g), np.array([1.49e9]), origin)
    np.testing.assert_allclose(out.foliage_db[0], [1.5 * 6.0 / np.cos(np.radians(el)), 0.0],
                               atol=2e-3)
    assert not out.blocked.any()
    capped = load_profile("ideal", {"foliage": {"enabled": True, "db_per_m": 10.0,
                                                "max_db": 20.0}})
    out = compute_sky(Receiver(capped, sky, scene, g), np.array([1.49e9]), origin)
    assert out.foliage_db[0, 0] == pytest.approx(20.0)  # saturates


def test_wall_distance_is_to_the_nearest_footprint_above_the_antenna(two_walls):
    facades = _facades(two_walls)
    ant = np.array([
        [3.0, 10.0, 1.5],  # between the walls: A's north face at 0.5 is 9.5 m away
        [3.0, 10.0, 20.0],  # above A (12 m high): B's south face at 20, 10 m away
        [3.0, 10.0, 40.0],  # above both
        [60.0, 10.0, 1.5],  # beyond the walls' east ends (x = 50): to A's corner
        [3.0, 60.0, 1.5],  # 39.5 m north of B: out of reach
    ])
    np.testing.assert_allclose(facades.wall_dist_m(ant, 30.0),
                               [9.5, 10.0, np.inf, np.hypot(10.0, 9.5), np.inf], atol=1e-9)
    assert facades.wall_dist_m(ant[:1], 5.0)[0] == np.inf  # beyond max_dist_m: none


def test_multipath_in_the_receiver_acts_near_a_wall_and_not_far_from_it(two_walls):
    from virtualgps.receiver.definition import Georef

    g = Georef(two_walls.lat_deg, two_walls.lon_deg, two_walls.alt_hae_m)

    sky = FixedSky([0.0, 90.0, 200.0, 300.0, 30.0], [80.0, 70.0, 75.0, 72.0, 60.0],
                   georef=g)  # all clear
    # "Off" is the effect with sigma_m = 0: the same row of uniforms per epoch (switching the
    # effect on widens the row, which moves every later epoch's draws).
    base = {"dop_error": {"enabled": True}}
    on = load_profile("ideal", {**base, "multipath": {"enabled": True}})
    off = load_profile("ideal", {**base, "multipath": {"enabled": True, "sigma_m": 0.0}})

    def run(prof, where):
        ant = np.array([where] * 3)
        args = (1.49e9 + np.arange(3.0), ant, np.zeros((3, 3)), np.ones(3, bool),
                ReceiverState(), np.random.default_rng(0))
        return simulate(Receiver(prof, sky, two_walls, g), *args)[0]

    near_on, near_off = run(on, [3.0, 10.0, 1.5]), run(off, [3.0, 10.0, 1.5])
    assert np.abs(near_on.lat_deg - near_off.lat_deg).max() > 1e-9  # ~0.1 mm or more
    far_on, far_off = run(on, [3.0, 100.0, 1.5]), run(off, [3.0, 100.0, 1.5])
    np.testing.assert_array_equal(far_on.lat_deg, far_off.lat_deg)
    np.testing.assert_array_equal(far_on.lon_deg, far_off.lon_deg)
    np.testing.assert_array_equal(far_on.alt_msl_m, far_off.alt_msl_m)


def _random_walls(n_walls, half_width_m, length_m, seed):
    """Facades of ``n_walls`` vertical rectangles (two triangles each, one object each) scattered
    over a square of +-``half_width_m``, ``length_m`` (low, high) long, tops 0.5-15 m above the
    ground at 0."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-half_width_m, half_width_m, (n_walls, 2))
    ang = rng.uniform(0.0, np.pi, n_walls)
    b = a + rng.uniform(*length_m, n_walls)[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    top = rng.uniform(0.5, 15.0, n_walls)
    verts = np.concatenate([np.c_[a, np.zeros(n_walls)], np.c_[b, np.zeros(n_walls)],
                            np.c_[b, top], np.c_[a, top]])  # corners k, k + n, k + 2n, k + 3n
    k = np.arange(n_walls)
    faces = np.concatenate([np.c_[k, k + n_walls, k + 2 * n_walls],
                            np.c_[k, k + 2 * n_walls, k + 3 * n_walls]])
    return walls.Facades(verts, faces, np.concatenate([k, k]))


# A town (walls 2-20 m long over 200 m) and a dense thicket of short walls, where the nearest
# wall often is not among the NEAR_WALLS nearest to the cell's centre (they are all close).
@pytest.mark.parametrize("layout", [(400, 100.0, (2.0, 20.0)), (2000, 30.0, (0.5, 2.0))])
@pytest.mark.parametrize("max_dist_m", [5.0, 30.0])
def test_wall_distance_is_the_brute_force_nearest(layout, max_dist_m):
    n_walls, half_width_m, length_m = layout
    facades = _random_walls(n_walls, half_width_m, length_m, seed=3)
    rng = np.random.default_rng(4)
    walk = np.cumsum(rng.normal(0.0, 1.5, (300, 2)), axis=0)  # cells visited many times
    xy = np.concatenate([rng.uniform(-1.2 * half_width_m, 1.2 * half_width_m, (300, 2)), walk])
    ant = np.c_[xy, rng.uniform(0.0, 12.0, len(xy))]
    got = facades.wall_dist_m(ant, max_dist_m)
    # Every footprint, every antenna: distance to the segment, walls whose top is above it.
    p0, p1 = facades.footprint_xy_m[:, 0], facades.footprint_xy_m[:, 1]
    d = p1 - p0
    t = np.clip(((xy[:, None] - p0) * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
    dist = np.linalg.norm(xy[:, None] - (p0 + t[..., None] * d), axis=-1)
    dist = np.where(facades.hi_m[:, 2] > ant[:, 2, None], dist, np.inf).min(axis=1)
    want = np.where(dist <= max_dist_m, dist, np.inf)
    assert np.isfinite(want).sum() > 100
    np.testing.assert_array_equal(np.isinf(got), np.isinf(want))
    np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], atol=1e-9)
    # One antenna at a time (the live loop) gives the same numbers as the batch.
    one = [facades.wall_dist_m(ant[i : i + 1], max_dist_m)[0] for i in range(0, len(ant), 7)]
    np.testing.assert_array_equal(one, got[::7])


def test_paths_at_equal_loss_up_to_round_off_keep_the_shortest():
    # Two specular paths (loss 0 but for round-off) and a lossy short one, for query 0; one
    # path for query 1. The old rule (loss compared to the last bit) kept the 40 m path.
    query = np.array([0, 0, 0, 1])
    excess_m = np.array([40.0, 6.0, 1.0, 9.0])
    loss_db = np.array([1e-10, 3e-10, 2.0, 0.5])
    best = walls.least_loss_then_shortest(query, excess_m, loss_db)
    np.testing.assert_array_equal(best, [1, 3])
    # Losses that really differ still decide before the length does.
    assert walls.least_loss_then_shortest(query[:3], excess_m[:3],
                                            np.array([0.3, 0.4, 0.2])).tolist() == [2]
