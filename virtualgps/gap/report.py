"""The gap tool's reports: ``report.json`` (DESIGN section 7's contract) and a self-contained
``report.html`` with the figures inline (PNG data URIs, inline CSS, no script, no external
resource), for the diagnosis and for the self-check.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from virtualgps.gap import causes as cz
from virtualgps.gap import effects as fx
from virtualgps.gap.bands import holdout_warning
from virtualgps.gap.ingest import ingest_notes


@dataclass(frozen=True)
class RunFigureData:
    """One real run against its ensemble: ``n`` epochs, ``s`` seeds (see the gap tool)."""

    name: str
    t_unix_s: np.ndarray
    truth_lat_deg: np.ndarray
    truth_lon_deg: np.ndarray
    real_lat_deg: np.ndarray
    real_lon_deg: np.ndarray
    sim_lat_deg: np.ndarray
    sim_lon_deg: np.ndarray
    real_err_h_m: np.ndarray
    sim_err_h_m: np.ndarray
    real_sats_used: np.ndarray
    sim_sats_used: np.ndarray
    eq4_deg: np.ndarray
    final_lat_deg: np.ndarray | None = None
    final_lon_deg: np.ndarray | None = None
    final_err_h_m: np.ndarray | None = None
    final_sats_used: np.ndarray | None = None


@dataclass(frozen=True)
class GapFigureData:
    """Everything the report draws (arrays; see :mod:`virtualgps.plot`)."""

    runs: tuple[RunFigureData, ...]
    sky_az_deg: np.ndarray
    sky_el_deg: np.ndarray
    sky_disagreement: np.ndarray
    acf_lags_s: np.ndarray
    real_acf: np.ndarray
    sim_acf: np.ndarray
    waterfall_labels: tuple[str, ...]
    waterfall_gaps: tuple[float, ...]
    final_acf: np.ndarray | None = None


MAX_RUN_FIGURES = 6  # per-run figures for this many runs (the rest are in the tables)

CSS = """
body { font-family: sans-serif; margin: 2em; max-width: 75em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.85em; }
td, th { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: left; vertical-align: top; }
th { background: #eee; } tr.outside td { background: #fff0f0; }
figure { display: inline-block; margin: 0.5em; vertical-align: top; }
figcaption { font-size: 0.85em; color: #555; max-width: 40em; }
img { max-width: 100%; } .num { text-align: right; font-variant-numeric: tabular-nums; }
p.note { font-size: 0.9em; color: #444; max-width: 60em; }
"""


def outer_notes(outer: dict, added: list[str]) -> list[str]:
    """What the outer test cannot vouch for, one sentence each: every added effect it cannot
    judge (``outer.not_judged``), and, where its reduction's 95 % interval reaches 0 or below
    (``outer.confirmed`` false) for effects it could judge, that it does not confirm them.

    outer : the report's ``outer`` (``folds``: each group's choice, where given)
    added : the names of the effects the full selection added
    """
    blind = [n["effect"] for n in outer.get("not_judged", [])]
    notes = [f"the outer test cannot judge {n['effect']}: it shows only in "
             f"{'; '.join(n['shows_in'])}, and the choice made without that data did not add "
             f"it (seen once, it cannot be both chosen and held out); its held-out gain comes "
             f"from the inner folds alone, and logs that show it more than once would let the "
             f"outer test judge it" for n in outer.get("not_judged", [])]
    judged = [n for n in added if n not in blind]
    if judged and outer.get("confirmed") is False:
        lo, hi = outer["interval"]
        folds = outer.get("folds", [])
        why = ""
        if len({tuple(sorted(f["effects"])) for f in folds}) > 1:
            chosen = Counter(n for f in folds for n in f["effects"])
            said = [f"{n} in {k}" for n, k in chosen.most_common()]
            said += [f"nothing in {k}"] if (k := sum(not f["effects"] for f in folds)) else []
            why = f", and the {len(folds)} outer groups chose differently ({', '.join(said)})"
        moved = (f"fell by {outer['reduction']:.3f}" if outer["reduction"] >= 0
                 else f"grew by {-outer['reduction']:.3f}")
        notes.append(f"the outer test does not confirm {', '.join(judged)}: on data that "
                     f"neither the choice nor the fit saw the gap {moved} (reduction 95 %: "
                     f"{lo:.3f} to {hi:.3f}, not clearly above 0){why}: treat "
                     + ("it as a candidate to check on more data, not as a finding"
                        if len(judged) == 1 else
                        "them as candidates to check on more data, not as findings"))
    return notes


def single_effect_share(selfcheck: dict) -> str:
    """How often a self-check's single injected effect was ranked first, in words (the terminal's
    and the page's one rule): a run of null or pair trials only has none to count, not "0 %"."""
    first, other = selfcheck.get("share_ranked_first"), selfcheck.get("share_other_first")
    if not (isinstance(first, int | float) and math.isfinite(first)):
        return "no single-effect trials"
    other = other if isinstance(other, int | float) and math.isfinite(other) else 0.0
    return (f"injected effect ranked first in {100 * first:.0f} % of single-effect trials "
            f"(another effect in {100 * other:.0f} %)")


def added_effects(report: dict) -> list[str]:
    """The names of the effects a report's full selection added, in order."""
    return [e["name"] for e in report.get("effects", []) if e.get("accepted")]


def _jsonable(x: Any) -> Any:
    """Plain JSON values: numpy scalars and arrays converted, NaN and infinities as null."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.bool_ | bool):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating | float):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, Path):
        return str(x)
    return x


def write_json(report: dict, path: str | Path) -> None:
    """Write a report as strict JSON (NaN and infinities as null)."""
    Path(path).write_text(json.dumps(_jsonable(report), indent=1, allow_nan=False) + "\n",
                          encoding="utf-8")


def _holdout_sentence(band: dict) -> str:
    """The bands checked on the seeds themselves, in a sentence (empty where not made)."""
    h = band.get("seed_holdout") or {}
    if not h.get("reports"):
        return ""
    text = (f" Checked on the seeds themselves, each in turn taken as the real log: "
            f"{h['reports_with_any_row_outside']} of {h['reports']} would show a located gap.")
    if note := holdout_warning(band):
        text += f" <b>Warning: {html.escape(note)}.</b>"
    return text


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return "" if v is None else ("yes" if v else "no")
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        return "" if not math.isfinite(float(v)) else f"{float(v):.3g}"
    if isinstance(v, dict):
        return ", ".join(f"{k}={_fmt(x)}" for k, x in v.items())
    if isinstance(v, list | tuple):
        return ", ".join(_fmt(x) for x in v)
    return str(v)


def _table(rows: list[dict], cols: list[str], cls: Callable[[dict], str] | None = None) -> str:
    if not rows:
        return "<p>(none)</p>"
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = []
    for r in rows:
        c = f' class="{cls(r)}"' if cls else ""
        cells = "".join(
            f'<td class="num">{html.escape(_fmt(r.get(k)))}</td>'
            if isinstance(r.get(k), float | int) and not isinstance(r.get(k), bool)
            else f"<td>{html.escape(_fmt(r.get(k)))}</td>" for k in cols)
        body.append(f"<tr{c}>{cells}</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def _figure(fig_id: str, png: bytes, caption: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure class="vgps-figure" id="fig-{html.escape(fig_id)}">'
            f'<img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _page(title: str, body: list[str]) -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>"
            + "\n".join(body) + "</body></html>\n")


def _render(item: tuple[str, tuple]) -> bytes:
    """One figure's PNG: (name of a :mod:`virtualgps.plot` function, its arguments)."""
    from virtualgps import plot

    name, args = item
    return getattr(plot, name)(*args)


def gap_figures(data: GapFigureData, jobs: int | None = 1, dask: str | None = None
                ) -> list[str]:
    """The report's figures as HTML ``<figure>`` elements, drawn on ``jobs`` worker processes
    (or a Dask cluster) side by side: each is independent of the others."""
    from virtualgps.gap.jobs import map_jobs

    items: list[tuple[str, str, tuple]] = []
    for i, run in enumerate(data.runs[:MAX_RUN_FIGURES]):
        items += [
            (f"track-{i}", f"{run.name}: truth, real and simulated fixes (the paper's Fig. 5)",
             ("fig_track", (run,))),
            (f"error-{i}", f"{run.name}: horizontal error over time against the seeds' range, "
             "and the paper's Eq. 4 (Fig. 6)", ("fig_error_time", (run,))),
            (f"satellites-{i}", f"{run.name}: satellites used over time (the paper's Fig. 7)",
             ("fig_satellites", (run,)))]
    real = np.concatenate([r.real_err_h_m for r in data.runs])
    sim = np.concatenate([r.sim_err_h_m for r in data.runs], axis=1)
    items += [
        ("sky", "per-pass tracking disagreement on the sky (red: the real receiver tracks more)",
         ("fig_sky_disagreement", (data.sky_az_deg, data.sky_el_deg, data.sky_disagreement))),
        ("cdf", "horizontal error CDF: real against the seeds' 2.5-97.5 % range",
         ("fig_error_cdf", (real, sim))),
        ("acf", "error autocorrelation: real against the ensemble (longest run)",
         ("fig_autocorrelation", (data.acf_lags_s, data.real_acf, data.sim_acf,
                                  data.final_acf))),
        ("waterfall", "held-out gap through each added effect",
         ("fig_waterfall", (data.waterfall_labels, data.waterfall_gaps)))]
    pngs = map_jobs(_render, [it[2] for it in items], jobs=jobs, dask_address=dask)
    return [_figure(fid, png, caption) for (fid, caption, _), png in zip(items, pngs,
                                                                          strict=True)]


SCORE_EXPLAINED = (
    "How to read the gap score: for each metric, the real value's distance from what the "
    "profile's own seeds produce, in units of their spread (z: 1 is one predictive standard "
    "deviation; a difference within the metric's practical floor counts 0), less 1 and never "
    "below 0, at most 5; the score is the mean over the metrics a unit of data supports. A log "
    "made by the profile itself scores about 0.1; 1 means the metrics lie on average two "
    "spreads off; 3 or more, far outside anything the profile makes.")


def _headline_rows(report: dict) -> list[dict]:
    rows = []
    for h in report.get("headline", []):
        unit = f" {h['unit']}" if h.get("unit") else ""
        rows.append({"": h["label"], "real": f"{_fmt(h['real'])}{unit}",
                     "simulated (median; 95 % band)":
                         f"{_fmt(h['simulated'])}{unit} ({_fmt(h['sim_lo'])}"
                         f"–{_fmt(h['sim_hi'])})",
                     "calibrated": "" if h.get("calibrated") is None
                     else f"{_fmt(h['calibrated'])}{unit}",
                     "gap": "yes" if h.get("outside") else ""})
    return rows


def _cause_rows(report: dict) -> list[dict]:
    rows = []
    for c in report.get("causes", []):
        if c["name"] == "truth_offset":
            what = (f"{c['run']}: truth {c['size_m']:.1f} m off (E {c['east_m']:+.1f}, N "
                    f"{c['north_m']:+.1f} m; p = {c['p_value']:.2g} over {c['blocks']} blocks"
                    + (f", T² taken {c['inflation']:.1f}x smaller as the profile's own slow "
                       "error inflates it" if c.get("inflation", 1.0) > 1.0 else "") + ")"
                    + (": the truth was moved by it before judging" if c["applied"]
                       else ": not significant, left as it is" if c["p_value"] >= cz.OFFSET_P
                       else f": under {cz.OFFSET_MIN_M:g} m, left as it is")
                    + (f"; {c['reference_note']}" if c.get("reference_note") else ""))
        elif c["name"] == "time_offset":
            lo, hi = c["interval_s"]
            what = (f"{c['run']}: the fixes lag the truth by {c['lag_s']:.2f} s"
                    + (f" (95 %: {lo:.2f} to {hi:.2f} s)" if math.isfinite(lo) else "")
                    + f". {c['what']}; here {cz.lag_reading(c)}"
                    + (f". Before that, {cz.clock_note(c)}" if cz.clock_note(c) else ""))
        elif c["name"] in ("constellations", "sky"):
            what = f"{c['run']}: {c['what']}"
        else:
            what = c.get("what", "") + (
                f"; held-out gap {_fmt(c.get('gap_flat_earth'))} with it, "
                f"{_fmt(c.get('gap_exact'))} with the exact conversion"
                + (" (the effects below were chosen with the exact one)" if c.get("applied")
                   else "") if "gap_exact" in c else "")
        rows.append({"cause": c["name"], "what": what})
    return rows


def _tracking_section(report: dict) -> list[str]:
    """Per-satellite tracking disagreement on held-out units, before and after the effects,
    in all and per satellite system (where the runs hold several)."""
    tr = report.get("tracking_disagreement") or {}
    if not math.isfinite(tr.get("baseline", math.nan)):
        return []
    rows = [{"satellites": "all", "before": tr["baseline"], "after": tr.get("final")}]
    rows += [{"satellites": name, "before": v["baseline"], "after": v["final"]}
             for name, v in tr.get("by_system", {}).items()]
    return ["<h2>Which satellites are tracked</h2>",
            "<p>Per satellite, the held-out epochs the real receiver and the simulation track "
            "differently, as a share of the compared satellite-epochs (0: the same satellites "
            "tracked at the same times).</p>",
            _table(rows, ["satellites", "before", "after"])]


def _effect_rows(report: dict) -> list[dict]:
    rows = []
    for e in report.get("effects", []):
        fit = e.get("fit") or {}
        ident = fit.get("identifiable", {})
        intervals, spans = fit.get("intervals", {}), fit.get("spans", {})
        notes = []
        for k, ok in ident.items():
            iv, sp = intervals.get(k), spans.get(k)
            if not ok:
                notes.append(f"{k} not identifiable")
            elif sp:  # (a fit resolves a value only to its grid's points)
                notes.append(f"{k} {_fmt(iv[0])}–{_fmt(iv[1])} on the grid (values "
                             f"{_fmt(sp[0])}–{_fmt(sp[1])} round into it)")
            else:
                notes.append(f"{k} {_fmt(iv)}")
        notes += [f"{k} {v}" for k, v in fit.get("bounds", {}).items()]
        if e.get("tied_with"):
            notes.append("tied with " + ", ".join(e["tied_with"]))
        if e.get("alias"):
            notes.append(e["alias"])
        if e.get("removed"):
            notes.append("added, then taken out: " + e["removed"])
        elif not e.get("accepted") and e.get("accepted_test"):
            notes.append("not added: " + e["accepted_test"])
        params = ", ".join(f"{k}={fx.value_text(v)}" for k, v in (e.get("params") or {}).items())
        rows.append({"effect": e["name"], "added": e.get("accepted"), "params": params,
                     "held-out gap before": e.get("gap_before"),
                     "after": e.get("gap_after"),
                     "chosen in outer groups": e.get("outer_share"),
                     "notes": "; ".join(notes)})
    return rows


def write_html(report: dict, data: GapFigureData, path: str | Path, jobs: int | None = 1,
               dask: str | None = None) -> None:
    """Write the diagnosis as one self-contained HTML page (figures drawn on ``jobs`` worker
    processes or a Dask cluster, see :func:`gap_figures`)."""
    runs = report.get("runs", [])
    names = ", ".join(r["name"] if isinstance(r, dict) else str(r) for r in runs)
    where = report.get("where", [])
    design = report.get("design", {})
    outer = report.get("outer") or {}
    band = report.get("band", {})
    located = [{"metric": g["metric"], "rows": g["rows"],
                "worst segment": g["worst"]["segment"], "real": g["worst"]["real"],
                "band": f"{_fmt(g['worst']['sim_lo'])}–{_fmt(g['worst']['sim_hi'])}",
                "z": g["worst"]["z"], "segments": ", ".join(g["segments"][:12])
                + (" …" if len(g["segments"]) > 12 else "")}
               for g in report.get("located", [])]
    if outer.get("groups"):
        lo, hi = outer.get("interval", [math.nan, math.nan])
        held = (f"On data that neither the choice of effects nor their fit saw ("
                f"{outer['groups']} outer groups: {html.escape(design.get('scheme', ''))}), "
                f"the gap score goes from <b>{_fmt(report.get('gap_baseline'))}</b> with the "
                f"profile under test to <b>{_fmt(report.get('gap_final'))}</b> with the "
                f"effects each group's choice added (reduction {_fmt(outer.get('reduction'))}"
                + (f", 95 % interval {_fmt(lo)} to {_fmt(hi)}" if lo == lo else "") + ").")
    else:
        held = (f"Gap score of the profile under test: <b>{_fmt(report.get('gap_baseline'))}"
                "</b>. No held-out test of effects was possible.")
    # (each its own paragraph under the figure it qualifies: read in a minute, not missed)
    held_notes = "".join(f"<p><b>Note:</b> {html.escape(n[0].upper() + n[1:])}.</p>"
                         for n in outer_notes(outer, added_effects(report)))
    warnings = "".join(f"<p><b>Warning:</b> {html.escape(w)}</p>"
                       for w in design.get("warnings", []))
    warnings += "".join(f"<p><b>Warning:</b> {html.escape(r['name'])}: "
                        f"{html.escape(r['sky_warning'])}</p>"
                        for r in runs if isinstance(r, dict) and r.get("sky_warning"))
    warnings += "".join(f"<p><b>Note:</b> {html.escape(r['name'])}: {html.escape(n)}.</p>"
                        for r in runs if isinstance(r, dict) for n in ingest_notes(r))
    body = [
        f"<h1>virtualgps gap: {html.escape(str(report.get('profile', '')))}</h1>",
        f"<p>Runs: {html.escape(names)}.</p>", warnings,
        "<h2>At a glance (all epochs)</h2>",
        _table(_headline_rows(report), ["", "real", "simulated (median; 95 % band)",
                                        "calibrated", "gap"]),
        f"<p>{held} Calibrated profile: "
        f"{html.escape(str(report.get('calibrated_profile', '')))}.</p>", held_notes,
        f"<p class=\"note\">{html.escape(SCORE_EXPLAINED)}</p>",
        "<h2>Causes that are not receiver effects</h2>",
        _table(_cause_rows(report), ["cause", "what"]),
        "<h2>Effects, ranked by held-out gap</h2>",
        _table(_effect_rows(report), ["effect", "added", "params", "held-out gap before",
                                      "after", "chosen in outer groups", "notes"]),
        *([f"<p><b>An equally good explanation:</b> "
           f"{html.escape(report['alternative']['what'])}.</p>"]
          if report.get("alternative") else []),
        *_tracking_section(report),
        "<h2>Located gaps, by metric</h2>",
        f"<p>A row is a located gap when the real value leaves the band the profile's "
        f"{band.get('seeds', '')} seeds give it: a prediction interval for one more draw "
        f"(finite ensemble), widened by the metric's practical floor, at the level the "
        f"false-discovery rule over all {len(where)} rows sets "
        f"({_fmt(band.get('alpha_row'))} per row, {_fmt(band.get('fdr_q'))} over the report)."
        " Under the null (a log made by the profile under test) at most 5 % of reports show any."
        f"{_holdout_sentence(band)}</p>",
        _table(located, ["metric", "rows", "worst segment", "real", "band", "z", "segments"]),
        "<details><summary>every statistic</summary>",
        _table(where, ["metric", "segment", "same_as", "real", "sim_median", "sim_lo",
                       "sim_hi", "z", "q_value", "outside"],
               lambda r: "outside" if r.get("outside") else ""),
        "</details>",
        "<h2>Figures</h2>", *gap_figures(data, jobs, dask),
        "<h2>Unexplained (outside the band with the calibrated profile)</h2>",
        _table(report.get("unexplained", []), ["metric", "segment", "real", "sim_lo", "sim_hi",
                                               "beyond", "z"]),
        "<h2>Not assessed</h2>",
        _table(report.get("not_assessed", []), ["metric", "reason"]),
        "<h2>Effects not tried</h2>",
        _table([{"effect": k, "why": v} for k, v in report.get("candidates_skipped", {}).items()],
               ["effect", "why"]),
        "<h2>Outer test</h2>",
        _table(outer.get("folds", []), ["heldout", "effects", "params", "gap_before",
                                        "gap_after"]),
        "<h2>Runs as read</h2>",
        _table([r for r in runs if isinstance(r, dict)],
               ["name", "real", "truth", "epochs", "skipped", "time_offset_s", "simulated_in",
                "silent_prns"]),
    ]
    Path(path).write_text(_page("virtualgps gap", body), encoding="utf-8")


def write_selfcheck_html(selfcheck: dict, path: str | Path) -> None:
    """Write the self-check (confusion matrix, null calibration, trials) as one self-contained
    HTML page."""
    from virtualgps import plot

    conf = selfcheck.get("confusion", {})
    names = list(conf)
    firsts = sorted({f for row in conf.values() for f in row} | {
        n for n in names if "+" not in n and not n.startswith(("nothing", "real:"))})
    counts = [[conf[n].get(f, 0) for f in firsts] for n in names]
    rows = [{"injected": n, **{f: conf[n].get(f, 0) for f in firsts}} for n in names]
    cal = selfcheck.get("null_calibration", {})
    summary = [{"label": k, **v} for k, v in selfcheck.get("summary", {}).items()]
    body = [
        "<h1>virtualgps gap --selfcheck</h1>",
        f"<p>{len(selfcheck.get('trials', []))} trials, right in "
        f"{_fmt(100 * (selfcheck.get('share_success') or 0.0))} %: "
        f"{single_effect_share(selfcheck)}; a null trial (a "
        "log made by the profile under test) is right when nothing is added; a pair when both "
        "effects are the first added.</p>",
        f"<p>Under the null: {cal.get('reports_with_any_row_outside', 0)} of "
        f"{cal.get('reports', 0)} reports show any located gap "
        f"({cal.get('rows_outside', 0)} of {cal.get('rows', 0)} rows; nominal: "
        f"{html.escape(str(cal.get('nominal', '')))}); {cal.get('effects_added', 0)} added an "
        "effect.</p>",
        *([f"<p>Every trial's seeds, each in turn taken as the real log against the others: "
           f"{held['reports_with_any_row_outside']} of {held['reports']} such reports show a "
           f"located gap ({held['rows_outside']} of {held['rows']} rows).</p>"]
          if (held := cal.get("seed_holdout") or {}).get("reports") else []),
        *([f"<p>The outer test (its reduction's 95 % interval above 0) confirmed what was "
           f"added in {oc['right']['confirmed']} of {oc['right']['trials']} right trials and "
           f"{oc['wrong']['confirmed']} of {oc['wrong']['trials']} wrong ones (trials that "
           "added an effect it can judge).</p>"]
          if (oc := selfcheck.get("outer_confirmation")) else []),
        _figure("confusion", plot.fig_confusion(names, firsts, counts),
                "confusion matrix: injected x ranked first ('nothing': no effect added)")
        if names else "",
        "<h2>Per trial kind</h2>",
        _table(summary, ["label", "kind", "trials", "success", "share", "parameters_covered"]),
        "<h2>Confusion matrix</h2>", _table(rows, ["injected", *firsts]),
        "<h2>Trials</h2>",
        _table(selfcheck.get("trials", []), ["injected", "scenario", "params", "ranked_first",
                                             "accepted", "recovered", "recovered_interval",
                                             "covered", "gap_before", "gap_after",
                                             "outer_confirmed", "outer_not_judged",
                                             "where_outside"]),
    ]
    if selfcheck.get("real_bases_note"):
        body.append(f"<p>{html.escape(selfcheck['real_bases_note'])}</p>")
    Path(path).write_text(_page("virtualgps gap self-check", body), encoding="utf-8")
