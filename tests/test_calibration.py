"""holux-m1000 against the real MTK logs: the calibration table holds (issue #3).

The real column is measured on ../shared/data (MT3339 static hour, M-241 car track); the
simulated one replays the profile where and when each log was recorded and reads its NMEA back
through the same reader and statistics (virtualgps/gap/calibration.py). Tolerance: +-20 % on the
median over 8 seeds for every calibrated statistic (virtualgps.gap.calibration.STATISTICS).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from virtualgps.gap.calibration import (
    STATISTICS,
    Row,
    Statistic,
    blocked_pattern,
    compare,
    sim_blocked_pattern,
    sim_calibration_stats,
    waypoint_sky,
)
from virtualgps.gap.reallogs import real_calibration_stats
from virtualgps.profiles import load_profile

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tables(shared_data):
    real = real_calibration_stats(shared_data)
    sim = sim_calibration_stats(load_profile("holux-m1000"), shared_data)
    return real, sim


def test_holux_reproduces_the_real_mtk_statistics(tables):
    real, sim = tables
    rows = compare(real, sim)
    calibrated = [r for r in rows if r.stat.tolerance is not None]
    assert {r.stat.key for r in calibrated} >= {
        "cep50_m", "r95_m", "autocorr_h_s", "sats_used_mean", "sats_in_view_gps_mean",
        "hdop_median", "cn0_median_dbhz", "sats_in_view_mean",
    }
    bad = [f"{r.stat.log} {r.stat.label}: sim {r.sim_median:.3g} vs real {r.real:.3g}"
           for r in calibrated if not r.ok]
    assert not bad, bad


def test_the_paper_model_does_not_pass(shared_data, tables):
    # The table can fail: the paper's white noise (the usarsim profile) has no error memory
    # and no C/N0 model, and is far off the real receiver.
    real, _ = tables
    sim = sim_calibration_stats(load_profile("usarsim"), shared_data, seeds=(0,))
    rows = {(r.stat.log, r.stat.key): r for r in compare(real, sim)}
    assert not rows[("mt3339_static", "autocorr_h_s")].ok  # white: ~1 s, not ~150 s
    assert not rows[("mt3339_static", "cep50_m")].ok


def test_simulated_runs_are_what_they_claim(tables):
    _, sim = tables
    mt, mv = sim["mt3339_static"], sim["m241_moving"]
    assert len(mt["cep50_m"]) == len(mv["hdop_median"]) == 8  # one run per seed
    assert min(mt["duration_s"]) > 3500  # the hour
    assert np.median(mt["fix_fraction"]) > 0.99
    # the M-241's moving records: 905, some of them a second record of the same second
    assert 800 < np.median(mv["n_epochs"]) <= 905


def test_tolerance_verdicts():
    st = Statistic("cep50_m", "mt3339_static", "CEP50 (m)", 0.2)
    assert Row(st, 4.0, 4.79, 4.0, 5.0).ok and not Row(st, 4.0, 4.81, 4.0, 5.0).ok
    assert Row(Statistic("x", "m241_moving", "x", None), 1.0, 9.0, 9.0, 9.0).ok is None
    assert all(s.log in ("mt3339_static", "m241_moving") for s in STATISTICS)


def test_calibrate_tool_rewrites_the_readme_block(tmp_path):
    spec = importlib.util.spec_from_file_location("calibrate", ROOT / "tools" / "calibrate.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{tool.START}\nold\n{tool.END}\nrest\n")
    st = Statistic("cep50_m", "mt3339_static", "CEP50 (m)")
    table = tool.markdown([Row(st, 4.46, 4.4, 4.0, 5.2)], 8, "python tools/calibrate.py")
    tool.rewrite_readme(readme, table)
    text = readme.read_text()
    assert "old" not in text and text.startswith("intro\n") and text.endswith("rest\n")
    row = "| MT3339 static hour | CEP50 (m) | 4.46 | 4.40 | 4.00-5.20 | 0.99 | yes (+-20%) |"
    assert row in text
    readme.write_text("no markers")
    with pytest.raises(SystemExit):
        tool.rewrite_readme(readme, table)


# --- Magdeburg waypoints (issue #3): satellites behind buildings ------------------------------


@pytest.fixture(scope="module")
def magdeburg(shared_data):
    from virtualgps.config import BUNDLED_SCENES_DIR
    from virtualgps.scene import load_scene

    return shared_data, load_scene(BUNDLED_SCENES_DIR / "magdeburg-campus")


@pytest.fixture(scope="module")
def waypoints(magdeburg):
    data, scene = magdeburg
    return waypoint_sky(load_profile("holux-m1000"), data, scene)


def test_real_waypoint_logs_show_blocked_satellites_tracked_and_weaker(waypoints):
    # What SOURCES.md measured (by passes: 58 % tracked, 6.7 +- 0.7 dB weaker); here by
    # satellite-epochs, PRN-matched for the C/N0.
    real = blocked_pattern(waypoints, "real")
    assert real["n_blocked"] > 1000
    assert real["tracked_blocked"] == pytest.approx(0.57, abs=0.02)
    assert real["tracked_clear"] > 0.85
    assert real["weaker_db"] == pytest.approx(6.5, abs=0.5)


def test_holux_tracks_building_crossing_satellites_part_of_the_time_and_weaker(magdeburg,
                                                                             waypoints):
    data, scene = magdeburg
    sim = sim_blocked_pattern(load_profile("holux-m1000"), data, scene)
    # Not always lost, not always kept: less often than clear ones, several dB weaker
    # (measured: 10 % of them tracked, 9.5 dB weaker, medians of 5 seeds; single seeds
    # 7.4-9.7 dB).
    assert 0.08 <= sim["tracked_blocked"] <= 0.8 * sim["tracked_clear"]
    assert 4.0 <= sim["weaker_db"] <= 11.0
    # Without nlos a blocked satellite is always lost.
    bare = waypoint_sky(load_profile("holux-m1000", {"nlos": {"enabled": False}}), data, scene)
    assert blocked_pattern(bare, "sim")["tracked_blocked"] == 0.0


def test_waypoint_geometry_with_the_phones_sensitivity_is_near_the_phone(magdeburg, waypoints):
    # The phone tracks down to its SNR floor of 12 dB-Hz (an MTK receiver stops at ~14): with
    # tracking thresholds like the phone's, the simulated receiver keeps clear satellites as
    # often as the phone and loses about as much on a building crossing, but tracks about half
    # as many blocked satellites (25 % vs 57 %): the paths it finds (for ~60 %) are often too
    # weak; the LOD1 mesh has no facade detail and single bounces only (see the README). The
    # paths it finds lose more than the phone's: measured 8.7 dB (median of 5 seeds; single
    # seeds 7.7-8.9) against the phone's 6.5.
    data, scene = magdeburg
    phone = load_profile("holux-m1000", {"cn0_tracking": {"acq_dbhz": 12.0, "track_dbhz": 9.0}})
    sim = sim_blocked_pattern(phone, data, scene)
    real = blocked_pattern(waypoints, "real")
    assert sim["tracked_clear"] == pytest.approx(real["tracked_clear"], abs=0.05)
    assert real["weaker_db"] < sim["weaker_db"] < real["weaker_db"] + 2.5
    assert 0.2 <= sim["tracked_blocked"] < real["tracked_blocked"]
