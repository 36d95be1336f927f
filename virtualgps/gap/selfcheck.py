"""The withheld-effect check of the diagnosis itself (``virtualgps gap --selfcheck``, DESIGN
section 7.4): runs the diagnosis on the synthetic trials (:mod:`.synthetic`) and on real logs
with an effect injected (:mod:`.selfcheck_real`), and sums them up.

A trial succeeds when the injected effect is ranked first (``ranked[0]``: the first effect
added, else the candidate with the lowest held-out gap; ``nothing`` for a log with nothing
injected); the confusion matrix counts injected x ranked first, a second one injected x added
first (``none`` where no effect clears the acceptance rule), and the recovered parameters, the
held-out shrinkage and the band's calibration under the null are reported.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from virtualgps.gap import diagnose as dg
from virtualgps.gap.report import single_effect_share
from virtualgps.gap.synthetic import (
    INJECTIONS,
    NOTHING,
    NULL_SCENARIOS,
    PAIRS,
    _row,
    make_trial,
    spec_of,
)

# --- trajectories ------------------------------------------------------------------------------


def default_labels(effects: tuple[str, ...] | None) -> list[str]:
    """The trial labels of a self-check: every injectable effect (or those asked), the null
    trials of each profile, and the pairs (all, when no effect is named)."""
    if effects:
        return [e for e in effects if not e.startswith("real:")]
    return ([*INJECTIONS] + [f"{NOTHING}@{p}" for p in NULL_SCENARIOS] + list(PAIRS))


def run(opts: dg.Options, trials: int = 3, out_dir: str | Path = "selfcheck",
        progress: Callable[[str], None] | None = None, labels: list[str] | None = None,
        data: str | Path | None = None) -> dict:
    """Run the self-check and write ``selfcheck.json`` and ``report.html`` into ``out_dir``.

    Parameters
    ----------
    opts : diagnosis options (``effects`` restricts the trials: effect names, pairs ``a+b``,
        ``nothing@PROFILE``, real-log trials ``real:gsdc:EFFECT``)
    trials : trials per label
    out_dir : output folder (its ``work/`` subfolder keeps the pseudo-real logs)
    progress : called with a short text as trials finish
    labels : the trial labels (default: :func:`default_labels` of ``opts.effects``)
    data : the shared real logs (``../shared/data``): real-log bases with effects injected
        (:mod:`.selfcheck_real`: all, or those ``effects`` names); None: none

    Returns
    -------
    result : the ``selfcheck.json`` content
    """
    from virtualgps.gap import report as rp
    from virtualgps.gap import tool
    from virtualgps.run.config import BUNDLED_SCENES_DIR, DEFAULT_SCENE
    from virtualgps.sky.ephemeris import default_tle_path
    from virtualgps.sky.scene import load_scene

    out = Path(out_dir)
    work = out / "work"
    scene_dir = str(BUNDLED_SCENES_DIR / DEFAULT_SCENE)
    scene = load_scene(scene_dir)
    scene_tle = str(scene.tle_path)
    open_tle = str(default_tle_path())
    labels = labels if labels is not None else default_labels(opts.effects)
    diag_opts = replace(opts, effects=None)
    rows = []
    for label in labels:
        spec = spec_of(label)
        for i in range(trials):
            tr = make_trial(label, i, work, scene, scene_dir, scene_tle, open_tle)
            inp = tool.GapInputs(real=(str(tr.real),), truth=(tr.truth,), scene=tr.scene or "none",
                                 tle=tuple(tr.tle.split(os.pathsep)), profile=str(tr.profile))
            report, _, _ = tool.diagnose(inp, diag_opts)
            rows.append(_row(tr, spec.kind, spec.effects, report))
            if progress:
                progress(f"self-check {label} trial {i + 1}/{trials}: ranked first "
                         f"{rows[-1]['ranked_first']}")
    real_note = None
    if data is not None:
        from virtualgps.gap import selfcheck_real

        asked = selfcheck_real.named_effects(opts.effects)
        real_rows, real_note = (selfcheck_real.run(Path(data), diag_opts, trials, work,
                                                   progress, effects=asked)
                                if asked else ([], None))
        rows += real_rows
    result = summarise(rows, opts)
    if real_note:
        result["real_bases_note"] = real_note
    out.mkdir(parents=True, exist_ok=True)
    rp.write_json(result, out / "selfcheck.json")
    rp.write_selfcheck_html(result, out / "report.html")
    return result


def _share_interval(k: int, n: int) -> list[float]:
    """The Clopper-Pearson 95 % interval of a share k/n."""
    from scipy import special

    if n == 0:
        return [math.nan, math.nan]
    lo = 0.0 if k == 0 else float(special.betaincinv(k, n - k + 1, 0.025))
    hi = 1.0 if k == n else float(special.betaincinv(k + 1, n - k, 0.975))
    return [lo, hi]


def summarise(rows: list[dict], opts: dg.Options) -> dict:
    """``selfcheck.json``: the trials, the confusion matrices (``nothing`` included), per label
    the success share and parameter coverage, and the band's calibration under the null."""
    labels = list(dict.fromkeys(r["injected"] for r in rows))
    summary = {}
    for label in labels:
        mine = [r for r in rows if r["injected"] == label]
        cov = [v for r in mine for v in r["covered"].values()]
        summary[label] = {
            "kind": mine[0]["kind"], "trials": len(mine),
            "ranked_first": sum(r["ranked_first"] == (r["effects"][0] if r["effects"]
                                                      else NOTHING) for r in mine),
            "success": sum(r["success"] for r in mine),
            "share": sum(r["success"] for r in mine) / len(mine),
            "parameters_covered": f"{sum(cov)}/{len(cov)}" if cov else None,
        }
    null = [r for r in rows if r["kind"] == "null"]
    n_rows = sum(r["where_rows"] for r in null)
    n_out = sum(r["where_outside"] for r in null)
    any_out = sum(r["where_outside"] > 0 for r in null)
    calibration = {
        "reports": len(null), "reports_with_any_row_outside": any_out,
        "report_share": any_out / len(null) if null else math.nan,
        "report_share_interval": _share_interval(any_out, len(null)),
        "rows": n_rows, "rows_outside": n_out,
        "row_share": n_out / n_rows if n_rows else math.nan,
        "nominal": "false-discovery rate 0.05 over a report's rows: under the null at most 5 % "
                   "of reports show any row outside",
        "effects_added": sum(bool(r["accepted"]) for r in null),
    }
    n = len(rows)
    single = [r for r in rows if r["kind"] in ("single", "real")]
    # (once per truth: the real-log bases' trials share one ensemble, simulated along the same
    # truth with the same seeds, and would count its seeds again and again)
    held = list({r["truth"]: r["seed_holdout"] for r in reversed(rows)
                 if (r.get("seed_holdout") or {}).get("reports")}.values())
    h_n = sum(h["reports"] for h in held)
    h_k = sum(h["reports_with_any_row_outside"] for h in held)
    h_metrics: dict[str, int] = {}
    for h in held:
        for m, c in h["metrics"].items():
            h_metrics[m] = h_metrics.get(m, 0) + c
    calibration["seed_holdout"] = {
        "truths": len(held), "reports": h_n, "reports_with_any_row_outside": h_k,
        "report_share": h_k / h_n if h_n else math.nan,
        "report_share_interval": _share_interval(h_k, h_n),
        "rows": sum(h["rows"] for h in held),
        "rows_outside": sum(h["rows_outside"] for h in held), "metrics": h_metrics,
        "what": "every trial's baseline seeds, each in turn taken as the real log against the "
                "others: logs of the profile under test along every trial's truth, each truth "
                "once (trials on one real log share its ensemble; the interval treats the "
                "reports as independent, but those of one truth share their ensemble, so it "
                "is too narrow)",
    }
    return {
        "trials": rows,
        "outer_confirmation": _outer_confirmation(rows),
        "confusion": _confusion(rows, "ranked_first"),
        "confusion_added_first": _confusion(rows, "added_first"),
        "summary": summary,
        "null_calibration": calibration,
        "share_success": sum(r["success"] for r in rows) / n if n else math.nan,
        "share_ranked_first": (sum(r["ranked_first"] == r["effects"][0] for r in single)
                               / len(single) if single else math.nan),
        "share_other_first": (sum(r["ranked_first"] not in (r["effects"][0], NOTHING)
                                  for r in single) / len(single) if single else math.nan),
        "seeds": opts.seeds, "fit_seeds": opts.n_fit,
    }


def _outer_confirmation(rows: list[dict]) -> dict:
    """How often the outer test confirmed what a trial's diagnosis added (its reduction's 95 %
    interval above 0), apart for the right and the wrong trials: over the trials that added an
    effect the outer test can judge and that had an interval (two outer groups or more)."""
    out = {}
    for name, right in (("right", True), ("wrong", False)):
        mine = [r for r in rows if bool(r["success"]) == right
                and r.get("outer_confirmed") is not None
                and set(r["accepted"]) - set(r.get("outer_not_judged", []))]
        out[name] = {"trials": len(mine), "confirmed": sum(r["outer_confirmed"] for r in mine)}
    return out


def _confusion(rows: list[dict], key: str) -> dict[str, dict[str, int]]:
    """injected -> {effect in ``key`` (ranked or added first; ``nothing``): trials}."""
    out: dict[str, dict[str, int]] = {}
    for r in rows:
        c = out.setdefault(r["injected"], {})
        c[r[key]] = c.get(r[key], 0) + 1
    return out


def summary_lines(result: dict) -> list[str]:
    """The terminal summary: per trial label, how often the diagnosis got it right."""
    cal = result["null_calibration"]
    lines = [f"self-check: {len(result['trials'])} trials, right in "
             f"{100 * result['share_success']:.0f} %; {single_effect_share(result)}"]
    if cal["reports"]:
        lines.append(f"  null: {cal['reports_with_any_row_outside']}/{cal['reports']} reports "
                     f"with a located gap ({cal['rows_outside']}/{cal['rows']} rows), "
                     f"{cal['effects_added']} with an effect added")
    if (held := cal.get("seed_holdout") or {}).get("reports"):
        lines.append(f"  seeds held out in turn: {held['reports_with_any_row_outside']}/"
                     f"{held['reports']} reports with a located gap "
                     f"({held['rows_outside']}/{held['rows']} rows)")
    if oc := result.get("outer_confirmation"):
        lines.append(f"  outer test confirms what was added in {oc['right']['confirmed']}/"
                     f"{oc['right']['trials']} right trials, {oc['wrong']['confirmed']}/"
                     f"{oc['wrong']['trials']} wrong ones")
    for label, s in result["summary"].items():
        # (what was ranked first that the trials did not inject: a real base's label is not an
        # effect's name, and either effect of a pair may come first)
        injected = {e for r in result["trials"] if r["injected"] == label
                    for e in r["effects"]} or {NOTHING}
        others = ", ".join(f"{k} {v}" for k, v in result["confusion"][label].items()
                           if k not in injected)
        lines.append(f"  {label}: right {s['success']}/{s['trials']}"
                     + (f", parameters covered {s['parameters_covered']}"
                        if s["parameters_covered"] else "")
                     + (f" (ranked first instead: {others})" if others else ""))
    return lines

