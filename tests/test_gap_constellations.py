"""The diagnosis and several satellite systems (issue 23): a log of a GPS + GLONASS receiver
diagnosed against a GPS-only profile names ``constellations`` and its systems; without a set of
the logged system's satellites the candidate is left out with the reason."""

from __future__ import annotations

import numpy as np
import pytest
from test_cli import write_walk
from test_nmea_multignss import multi_profile

from virtualgps.cli import main
from virtualgps.gap import diagnose as dg
from virtualgps.gap import tool
from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR

SETS = [str(BUNDLED_EPHEMERIS_DIR / f"{g}-2017-03-28.tle") for g in ("gps-ops", "glo-ops")]


@pytest.fixture(scope="module")
def two_system_log(tmp_path_factory):
    """Ten minutes of a walk on the campus, logged by holux-m1000 tracking GPS and GLONASS
    (NMEA 4.11: GN GSA per system, GLGSV)."""
    tmp = tmp_path_factory.mktemp("two-systems")
    walk = write_walk(tmp / "walk.jsonl", n=600, dt_s=1.0)
    prof = multi_profile(tmp / "two.toml")
    real = tmp / "real.nmea"
    assert main(["replay", str(walk), "--out", str(real), "--profile", str(prof), "--seed",
                 "777", *(f"--tle={s}" for s in SETS)]) == 0
    return real, walk


def test_a_two_system_log_against_a_gps_profile_names_constellations(two_system_log, tmp_path):
    real, walk = two_system_log
    inp = tool.GapInputs(real=(str(real),), truth=(str(walk),), scene=None, tle=tuple(SETS),
                         profile="holux-m1000")
    report, figures, calibrated = tool.diagnose(inp, dg.Options(seeds=10, jobs=1))
    added = [e for e in report["effects"] if e.get("accepted")]
    assert added and added[0]["name"] == "constellations", [
        (e["name"], e.get("accepted_test")) for e in report["effects"][:4]]
    assert added[0]["params"] == {"systems": ["GPS", "GLONASS"]}
    assert calibrated["constellations"] == {"enabled": True, "systems": ["GPS", "GLONASS"]}
    assert report["gap_final"] < 0.5 * report["gap_baseline"]
    # the GLONASS satellites are compared one by one (the view's columns hold both systems)
    rows = {w["metric"]: w for w in report["where"] if w["segment"] == "all"}
    assert rows["tracked_agreement"]["outside"] is True  # against GPS alone, before
    # per system: GLONASS untracked by the GPS profile, then tracked as the log does
    by = report["tracking_disagreement"]["by_system"]
    assert set(by) == {"GPS", "GLONASS"}
    assert by["GLONASS"]["baseline"] > 0.5 > 0.2 > by["GLONASS"]["final"]
    assert by["GPS"]["final"] < 0.2
    # the figures' baseline arrays (made while the effects were chosen) with the final's added
    assert figures.waterfall_labels == ("baseline", *(f"+{e['name']}" for e in added))
    assert figures.waterfall_gaps[0] > figures.waterfall_gaps[-1]
    run = figures.runs[0]
    assert run.final_err_h_m.shape == run.sim_err_h_m.shape == (10, run.t_unix_s.size)
    assert figures.final_acf.shape == figures.sim_acf.shape
    assert not np.array_equal(run.final_sats_used, run.sim_sats_used)  # GLONASS used too
    tool.write_outputs(report, figures, calibrated, report["profile"], tmp_path, 1, None)
    html = (tmp_path / "report.html").read_text()
    assert "Which satellites are tracked" in html and "<td>GLONASS</td>" in html


def test_without_a_set_of_the_logged_system_the_candidate_is_left_out(two_system_log):
    real, walk = two_system_log
    inp = tool.GapInputs(real=(str(real),), truth=(str(walk),), scene=None, tle=SETS[0],
                         profile="holux-m1000")
    report, _, _ = tool.diagnose(inp, dg.Options(seeds=6, jobs=1, effects=("constellations",)))
    assert "give --tle with a set of them" in report["candidates_skipped"]["constellations"]
    assert "GLONASS" in report["candidates_skipped"]["constellations"]
    assert not [e for e in report["effects"] if e.get("accepted")]
