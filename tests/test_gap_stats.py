"""The gap tool's statistics against closed forms and simulation: calibrated bands under the
null whatever the seed count, the false-discovery control, practical floors, print resolution,
the held-out design's blocks and guards, parameter identifiability and the outer test (the
causes that are not receiver effects and the lag terms: test_gap_causes.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from virtualgps.gap import bands, design, fit, observed, select, where
from virtualgps.gap import effects as fx


@pytest.mark.parametrize("seeds", [5, 8, 20, 50])
@pytest.mark.parametrize("metric", ["cep50_m", "fix_fraction"])
def test_predictive_p_is_uniform_under_the_null_whatever_the_seed_count(seeds, metric):
    """Real and seeds drawn from one distribution (log-normal CEP, normal share): the share of
    p-values below 5 % (and 1 %) is the nominal one, within binomial noise."""
    rng = np.random.default_rng(seeds)
    n = 4000
    if metric == "cep50_m":
        draws = np.exp(rng.normal(np.log(100.0), 0.6, (n, seeds + 1)))
    else:
        draws = rng.normal(0.5, 0.15, (n, seeds + 1))
    p = np.array([bands.judge(metric, d[0], d[1:]).p for d in draws])
    for level in (0.05, 0.01):
        share = np.mean(p <= level)
        se = math.sqrt(level * (1 - level) / n)
        # the floor (0.5 m / 0.01) can only make the test conservative
        assert share <= level + 3.5 * se, (level, share)
        assert share >= level * 0.5, (level, share)


def test_band_holds_exactly_the_values_not_flagged():
    rng = np.random.default_rng(1)
    sims = np.exp(rng.normal(np.log(5.0), 0.4, 30))
    for alpha in (0.05, 0.001):
        lo, hi = bands.band("r95_m", sims, alpha)
        for real in np.linspace(0.1, 40.0, 400):
            p = bands.judge("r95_m", real, sims).p
            inside = lo <= real <= hi
            assert inside == (p > alpha) or abs(real - lo) < 0.1 or abs(real - hi) < 0.1


def test_bands_stay_within_the_values_a_metric_takes():
    """A share's band runs from 0 to 1 and a scale's from 0 (a fix fraction's normal
    prediction interval "0.99..1.01" read as fixes that are not there; "-..0.1" changes per
    minute as a value below nothing), and still holds every value not flagged."""
    rng = np.random.default_rng(2)
    # (each with a value at the metric's end beside its seeds: not flagged, inside the band)
    for metric, sims, edge in (("fix_fraction", 1.0 - rng.uniform(0.0, 0.004, 30), 1.0),
                               ("dgps_fraction", np.zeros(30), 0.0),
                               ("used_changes_per_min", rng.uniform(0.0, 0.05, 30), 0.0)):
        for alpha in (0.05, 0.001):
            lo, hi = bands.band(metric, sims, alpha)
            share = bands.METRICS[metric].share
            assert lo >= 0.0 and (hi <= 1.0 or not share), (metric, lo, hi)
            assert bands.judge(metric, edge, sims).p > alpha and lo <= edge <= hi
    # an ensemble that cannot flag: every value the metric takes
    assert bands.band("fix_fraction", [0.5, math.nan], 0.05) == (0.0, 1.0)
    assert bands.band("lag_s", [0.5, math.nan], 0.05) == (-math.inf, math.inf)


def test_practical_floor_makes_print_digits_no_gap():
    sims = np.full(50, 0.9994)
    j = bands.judge("fix_fraction", 1.0, sims)
    assert j.p == 1.0 and j.z == 0.0 and bands.distance(j.z) == 0.0
    j = bands.judge("hdop_median", 1.00, np.full(50, 1.0028))
    assert j.p == 1.0
    # beyond the floor a degenerate ensemble is certain
    j = bands.judge("fix_fraction", 0.9, sims)
    assert j.p == 0.0 and j.z == -bands.Z_CAP


def test_smoothing_below_half_a_step_is_no_gap_and_a_filter_is():
    """A null drive's smoothing estimate on a short block: the seeds pile up on 0 and 0.1 s and
    the log, one more draw, says 0.3 s; that is no gap (a fresh null drive's block had taken a
    0.3 s for a filter with the floor at 0.1 s). A 2 s filter against the same seeds is."""
    sims = np.array([0.0] * 26 + [0.1] * 4)
    assert bands.judge("smoothing_s", 0.3, sims).z == 0.0
    assert bands.judge("smoothing_s", 2.0, sims).z > 5
    # and between filters: 2.5 s against seeds at 1.5 s
    assert bands.judge("smoothing_s", 2.5, np.full(30, 1.5) + np.linspace(-0.1, 0.1, 30)).z > 3


def test_rank_judged_metrics_count_missing_seeds_as_longest():
    sims = np.array([np.nan] * 40 + list(np.linspace(100, 200, 10)))
    j = bands.judge("autocorr_s", 30.0, sims)  # below every seed: rank 0 of 50
    assert j.rank and j.p == pytest.approx(2.0 / 51.0)
    lo, hi = bands.band("autocorr_s", sims, 0.05)
    assert math.isinf(hi) and lo <= 100.0


def test_bh_alpha_is_the_benjamini_hochberg_threshold():
    p = np.array([0.001, 0.008, 0.039, 0.041, 0.042, 0.06, 0.074, 0.205, 0.212, 0.216])
    # the textbook rule at q = 0.05: p_(k) <= 0.05 k / 10 holds up to k = 2
    assert bands.bh_alpha(p, 0.05) == pytest.approx(0.01)
    assert bands.bh_alpha(np.full(10, 0.5), 0.05) == pytest.approx(0.005)


def test_rows_judged_together_flag_about_q_of_null_reports():
    """200 null rows per report: with the false-discovery rule, at most ~5 % of reports flag
    any row (independent rows; the rows of a real report are positively dependent)."""
    rng = np.random.default_rng(7)
    reports, any_flag, flagged = 300, 0, 0
    for i in range(reports):
        rows = []
        for k in range(200):
            d = np.exp(rng.normal(1.0, 0.3, 21))
            rows.append({"metric": "cep50_m", "segment": f"s{k}", "real": float(d[0]),
                         "p_value": bands.judge("cep50_m", d[0], d[1:]).p, "z": 0.0,
                         "_sims": d[1:]})
        full = where.finish_rows([dict(r) for r in rows]) if i == 0 else None
        out, _, checked = where.finish_rows(rows, holdout=False)
        if full is not None:  # (the seed holdout, left out, leaves the rows alone)
            assert checked == {} and full[2]["reports"] == 20
            assert [r["outside"] for r in out] == [r["outside"] for r in full[0]]
        n = sum(r["outside"] for r in out)
        any_flag += n > 0
        flagged += n
    assert any_flag / reports <= 0.05 + 3 * math.sqrt(0.05 * 0.95 / reports)
    assert flagged / (reports * 200) < 0.005


def test_each_seed_held_out_is_judged_as_judge_judges_it():
    """The vectorised seed holdout against one :func:`judge` call per seed, over judging
    scales (log, linear share, linear level), seeds without a value, seeds all alike, and a
    rank-judged metric with missing seeds."""
    rng = np.random.default_rng(11)
    cases = {
        "cep50_m": np.exp(rng.normal(1.5, 0.4, 30)),
        "fix_fraction": np.clip(rng.normal(0.97, 0.02, 30), 0, 1),
        "cn0_median_dbhz": np.round(rng.normal(38.0, 2.5, 30)),
        "hdop_median": np.full(30, 1.3),
        "lag_s": np.where(rng.random(30) < 0.2, np.nan, rng.normal(0.3, 0.4, 30)),
        "ttff_s": np.where(rng.random(30) < 0.3, np.nan, rng.uniform(20, 60, 30)),
    }
    for metric, sims in cases.items():
        got = bands.holdout_p(metric, sims)
        want = np.array([bands.judge(metric, float(x), np.delete(sims, k)).p
                         if np.isfinite(x) else np.nan for k, x in enumerate(sims)])
        assert np.array_equal(np.isnan(got), np.isnan(want)), metric
        np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)],
                                   rtol=1e-9, atol=1e-12, err_msg=metric)
    assert np.isnan(bands.holdout_p("cep50_m", [1.0, 2.0, np.nan, 3.0])).all()  # 2 others


def _holdout_rows(draw, rows: int = 150) -> list[dict]:
    return [{"metric": "lag_s", "segment": f"s{k}", "real": 0.0, "p_value": 1.0, "z": 0.0,
             "_sims": draw()} for k in range(rows)]


def test_the_seed_holdout_passes_calibrated_bands_and_warns_of_heavy_tails():
    """Seeds from a normal: the bands the predictive t gives are calibrated, and few of the
    seeds taken as the real log show a located gap (no warning). Seeds from a Cauchy: the
    normal-theory band is too narrow, most of them do, and the report warns, naming the
    metric."""
    rng = np.random.default_rng(5)
    normal = where.seed_holdout(_holdout_rows(lambda: rng.normal(0.0, 1.0, 50)))
    assert normal["reports"] == 50 and normal["rows"] == 150 * 50
    assert normal["share"] <= 0.1
    assert bands.holdout_warning({"seed_holdout": normal}) is None
    heavy = where.seed_holdout(_holdout_rows(lambda: rng.standard_cauchy(50)))
    assert heavy["share"] > 0.5 and heavy["metrics"]["lag_s"] == heavy["rows_outside"]
    note = bands.holdout_warning({"seed_holdout": heavy})
    assert note is not None and "lag_s" in note and f"of {heavy['reports']} seeds" in note
    # the warning's level: at 50 seeds 7 reports are within a calibrated band's luck, 8 not
    def entry(k: int) -> dict:
        return {"seed_holdout": {"reports": 50, "reports_with_any_row_outside": k,
                                 "metrics": {"cep50_m": k}}}
    assert bands.holdout_warning(entry(7)) is None
    assert bands.holdout_warning(entry(8)) is not None
    assert bands.holdout_warning({}) is None


def test_score_is_near_zero_under_the_null_and_grows_with_the_gap():
    rng = np.random.default_rng(3)
    null = []
    for _ in range(2000):
        d = np.exp(rng.normal(1.5, 0.3, 9))
        null.append(bands.distance(bands.judge("cep50_m", d[0], d[1:]).z))
    assert np.mean(null) < 0.15
    sims = np.exp(rng.normal(1.5, 0.3, 8))
    far = [bands.distance(bands.judge("cep50_m", np.exp(1.5) * f, sims).z) for f in (2, 4, 8)]
    assert far[0] < far[1] < far[2] <= bands.D_CAP


def test_a_candidate_gains_nothing_by_widening_its_spread_away_from_the_real_value():
    """The GSDC case: the profile under test says HDOP 1.0 with little scatter, the phone
    prints 0.38; a candidate moves the HDOP to 3.7 and widens its scatter. In its own spread
    its distance falls; guarded by the profile under test it does not."""
    rng = np.random.default_rng(11)
    ref_sims = np.exp(rng.normal(np.log(1.0), 0.03, 8))
    cand_sims = np.exp(rng.normal(np.log(3.7), 0.6, 8))
    real = 0.38
    ref = bands.judge("hdop_median", real, ref_sims)
    own = bands.judge("hdop_median", real, cand_sims)
    d_ref = bands.distance_against("hdop_median", real, ref, ref)
    assert bands.distance(own.z) < d_ref  # the trap: widening alone looks like a gain
    d = bands.distance_against("hdop_median", real, own, ref)
    assert d >= d_ref and d >= bands.distance(own.z)


def test_a_metric_missed_beyond_the_cap_cannot_be_moved_further_for_nothing():
    """A metric the profile under test misses far beyond the cap: for what a candidate
    worsens (``beyond``), one that takes its centre a few spreads further from the real value
    exceeds the cap by that move in the reference's spreads, less the centres' noise, past the
    cap's reach (closed form, Student's t from scipy.stats), at most D_CAP more; one at the
    reference's centre, or nearer the log, stays at or under the cap. The score's distance
    (and its vector twin) stays capped, and a unit's gap takes each part at most D_CAP. The
    GSDC SPAN reference as the real log: 11.4 satellites used, 8 in every seed (no spread): a
    move is counted in floors."""
    from scipy import special, stats

    rng = np.random.default_rng(21)

    def g(metric, x):  # the metric's judging scale
        return np.log(np.asarray(x, dtype=float) + bands.METRICS[metric].c)

    sd = 0.2  # (CEP50 over a held-out block, log scale)
    real = 400.0
    ref = bands.judge("cep50_m", real, np.exp(g("cep50_m", 3.0) + rng.normal(0, sd, 12)) - 0.5)
    assert bands.distance_against("cep50_m", real, ref, ref) == bands.D_CAP
    out = {}
    for name, k in (("further", 4.0), ("same", 0.0), ("nearer", -3.0), ("far", 100.0)):
        own = bands.judge("cep50_m", real, np.exp(g("cep50_m", ref.centre) - k * sd
                                                  + rng.normal(0, sd, 12)) - 0.5)
        d = bands.distance_against("cep50_m", real, own, ref, beyond=True)
        capped = bands.distance_against("cep50_m", real, own, ref)
        assert capped == min(d, bands.D_CAP)
        assert capped == pytest.approx(bands.distances_many(
            "cep50_m", np.array([real]), [own], [np.zeros(12)], ref)[0, 0])
        out[name] = d
        if name == "further":
            spread = ref.sd_g * math.sqrt(1 + 1 / ref.n)
            floor_g = float(g("cep50_m", ref.centre + 0.5) - g("cep50_m", ref.centre))
            assert spread > floor_g  # (counted in spreads)
            tol = stats.t.isf(bands.GUARD_P, 11) * math.sqrt((own.sd_g ** 2 + ref.sd_g ** 2) / 12)
            cap_t = stats.t.isf(special.ndtr(-(bands.D_CAP + bands.DEAD_ZONE_Z)), 11)
            miss_own, miss_ref = (abs(float(g("cep50_m", real) - g("cep50_m", c)))
                                  for c in (own.centre, ref.centre))
            extra = (miss_own - tol - max(miss_ref, floor_g + cap_t * spread)) / spread
            assert 17 < cap_t < 18 and 1 < extra < bands.D_CAP
            assert d == pytest.approx(bands.D_CAP + extra)
    assert out["further"] > bands.D_CAP + 1.0  # (select.WORSEN_MAX: the step that rejects it)
    assert out["same"] == bands.D_CAP and out["nearer"] <= bands.D_CAP
    assert out["far"] == 2 * bands.D_CAP
    gap, parts = where.gap_score({"cep50_m": (real, own)}, {"cep50_m": (real, ref)})
    assert parts["cep50_m"] == 2 * bands.D_CAP and gap == bands.D_CAP

    def sats(x):
        return g("sats_used_mean", x)

    real = 11.4
    ref0 = bands.judge("sats_used_mean", real, np.full(8, 8.0))
    own0 = bands.judge("sats_used_mean", real, np.full(8, 7.0))
    assert ref0.sd_g == 0 and bands.distance_against("sats_used_mean", real, ref0, ref0) == 5
    floor = float(sats(8.5) - sats(8.0))  # (0.5 satellites)
    assert bands.distance_against("sats_used_mean", real, own0, ref0,
                                  beyond=True) == pytest.approx(
        bands.D_CAP + float(sats(8.0) - sats(7.0)) / floor)
    assert bands.distance_against("sats_used_mean", real, bands.judge(
        "sats_used_mean", real, np.full(8, 4.0)), ref0, beyond=True) == 2 * bands.D_CAP


def test_a_guarded_distance_keeps_the_candidates_own_spread_when_its_centre_comes_closer():
    """A candidate that moves the centre onto the real value keeps its own (calibrated)
    distance, however wide its spread; one with the reference's centre and a wider spread (a
    correlated error scattering whole-unit CEPs) too; the reference itself is unchanged."""
    rng = np.random.default_rng(12)
    ref_sims = np.exp(rng.normal(np.log(1.0), 0.03, 8))
    real = 0.38
    ref = bands.judge("hdop_median", real, ref_sims)
    closer = bands.judge("hdop_median", real, np.exp(rng.normal(np.log(0.4), 0.5, 8)))
    assert bands.distance_against("hdop_median", real, closer, ref) == \
        bands.distance(closer.z) < bands.distance(ref.z)
    null, kept = [], 0
    for _ in range(500):
        sharp = np.exp(rng.normal(np.log(4.0), 0.05, 9))
        wide = np.exp(rng.normal(np.log(4.0), 0.5, 9))
        y = float(np.exp(rng.normal(np.log(4.0), 0.5)))  # the real scatter is the wide one
        r, w = bands.judge("cep50_m", y, sharp[1:]), bands.judge("cep50_m", y, wide[1:])
        kept += bands.distance_against("cep50_m", y, w, r) == bands.distance(w.z)
        null.append(bands.distance_against("cep50_m", y, w, r))
    assert kept / 500 > 0.99 and np.mean(null) < 0.2
    assert bands.distance_against("hdop_median", real, ref, ref) == bands.distance(ref.z)


def test_what_a_candidate_worsens_is_its_centres_move_not_a_narrower_spread():
    """For the veto on worsening, a candidate whose seeds scatter less than the model before
    it is judged by where its centre lies in that model's (wider) spread: the same centre
    worsens nothing however narrow its spread (its own distance rises far: the tau 2.99 s
    filter's autocorr_s after noise_level), a centre moved three of the before-model's
    spreads away from the log worsens by more than select.WORSEN_MAX, as it does in its own
    spread. A wider spread, or a rank-judged metric, keeps distance_against. Closed form:
    seeds placed at the normal quantiles, so each ensemble's mean and deviation are exact."""
    from scipy import special, stats

    s = 12
    q = special.ndtri((np.arange(s) + 0.5) / s)
    q = q / q.std(ddof=1)  # (unit sample deviation)

    def seeds(centre_m, sd_log):  # cep50_m is judged on log(x + 0.5)
        return np.exp(np.log(centre_m + 0.5) + sd_log * q) - 0.5

    real = 6.0
    before = bands.judge("cep50_m", real, seeds(4.0, 0.3))
    d_before = bands.distance_against("cep50_m", real, before, before, beyond=True)
    same_narrow = bands.judge("cep50_m", real, seeds(4.0, 0.03))
    # (in its own spread: far outside)
    assert bands.distance(same_narrow.z) > d_before + select.WORSEN_MAX
    d = bands.distance_moved("cep50_m", real, same_narrow, before, before)
    assert d == pytest.approx(d_before, abs=1e-9)
    # moved away by three of the before-model's spreads, narrower: a worsening either way
    g_away = np.log(4.5) - 3 * 0.3
    moved = bands.judge("cep50_m", real, seeds(float(np.exp(g_away)) - 0.5, 0.1))
    d = bands.distance_moved("cep50_m", real, moved, before, before)
    edge = np.log(np.exp(g_away) + 0.5)  # (the floor: 0.5 m, above 5 % of the centre)
    z = -special.ndtri(stats.t.sf((np.log(6.5) - edge) / (0.3 * np.sqrt(1 + 1 / s)), s - 1))
    assert d == pytest.approx(max(0.0, z - bands.DEAD_ZONE_Z), rel=1e-6)
    assert d - d_before > select.WORSEN_MAX
    # a wider spread, or no before-model: distance_against itself
    wide = bands.judge("cep50_m", real, seeds(3.0, 0.6))
    assert bands.distance_moved("cep50_m", real, wide, before, before) == \
        bands.distance_against("cep50_m", real, wide, before, beyond=True)
    assert bands.distance_moved("cep50_m", real, same_narrow, None, before) == \
        bands.distance(same_narrow.z)
    ranked = bands.judge("autocorr_s", 60.0, np.r_[np.full(6, 50.0), np.full(6, np.nan)])
    assert ranked.rank
    assert bands.distance_moved("autocorr_s", 60.0, ranked, before, None) == \
        bands.distance(ranked.z)
    # where.moved_parts over a unit's metrics, and the veto reading it
    parts = where.moved_parts({"cep50_m": (real, same_narrow)}, {"cep50_m": (real, before)})
    assert parts["cep50_m"] == pytest.approx(d_before, abs=1e-9)
    b, a = np.array([1.0, 1.0]), np.array([0.5, 0.5])
    tried = select.Tried(cand=fx.Candidate("noise_level", (), lambda p: {}, ()),
                         fold_overrides=[], fold_points=[], before=b, after=a, before_fit=b,
                         after_fit=a, metrics_before={"cep50_m": d_before},
                         metrics_after={"cep50_m": bands.D_CAP},
                         metrics_moved={"cep50_m": d_before})
    assert select.acceptable(tried, 1.0) == (True, "")
    tried.metrics_moved = None
    ok, why = select.acceptable(tried, 1.0)
    assert not ok and why.startswith("it worsens cep50_m by")


def test_printed_step_reads_the_logs_digits():
    assert observed.printed_step(np.array([1.0, 0.99, 1.23])) == pytest.approx(0.01)
    assert observed.printed_step(np.array([0.9, 1.1, 2.0])) == pytest.approx(0.1)
    assert observed.printed_step(np.array([135.2, 140.0, np.nan])) == pytest.approx(0.1)
    assert observed.printed_step(np.array([np.nan])) == 0.0


def test_segments_holding_the_same_epochs_are_one_row():
    a = np.array([True, True, False])
    got = where.merged_segments({"all": np.ones(3, bool), "steady": np.ones(3, bool),
                                 "moving": a, "open": np.ones(3, bool)})
    assert list(got) == ["all", "moving"] and got["all"][1] == ["steady", "open"]


# --- held-out design ---------------------------------------------------------------------------


def test_blocks_are_guarded_by_the_correlation_time():
    t = np.arange(3600.0)
    d = design.make_design(["hour"], [t], [np.ones(t.size, bool)], [150.0], 4)
    assert d.claims and len(d.units) == 4 and len(d.outer) == 4
    spans = [(t[u.mask][0], t[u.mask][-1]) for u in d.units]
    for (_, end), (start, _) in zip(spans[:-1], spans[1:], strict=True):
        assert start - end >= 150.0
    assert not (d.units[0].mask & d.units[1].mask).any()


def test_a_run_too_short_for_blocks_claims_nothing():
    t = np.arange(10.0)
    d = design.make_design(["ten"], [t], [np.ones(10, bool)], [5.0], 4)
    assert not d.claims and d.outer == [] and "no effect is claimed" in d.warnings[-1]


def test_three_runs_are_left_out_one_at_a_time():
    ts = [np.arange(300.0) + 1000.0 * k for k in range(3)]
    d = design.make_design(["a", "b", "c"], ts, [np.ones(300, bool)] * 3, [np.nan] * 3, 4)
    assert d.scheme == "leave one run out" and len(d.units) == 3 and d.outer == [[0], [1], [2]]


def test_runs_at_the_same_time_are_held_out_together():
    """Two phones in one car share their errors' slow part: the same time block of both is one
    key, held out together by the outer groups and the inner folds; three such runs are not
    left out one at a time. A run that overlaps neither is its own."""
    t = np.arange(1800.0)
    ones = np.ones(t.size, bool)
    d = design.make_design(["a", "b"], [t, t + 0.4], [ones, ones], [60.0, 90.0], 4)
    assert d.claims and "held out together" in d.scheme and d.guard_s == 90.0
    assert len(d.units) == 8 and len(set(d.unit_keys())) == 4
    for g in d.outer:  # each outer group: both runs' blocks of its times
        assert sorted(d.units[u].run for u in g) == [0, 1]
        assert len({d.unit_keys()[u] for u in g}) == 1
    inner = [u for u in range(8) if u not in d.outer[0]]
    for f in design.folds(inner, 3, d.unit_keys()):
        assert sorted(d.units[u].run for u in f) == [0, 1]
    d3 = design.make_design(["a", "b", "c"], [t, t, t + 10_000.0], [ones] * 3, [60.0] * 3, 4)
    assert d3.scheme.startswith("leave one time block out") and len(set(d3.unit_keys())) == 8
    assert d3.units[-1].run == 2 and d3.unit_keys()[-1] != d3.unit_keys()[0]
    # (a short pair: one key of two blocks is no held-out test)
    short = np.arange(200.0)
    d2 = design.make_design(["a", "b"], [short, short], [np.ones(200, bool)] * 2, [60.0] * 2, 4)
    assert not d2.claims and "1 unit(s)" in d2.warnings[-1]


# --- fits ----------------------------------------------------------------------------------------


def _cand() -> fx.Candidate:
    axes = (fx.Axis("tau_s", (30.0, 60.0, 120.0, 240.0, 480.0), 1.0, 7200.0),
            fx.Axis("sigma_m", (1.0, 2.0, 4.0), 0.1, 100.0))
    return fx.Candidate("correlated_error", axes, lambda p: {"correlated_error": dict(p)},
                        ("tau_s", "sigma_m"), {"tau_s": 120.0, "sigma_m": 2.0})


def test_identify_reports_what_the_data_cannot_pin_down():
    c = _cand()
    pts = c.points
    # the objective depends on sigma only: tau is not identifiable and stays at its default
    j = np.array([abs(p["sigma_m"] - 4.0) for p in pts])
    idx, info = fit.identify(c, j, j + 0.001)
    assert pts[idx] == {"tau_s": 120.0, "sigma_m": 4.0}
    assert info["identifiable"] == {"tau_s": False, "sigma_m": True}
    assert info["grid_edge"] == {"sigma_m": "upper"}
    # flat: the default point
    idx, info = fit.identify(c, np.zeros(len(pts)), np.zeros(len(pts)))
    assert pts[idx] == c.default and info["flat"]


def test_an_axis_extends_on_its_own_spacing():
    c = _cand()
    assert c.extended("tau_s", True).axes[0].values[-1] == 960.0
    assert c.extended("sigma_m", False).axes[1].values[0] == 0.5
    lat = fx.Axis("latency_s", (0.1, 0.25, 0.4), 0.0, 30.0)
    assert lat.step_beyond(False) is None  # 0.1 - 0.15 < 0


def test_a_refit_against_the_end_of_its_cut_grid_goes_on_past_it():
    c = _cand()
    cut = c.near([{"tau_s": 120.0, "sigma_m": 4.0}])  # tau 60-240, sigma 2-4
    assert cut.whole is c and cut.near([cut.points[0]]).whole is c
    assert [a.values for a in cut.axes] == [(60.0, 120.0, 240.0), (2.0, 4.0)]
    pts = cut.points

    def obj(f) -> np.ndarray:
        return np.array([f(p["tau_s"], p["sigma_m"]) for p in pts])
    # the best tau at the cut's lower end (60 s), clearly below 120 s: the whole grid has 30 s
    assert fit.pulled_past_cut(cut, obj(lambda tau, sig: tau / 100.0))
    # ... within FLAT_MIN of its inward neighbour: the data cannot say the fit would go on
    assert not fit.pulled_past_cut(cut, obj(lambda tau, sig: tau / 1e4))
    # the best inside the cut, or at an end of the whole grid (sigma 4), stays
    assert not fit.pulled_past_cut(cut, obj(lambda tau, sig: abs(tau - 120.0) / 100.0))
    assert not fit.pulled_past_cut(cut, obj(lambda tau, sig: -sig + abs(tau - 120.0)))
    # sigma's cut end 2 is not the whole grid's 1
    assert fit.pulled_past_cut(cut, obj(lambda tau, sig: sig + abs(tau - 120.0)))
    # a fit at a cut end extends into the whole grid first, then past it on its own spacing
    assert cut.extended("tau_s", False).axes[0].values == (30.0, 60.0, 120.0, 240.0)
    assert cut.extended("tau_s", True).axes[0].values[-1] == 480.0
    assert cut.whole_beyond("sigma_m", True) is None and c.whole_beyond("tau_s", True) is None
    assert cut.extended("sigma_m", True).axes[1].values[-1] == 6.0
    # a whole grid has no cut; the objective's gaps (NaN) are left out
    assert not fit.pulled_past_cut(c, np.arange(len(c.points), dtype=float))
    assert not fit.pulled_past_cut(cut, np.full(len(pts), np.nan))


def test_two_searches_that_end_alike_are_a_tie_the_report_names():
    """The second search (from the first round's runner-up) is kept only where it ends
    clearly lower; where neither ends clearly lower with other effects, the report names the
    other as an equally good explanation (the GSDC drive delayed 0.7 s: a filter 0.628, a
    delay 0.600)."""
    from virtualgps.gap import tool

    def two(a: float, b: float, second=("latency", "noise_level")) -> list[dict]:
        return [{"first": "nav_filter", "effects": ["nav_filter", "noise_level"],
                 "gap_after": a},
                {"first": second[0], "effects": list(second), "gap_after": b}]

    paths = two(0.628, 0.600)
    assert select.settle_paths(paths) == 0 and paths[0]["kept"] and paths[1]["tie"]
    alt = select.alternative(paths)
    assert alt["effects"] == ["latency", "noise_level"] and alt["chosen_gap_after"] == 0.628
    assert "do not decide between nav_filter and latency" in alt["what"]
    report = {"headline": [], "outer": {}, "design": {"scheme": "", "warnings": []},
              "runs": [], "effects": [], "located": [], "profile": "holux-m1000",
              "gap_baseline": 1.5, "causes": [], "alternative": alt}
    assert f"  alternative: {alt['what']}" in tool.summary_lines(report)
    # clearly lower (by more than 0.1, what adding an effect needs): the second is kept
    paths = two(0.8, 0.6)
    assert select.settle_paths(paths) == 1 and "tie" not in paths[0]
    assert select.alternative(paths) is None
    # clearly higher: no tie; the same effects found in another order: no alternative
    for paths in (two(0.5, 0.7), two(0.6, 0.62, ("noise_level", "nav_filter"))):
        assert select.settle_paths(paths) == 0 and select.alternative(paths) is None


def test_defaults_are_the_profiles_own_values_or_the_grids_centre():
    usarsim = {"noise": {"model": "usarsim"}}
    cands = {c.name: c for c in fx.candidates(usarsim, has_mesh=False)[0]}
    ce = cands["correlated_error"]
    assert ce.default == {"tau_s": 120.0, "sigma_m": 2.5}  # the grid's centre
    own = {"noise": {"model": "none"}, "correlated_error": {"tau_s": 500.0, "sigma_m": 1.2}}
    ce = {c.name: c for c in fx.candidates(own, has_mesh=False)[0]}["correlated_error"]
    assert ce.default == {"tau_s": 480.0, "sigma_m": 1.0}  # nearest the profile's own


def test_the_terminal_headline_says_each_value_in_its_unit():
    from virtualgps.gap import tool

    rows = [{"label": "CEP50", "unit": "m", "real": 0.117, "simulated": 0.715, "sim_lo": 0.0106,
             "sim_hi": 2.08, "outside": False, "calibrated": None},
            {"label": "satellites used", "unit": "", "real": 8.0, "simulated": 10.0,
             "sim_lo": 9.5, "sim_hi": 10.5, "outside": True, "calibrated": None}]
    report = {"headline": rows, "outer": {}, "design": {"scheme": "", "warnings": []},
              "runs": [], "effects": [], "located": [], "profile": "holux-m1000",
              "gap_baseline": 2.48, "causes": []}
    lines = tool.summary_lines(report)
    assert lines[0] == "CEP50: real 0.117 m, simulated 0.715 m (0.0106..2.08)"
    assert lines[1] == "satellites used: real 8, simulated 10 (9.5..10.5)  <- gap"


def test_many_values_against_many_ensembles_are_judged_as_one_by_one():
    """distances_many is judge's distance for each pair: normal ensembles, rank-judged ones
    (seeds with no value), a degenerate one, one too small to judge, and values with none."""
    rng = np.random.default_rng(3)
    for metric in ("cep50_m", "fix_fraction", "ttff_s", "lag_s"):
        ens = [np.exp(rng.normal(1.0, 0.5, 8)), np.full(8, 2.0),
               np.array([np.nan] * 3 + list(rng.uniform(10.0, 60.0, 5))),
               np.array([1.0, np.nan, np.nan, np.nan])]
        if metric == "fix_fraction":
            ens[0] = 1.0 - rng.uniform(0.0, 0.05, 8)
        values = np.concatenate([np.exp(rng.normal(1.0, 1.0, 12)), [0.0, 2.0, np.nan]])
        judged = [bands.judge(metric, 1.0, e) for e in ens]
        got = bands.distances_many(metric, values, judged, ens)
        want = np.array([[bands.distance(bands.judge(metric, float(v), e).z)
                          if math.isfinite(v) else math.nan for v in values] for e in ens])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def test_many_values_are_guarded_by_the_reference_as_one_by_one():
    """With a reference, distances_many is distance_against for each pair: an ensemble whose
    centre lies further from a value than the reference's, beyond their noise, is measured in
    the reference's spread where that is further (a wide ensemble far off gains nothing by its
    width); one no further keeps its own distance. Rank-judged ensembles or references keep
    their own too."""
    rng = np.random.default_rng(11)
    for metric in ("cep50_m", "fix_fraction", "ttff_s"):
        ens = [np.exp(rng.normal(1.0, 0.1, 8)),  # narrow, at the reference
               np.exp(rng.normal(4.5, 1.5, 8)),  # wide and far: guarded
               np.exp(rng.normal(0.2, 0.05, 8)),  # narrow, off to the other side
               np.array([np.nan] * 3 + list(rng.uniform(10.0, 60.0, 5)))]
        refs = [np.exp(rng.normal(1.0, 0.1, 8)), np.array([1.0, 2.0, 3.0, np.nan] * 2)]
        if metric == "fix_fraction":
            ens = [1.0 - np.abs(e - np.nanmedian(e)) / 100.0 for e in ens]
            refs = [1.0 - np.abs(r - np.nanmedian(r)) / 100.0 for r in refs]
        values = np.concatenate([np.exp(rng.normal(1.0, 0.3, 10)), [np.nan]])
        if metric == "fix_fraction":
            values = 1.0 - np.abs(values - 1.0) / 100.0
        if metric == "ttff_s":  # (start-ups of tens of seconds: beyond the 2 s floor)
            ens, refs, values = [20.0 * e for e in ens], [20.0 * r for r in refs], 20.0 * values
        guarded = 0
        for r in refs:
            ref = bands.judge(metric, 1.0, r)
            judged = [bands.judge(metric, 1.0, e) for e in ens]
            got = bands.distances_many(metric, values, judged, ens, ref)
            want = np.array([[bands.distance_against(metric, float(v), bands.judge(
                metric, float(v), e), bands.judge(metric, float(v), r))
                if math.isfinite(v) else math.nan for v in values] for e in ens])
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
            guarded += int(np.sum(got > bands.distances_many(metric, values, judged, ens)))
        assert guarded > 0, metric  # (the wide, far ensemble was guarded somewhere)


class _GridSim:
    """A stand-in for the Simulator's scores: grid point k's seeds of each seed set, per unit
    (only :meth:`scores` and :meth:`reference_scores` are read by a fit's refits); the
    reference is one of the grid's points."""

    def __init__(self, scores: dict, reference: dict | None = None) -> None:
        self._scores = scores
        self.reference_table = reference

    def scores(self, table: dict, seed_set: int, units: list[int]) -> list:
        return [self._scores[(table["k"], seed_set, u)] for u in units]

    def reference_scores(self, seed_set: int, units: list[int]) -> list | None:
        if self.reference_table is None:
            return None
        return self.scores(self.reference_table, seed_set, units)


def _cold_start_fit(rng: np.random.Generator, truth_k: int, spread: float, n_units: int = 1):
    """One fit of a start-up delay on a grid of 20-90 s: the real log and every grid point's
    8 + 8 seeds drawn alike (TTFF log-normal about the point, CEP50 unmoved); returns the
    candidate, the chosen index, the identify info and the refits' picks."""
    from virtualgps.gap.simulator import FIT, HELD, UnitScore

    axis = fx.Axis("ttff_cold_s", (20.0, 30.0, 45.0, 60.0, 90.0), 1.0, 600.0)
    cand = fx.Candidate("cold_start", (axis,), lambda p: {"cold_start": dict(p)},
                        ("ttff_cold_s",), {"ttff_cold_s": 45.0})
    values = axis.values

    def draw(v: float, n: int) -> dict:
        return {"ttff_s": v * np.exp(rng.normal(0.0, spread, n)),
                "cep50_m": np.exp(rng.normal(1.0, 0.3, n))}

    real = [{m: float(x[0]) for m, x in draw(values[truth_k], 1).items()}
            for _ in range(n_units)]
    scores = {}
    for k, v in enumerate(values):
        for seed_set in (FIT, HELD):
            for u in range(n_units):
                seeds = draw(v, 8)
                judged = {m: (real[u][m], bands.judge(m, real[u][m], seeds[m])) for m in seeds}
                scores[(k, seed_set, u)] = UnitScore(judged, seeds=seeds)
    units = list(range(n_units))
    j = {s: np.array([np.mean([where.gap_score(scores[(k, s, u)].judged)[0] for u in units])
                      for k in range(len(values))]) for s in (FIT, HELD)}
    idx, info = fit.identify(cand, j[FIT], j[HELD])
    grid = [{"k": k} for k in range(len(values))]
    picks = fit.refit_points(_GridSim(scores, grid[cand.default_index]), grid, idx, units,
                             cand.default_index)
    return cand, idx, info, picks


def test_a_fits_interval_holds_what_fits_to_logs_from_its_point_pick():
    """The points within the seeds' noise of the best leave out the real log's own luck; the
    points that fits to logs drawn from the chosen point pick (the chosen point's seeds of one
    set taken as real, against the other set's) put it back. On a grid whose points the seeds
    barely tell apart, the interval so holds the true point in at least 95 % of fits (the
    near-optimal points alone: some 90 %), one grid point wider on average."""
    rng = np.random.default_rng(7)
    held = {"near": 0, "refits": 0}
    n = 150
    for _ in range(n):
        truth = int(rng.integers(0, 5))
        cand, idx, info, picks = _cold_start_fit(rng, truth, spread=0.4)
        assert len(picks) == 16  # each seed of either set, one fit each
        iv = fit.intervals(cand, [*info["near"], *picks])["ttff_cold_s"]
        near = fit.intervals(cand, info["near"])["ttff_cold_s"]
        value = cand.axes[0].values[truth]
        held["near"] += near[0] <= value <= near[1]
        held["refits"] += iv[0] <= value <= iv[1]
    assert held["refits"] / n >= 0.95, held
    assert held["refits"] > held["near"], held
    # seeds that tell the points apart: the refits pick the chosen point alone
    _, idx, info, picks = _cold_start_fit(rng, 2, spread=0.02)
    assert set(picks) == {idx} == {2}


def test_statistics_and_scores_come_back_from_a_worker_as_they_left():
    """Results cross to the main process pickled, their per-seed values packed as one array
    (where.pack_vectors): what comes back equals what was sent, value for value and type for
    type, whatever the dict holds."""
    import pickle

    from virtualgps.gap.simulator import UnitScore

    rng = np.random.default_rng(3)
    sim = {"cep50_m": rng.uniform(1, 3, 8), "fix_fraction": np.r_[1.0, np.nan, 0.9, 1, 1, 1, 1, 1]}
    pair = {"eq4_deg": rng.uniform(0, 1e-5, 8)}
    stats = where.SegmentStats({"cep50_m": 2.0, "eq4_deg": 3e-6}, sim, pair,
                               (rng.uniform(size=(8, 4)), np.arange(4)))
    odd = where.SegmentStats({}, {"ttff_s": np.arange(8)}, {})  # (an int array: left as it is)
    judged = {m: (1.5, bands.judge(m, 1.5, v)) for m, v in sim.items()}
    scores = [UnitScore(judged, np.ones((3, 4)), None, {m: v for m, v in sim.items()}),
              UnitScore(judged), UnitScore({}, seeds={})]

    def same(a, b):
        if type(a) is not type(b):
            return False
        if isinstance(a, dict):
            return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
        if isinstance(a, np.ndarray):
            return a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)
        if isinstance(a, tuple):  # (named ones too: Judged)
            return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
        if hasattr(a, "__dataclass_fields__"):
            return all(same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
        if isinstance(a, float):
            return a == b or (math.isnan(a) and math.isnan(b))
        return a == b

    for x in (stats, odd, *scores):
        back = pickle.loads(pickle.dumps(x, pickle.HIGHEST_PROTOCOL))
        assert same(x, back), x
    assert not same(stats, where.SegmentStats(stats.real, {**sim, "cep50_m": sim["cep50_m"] + 1},
                                              pair, stats.fractions))


def test_an_effect_seen_once_is_not_claimed_by_the_outer_test():
    """A start-up shows in the one block that holds the power-on: the outer group that holds
    that block chose without it, so the outer test cannot judge it, and the report says so;
    an effect some group holding its evidence chose is judged, one that shows nowhere is not
    named."""
    from virtualgps.gap import diagnose, report

    outer = [{"heldout": f"time block {k + 1}/4", "units": [k],
              "effects": ["correlated_error"] + (["cold_start"] if k else [])}
             for k in range(4)]
    steps = [{"name": "correlated_error", "_shows_in": [0, 1, 2, 3]},
             {"name": "cold_start", "_shows_in": [0]},
             {"name": "sbas", "_shows_in": []}]
    blind = diagnose.not_judged(steps, outer)
    assert blind == [{"effect": "cold_start", "shows_in": ["time block 1/4"]}]
    # shown in every block and chosen by no group, it is another explanation's, not unseen
    steps[1]["_shows_in"] = [0, 1, 2, 3]
    for o in outer:
        o["effects"] = ["correlated_error"]
    assert diagnose.not_judged(steps, outer) == []
    for o in outer[1:]:
        o["effects"].append("cold_start")
    # with the power-on in a second run's block too, a group that holds one chose it
    outer[0]["units"] = [0, 4]
    outer[1]["units"] = [1, 5]
    steps[1]["_shows_in"] = [0, 5]
    assert diagnose.not_judged(steps, outer) == []
    (note,) = report.outer_notes({"not_judged": blind}, ["correlated_error", "cold_start"])
    assert "cannot judge cold_start" in note and "time block 1/4" in note


def test_the_outer_test_says_when_it_does_not_confirm_what_was_added():
    """The outer test's reduction with its t interval over the groups: where the interval
    reaches 0 the terminal and the page say the added effects are not confirmed, with what the
    groups chose; where it lies above 0, or every added effect is one the outer test cannot
    judge, nothing is said; one group gives no interval and no verdict."""
    from scipy import stats

    from virtualgps.gap import diagnose, report

    def choice(before, after, chose):
        full = select.Selection(steps=[], ranking=[], skipped={}, baseline=math.nan,
                                final=math.nan, final_table={}, fold_tables=[], folds=[])
        groups = zip(before, after, chose, strict=True)
        return diagnose.Choice(full, [{"heldout": f"time block {k + 1}", "units": [k],
                                       "effects": c, "gap_before": b, "gap_after": a}
                                      for k, (b, a, c) in enumerate(groups)])

    before = [2.0, 1.8, 2.4, 1.9]
    mixed = choice(before, [1.2, 2.1, 1.6, 2.2],
                   [["dop_error"], ["cn0_tracking"], ["dop_error", "cn0_tracking"], []])
    out = mixed.outer_summary()
    d = np.array(before) - [1.2, 2.1, 1.6, 2.2]
    half = stats.t.ppf(0.975, 3) * d.std(ddof=1) / 2.0  # (closed form: scipy's t quantile)
    assert out["reduction"] == pytest.approx(d.mean())
    assert out["interval"] == pytest.approx([d.mean() - half, d.mean() + half])
    assert out["interval"][0] < 0 < out["interval"][1] and out["confirmed"] is False
    (note,) = report.outer_notes({**out, "folds": mixed.outer}, ["dop_error"])
    assert note.startswith("the outer test does not confirm dop_error: ")
    assert "(dop_error in 2, cn0_tracking in 2, nothing in 1)" in note
    assert f"the gap fell by {d.mean():.3f} (reduction 95 %: {out['interval'][0]:.3f} to " in note
    worse = {**out, "reduction": -0.351, "interval": [-1.028, 0.325]}
    assert "the gap grew by 0.351 (reduction 95 %: -1.028 to 0.325, not clearly above 0)" in \
        report.outer_notes(worse, ["dop_error"])[0]
    assert note.endswith("treat it as a candidate to check on more data, not as a finding")
    two = report.outer_notes({**out, "folds": mixed.outer}, ["dop_error", "cn0_tracking"])
    assert two[0].startswith("the outer test does not confirm dop_error, cn0_tracking: ")
    assert two[0].endswith("treat them as candidates to check on more data, not as findings")
    # an effect the outer test cannot judge has its own note, not this one
    blind = {**out, "not_judged": [{"effect": "cold_start", "shows_in": ["time block 1"]}]}
    (note,) = report.outer_notes(blind, ["cold_start"])
    assert "cannot judge cold_start" in note
    # every group's choice helps it: confirmed, nothing to say
    clear = choice(before, [1.1, 1.0, 1.5, 1.2], [["dop_error"]] * 4).outer_summary()
    assert clear["confirmed"] is True and clear["interval"][0] > 0
    assert report.outer_notes(clear, ["dop_error"]) == []
    # one group: a reduction but no interval and no verdict
    one = choice(before[:1], [1.1], [["dop_error"]]).outer_summary()
    assert one["confirmed"] is None and math.isnan(one["interval"][0])
    assert report.outer_notes(one, ["dop_error"]) == []
