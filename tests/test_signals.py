"""cn0_tracking: the hysteresis state machine against a hand-worked sequence, chunk invariance,
and its effect in the receiver (SNR, used = tracked and above the mask, blocked = lost)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_receiver import GEOREF, FixedSky, WallOnAzimuth
from virtualgps import signals
from virtualgps.profiles import load_profile
from virtualgps.receiver import Receiver, ReceiverState, simulate


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
