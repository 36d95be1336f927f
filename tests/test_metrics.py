"""Metrics against closed forms and scipy/pymap3d; real-log readers; the MT3339 facts of SOURCES.md.

References: Rayleigh quantiles (E, N independent N(0, sigma^2): CEP50 = sigma sqrt(2 ln 2) =
1.1774 sigma, R95 = sigma sqrt(-2 ln 0.05) = 2.4477 sigma); a first-order Gauss-Markov series
has rho(k dt) = exp(-k dt / tau), so it falls to 1/e at lag tau; scipy.stats.wasserstein_distance;
pymap3d.geodetic2enu.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from mtk_logs import (
    MT3339_SOURCES_AUTOCORR_RANGE_S,
    MT3339_SOURCES_FACTS,
    read_mtk_logger_csv,
    real_calibration_stats,
)
from scipy.signal import lfilter
from scipy.stats import wasserstein_distance

from virtualgps.device.nmea import format_sentence, nmea_epochs_from_lines
from virtualgps.gap import metrics as M
from virtualgps.receiver.records import Fixes

MILLIMETRE = 1e-3
CENTIMETRE = 1e-2


def gauss_markov(rng: np.random.Generator, n: int, k: int, tau_s: float, dt_s: float) -> np.ndarray:
    """(n, k) unit-variance first-order Gauss-Markov series, stationary from the first sample."""
    a = math.exp(-dt_s / tau_s)
    w = rng.standard_normal((n, k)) * math.sqrt(1.0 - a * a)
    x0 = rng.standard_normal(k)
    return lfilter([1.0], [1.0, -a], w, axis=0, zi=(a * x0)[None, :])[0]


# --- position errors -------------------------------------------------------------------------


def test_errors_enu_match_pymap3d():
    rng = np.random.default_rng(1)
    lat0, lon0, h0 = 44.9837, -93.2441, 230.0
    lat = lat0 + rng.normal(0, 1e-4, 50)
    lon = lon0 + rng.normal(0, 1e-4, 50)
    h = h0 + rng.normal(0, 5, 50)
    got = M.errors_enu_m(lat, lon, h, lat0, lon0, h0)
    want = np.stack(pymap3d.geodetic2enu(lat, lon, h, lat0, lon0, h0), axis=-1)
    np.testing.assert_allclose(got, want, atol=MILLIMETRE)
    # a fix without altitude keeps its horizontal error, Up is NaN
    h_nan = h.copy()
    h_nan[:5] = np.nan
    got2 = M.errors_enu_m(lat, lon, h_nan, lat0, lon0, h0)
    assert np.all(np.isnan(got2[:5, 2]))
    np.testing.assert_allclose(
        M.horizontal_error_m(got2), M.horizontal_error_m(want), atol=CENTIMETRE
    )
    # a reference without a height (the median of a log that prints none): the horizontal
    # errors as about the reference at the fixes' heights, Up NaN; with or without the fixes'
    for fix_h in (h, np.full(50, np.nan)):
        got_nan_ref = M.errors_enu_m(lat, lon, fix_h, lat0, lon0, np.nan)
        assert np.all(np.isnan(got_nan_ref[:, 2]))
        np.testing.assert_allclose(got_nan_ref[:, :2], want[:, :2], atol=CENTIMETRE)
    # per-epoch reference (truth) broadcasts
    got3 = M.errors_enu_m(lat, lon, h, lat, lon, h)
    np.testing.assert_allclose(got3, 0.0, atol=MILLIMETRE)


def test_rayleigh_cep50_r95_bias_sigma():
    rng = np.random.default_rng(2)
    sigma_m, n = 2.0, 400_000
    e = rng.normal(0.0, sigma_m, (n, 3)) + np.array([0.5, -1.0, 2.0])
    e[::97] = np.nan  # missing epochs are ignored
    h = M.horizontal_error_m(e - M.bias_enu_m(e))
    assert M.cep50_m(h) == pytest.approx(math.sqrt(2 * math.log(2)) * sigma_m, rel=0.01)
    assert M.r95_m(h) == pytest.approx(math.sqrt(-2 * math.log(0.05)) * sigma_m, rel=0.01)
    assert 1.1774 * sigma_m == pytest.approx(math.sqrt(2 * math.log(2)) * sigma_m, rel=1e-4)
    np.testing.assert_allclose(M.bias_enu_m(e), [0.5, -1.0, 2.0], atol=0.02)
    np.testing.assert_allclose(M.sigma_enu_m(e), sigma_m, rtol=0.01)
    assert math.isnan(M.cep50_m([np.nan])) and math.isnan(M.r95_m([]))


def test_median_position():
    lat, lon, alt = M.median_position([1.0, 2.0, 30.0, np.nan], [5.0, 6.0, 7.0, 8.0], [np.nan] * 4)
    assert (lat, lon) == (2.0, 6.5) and math.isnan(alt)


# --- autocorrelation time --------------------------------------------------------------------


@pytest.mark.parametrize("k_axes", [1, 2, 3])
@pytest.mark.parametrize("dt_s", [1.0, 0.5])
def test_gauss_markov_autocorrelation_time(k_axes, dt_s):
    rng = np.random.default_rng(3 + k_axes)
    tau_s = 5.0
    x = gauss_markov(rng, 400_000, k_axes, tau_s, dt_s) * np.arange(1, k_axes + 1)
    got = M.autocorrelation_time_s(x, dt_s, max_lag_s=10 * tau_s)
    # Bartlett's variance of r(k) (Box & Jenkins eq. 2.1.13) for a record of T = 2e5..4e5 s:
    # sd(r(tau)) ~ sqrt(1.46 tau / T) = 0.004-0.006, i.e. 1.1-1.6 % of tau for one axis
    assert got == pytest.approx(tau_s, rel=0.07)
    rho = M.autocorrelation(x, int(3 * tau_s / dt_s))
    lags_s = np.arange(rho.size) * dt_s
    np.testing.assert_allclose(rho, np.exp(-lags_s / tau_s), atol=0.03)


def test_autocorrelation_time_with_gaps_and_jitter():
    rng = np.random.default_rng(5)
    tau_s, dt_s = 10.0, 1.0
    x = gauss_markov(rng, 150_000, 2, tau_s, dt_s)
    keep = rng.random(x.shape[0]) > 0.3  # 30 % of the epochs missing
    keep[50_000:60_000] = False  # and a long outage
    t = 1.0e9 + np.arange(x.shape[0]) * dt_s + rng.uniform(-0.05, 0.05, x.shape[0])
    grid_t, grid = M.to_regular_grid(t[keep], x[keep], dt_s)
    assert grid.shape[0] == np.flatnonzero(keep)[-1] - np.flatnonzero(keep)[0] + 1
    assert np.isnan(grid[50_000 - np.flatnonzero(keep)[0]]).all()
    # sd of the estimate ~1.5 % here (Bartlett, see above, with 30 % fewer pairs)
    assert M.autocorrelation_time_s(grid, dt_s, max_lag_s=300) == pytest.approx(tau_s, rel=0.07)
    # a NaN in one axis drops the epoch
    grid[::7, 0] = np.nan
    assert M.autocorrelation_time_s(grid, dt_s, max_lag_s=300) == pytest.approx(tau_s, rel=0.07)


def test_autocorrelation_time_white_noise_and_edge_cases():
    rng = np.random.default_rng(6)
    w = rng.standard_normal(100_000)
    # rho falls from 1 to ~0 in one step: the interpolated crossing is at 1 - 1/e of a step
    assert M.autocorrelation_time_s(w, 2.0) == pytest.approx(2.0 * (1 - math.exp(-1)), abs=0.02)
    # a random walk never decorrelates within 5 samples
    assert math.isnan(M.autocorrelation_time_s(np.cumsum(w), 1.0, max_lag_s=5))
    assert math.isnan(M.autocorrelation_time_s(np.full(100, np.nan), 1.0))
    assert math.isnan(M.autocorrelation_time_s(np.ones(100), 1.0))  # no variance
    with pytest.raises(ValueError, match="detrend"):
        M.autocorrelation(w, 10, detrend="quadratic")


def test_linear_detrend_removes_a_drift():
    rng = np.random.default_rng(7)
    tau_s = 10.0
    x = gauss_markov(rng, 50_000, 1, tau_s, 1.0)[:, 0] + np.linspace(0.0, 20.0, 50_000)
    assert M.autocorrelation_time_s(x, 1.0, detrend="linear") == pytest.approx(tau_s, rel=0.08)
    assert M.autocorrelation_time_s(x, 1.0, detrend="mean") > 10 * tau_s


# --- distributions ---------------------------------------------------------------------------


def test_wasserstein1_shift_and_scipy():
    rng = np.random.default_rng(8)
    a = rng.normal(3.0, 2.0, 5000)
    assert M.wasserstein1(a, a + 1.7) == pytest.approx(1.7, abs=1e-9)
    assert M.wasserstein1(a, a + 1.7) == pytest.approx(wasserstein_distance(a, a + 1.7), abs=1e-9)
    b = rng.gamma(2.0, 2.0, 3001)
    assert M.wasserstein1(a, b) == pytest.approx(wasserstein_distance(a, b), rel=1e-12)
    a_nan = np.concatenate([a, [np.nan]])
    assert M.wasserstein1(a_nan, b) == pytest.approx(wasserstein_distance(a, b), rel=1e-12)
    assert math.isnan(M.wasserstein1([], b))


def test_distribution_hdop_and_cn0_summaries():
    x = np.arange(101.0)  # quantiles of 0..100 are the percentages themselves
    s = M.hdop_summary(np.concatenate([x, [np.nan]]))
    assert (s["median"], s["p05"], s["p25"], s["p75"], s["p95"], s["n"]) == (
        50.0, 5.0, 25.0, 75.0, 95.0, 101.0,
    )  # fmt: skip
    cn0 = np.array([[30.0, np.nan], [40.0, 20.0]])
    c = M.cn0_summary(cn0)
    assert (c["median"], c["mean"], c["n"]) == (30.0, 30.0, 3.0)
    assert math.isnan(M.cn0_summary(np.full((2, 2), np.nan))["median"])


# --- availability and satellites -------------------------------------------------------------


def test_fix_fraction_and_ttff():
    t = 1000.0 + np.arange(10.0)
    q = np.array([0, 0, 0, 1, 1, 0, 2, 1, 1, 1])
    assert M.fix_fraction(q) == pytest.approx(0.6)
    assert M.ttff_s(t, q) == 3.0
    assert M.ttff_s(t, q, t_start_s=990.0) == 13.0
    assert math.isnan(M.ttff_s(t, np.zeros(10)))
    assert math.isnan(M.fix_fraction([]))


def test_count_stats_and_changes_per_minute():
    t = np.arange(121.0)  # 2 minutes at 1 Hz
    c = np.where(np.arange(121) % 2 == 0, 8, 9)  # a change every second
    assert M.changes_per_minute(c, t) == pytest.approx(60.0)
    c2 = np.full(121, 7)
    c2[60:] = 8  # one change in two minutes
    assert M.changes_per_minute(c2, t) == pytest.approx(0.5)
    # a gap is neither time observed nor a change; unknown counts (-1) likewise
    t3 = np.concatenate([np.arange(61.0), 1000.0 + np.arange(61.0)])
    c3 = np.concatenate([np.full(61, 7), np.full(61, 9)])
    assert M.changes_per_minute(c3, t3) == pytest.approx(0.0)
    c3[30] = -1
    assert M.changes_per_minute(c3, t3) == pytest.approx(0.0)
    s = M.count_stats([3, 9, 9, 10, -1])
    assert (s["median"], s["min"], s["max"], s["mean"]) == (9.0, 3.0, 10.0, 7.75)


def _fixes(
    n_t: int, err_enu_m: np.ndarray, used: np.ndarray, cn0: np.ndarray, moving: bool = True
) -> Fixes:
    lat0, lon0, h0 = 52.14, 11.64, 100.0
    truth_lat = lat0 + np.linspace(0, 1e-3 if moving else 0.0, n_t)  # 111 m north, or static
    truth_lon = np.full(n_t, lon0)
    truth_h = np.full(n_t, h0)
    lat, lon, h = pymap3d.enu2geodetic(*err_enu_m.T, truth_lat, truth_lon, truth_h)
    sep = np.full(n_t, 40.0)
    n_sat = used.shape[1]
    return Fixes(
        t_unix_s=1.7e9 + np.arange(n_t, dtype=float),
        lat_deg=lat,
        lon_deg=lon,
        alt_msl_m=h - sep,
        geoid_sep_m=sep,
        quality=np.ones(n_t, dtype=np.int8),
        mode=np.full(n_t, 3, dtype=np.int8),
        hdop=np.full(n_t, 1.2),
        vdop=np.full(n_t, 1.5),
        pdop=np.full(n_t, 1.9),
        speed_mps=np.zeros(n_t),
        course_deg=np.zeros(n_t),
        prn=np.arange(1, n_sat + 1),
        az_deg=np.zeros((n_t, n_sat)),
        el_deg=np.full((n_t, n_sat), 30.0),
        cn0_dbhz=cn0,
        in_view=np.ones((n_t, n_sat), dtype=bool),
        used=used,
        truth_lat_deg=truth_lat,
        truth_lon_deg=truth_lon,
        truth_alt_hae_m=truth_h,
    )


def test_summary_of_simulated_fixes_against_truth():
    rng = np.random.default_rng(9)
    # tau 5 s over 1e5 s: the 1/e lag has sd ~2.3 % per axis (Bartlett), so 10 % is > 4 sd
    n_t, n_sat, sigma_m, tau_s = 100_000, 12, 3.0, 5.0
    err = gauss_markov(rng, n_t, 3, tau_s, 1.0) * sigma_m
    used = np.zeros((n_t, n_sat), dtype=bool)
    used[:, :9] = True
    used[::10, 8] = False  # 8 used every 10th epoch: 2 changes per 10 s = 12 per minute
    cn0 = np.full((n_t, n_sat), 35.0)
    cn0[:, 10:] = np.nan  # two satellites in view, not tracked
    s = M.summary(_fixes(n_t, err, used, cn0))
    assert s["cep50_m"] == pytest.approx(1.1774 * sigma_m, rel=0.05)
    assert s["r95_m"] == pytest.approx(2.4477 * sigma_m, rel=0.05)
    for a in "enu":
        assert s[f"sigma_{a}_m"] == pytest.approx(sigma_m, rel=0.05)
        assert s[f"autocorr_{a}_s"] == pytest.approx(tau_s, rel=0.1)
    assert s["autocorr_h_s"] == pytest.approx(tau_s, rel=0.1)
    assert (s["sats_used_median"], s["sats_used_min"], s["sats_used_max"]) == (9.0, 8.0, 9.0)
    assert s["sats_used_changes_per_min"] == pytest.approx(12.0, rel=0.01)
    assert (s["sats_in_view_median"], s["sats_in_view_gps_median"]) == (12.0, 12.0)
    assert s["sats_tracked_median"] == 10.0
    assert (s["hdop_median"], s["cn0_median_dbhz"], s["fix_fraction"], s["ttff_s"]) == (
        1.2, 35.0, 1.0, 0.0,
    )  # fmt: skip
    # about the median instead: same spread, bias removed
    s2 = M.summary(_fixes(n_t, err + 10.0, used, cn0, moving=False), reference="median")
    assert s2["cep50_m"] == pytest.approx(s["cep50_m"], rel=0.05)
    assert abs(s2["bias_e_m"]) < 0.5
    s3 = M.summary(_fixes(n_t, err, used, cn0), reference=None)
    assert math.isnan(s3["cep50_m"]) and s3["hdop_median"] == 1.2


# --- readers ---------------------------------------------------------------------------------


def _nmea(*bodies: str) -> list[str]:
    return [format_sentence(b).rstrip("\r\n") for b in bodies]


def test_nmea_epochs_grouping_partial_gsv_and_corrupt_lines():
    lines = ["\x8a\x14\xa6junk$$GP", "$PGTOP,11,2*6E"]
    lines += _nmea(
        "GPGGA,235958.000,,,,,0,04,,,M,,M,,",
        "GPGSA,A,1,,,,,,,,,,,,,,,",
        "GPGSV,2,1,05,26,67,098,32,16,57,167,,23,51,304,23,03,48,237,21",
        "GPGSV,2,2,05,34,,,",
        "GPRMC,235958.000,V,,,,,0.19,250.14,311216,,,N",
        # next epoch, after midnight, its RMC lost: the date comes from the neighbour
        "GPGGA,000001.000,4459.0085,N,09314.6412,W,1,03,1.50,268.4,M,-31.9,M,,",
        "GPGSA,A,3,26,23,03,,,,,,,,,,2.10,1.50,1.40",
        "GPGSV,2,1,05,26,67,098,33,16,57,167,,23,51,304,25,03,48,237,22",
        # GSV 2/2 missing (partial epoch)
    )
    bad = format_sentence("GPGGA,000002.000,4459.0085,N,09314.6412,W,1,03,1.50,268.4,M,,M,,")
    lines.append(bad[:-5] + "00")  # wrong checksum
    e = nmea_epochs_from_lines(lines)
    assert len(e) == 2 and e.n_bad == 2  # the junk line with $ and the bad checksum
    np.testing.assert_allclose(np.diff(e.t_unix_s), 3.0)
    assert e.t_unix_s[1] == pytest.approx(1483228801.0)  # 2017-01-01 00:00:01 UTC
    assert list(e.quality) == [0, 1] and list(e.sats_used) == [4, 3]
    assert list(e.sats_used_gsa) == [0, 3] and list(e.sats_in_view) == [5, 5]
    assert list(e.gsv_complete) == [True, False]
    assert list(e.prn) == [3, 16, 23, 26, 121]  # (GPGSV's 34: SBAS PRN 121)
    j = {p: k for k, p in enumerate(e.prn)}
    assert e.cn0_dbhz[1, j[26]] == 33.0 and math.isnan(e.cn0_dbhz[0, j[16]])
    assert e.in_view[0, j[121]] and math.isnan(e.el_deg[0, j[121]]) and not e.in_view[1, j[121]]
    assert e.used[1, [j[3], j[23], j[26]]].all() and e.used.sum() == 3
    assert e.lat_deg[1] == pytest.approx(44 + 59.0085 / 60) and e.lon_deg[1] < 0
    assert math.isnan(e.lat_deg[0]) and e.hdop[1] == 1.5 and e.pdop[1] == 2.1


def test_a_dual_band_receivers_gsv_lists_count_each_satellite_once():
    """NMEA 4.11 GSV per signal (a u-blox F9P: GPS L1 C/A, ID 1, then L2 CL, ID 6; each list
    numbered 1..N of its own): in view is the larger list's count per talker, summed over
    talkers, and the epoch's GSV is complete; a satellite's C/N0 is its first signal's."""
    e = nmea_epochs_from_lines(_nmea(
        "GNGGA,120000.00,4459.0085,N,09314.6412,W,1,05,1.10,268.4,M,-31.9,M,,",
        "GNRMC,120000.00,A,4459.0085,N,09314.6412,W,0.0,,150323,,,A,V",
        "GPGSV,2,1,05,02,60,010,45,05,40,100,42,12,30,200,40,25,20,300,38,1",
        "GPGSV,2,2,05,29,10,350,33,1",
        "GPGSV,1,1,03,02,60,010,39,05,40,100,36,12,30,200,31,6",
        "GLGSV,1,1,02,65,50,120,41,66,25,220,37,1",
        "GLGSV,1,1,02,65,50,120,35,66,25,220,30,3",
    ))
    assert list(e.sats_in_view) == [7] and list(e.gsv_complete) == [True]
    assert list(e.prn) == [2, 5, 12, 25, 29, 65, 66]
    assert e.in_view.sum() == 7 and e.cn0_dbhz[0, 0] == 45.0 and e.cn0_dbhz[0, 5] == 41.0


def test_mtk_logger_csv(tmp_path):
    p = tmp_path / "log.csv"
    p.write_text(
        "INDEX,RCR,DATE,TIME,VALID,LATITUDE,N/S,LONGITUDE,E/W,HEIGHT,SPEED,PDOP,HDOP,VDOP,"
        "NSAT (USED/VIEW),SAT INFO (SID-SNR),DISTANCE,\n"
        "1,T,2015/07/15,10:53:26.000,SPS,52.634804,N,1.263404,W,-64.153 m,3.6 km/h,2.32,2.09,"
        "1.00,3(7),25-00;#14-35;#31-16;29-00;#06-29;03-00;12-00,     76.99 m,\n"
        "2,T,2015/07/15,10:53:36.000,DGPS,52.634843,S,1.263334,E,-87.184 m,0.083 km/h,2.32,"
        "2.10,1.00,3(3),#14-35;#31-16;#06-28,     23.90 m,\n"
        "3,T,2015/07/15,bad time,SPS,52.6,N,1.2,E,1 m,0 km/h,1,1,1,3(3),,0 m,\n"
    )
    tr = read_mtk_logger_csv(p)
    assert len(tr) == 2 and tr.n_bad == 1
    assert tr.t_unix_s[0] == pytest.approx(1436957606.0)  # 2015-07-15 10:53:26 UTC
    assert tr.lon_deg[0] < 0 and tr.lat_deg[1] < 0 and list(tr.quality) == [1, 2]
    assert tr.speed_mps[0] == pytest.approx(1.0) and tr.alt_hae_m[0] == -64.153
    assert list(tr.sats_used) == [3, 3] and list(tr.sats_in_view) == [7, 3]
    assert list(tr.prn) == [3, 6, 12, 14, 25, 29, 31]
    assert tr.used.sum(axis=1).tolist() == [3, 3] and tr.in_view.sum(axis=1).tolist() == [7, 3]
    assert np.isfinite(tr.cn0_dbhz).sum(axis=1).tolist() == [3, 3]  # SNR 00: not tracked


# --- the real logs ---------------------------------------------------------------------------


def test_mt3339_static_hour_reproduces_sources_facts(shared_data):
    """The facts SOURCES.md states for mt3339-static/hour_test_1.txt, recomputed."""
    stats = real_calibration_stats(shared_data)
    mt = stats["mt3339_static"]
    f = MT3339_SOURCES_FACTS
    # stated to 0.1 m: the recomputation must round to them
    for key in ("cep50_m", "r95_m", "sigma_e_m", "sigma_n_m", "sigma_u_m"):
        assert mt[key] == pytest.approx(f[key], abs=0.06), key
    for key in ("hdop_median", "sats_used_median", "sats_used_min", "sats_used_max"):
        assert mt[key] == f[key], key
    assert mt["sats_in_view_median"] == f["sats_in_view_median"]  # "about 12"
    assert mt["cn0_median_dbhz"] == f["cn0_median_dbhz"]
    assert mt["ttff_s"] == pytest.approx(f["ttff_s"], abs=1.0)  # "after about 31 s"
    lo, hi = MT3339_SOURCES_AUTOCORR_RANGE_S
    for key in ("autocorr_h_s", "autocorr_e_s", "autocorr_n_s"):
        assert lo <= mt[key] <= hi, key
    assert mt["sats_used_gsa_median"] == mt["sats_used_median"]  # GGA and GSA agree
    assert mt["n_fixed"] > 3100 and mt["fix_fraction"] > 0.98

    mv = stats["m241_moving"]
    assert mv["n_epochs"] > 800 and mv["fix_fraction"] == 1.0
    assert 7 <= mv["sats_used_min"] <= mv["sats_used_median"] <= mv["sats_used_max"] <= 12
    assert mv["sats_used_max"] <= mv["sats_in_view_max"]
    assert 0.8 < mv["hdop_median"] < 2.0


def test_used_set_vdop_closed_form():
    # A satellite at the zenith and three on the horizon 120 deg apart: the vertical/clock
    # block of G'G is [[1, 1], [1, 4]], so VDOP = sqrt(4 / 3).
    el = np.array([[90.0, 0.0, 0.0, 0.0, 45.0]])
    az = np.array([[0.0, 0.0, 120.0, 240.0, 10.0]])
    used = np.array([[True, True, True, True, False]])
    np.testing.assert_allclose(M.used_set_vdop(el, az, used), [np.sqrt(4.0 / 3.0)])
    # fewer than four used: no VDOP
    assert np.isnan(M.used_set_vdop(el, az, used & [[1, 1, 1, 0, 0]])[0])


def test_elevation_bin_stats():
    el = np.array([[10.0, 20.0, 70.0, 50.0], [12.0, 25.0, 80.0, 3.0]])
    cn0 = np.array([[30.0, np.nan, 40.0, 35.0], [32.0, 28.0, 44.0, 20.0]])
    listed = np.array([[True, True, True, True], [True, True, True, False]])
    s = M.elevation_bin_stats(el, cn0, listed)
    assert s["cn0_el5_15_median_dbhz"] == 31.0 and s["tracked_el5_15_share"] == 1.0
    assert s["cn0_el15_30_median_dbhz"] == 28.0 and s["tracked_el15_30_share"] == 0.5
    assert s["cn0_el30_60_median_dbhz"] == 35.0 and s["cn0_el60_90_median_dbhz"] == 42.0
