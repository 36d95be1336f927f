"""The sim-to-real gap tool (issue #8): its statistics against closed forms and numpy, the
withheld-effect self-check, and the real withheld cases of ../shared/data through the command
line (reading real logs: test_gap_ingest.py)."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tests.test_gap_ingest import sentence
from virtualgps.gap import diagnose as dg
from virtualgps.gap import effects as fx
from virtualgps.gap import fit, motion, observed, runs, where
from virtualgps.gap.ingest import read_real_log
from virtualgps.receiver.profiles import build_profile, load_profile, load_profile_dict


@pytest.fixture(autouse=True)
def stop_workers():
    """Local worker pools live for the process; a test ends with none (no leaked pipes)."""
    yield
    from virtualgps.gap import jobs

    jobs.shutdown()


# --- statistics ----------------------------------------------------------------------------------


def test_row_quantile_is_numpys_nanquantile():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(6, 300))
    x[x > 1.2] = np.nan
    x[4] = np.nan  # an empty row
    for q in (0.05, 0.5, 0.95):
        got = where.row_quantile(x, q)
        rows = [0, 1, 2, 3, 5]
        np.testing.assert_allclose(got[rows], np.nanquantile(x[rows], q, axis=1), rtol=1e-12)
        assert np.isnan(got[4])


def test_binned_quantile_of_whole_numbers_is_the_order_statistic():
    rng = np.random.default_rng(2)
    x = rng.integers(10, 50, size=(4, 500)).astype(float)
    m = rng.random(x.shape) > 0.3
    got = where.binned_quantile(x, m, 0.5, 1.0, 99.0)
    for i in range(4):
        v = np.sort(x[i][m[i]])
        assert got[i] == v[(v.size - 1) // 2]


def test_lag_recovers_a_known_latency():
    """e = b - L v + noise: the least-squares lag is L within its noise (vehicle turning)."""
    rng = np.random.default_rng(3)
    t = np.arange(600.0)
    heading = 0.02 * t
    vel = np.stack([5 * np.sin(heading), 5 * np.cos(heading), 0 * t], axis=1)
    err = np.array([2.0, -1.0, 0.0]) - 1.3 * vel + rng.normal(0, 1.0, (600, 3))
    lag = motion.lag_s(err[None], vel, np.ones(600, bool))
    assert lag[0] == pytest.approx(1.3, abs=0.05)


def test_position_quantum_is_the_logs_printed_resolution():
    lat = 52.0 + np.round(np.random.default_rng(4).normal(0, 1e-4, 200) * 6e5) / 6e5
    assert observed.position_quantum_min(lat, lat) == pytest.approx(1e-4)


def _read_fixes(lats, lons) -> tuple[np.ndarray, np.ndarray]:
    """Fixes printed as GGA fields (ddmm.mmmm, hemisphere) and read back by the log reader."""
    from datetime import date

    from virtualgps.device.nmea import nmea_epochs_from_lines
    from virtualgps.device.nmea.sentence import format_sentence

    lines = [format_sentence(f"GPGGA,1200{i:02d}.00,{la},{lh},{lo},{oh},1,08,1.0,10.0,M,0.0,M,,")
             for i, ((la, lh), (lo, oh)) in enumerate(zip(lats, lons, strict=True))]
    ep = nmea_epochs_from_lines(lines, default_date=date(2020, 5, 14))
    return ep.lat_deg, ep.lon_deg


@pytest.mark.parametrize(("lats", "lons", "quantum"), [
    # one fix printed throughout (an ideal receiver, a held static fix), south and east
    ([("2609.8760", "S")] * 50, [("07629.4120", "E")] * 50, 1e-3),
    # one fix of a logger printing two decimals, west
    ([("4807.04", "N")], [("12205.00", "W")], 1e-2),
    # six fixes printed to 1e-6 that step by ~1e-3 (gpsd's mtk-3301.log)
    ([("5212.982135", "N"), ("5212.981473", "N"), ("5212.982641", "N"), ("5212.981832", "N"),
      ("5212.982003", "N"), ("5212.981120", "N")],
     [("00653.101394", "E"), ("00653.102458", "E"), ("00653.105897", "E"),
      ("00653.104686", "E"), ("00653.103301", "E"), ("00653.102207", "E")], 1e-6),
    # a phone's seven decimals, stepping by far more
    ([("3725.4147812", "N"), ("3725.4148423", "N")],
     [("12205.6470745", "W"), ("12205.6472189", "W")], 1e-7),
    # two fixes far apart
    ([("4807.0400", "N"), ("4807.9400", "N")], [("01131.0000", "E")] * 2, 1e-2),
])
def test_position_quantum_is_read_from_the_digits_not_the_steps(lats, lons, quantum):
    """Every fix lies on the printed grid, however few fixes or steps there are; and rounding
    fixes to it moves them by at most half a step (a log of one repeated fix was once read as
    printing to 10,000 arc-minutes, and its simulation rounded thousands of km away)."""
    lat, lon = _read_fixes(lats, lons)
    q = observed.position_quantum_min(np.append(lat, np.nan), np.append(lon, np.nan))
    assert q == pytest.approx(quantum)
    sim = lat[:1] + np.array([0.0, 3e-7, -2e-6])  # simulated fixes near the first
    obs = observed.Obs(lat_deg=sim[None], lon_deg=np.full((1, 3), lon[0]),
                       alt_hae_m=np.zeros((1, 3)), quality=np.ones((1, 3), np.int16),
                       hdop=np.ones((1, 3)), sats_used=np.full((1, 3), 8.0),
                       speed_mps=np.zeros((1, 3)), tracked=np.zeros((1, 3, 1), bool),
                       cn0_dbhz=np.full((1, 3, 1), np.nan), used=np.zeros((1, 3, 1), bool))
    moved_min = np.abs(observed.quantize(obs, q).lat_deg - sim) * 60.0
    assert np.all(moved_min <= q / 2 + 1e-12)


def test_a_log_without_a_fix_prints_no_position_resolution():
    assert observed.position_quantum_min(np.full(5, np.nan), np.full(5, np.nan)) == 0.0


# --- candidates and profiles ---------------------------------------------------------------------


def test_candidates_are_the_effects_a_profile_lacks_and_build_valid_profiles():
    usarsim, _ = load_profile_dict("usarsim")
    cands, skipped = fx.candidates(usarsim, has_mesh=True)
    names = {c.name for c in cands}
    assert {"correlated_error", "cold_start", "nlos", "cn0_tracking", "latency", "noise_level",
            "dop_error", "foliage", "elevation_mask", "static_hold", "nav_filter",
            "sbas"} <= names
    assert "multipath" in skipped  # needs dop_error
    holux, _ = load_profile_dict("holux-m1000")
    hc = {c.name for c in fx.candidates(holux, has_mesh=False)[0]}
    assert "correlated_error" not in hc and "nlos" not in fx.candidates(holux, True)[0]
    # holux-m1000 powers on hot: a slow start is what it lacks, tried from the grid's centre
    # (it names no cold TTFF); where no log starts at power-on, a start-up cannot show and it
    # is not tried
    cold = {c.name: c for c in fx.candidates(holux, has_mesh=False)[0]}["cold_start"]
    assert cold.points[cold.default_index] == {"ttff_cold_s": 30.0}
    assert "cold_start" in fx.candidates(holux, False, starts=False)[1]
    cold_holux = fx.apply(holux, cold.grid[-1])
    assert "cold_start" not in {c.name for c in fx.candidates(cold_holux, False)[0]}
    # its error is DOP-driven: noise_level scales the whole range-error budget (the UERE and
    # the correlated error's sigma), from 1, the profile as it is
    nl = {c.name: c for c in fx.candidates(holux, has_mesh=False)[0]}["noise_level"]
    assert nl.points[nl.default_index] == {"scale": 1.0}
    same = fx.apply(holux, nl.grid[nl.default_index])
    assert build_profile(same) == build_profile(holux)
    third = build_profile(fx.apply(holux, nl.grid[0]))  # (the grid's 0.25)
    assert third.correlated_error.sigma_m == pytest.approx(0.25 * 3.5, abs=1e-3)
    assert third.dop_error.iono_zenith_m == pytest.approx(0.5)
    for c in cands:
        for pt in (c.grid[0], c.grid[-1], c.grid[c.default_index]):
            build_profile(fx.apply(usarsim, pt))  # every grid point is a valid profile


def _tried(before: list[float], after: list[float]):
    from virtualgps.gap import select

    b, a = np.array(before), np.array(after)
    return select.Tried(cand=fx.Candidate("multipath", (), lambda p: {}, ()), fold_overrides=[],
                        fold_points=[], before=b, after=a, before_fit=b, after_fit=a - 0.01,
                        metrics_before={}, metrics_after={})


def test_acceptance_does_not_jump_as_a_group_crosses_the_flat_threshold():
    """The held-out gain over the groups an effect changes is continuous in each group's
    change: a group changed by just under FLAT_MIN counts almost as one changed by just over
    it (counted whole or not at all, such a group turned a gain under 0.1 over three groups
    into one over 0.1 over two); a start-up that leaves the other groups unchanged is judged
    on the group it changes, undiluted."""
    from virtualgps.gap import select

    flat = fit.FLAT_MIN
    gains = [0.13, 0.09, 0.0]  # a mean over the first two of 0.11, over three 0.073
    verdicts = []
    for third in (flat * 0.999, flat * 1.001):
        before = [1.0, 1.0, 1.0]
        after = [1.0 - gains[0], 1.0 - gains[1], 1.0 - third]
        verdicts.append(select.acceptable(_tried(before, after), 1.0)[0])
    assert verdicts[0] == verdicts[1] is False
    # a start-up: one group changed, the others untouched
    ok, why = select.acceptable(_tried([1.0, 1.0, 1.0], [0.8, 1.0, 1.0]), 1.0)
    assert ok, why
    # a large help in one group, harm in two: not most of what it changes
    ok, why = select.acceptable(_tried([1.0, 1.0, 1.0], [0.1, 1.2, 1.2]), 1.0)
    assert not ok and "fewer than half" in why


def test_calibrated_profile_toml_round_trips(tmp_path):
    table, _ = load_profile_dict("holux-m1000")
    table = fx.apply(table, {"latency": {"enabled": True, "latency_s": 0.5}})
    p = tmp_path / "cal.toml"
    dg.write_profile(table, "holux-m1000", ["latency"], p)
    prof = load_profile(str(p))
    assert prof.latency.enabled and prof.latency.latency_s == 0.5
    assert prof.name == "holux-m1000-calibrated"
    assert prof.description == "holux-m1000 + latency"
    assert tomllib.loads(p.read_text())["nmea"]["sentences"][0] == "GGA"
    # what the outer test cannot vouch for heads the file as comments; it loads the same
    note = ("the outer test does not confirm latency: on data that neither the choice nor the "
            "fit saw the gap fell by -0.351 (95 %: -1.028 to 0.325), not clearly above 0")
    dg.write_profile(table, "holux-m1000", ["latency"], p, [note])
    head = [x for x in p.read_text().splitlines() if x.startswith("#")]
    assert len(head) >= 4 and all(len(x) <= 100 for x in head)
    assert " ".join(x[2:] for x in head[2:]) == note[0].upper() + note[1:] + "."
    assert load_profile(str(p)).latency.latency_s == 0.5
    # calibrated again: the name stays, the description grows by what this run added
    again, _ = load_profile_dict(str(p))
    p2 = tmp_path / "again.toml"
    dg.write_profile(again, "holux-m1000-calibrated", ["dop_error", "noise_level"], p2)
    prof = load_profile(str(p2))
    assert prof.name == "holux-m1000-calibrated"
    assert prof.description == "holux-m1000 + latency + dop_error, noise_level"
    dg.write_profile(again, "holux-m1000-calibrated", [], p2)
    assert load_profile(str(p2)).description == "holux-m1000 + latency"
    dg.write_profile(table, "holux-m1000", [], p2)
    nothing, _ = load_profile_dict(str(p2))
    assert nothing["description"] == "holux-m1000 (no effect reduced the held-out gap)"
    dg.write_profile(nothing, "holux-m1000-calibrated", ["latency"], p2)
    assert load_profile(str(p2)).description == "holux-m1000 + latency"


def test_fit_keeps_the_default_without_evidence():
    j = np.array([0.50, 0.501, 0.499])
    assert fit.fit_index(j, default=1) == 1
    j[0] = 0.3  # clear evidence for point 0
    assert fit.fit_index(j, default=1) == 0


def test_learned_sky_mask_blocks_bins_the_real_receiver_loses():
    n_bins = 6 * 12  # 15 x 30 deg bins
    counts = np.zeros((5, n_bins))
    counts[0, [8, 9, 30, 40]] = [600, 600, 600, 10]  # compared satellite-epochs
    counts[2, [8, 9, 30, 40]] = [290, 580, 600, 10]  # simulated tracked (low bins: part time)
    counts[1, [8, 9, 30, 40]] = [0, 520, 590, 0]  # real: loses bin 8 (and 40, too few epochs)
    table = fx.learned_sky_mask(counts, 0.25, 30.0, 15.0)["sky_mask"]
    atten = np.array(table["atten_db"])
    assert atten.shape == (1, 12) and np.isinf(atten[0, 8]) and np.isfinite(atten).sum() == 11
    counts[1, 8] = 200  # tracked 2/3 as often as simulated: an attenuation, not a mask
    assert fx.learned_sky_mask(counts, 0.25, 30.0, 15.0) is None


def test_learned_sky_mask_attenuates_bins_tracked_weaker():
    n_bins = 6 * 12
    counts = np.zeros((5, n_bins))
    counts[0, [3, 20, 50]] = 600
    counts[1, [3, 20, 50]] = [600, 590, 20]  # real tracked (bin 50: too few to judge its SNR)
    counts[2, [3, 20, 50]] = 600  # simulated tracked
    counts[3, [3, 20, 50]] = np.array([600, 590, 20]) * [30.0, 38.0, 10.0]  # real SNR sums
    counts[4, [3, 20, 50]] = 600 * np.array([42.0, 39.5, 40.0])  # simulated SNR sums
    blocked = np.array(fx.learned_sky_mask(counts, 0.25, 30.0, 15.0)["sky_mask"]["atten_db"])
    assert np.isinf(blocked[4, 2]) and (blocked > 0).sum() == 1  # (no attenuation asked)
    atten = np.array(fx.learned_sky_mask(counts, 0.25, 30.0, 15.0, atten=True)
                     ["sky_mask"]["atten_db"])
    # bin 3: 12 dB weaker; bin 20: 1.5 dB, within a log's fades; bin 50 lost: blocked
    assert atten.shape == (5, 12) and atten[0, 3] == 12.0 and atten[1, 8] == 0.0
    assert np.isinf(atten[4, 2]) and (atten > 0).sum() == 2


def test_selfcheck_sector_lies_where_satellites_pass_low_inside_and_outside():
    from virtualgps.gap import synthetic

    low = np.zeros(12)
    low[[2, 7]] = 2.0  # two satellites low in the sky at 60-90 deg, two at 210-240 deg
    for seed in range(20):
        rows = np.array(synthetic._sector(np.random.default_rng(seed), low))
        blocked = np.isinf(rows[0])
        assert 2 <= blocked.sum() <= 4 and blocked[2] != blocked[7]


# --- self-check and real cases -------------------------------------------------------------------


def test_an_interval_of_grid_points_holds_what_rounds_into_it():
    from virtualgps.gap.synthetic import covered

    grid = {"tau_s": [1.5, 2.0, 2.5, 3.0, 16.0]}
    one = {"tau_s": [2.5, 2.5]}
    assert covered({"tau_s": 2.7}, one, grid) == {"tau_s": True}  # nearer 2.5 than 3.0
    assert covered({"tau_s": 2.26}, one, grid) == {"tau_s": True}
    assert covered({"tau_s": 2.8}, one, grid) == {"tau_s": False}
    assert covered({"tau_s": 2.7}, one) == {"tau_s": False}  # (no grid: the span itself)
    assert covered({"tau_s": 20.0}, {"tau_s": [16.0, 16.0]}, grid) == {"tau_s": False}
    assert covered({"tau_s": 10.0}, {"tau_s": [16.0, 16.0]}, grid) == {"tau_s": True}
    assert covered({"velocity_aided": True}, {"velocity_aided": [True]}, grid) == {}


def test_the_report_says_which_values_round_into_a_fits_interval():
    """The report's ``fit.spans``, its page and the terminal state the values a fit resolves
    into its interval's grid points: those the self-check counts as held."""
    from virtualgps.gap import report as rp
    from virtualgps.gap import tool
    from virtualgps.gap.fit import Fitted
    from virtualgps.gap.synthetic import covered

    grid = {"tau_s": [1.5, 2.0, 2.5, 3.0, 16.0], "sigma_m": [1.0, 2.0, 4.0]}
    fit = Fitted({}, {"tau_s": 2.5, "sigma_m": 4.0},
                 intervals={"tau_s": [2.0, 3.0], "sigma_m": [4.0, 4.0],
                            "velocity_aided": [False, True]},
                 identifiable={"tau_s": True, "sigma_m": True, "velocity_aided": False},
                 grid=grid).public()
    assert fit["spans"] == {"tau_s": [1.75, 9.5], "sigma_m": [3.0, 4.0]}  # (4 m: the top)
    for name, v, held in (("tau_s", 1.76, True), ("tau_s", 9.4, True), ("tau_s", 9.6, False),
                          ("sigma_m", 3.01, True), ("sigma_m", 2.99, False)):
        assert covered({name: v}, fit["intervals"], grid)[name] is held, (name, v)
    effect = {"name": "correlated_error", "accepted": True, "gap_before": 1.0,
              "gap_after": 0.4, "fit": fit,
              "params": {"tau_s": 2.5, "sigma_m": 4.0, "velocity_aided": False}}
    notes = rp._effect_rows({"effects": [effect]})[0]["notes"]
    assert "tau_s 2–3 on the grid (values 1.75–9.5 round into it)" in notes
    assert "velocity_aided not identifiable" in notes
    report = {"headline": [], "outer": {}, "design": {"scheme": "", "warnings": []},
              "runs": [], "effects": [effect], "located": [], "profile": "usarsim",
              "gap_baseline": 1.0, "causes": []}
    assert tool.summary_lines(report)[-1] == (
        "  effect correlated_error (added): held-out gap 1.000 -> 0.400; tau_s=2.5 (1.75..9.5), "
        "sigma_m=4 (3..4), velocity_aided=False (not identifiable)")
    # a fit still at its grid's end after extending it is a bound (a 0.2 Hz phone log's
    # velocity-aided filter: tau_s at 32 s, the top)
    effect["fit"] = dict(fit, bounds={"tau_s": ">= 16"}, grid_edge={"tau_s": "upper"})
    effect["params"] = {"tau_s": 16.0, "sigma_m": 4.0}
    assert tool.summary_lines(report)[-1].endswith(
        "tau_s=16 (>= 16: at the grid's end, a bound), sigma_m=4 (3..4)")
    # a learned sky mask's table is said by its cells that attenuate, not cell by cell
    effect = {"name": "sky_mask", "accepted": False, "gap_before": 1.0, "gap_after": 1.0,
              "fit": {}, "params": {"az_bin_deg": 30, "atten_db": [[0.0, 0.0, 3.0],
                                                                   [2.0, 0.0, 0.0]]}}
    report["effects"] = [effect]
    said = "az_bin_deg=30, atten_db=2 of 6 cells not zero, up to 3"
    assert tool.summary_lines(report)[-1].endswith(said)
    assert rp._effect_rows(report)[0]["params"] == said


def test_selfcheck_ranks_injected_effects_first(tmp_path):
    from virtualgps.gap import selfcheck

    res = selfcheck.run(dg.Options(seeds=10, jobs=2, effects=("latency", "sbas")), trials=1,
                        out_dir=tmp_path)
    assert [t["ranked_first"] for t in res["trials"]] == ["latency", "sbas"]
    assert all(t["success"] and t["ranked"][0] == t["ranked_first"] for t in res["trials"])
    lat = res["trials"][0]
    lo, hi = lat["recovered_interval"]["latency_s"]
    assert lo <= lat["recovered"]["latency_s"] <= hi and lat["covered"] == {"latency_s": True}
    assert lat["recovered"]["latency_s"] == pytest.approx(lat["params"]["latency_s"], abs=0.3)
    doc = json.loads((tmp_path / "selfcheck.json").read_text())
    assert set(doc) >= {"trials", "confusion", "null_calibration"}
    assert doc["confusion"]["latency"] == {"latency": 1}
    assert (tmp_path / "report.html").stat().st_size > 10_000
    # whether the outer test confirmed what each trial added, counted for right and wrong trials
    for t in res["trials"]:
        lo = t["outer_interval"][0]
        assert t["outer_confirmed"] == (None if not math.isfinite(lo) else lo > 0), t
    judged = [t for t in res["trials"] if t["outer_confirmed"] is not None]
    assert doc["outer_confirmation"]["right"] == {
        "trials": len(judged), "confirmed": sum(t["outer_confirmed"] for t in judged)}
    assert any(x.startswith("  outer test confirms what was added in ")
               for x in selfcheck.summary_lines(res))


def test_selfcheck_null_adds_nothing_and_a_pair_adds_both(tmp_path):
    """A log made by the profile under test itself: "nothing" first, and no located gap beyond
    the false-discovery rate; two effects injected at once: both are the first added."""
    from virtualgps.gap import selfcheck

    res = selfcheck.run(dg.Options(seeds=12, jobs=2), trials=1, out_dir=tmp_path,
                        labels=["nothing@holux-m1000", "cold_start+latency"])
    null, pair = res["trials"]
    assert null["ranked_first"] == "nothing" and null["accepted"] == [], null
    assert null["alternative"] is None  # (nothing added: no second search, no alternative)
    assert null["where_outside"] <= 0.05 * null["where_rows"]
    assert res["null_calibration"]["reports"] == 1
    # every trial's seeds held out in turn: 12 reports each, added up
    assert null["seed_holdout"]["reports"] == pair["seed_holdout"]["reports"] == 12
    held = res["null_calibration"]["seed_holdout"]
    assert held["truths"] == 2 and held["reports"] == 24
    assert held["reports_with_any_row_outside"] == sum(
        t["seed_holdout"]["reports_with_any_row_outside"] for t in res["trials"])
    assert set(pair["accepted"][:2]) == {"cold_start", "latency"}, pair
    assert res["confusion"]["nothing@holux-m1000"] == {"nothing": 1}
    assert "  nothing@holux-m1000: right 1/1" in selfcheck.summary_lines(res)
    # (no single-effect trial here: none to count, rather than "ranked first in 0 %")
    assert selfcheck.summary_lines(res)[0].endswith("; no single-effect trials")
    assert " %: no single-effect trials;" in (tmp_path / "report.html").read_text()


def test_a_null_trial_takes_any_profile(tmp_path):
    """``nothing@PROFILE`` is the null of any profile (a name or a TOML path), in the four
    kinds of place; usarsim's in open sky. A path's trial is written under the work folder,
    its separators out of the file names."""
    from virtualgps.gap import synthetic
    from virtualgps.sky.ephemeris import default_tle_path

    for name in ("ublox-m8n", "phone", "my/own.toml"):
        spec = synthetic.spec_of(f"nothing@{name}")
        assert spec.base == name and spec.scenarios == synthetic.ALL_SCENARIOS
    assert synthetic.spec_of("nothing@usarsim").scenarios == ("static_open", "moving_open")
    own = tmp_path / "mine" / "m8n-5hz.toml"
    own.parent.mkdir()
    table, _ = load_profile_dict("ublox-m8n")
    own.write_text(fx.to_toml(dict(table, name="m8n-5hz", rate_hz=5.0)), encoding="utf-8")
    work = tmp_path / "work"
    tle = str(default_tle_path())
    tr = synthetic.make_trial(f"nothing@{own}", 0, work, None, "", tle, tle)  # static, open
    assert tr.scenario == "static_open" and tr.real.parent == work
    assert tr.real.name == f"{synthetic.trial_tag(f'nothing@{own}')}-0.nmea"
    assert "/" not in tr.real.name and tr.profile.parent == work
    rmc = [ln for ln in tr.real.read_text().splitlines() if ln[3:6] == "RMC"]
    assert len(rmc) == 5 * synthetic.DURATION_S + 1  # the profile's own rate, 5 Hz
    assert synthetic.trial_tag("cold_start+latency") == "cold_start-latency"
    assert synthetic.trial_tag("nothing@holux-m1000") == "nothing-holux-m1000"


def test_an_effect_trial_takes_another_profile(tmp_path):
    """``EFFECT@PROFILE`` injects the effect's own draw into another profile and withholds it
    there (a u-blox already has a correlated error: it is switched off in the profile under
    test, and on in the log); the noise trials, stated in their own base's noise, and names
    no trial injects are refused with a reason."""
    from virtualgps.gap import selfcheck, synthetic
    from virtualgps.sky.ephemeris import default_tle_path

    spec = synthetic.spec_of("latency@ublox-m8n")
    assert (spec.base, spec.kind, spec.effects) == ("ublox-m8n", "single", ("latency",))
    assert spec.scenarios == synthetic.INJECTIONS["latency"].scenarios
    assert synthetic.spec_of("cold_start+latency@phone").base == "phone"
    with pytest.raises(ValueError, match="usarsim only"):
        synthetic.spec_of("noise_level@ublox-m8n")
    with pytest.raises(ValueError, match="no self-check trial injects foliage"):
        synthetic.spec_of("foliage")
    assert selfcheck.default_labels(("latency@ublox-m8n", "real:gsdc:latency", "nothing")) == [
        "latency@ublox-m8n", "nothing"]
    # (a u-blox's trial runs at the scene set's date, where GLONASS sets are bundled too)
    scene_tle = str(default_tle_path().with_name("gps-ops-2017-03-26.tle"))
    tr = synthetic.make_trial("correlated_error@ublox-m8n", 0, tmp_path, None, "", scene_tle,
                              str(default_tle_path()))
    assert tr.scenario == "static_open"
    sets = [Path(p).name for p in tr.tle.split(os.pathsep)]
    assert sets[0] == "gps-ops-2017-03-26.tle" and sets[1].startswith("glo-ops-2017-03-2")
    tested = tomllib.loads(tr.profile.read_text())
    assert tested["name"] == "ublox-m8n-without-correlated_error"
    assert tested["correlated_error"]["enabled"] is False
    assert tested["constellations"] == load_profile_dict("ublox-m8n")[0]["constellations"]
    assert tr.injected["correlated_error"]["enabled"] is True
    talkers = {ln[1:3] for ln in tr.real.read_text().splitlines() if ln[3:6] == "GSV"}
    assert len(talkers) > 1  # the u-blox's own sky (GPS and more), not holux-m1000's GPS alone


def test_selfcheck_tells_the_papers_noise_from_dop_driven_errors(tmp_path):
    """Both make larger white errors; the paper's leaves the height alone and DOP-driven ones
    scatter it (``up_p68_m``): without that metric 3 of 10 noise_level trials went to
    dop_error."""
    from virtualgps.gap import selfcheck

    res = selfcheck.run(dg.Options(seeds=10, jobs=2, effects=("noise_level", "dop_error")),
                        trials=2, out_dir=tmp_path)
    assert [t["ranked_first"] for t in res["trials"]] == ["noise_level"] * 2 + ["dop_error"] * 2
    for t in res["trials"]:
        assert t["gap_after"] < 0.5 * t["gap_before"]
        # each recovered on the candidate's one axis, a scale: the paper's noise drawn as one,
        # the DOP-driven errors' UERE budget as it is (1)
        assert t["covered"] == {"scale": True}, (t["params"], t["recovered"])
        assert t["recovered"]["scale"] == pytest.approx(t["params"]["scale"], rel=0.45)
    assert {t["params"]["scale"] for t in res["trials"][2:]} == {1.0}


def _gap_cli(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "virtualgps", "gap", *args],
                          capture_output=True, text=True, timeout=900)


@pytest.mark.slow
def test_mt3339_hour_names_correlated_error_and_cold_start(shared_data, tmp_path):
    import gap_cases

    inp = gap_cases.case_inputs("mt3339", shared_data)
    out = tmp_path / "mt"
    r = _gap_cli(["--real", inp.real[0], "--truth", "static", "--scene", "none", "--tle",
                  inp.tle, "--profile", "usarsim", "--seeds", "20", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert set(report) >= {"runs", "profile", "where", "effects", "gap_baseline", "gap_final",
                           "unexplained", "calibrated_profile", "not_assessed"}
    for what, ok, measured in gap_cases.checks("mt3339", report):
        assert ok, f"{what}: {measured}"
    # the hour holds one power-on: the outer group that holds it chose without a start-up,
    # and the report says the outer test cannot judge cold_start (it judges the rest)
    assert [n["effect"] for n in report["outer"]["not_judged"]] == ["cold_start"]
    assert report["outer"]["not_judged"][0]["shows_in"][0].startswith("time block 1/")
    assert "the outer test cannot judge cold_start" in r.stdout
    # what it judges it confirms (the reduction's interval above 0): no such note; the page and
    # the calibrated profile's head carry the one about cold_start
    assert report["outer"]["confirmed"] is True and "does not confirm" not in r.stdout
    assert "<p><b>Note:</b> The outer test cannot judge cold_start" in (
        out / "report.html").read_text()
    assert "# The outer test cannot judge cold_start" in (out / "calibrated.toml").read_text()
    # the bands checked on the seeds themselves: each of the 20 taken as the real log
    held = report["band"]["seed_holdout"]
    assert held["reports"] == 20 and 0 <= held["reports_with_any_row_outside"] <= 20
    assert held["rows"] > len(report["where"]) and held["rows_outside"] == sum(
        held["metrics"].values())
    assert "Checked on the seeds themselves" in (out / "report.html").read_text()
    w = {(x["metric"], x["segment"]) for x in report["where"]}
    assert {("cep50_m", "all"), ("autocorr_s", "all"), ("ttff_s", "startup"),
            ("eq4_deg", "all")} <= w
    # the calibrated profile runs in replay
    poses = tmp_path / "still.jsonl"
    poses.write_text("".join(json.dumps({"t": 1489257600.0 + k, "x": 0.0, "y": 0.0, "z": 0.0})
                             + "\n" for k in range(30)))
    cal = out / report["calibrated_profile"]
    rep = subprocess.run([sys.executable, "-m", "virtualgps", "replay", str(poses), "--out",
                          str(tmp_path / "x.nmea"), "--profile", str(cal), "--scene", "none",
                          "--origin", "44.98,-93.24,250", "--tle", inp.tle],
                         capture_output=True, text=True, timeout=120)
    assert rep.returncode == 0, rep.stderr
    assert (tmp_path / "x.nmea").read_text().count("$GPGGA") == 30


@pytest.mark.slow
def test_magdeburg_waypoints_rank_nlos_first(shared_data, tmp_path):
    import gap_cases

    report, _ = gap_cases.run_case("magdeburg", shared_data, tmp_path, dg.Options(seeds=20))
    for what, ok, measured in gap_cases.checks("magdeburg", report):
        assert ok, f"{what}: {measured}"


@pytest.mark.slow
def test_gsdc_drive_without_gsv_reports_what_it_cannot_assess(shared_data, tmp_path):
    import gap_cases

    report, _ = gap_cases.run_case("gsdc", shared_data, tmp_path, dg.Options(seeds=10))
    for what, ok, measured in gap_cases.checks("gsdc", report):
        assert ok, f"{what}: {measured}"
    html = (tmp_path / "gsdc" / "report.html").read_text()
    assert "no GSV" in html or "not assessed" in html.lower()
    # a roboticist's minute: the headline in metres and seconds, what the score means, the
    # lag between the phone's fixes and the truth, in a real browser with every figure drawn
    from test_report import _rendered_widths

    assert "At a glance" in html and "How to read the gap score" in html
    assert re.search(r"<td>CEP50</td><td>[0-9.]+ m</td>", html)
    assert re.search(r"<td>smoothing</td><td>[0-9.]+ s</td>", html)  # (a delay's or a filter's)
    assert "the fixes lag the truth by" in html
    widths = _rendered_widths(tmp_path / "gsdc" / "report.html", tmp_path)
    assert len(widths) >= 7 and all(w > 100 for w in widths), widths


@pytest.mark.slow
def test_a_drive_far_from_the_origin_blames_the_flat_earth_not_the_truth(shared_data):
    """The GSDC drive (SPAN truth, right to centimetres) against ``usarsim``, whose flat-earth
    conversion misplaces the simulated antenna by up to 56 m there: the georeference is named
    and swapped, and the truth stays where it is (judged against the seeds as they were, it
    was "29 m off", moved, and the phone's 0.8 m CEP50 read as 28.6 m)."""
    from dataclasses import replace

    import gap_cases

    from virtualgps.gap import tool

    inp = replace(gap_cases.case_inputs("gsdc", shared_data), profile="usarsim")
    report, _, _ = tool.diagnose(inp, dg.Options(seeds=8, jobs=2))
    causes = {c["name"]: c for c in report["causes"]}
    assert causes["georeference_model"]["applied"]
    off = causes["truth_offset"]
    assert off["reference"] == "wgs84" and not off["applied"], off
    assert "exact conversion" in off["reference_note"]
    cep = next(w for w in report["where"] if (w["metric"], w["segment"]) == ("cep50_m", "all"))
    assert cep["real"] < 1.5  # the phone's own error, about the SPAN truth


def test_a_selfcheck_runs_the_real_log_trials_it_names_and_no_others(tmp_path):
    """``--effects`` names the self-check's trials, the real-log ones by their label: naming
    only synthetic trials runs none of them (before, every one ran, some ten minutes); an
    unknown label is one clear error before anything runs."""
    from virtualgps.gap import selfcheck_real as sr

    assert sr.named_effects(None) == sr.REAL_EFFECTS
    assert sr.named_effects(("latency", "nothing@usarsim")) == ()
    assert sr.named_effects(("latency", "real:gsdc:nav_filter")) == ("nav_filter",)
    with pytest.raises(ValueError, match="real:gsdc:latency"):
        sr.named_effects(("real:latency",))
    r = _gap_cli(["--selfcheck", "--effects", "sbas,real:gsdc:delay", "--out", str(tmp_path)])
    assert r.returncode == 2 and "unknown real-log trial real:gsdc:delay" in r.stderr, r.stderr
    assert not (tmp_path / "work").exists()


def test_the_real_bases_slow_offset_is_a_gauss_markov_process_of_its_tau_and_sigma():
    """The slow offset injected into a real log: per horizontal axis a stationary first-order
    Gauss-Markov process, its standard deviation sigma and its autocorrelation e^-1 at a lag of
    tau (closed form), whatever the steps between fixes."""
    from virtualgps.gap import selfcheck_real as sr

    rng = np.random.default_rng(3)
    t = np.cumsum(rng.choice([1.0, 1.0, 2.0], size=40000))
    lat, lon = np.full(t.size, 37.4), np.full(t.size, -122.1)
    nlat, nlon = sr.inject("correlated_error", 50.0, t, lat, lon, np.zeros(t.size), 3.0,
                           np.random.default_rng(4))
    off = sr._enu(nlat, nlon, 37.4, -122.1)
    assert np.std(off, axis=0) == pytest.approx([3.0, 3.0], rel=0.1)
    k = np.searchsorted(t, t + 50.0)[: t.size // 2]  # the fix 50 s later (or the next one)
    i = np.arange(k.size)[t[k] - t[: k.size] == 50.0]
    rho = [np.corrcoef(off[i, a], off[k[i], a])[0, 1] for a in (0, 1)]
    assert rho == pytest.approx([math.exp(-1.0)] * 2, abs=0.08)


def test_the_real_bases_injections_print_what_a_receiver_prints(tmp_path):
    """A cold start blanks the fixes of a log's first seconds across midnight, as a receiver
    without a fix prints them; moved fixes keep the log's digits. pynmeagps reads every
    changed sentence (checksums checked) and the gap tool's reader sees no fix where blanked,
    the new position where moved."""
    import datetime as dt

    import pynmeagps

    from virtualgps.device.nmea import nmea_checksum
    from virtualgps.gap.selfcheck_real import blank_fixes, rewrite_fixes

    def line(body: str) -> str:
        return f"${body}*{nmea_checksum(body)}"

    lines = []
    for tod in ("235958.00", "235959.00", "000000.00", "000001.00", "000002.00"):
        lines += [line(f"GPGGA,{tod},3725.415069,N,12205.647326,W,1,08,0.9,10.0,M,0.0,M,,"),
                  line(f"GPRMC,{tod},A,3725.415069,N,12205.647326,W,000.0,000.0,"
                       f"{'140520' if tod.startswith('23') else '150520'},,,A")]
    start = dt.datetime(2020, 5, 14, 23, 59, 58, tzinfo=dt.UTC).timestamp()
    blanked = blank_fixes(lines + ["not a sentence"], start, 3.0)
    assert blanked[-1] == "not a sentence" and blanked[6:10] == lines[6:10]
    for text in blanked[:6]:
        msg = pynmeagps.NMEAReader.parse(text, validate=pynmeagps.VALCKSUM)
        assert (msg.quality == 0 if msg.msgID == "GGA" else msg.status == "V") and msg.lat == ""
    path = tmp_path / "cold.nmea"
    path.write_text("\n".join(blanked) + "\n")
    ep, *_ = read_real_log(path)
    assert (ep.quality > 0).tolist() == [False, False, False, True, True]
    moved = rewrite_fixes(lines, np.array([start + 4.0]), np.array([37.5]), np.array([-122.0]))
    assert moved[:8] == lines[:8]
    gga = pynmeagps.NMEAReader.parse(moved[8], validate=pynmeagps.VALCKSUM)
    assert moved[8].split(",")[2] == "3730.000000"  # (the log's six decimals kept)
    assert gga.lat == pytest.approx(37.5) and gga.lon == pytest.approx(-122.0)


def test_gap_cli_errors_are_one_line(tmp_path):
    empty = tmp_path / "empty.nmea"
    empty.write_text("")
    for args in (["--real", str(empty), "--truth", "static"],
                 ["--real", str(tmp_path / "none.nmea"), "--truth", "static"],
                 ["--real", str(empty)],
                 ["--effects", "teleport"]):
        r = _gap_cli([*args, "--out", str(tmp_path / "o")])
        assert r.returncode == 2, (args, r.stderr)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("virtualgps: error:"), r.stderr
    # a truth logged in local time (two hours on): both spans, in UTC, in the one line
    fix = "GPGGA,{0},5207.0000,N,01138.0000,E,1,08,0.9,50.0,M,44.0,M,,"
    rmc = "GPRMC,{0},A,5207.0000,N,01138.0000,E,0.0,0.0,010318,,,A"
    log = tmp_path / "log.nmea"
    log.write_text("".join(sentence(f.format(f"12000{k}.000")) + "\n"
                           for k in range(6) for f in (fix, rmc)))
    truth = tmp_path / "truth.csv"
    truth.write_text("t,lat,lon,alt\n" + "".join(f"{1519912800.0 + k},52.1166,11.6333,94\n"
                                                 for k in range(6)))
    r = _gap_cli(["--real", str(log), "--truth", str(truth), "--scene", "none", "--out",
                  str(tmp_path / "o")])
    assert r.returncode == 2 and "(log 2018-03-01 12:00:00 to 12:00:05 UTC, truth 2018-03-01 " \
        "14:00:00 to 14:00:05 UTC)" in r.stderr, r.stderr


def test_a_satellite_never_tracked_over_a_long_pass_is_silent_not_blocked():
    """PRN columns: 0 high and tracked; 1 rises from 60 to 80 deg across the sky and is never
    tracked while the lower 2 and 3 are: not transmitting; 4, low and never tracked, has no
    tracked satellite below it: it may be blocked, and stays compared; 5 never tracked in a
    short, fixed direction: cannot be told from an obstruction."""
    n = 50
    el = np.tile([70.0, 60.0, 20.0, 30.0, 8.0, 85.0], (n, 1))
    el[:, 1] = np.linspace(60.0, 80.0, n)
    az = np.tile([10.0, 0.0, 200.0, 300.0, 90.0, 45.0], (n, 1))
    az[:, 1] = np.linspace(0.0, 100.0, n)
    tracked = np.zeros((n, 6), bool)
    tracked[:, [0, 2, 3]] = True
    silent = runs._silent_prns(tracked, el, az, np.ones((n, 6), bool))
    assert silent.tolist() == [False, True, False, False, False, False]


def test_gap_takes_the_tle_set_replay_takes(shared_data):
    """Without --tle, the gap tool's sky for a log is the one run and replay take for the same
    time (one rule): a 2017 log gets a 2017 set, not the newest bundled one."""
    from virtualgps.gap import tool
    from virtualgps.sky.skytime import choose_tle_set

    log = shared_data / "mt3339-static" / "hour_test_1.txt"
    inp = tool.GapInputs(real=(str(log),), truth=("static",), scene="none", tle=None,
                         profile="usarsim")
    runs, _, _, tle, _, _ = tool.load_inputs(inp)
    t0 = float(runs[0].epochs.t_unix_s[0])
    assert Path(tle) == choose_tle_set(None, None, t0)[0]
    assert "2017" in Path(tle).name


def test_the_separation_of_a_logs_satellites_from_the_simulated_sky():
    """The angle between where a log's GSV puts a PRN and where the ephemeris does, against the
    spherical law of cosines; a PRN the log never gives angles for is not compared; most PRNs
    beyond SKY_SEP_MAX_DEG make the sky wrong, a few only those PRNs."""
    from types import SimpleNamespace

    n = 4
    # the log's columns: PRN 7, 3, 9, 5 (5 listed without angles, as MTK before its almanac)
    log_el = np.tile([30.0, 10.0, 45.0, np.nan], (n, 1))
    log_az = np.tile([0.0, 120.0, 200.0, np.nan], (n, 1))
    log = SimpleNamespace(prn=np.array([7, 3, 9, 5]), el_deg=log_el, az_deg=log_az)
    prn = np.array([3, 5, 7, 9, 11])  # the simulator's columns; 11 the log never lists
    el = np.tile([20.0, 50.0, 30.0, 45.0, 60.0], (n, 1))
    az = np.tile([120.0, 10.0, 90.0, 201.0, 0.0], (n, 1))
    el[0, 0] = 70.0  # one epoch far off: the median over the run holds
    sep = runs._sky_separation_deg(log, prn, el, az)

    def law_of_cosines(e1, a1, e2, a2):
        e1, a1, e2, a2 = map(math.radians, (e1, a1, e2, a2))
        return math.degrees(math.acos(math.sin(e1) * math.sin(e2)
                                      + math.cos(e1) * math.cos(e2) * math.cos(a1 - a2)))

    assert sep[0] == pytest.approx(10.0)
    assert np.isnan(sep[1]) and np.isnan(sep[4])
    assert sep[2] == pytest.approx(law_of_cosines(30, 0, 30, 90))  # 75.5 deg
    assert sep[3] == pytest.approx(law_of_cosines(45, 200, 45, 201))  # 0.71 deg
    info, cols = runs._sky_info(prn, sep)
    assert info["prns_compared"] == 3 and info["misplaced_prns"] == [3, 7]
    assert info["wrong"] == ["GPS"] and cols.all()
    info, cols = runs._sky_info(prn, np.array([1.0, np.nan, 9.0, 0.5, 2.0]))
    assert info["wrong"] == [] and not cols.any()
    # judged per system: GLONASS (65-96) numbered off does not make the GPS sky wrong
    both = np.array([3, 7, 9, 65, 66, 70])
    info, cols = runs._sky_info(both, np.array([0.5, 0.4, 6.0, 40.0, 35.0, 1.0]))
    assert info["wrong"] == ["GLONASS"] and info["misplaced_prns"] == [9, 65, 66]
    assert cols.tolist() == [False, False, False, True, True, True]


def test_a_sky_that_is_not_the_logs_is_named_and_no_effect_is_fitted_to_it(shared_data):
    """The MT3339 hour (2017-03-11) against the 2017-03-26 set: its GSV angles lie 0.4 deg from
    the simulated sky (GSV's whole degrees), nothing misplaced. Against the 2020 set (three years
    on, its sky shifted to the same sidereal time: plausible, not the log's) most of its PRNs
    stand over 5 deg off: the cause says so, no satellite's tracking is compared, and the
    effects placed on the sky are not tried (a wrong sky was taken for an elevation mask)."""
    from virtualgps.gap import causes as cz
    from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR

    right, _, _ = _prepared_hour(shared_data, str(BUNDLED_EPHEMERIS_DIR / "gps-ops-2017-03-26.tle"))
    sky = right[0].info["sky"]
    assert sky["prns_compared"] >= 10 and sky["median_sep_deg"] < 1.0
    assert sky["misplaced_prns"] == [] and cz.sky(right[0]) is None
    assert right[0].view.sat_ok.any()

    wrong, table, _ = _prepared_hour(shared_data,
                                     str(BUNDLED_EPHEMERIS_DIR / "gps-ops-2020-05-14T22Z.tle"))
    cause = cz.sky(wrong[0])
    assert cause is not None and cause["systems_wrong"] == ["GPS"], wrong[0].info["sky"]
    assert 2 * len(cause["misplaced_prns"]) > cause["prns_compared"]
    assert "not the log's" in cause["what"] and not wrong[0].view.sat_ok.any()
    reasons = {n["metric"]: n["reason"] for n in dg.not_assessed(wrong)}
    assert "causes: sky" in reasons["tracked_agreement"]
    assert "causes: sky" in reasons["used_el_p05_deg"]
    why = cz.sky_wrong([cause])
    cands, skipped = fx.candidates(table, False, None, True, "G", "G", sky_wrong=why)
    assert {c.name for c in cands}.isdisjoint(fx.SKY_PLACED)
    assert skipped["elevation_mask"] == why and skipped["sky_mask"] == why
    assert {c.name for c in cands} >= {"nav_filter", "latency", "cold_start"}
    # the terminal names the cause and what was not tried; the page lists it
    from virtualgps.gap import report as rp
    from virtualgps.gap import tool

    report = {"headline": [], "outer": {}, "design": {"scheme": "", "warnings": []},
              "runs": [], "effects": [], "located": [], "profile": "holux-m1000",
              "gap_baseline": 1.0, "causes": [cause], "candidates_skipped": skipped}
    lines = tool.summary_lines(report)
    assert f"  cause: hour_test_1: {cause['what']}" in lines
    note = [ln for ln in lines if ln.startswith("  note: not tried on a sky")]
    assert len(note) == 1 and "elevation_mask" in note[0] and "nav_filter" not in note[0]
    assert rp._cause_rows(report)[0] == {"cause": "sky", "what": f"hour_test_1: {cause['what']}"}


def test_a_truth_in_another_place_is_one_clear_error(shared_data, tmp_path):
    """A truth with its longitude's sign left off lies 9,000 km from the MT3339 hour's fixes:
    one error naming the log, the distance and what to check, before anything is simulated
    (before, the truth was "moved by 6,389 km" and judged). The limit on its own: 40 km from
    the fixes is a truth offset to measure, 60 km is another place."""
    from types import SimpleNamespace

    from virtualgps.exceptions import InputFileError

    r = subprocess.run([sys.executable, "-m", "virtualgps", "gap", "--real",
                        str(shared_data / "mt3339-static" / "hour_test_1.txt"), "--truth",
                        "static:44.98,93.24,250", "--out", str(tmp_path / "gap")],
                       capture_output=True, text=True, timeout=300)
    errors = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert r.returncode == 2 and len(errors) == 1, r.stderr
    assert "hour_test_1.txt: its fixes lie a median 9,0" in errors[0]
    assert "km from its truth" in errors[0] and "south and west negative" in errors[0]
    assert not (tmp_path / "gap" / "report.json").exists()

    n = 20
    ep = SimpleNamespace(quality=np.ones(n, int), lat_deg=np.full(n, 45.0),
                         lon_deg=np.full(n, -93.0))
    run = SimpleNamespace(epochs=ep, path=Path("log.nmea"))
    north = [d / 111_132.0 for d in (40_000.0, 60_000.0)]  # (metres per degree of latitude)
    runs._check_near(run, np.full(n, 45.0 + north[0]), np.full(n, -93.0), np.ones(n, bool))
    with pytest.raises(InputFileError, match="a median 60 km"):
        runs._check_near(run, np.full(n, 45.0 + north[1]), np.full(n, -93.0), np.ones(n, bool))


def _latency_trial(tmp_path: Path):
    """The self-check's first latency trial in the bundled scene (a 15-minute synthetic log
    with its truth, TLE set and profile)."""
    from virtualgps.gap import synthetic
    from virtualgps.run.config import BUNDLED_SCENES_DIR, DEFAULT_SCENE
    from virtualgps.sky.ephemeris import default_tle_path
    from virtualgps.sky.scene import load_scene

    scene_dir = str(BUNDLED_SCENES_DIR / DEFAULT_SCENE)
    scene = load_scene(scene_dir)
    return synthetic.make_trial("latency", 0, tmp_path, scene, scene_dir, str(scene.tle_path),
                                str(default_tle_path()))


def test_a_ten_second_log_claims_no_effect_and_says_why(tmp_path):
    """Too short for guarded blocks: a plain warning, the located gaps alone, no effect."""
    from virtualgps.gap import tool

    tr = _latency_trial(tmp_path)
    lines = tr.real.read_text().splitlines()
    starts = [i for i, ln in enumerate(lines) if ln.startswith("$GPGGA")]
    short = tmp_path / "ten.nmea"
    short.write_text("\n".join(lines[: starts[10]]) + "\n")
    inp = tool.GapInputs(real=(str(short),), truth=(tr.truth,), scene="none", tle=tr.tle,
                         profile=str(tr.profile))
    report, _, _ = tool.diagnose(inp, dg.Options(seeds=5, jobs=1))
    assert not report["design"]["claims"] and report["effects"] == []
    assert "too little data for a held-out test" in report["design"]["warnings"][-1]
    assert report["where"]  # the located gaps still stand


def test_effects_none_locates_the_gaps_and_offers_no_effect(tmp_path):
    """``--effects none``: a quick look. The located gaps, the causes and the bands checked on
    the seeds stand; no candidate is simulated, so the log's injected delay is not named."""
    tr = _latency_trial(tmp_path)
    out = tmp_path / "quick"
    r = _gap_cli(["--real", str(tr.real), "--truth", tr.truth, "--scene", "none", "--tle",
                  tr.tle, "--profile", str(tr.profile), "--seeds", "5", "--jobs", "1",
                  "--effects", "none", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["design"]["claims"] and report["effects"] == []
    assert report["where"] and report["band"]["seed_holdout"]["reports"] == 5
    assert any(c["name"] == "time_offset" for c in report["causes"])  # (the delay's clue)
    assert report["gap_final"] == report["gap_baseline"]


def test_a_five_hertz_receivers_delay_is_found_on_its_own_epochs(tmp_path, monkeypatch):
    """A u-blox at 5 Hz (what PX4 and ArduPilot configure) with a 1 s output delay: the
    diagnosis runs on the log's own epochs, names the delay rather than a filter, and its
    interval holds 1 s. (Power, docs/gap.md: a 0.6 s delay in 4 of 5 such drives at 5 Hz.)"""
    from virtualgps.gap import synthetic, tool
    from virtualgps.sky.ephemeris import default_tle_path

    monkeypatch.chdir(tmp_path)  # (a relative label: the trial's draws follow its label)
    table, _ = load_profile_dict("ublox-m8n")
    five = dict(table, name="m8n-5hz", rate_hz=5.0)
    late = dict(fx.apply(five, {"latency": {"enabled": True, "latency_s": 1.0}}), name="late")
    for name, t in (("m8n-5hz", five), ("late", late)):
        Path(f"{name}.toml").write_text(fx.to_toml(t), encoding="utf-8")
    tle = str(default_tle_path())
    tr = synthetic.make_trial("nothing@late.toml", 1, Path("w"), None, "", tle, tle)
    assert tr.scenario == "moving_open"
    inp = tool.GapInputs(real=(str(tr.real),), truth=(tr.truth,), scene=None, tle=tle,
                         profile="m8n-5hz.toml")
    report, _, _ = tool.diagnose(inp, dg.Options(seeds=10, jobs=2,
                                                 effects=("latency", "nav_filter")))
    assert report["runs"][0]["epochs"] == 5 * synthetic.DURATION_S + 1
    added = [e for e in report["effects"] if e.get("accepted")]
    assert [e["name"] for e in added] == ["latency"], report["effects"]
    lo, hi = added[0]["fit"]["spans"]["latency_s"]
    assert lo <= 1.0 <= hi and hi - lo <= 1.0, (lo, hi)
    lag = next(h for h in report["headline"] if h["metric"] == "lag_s")
    assert lag["outside"] and 0.75 <= lag["real"] <= 1.25


def test_workers_are_forked_before_the_located_gaps_thread_starts(tmp_path):
    """A fork copies only the forking thread: a module the located gaps' thread is importing
    stays locked in the worker, which hangs at its first import of it (a self-check in the
    suite hung so, every worker stuck on ``from scipy.signal import lfilter``). No worker is
    forked while that thread lives."""
    import multiprocessing
    import os
    import threading

    from virtualgps.gap import tool

    tr = _latency_trial(tmp_path)
    inp = tool.GapInputs(real=(str(tr.real),), truth=(tr.truth,), scene="none", tle=tr.tle,
                         profile=str(tr.profile))
    forks: list[list[str]] = []
    watching = [True]
    # (a hook cannot be removed: it stops recording when the test ends)
    os.register_at_fork(before=lambda: forks.append([t.name for t in threading.enumerate()])
                        if watching[0] else None)

    def unstick() -> None:  # (hung workers fail the test, not the suite's clock)
        for child in multiprocessing.active_children():
            child.kill()

    watchdog = threading.Timer(120.0, unstick)
    watchdog.start()
    try:
        report, _, _ = tool.diagnose(inp, dg.Options(seeds=4, fit_seeds=3, jobs=2,
                                                     effects=("latency",)))
    finally:
        watchdog.cancel()
        watching[0] = False
    assert report["design"]["claims"] and forks  # choices were made, on forked workers
    assert not [names for names in forks
                if any(n.startswith("ThreadPoolExecutor") for n in names)], forks


@pytest.mark.slow
def test_real_log_bases_tell_a_delay_from_a_filter_and_find_a_wrong_truth(shared_data,
                                                                          tmp_path):
    """The GSDC drive, untouched and then with a pure output delay or a first-order filter
    injected into its fixes, its truth moved by metres, or its first seconds without a fix.
    The untouched phone log needs holux-m1000's range errors scaled down (a dual-frequency
    phone's errors are a fraction of a 2008 logger's); the delay is the first effect the
    untouched log did not need, its length near the injected one; the filter is refitted as a
    filter of the motion near the injected time constant; the wrong truth is named as a truth
    offset and no receiver effect absorbs it; the late first fix is a cold start whose
    interval holds it; a slow offset is a correlated error.

    The candidates are the effects that act on the fixes' motion and error, those these
    injections are taken for (a delay for a filter, a wrong truth or a slow offset for more
    noise or a correlated error): without the sky's (``elevation_mask``, ``multipath``,
    ``sbas``) each of the seven diagnoses takes some 60 % of the time. The self-check
    (``virtualgps gap --selfcheck``, ``tools/real_base_checks.py``) tries every one."""
    from virtualgps.gap import selfcheck, selfcheck_real

    motion = ("noise_level", "correlated_error", "latency", "nav_filter", "static_hold",
              "cold_start")
    rows, note = selfcheck_real.run(shared_data, dg.Options(seeds=12, jobs=2, effects=motion), 1,
                                    tmp_path, effects=("latency", "nav_filter", "truth_offset",
                                                       "cold_start", "correlated_error"))
    assert note is None
    delay, filt, off, cold, slow = rows
    # a slow offset, against holux-m1000 with its own correlated error withheld: named as one,
    # its time constant inside the fit's interval (the untouched log against that profile
    # adds a filter of the phone's smooth errors, not a correlated error)
    assert slow["scenario"].endswith("holux-m1000-without-correlated_error")
    assert "correlated_error" not in slow["base_accepted"]
    assert slow["success"] and slow["added_first"] == "correlated_error", slow
    assert slow["covered"] == {"tau_s": True}
    assert cold["success"] and cold["added_first"] == "cold_start", cold
    assert cold["recovered"]["power_on"] == "cold" and cold["covered"] == {"ttff_cold_s": True}
    assert delay["base_accepted"] == ["noise_level"]
    assert delay["success"] and delay["added_first"] == "latency", delay
    assert delay["recovered"]["latency_s"] == pytest.approx(delay["params"]["latency_s"],
                                                            abs=0.3)
    assert filt["success"], filt
    assert filt["recovered"]["velocity_aided"] is False
    assert filt["recovered"]["tau_s"] == pytest.approx(filt["params"]["tau_s"], abs=0.7)
    assert off["success"] and "truth_offset" in off["causes"], off
    result = selfcheck.summarise(rows, dg.Options(seeds=12))
    assert result["confusion"]["real:gsdc:latency"] == {"latency": 1}
    # the terminal's summary names only what was ranked first and not injected
    lines = selfcheck.summary_lines(result)
    assert "  real:gsdc:latency: right 1/1, parameters covered 1/1" in lines, lines
    wrong = dict(rows[0], ranked_first="nav_filter", success=False)
    assert selfcheck.summary_lines(selfcheck.summarise([wrong], dg.Options(seeds=12)))[-1] \
        == "  real:gsdc:latency: right 0/1, parameters covered 1/1 (ranked first instead: " \
        "nav_filter 1)"


def _prepared_hour(shared_data: Path, tle: str | None = None) -> tuple[list, dict, str]:
    """The MT3339 static hour prepared against ``holux-m1000`` (GPS): its runs, the profile
    table and its source. ``tle``: the TLE set (default: the one nearest the log's time)."""
    from virtualgps.gap import tool
    from virtualgps.gap.ensemble import ephemeris_of
    from virtualgps.gap.runs import prepare_runs
    from virtualgps.sky import ephemeris as eph

    inp = tool.GapInputs(real=(str(shared_data / "mt3339-static" / "hour_test_1.txt"),),
                         truth=("static",), scene="none", tle=tle, profile="holux-m1000")
    runs_in, scene, scene_dir, tle, table, source = tool.load_inputs(inp)
    ephem = ephemeris_of(tle, "G")

    def shift(t0: float) -> float:
        return eph.sidereal_shift_s(t0, ephem.epoch_center_unix_s, tool.SKY_SHIFT_MAX_DAYS)

    return (prepare_runs(runs_in, scene, scene_dir, tle, build_profile(table, source), shift,
                         1, None), table, source)


def test_scores_do_not_depend_on_how_seeds_are_split_into_jobs(shared_data, monkeypatch):
    """A batch with few jobs splits their seeds over more jobs: the units' scores (gap, every
    metric's distance, the per-PRN and per-sky-bin counts) are the same to the bit as from one
    job over all the seeds (the seed-against-seed agreement is paired over all of them), and
    whether a worker kept what the real log shows in each unit or had to drop it."""
    from virtualgps.gap import simulator as sm
    from virtualgps.gap.ensemble import EnsembleJob, simulate_job
    from virtualgps.gap.runs import sim_obs

    prepared, table, source = _prepared_hour(shared_data)
    key = sm.share_runs(prepared)[0]
    t = prepared[0].view.t_unix_s
    units = (t < t[t.size // 2], t >= t[t.size // 2])
    # (weak signals, so that the seeds track differently: open sky tracks all alike)
    weak = fx.apply(table, {"cn0_tracking": {"cn0_zenith_dbhz": 24.0}})
    prof = build_profile(weak, source)

    def job(seeds):
        return sm.gap_job(sm.GapJob(key, weak, source, seeds, units, prn=True, bins=True,
                                    whole=False))

    whole = job((0, 1, 2, 3, 4))
    split = [job((0, 1)), job((2, 3, 4))]
    # (the jobs after the first read what the real log shows in each unit from the worker's
    # memo: the same as measured afresh, and as with no room to keep it)
    with monkeypatch.context() as mp:
        mp.setattr(sm, "UNIT_MEMO_BYTES", 1)
        job((0, 1))
        assert len(sm._UNIT_MEMO) == 1
        squeezed = job((0, 1))  # (the first unit measured again)
    for u in range(2):
        assert squeezed[u].stats.real == split[0][u].stats.real
        for m, values in split[0][u].stats.sim.items():
            np.testing.assert_array_equal(squeezed[u].stats.sim[m], values, err_msg=m)
    setup, view, err_real = sm.shared(key)
    sims = sim_obs(simulate_job(EnsembleJob(setup, prof, (0, 1, 2, 3, 4))), view)
    err = where.errors_enu(view, sims)
    for u in range(2):
        fresh = where.segment_stats(view, sims, err_real, err, units[u],
                                    metrics=where.SCORE_METRICS)
        assert fresh.real == whole[u].stats.real
        merged = where.merge_stats([split[0][u].stats, split[1][u].stats])
        for m, values in fresh.sim.items():
            np.testing.assert_array_equal(merged.sim[m], values, err_msg=m)
        assert merged.sim.keys() == whole[u].stats.sim.keys()
        assert merged.real == whole[u].stats.real
        for m, values in whole[u].stats.sim.items():
            np.testing.assert_array_equal(merged.sim[m], values, err_msg=m)
        a = sm.unit_score([whole[u]])
        in_job = sm.gap_job(sm.GapJob(key, weak, source, (0, 1, 2, 3, 4), units, True,
                                      True))[u]
        assert in_job.own == a.own
        np.testing.assert_array_equal(in_job.bins, a.bins)
        b = sm.unit_score([split[0][u], split[1][u]])
        assert "tracked_agreement" in a.own[1] and a.own == b.own
        np.testing.assert_array_equal(a.prn, b.prn)
        np.testing.assert_array_equal(a.bins, b.bins)


def test_a_fitting_job_scores_every_held_out_unit_of_its_run(shared_data):
    """A table asked with the fitting seeds on some blocks is scored on every block of the run
    (a fold asks its chosen point on its held-out block next; another selection may ask the
    same table on other blocks): later such requests submit no job, and score alike. Held-out
    seeds and the whole-run unit are scored only where asked."""
    from virtualgps.gap.design import make_design
    from virtualgps.gap.simulator import FIT, HELD, Simulator

    prepared, table, source = _prepared_hour(shared_data)
    v = prepared[0].view
    design = make_design([v.name], [v.t_unix_s], [v.valid], [60.0], 4)
    blocks = list(range(len(design.units)))
    whole = len(design.units)
    assert len(blocks) == 4
    sim = Simulator(prepared, design, 6, 1, None, source)
    sim.request([(table, FIT, [0, 1])])
    assert len(sim.batches) == 1
    assert sim.has([(table, FIT, blocks)])
    assert not sim.has([(table, FIT, [whole])]) and not sim.has([(table, HELD, [0])])
    sim.request([(table, FIT, [2, 3])])
    assert len(sim.batches) == 1  # (nothing submitted)
    # the same scores as a fresh simulator asked for those blocks alone
    other = Simulator(prepared, design, 6, 1, None, source, sim.keys)
    other.request([(table, FIT, [3])])
    alone, widened = other.scores(table, FIT, [3])[0].own, sim.scores(table, FIT, [3])[0].own
    assert np.isfinite(alone[0]) and alone == widened
    sim.request([(table, HELD, [0])])
    assert not sim.has([(table, HELD, [1])])
    assert sim.repeats == 0
    sim.request([(table, FIT, [whole])])  # (the whole run: simulated again)
    assert sim.repeats == 1 and len(sim.batches) == 3


def test_the_choice_does_not_depend_on_how_jobs_are_cut_or_when_they_finish(tmp_path):
    """The selections go on each as its own jobs come back: on one worker (jobs in order,
    whole seed sets) and on 16 modelled workers (seed sets cut into groups, jobs finishing in
    the order of their own run times) the diagnosis is the same."""
    from virtualgps.gap import jobs, tool

    tr = _latency_trial(tmp_path)
    inp = tool.GapInputs(real=(str(tr.real),), truth=(tr.truth,), scene="none", tle=tr.tle,
                         profile=str(tr.profile))
    opts = dg.Options(seeds=6, jobs=1, effects=("latency", "nav_filter"))
    one, _, _ = tool.diagnose(inp, opts)
    jobs.model(16)
    try:
        many, _, _ = tool.diagnose(inp, opts)
    finally:
        jobs.model(None)
    # (seed sets cut into groups: more jobs; how many more depends on how full the batches
    # are, which the candidates' grids set)
    assert sum(many["batches"]) > sum(one["batches"])
    for k in ("effects", "outer", "gap_baseline", "gap_final", "selection_rounds"):
        assert many[k] == one[k], k
    assert one["effects"] and one["effects"][0]["name"] == "latency"
