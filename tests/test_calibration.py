"""holux-m1000 against the real MTK logs: the calibration table holds (issue #3).

The real column is measured on ../shared/data (MT3339 static hour, M-241 car track); the
simulated one replays the profile where and when each log was recorded and reads its NMEA back
through the same reader and statistics (tools/mtk_calibration.py). Tolerance: +-20 % on the
median over 8 seeds for every calibrated statistic (mtk_calibration.STATISTICS).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from mtk_calibration import (
    M241_SITE,
    STATISTICS,
    Row,
    Statistic,
    blocked_pattern,
    capture_bins,
    compare,
    sim_blocked_pattern,
    sim_calibration_stats,
    site_profile,
    waypoint_sky,
)
from mtk_logs import real_calibration_stats

from virtualgps.receiver.profiles import load_profile

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tables(shared_data):
    real = real_calibration_stats(shared_data)
    sim = sim_calibration_stats(
        load_profile("holux-m1000"), shared_data,
        mt3339_profile=site_profile("holux-m1000", ROOT / "tools" / "mt3339-site.toml"),
        m241_profile=site_profile("holux-m1000", M241_SITE))
    return real, sim


def test_holux_reproduces_the_real_mtk_statistics(tables):
    real, sim = tables
    rows = compare(real, sim)
    calibrated = [r for r in rows if r.ok is not None]
    bins = {f"{what}_el{lo}_{hi}_{unit}" for lo, hi in ((5, 15), (15, 30), (30, 60), (60, 90))
            for what, unit in (("cn0", "median_dbhz"), ("tracked", "share"))}
    assert {r.stat.key for r in calibrated} >= {
        "cep50_m", "r95_m", "autocorr_h_s", "sats_used_mean", "vdop_used_median",
        "hdop_median", *bins}
    # No calibrated row that the ephemeris alone fixes (issue #11): satellites in view
    assert not {r.stat.key for r in calibrated} & {"sats_in_view_gps_mean", "sats_in_view_mean"}
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


def test_per_bin_rows_fail_a_wrong_antenna(shared_data, tables):
    # The per-bin C/N0 rows can fail (the pooled quartiles could not): 5 dB more at the zenith,
    # or the old 26 dB roll-off, moves a bin out of its 3 dB.
    real, _ = tables
    for over in ({"cn0_zenith_dbhz": 48.0}, {"cn0_zenith_dbhz": 37.0, "horizon_loss_db": 26.0}):
        wrong = load_profile("holux-m1000", {"cn0_tracking": over, "sky_mask": _site_table()})
        sim = sim_calibration_stats(wrong, shared_data, seeds=(0,))
        rows = [r for r in compare(real, sim) if r.stat.key.startswith("cn0_el")]
        assert any(not r.ok for r in rows), over


def _site_table() -> dict:
    import tomllib

    return tomllib.loads((ROOT / "tools" / "mt3339-site.toml").read_text())["sky_mask"]


def test_open_sky_antenna_against_the_gpsd_captures(shared_data):
    # The antenna's open-sky C/N0 at the captures' own satellites: high satellites as the
    # captures print them (38-50 dB-Hz), low ones within the captures' spread; the captures'
    # low and middle satellites are 7-8 dB weaker than the model (README: Calibration).
    b = capture_bins(load_profile("holux-m1000"), shared_data)
    assert [x["n"] for x in b] == [28, 66, 87, 31]
    assert abs(b[3]["model_median_dbhz"] - b[3]["real_median_dbhz"]) <= 3.0
    assert b[0]["real_min_dbhz"] <= b[0]["model_median_dbhz"] <= b[0]["real_max_dbhz"]
    assert b[3]["real_min_dbhz"] <= b[3]["model_median_dbhz"] <= b[3]["real_max_dbhz"]


def test_tolerance_verdicts():
    st = Statistic("cep50_m", "mt3339_static", "CEP50 (m)", 0.2)
    assert Row(st, 4.0, 4.79, 4.0, 5.0).ok and not Row(st, 4.0, 4.81, 4.0, 5.0).ok
    db = Statistic("cn0_el5_15_median_dbhz", "mt3339_static", "x", None, 3.0)
    assert Row(db, 28.0, 25.0, 25.0, 25.0).ok and not Row(db, 28.0, 24.5, 24.0, 25.0).ok
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
    from virtualgps.run.config import BUNDLED_SCENES_DIR
    from virtualgps.sky.scene import load_scene

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
    # (measured: 59 % of them tracked, 9.4 dB weaker, medians of 5 seeds).
    assert 0.2 <= sim["tracked_blocked"] <= 0.8 * sim["tracked_clear"]
    assert 4.0 <= sim["weaker_db"] <= 11.0
    # Without nlos a blocked satellite is always lost.
    bare = waypoint_sky(load_profile("holux-m1000", {"nlos": {"enabled": False}}), data, scene)
    assert blocked_pattern(bare, "sim")["tracked_blocked"] == 0.0


def test_holux_tracks_blocked_satellites_about_as_often_as_the_phone(magdeburg, waypoints):
    # With its open-sky antenna (43 dB-Hz at the zenith) and MTK's 11 dB-Hz tracking floor,
    # holux-m1000 keeps building-crossing satellites about as often as the phone (measured 59 %
    # against 57 %), and clear ones at least as often (100 % against 91 %); the paths it finds
    # lose more than the phone's (9.4 dB against 6.5: the LOD1 mesh has no facade detail and
    # single bounces only). With the phone's 9 dB-Hz floor it tracks no fewer.
    data, scene = magdeburg
    real = blocked_pattern(waypoints, "real")
    sim = sim_blocked_pattern(load_profile("holux-m1000"), data, scene)
    assert sim["tracked_blocked"] == pytest.approx(real["tracked_blocked"], abs=0.1)
    assert sim["tracked_clear"] >= real["tracked_clear"]
    assert real["weaker_db"] < sim["weaker_db"] < real["weaker_db"] + 4.0
    phone = load_profile("holux-m1000", {"cn0_tracking": {"acq_dbhz": 12.0, "track_dbhz": 9.0}})
    assert sim_blocked_pattern(phone, data, scene)["tracked_blocked"] >= sim["tracked_blocked"]
