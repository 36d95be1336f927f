"""The gap tool's reports: ``report.json`` (DESIGN section 7's contract) and a self-contained
``report.html`` with the figures inline (PNG data URIs, inline CSS, no script, no external
resource), for the diagnosis and for the self-check.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np


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
"""


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


def gap_figures(data: GapFigureData) -> list[str]:
    """The report's figures as HTML ``<figure>`` elements."""
    from virtualgps import plot

    out = []
    for i, run in enumerate(data.runs[:MAX_RUN_FIGURES]):
        out.append(_figure(f"track-{i}", plot.fig_track(run),
                           f"{run.name}: truth, real and simulated fixes (the paper's Fig. 5)"))
        out.append(_figure(f"error-{i}", plot.fig_error_time(run),
                           f"{run.name}: horizontal error over time against the ensemble band, "
                           "and the paper's Eq. 4 (Fig. 6)"))
        out.append(_figure(f"satellites-{i}", plot.fig_satellites(run),
                           f"{run.name}: satellites used over time (the paper's Fig. 7)"))
    out.append(_figure("sky", plot.fig_sky_disagreement(
        data.sky_az_deg, data.sky_el_deg, data.sky_disagreement),
        "per-pass tracking disagreement on the sky (red: the real receiver tracks more)"))
    real = np.concatenate([r.real_err_h_m for r in data.runs])
    sim = np.concatenate([r.sim_err_h_m for r in data.runs], axis=1)
    out.append(_figure("cdf", plot.fig_error_cdf(real, sim),
                       "horizontal error CDF: real against the ensemble's 2.5-97.5 % band"))
    out.append(_figure("acf", plot.fig_autocorrelation(
        data.acf_lags_s, data.real_acf, data.sim_acf, data.final_acf),
        "error autocorrelation: real against the ensemble (longest run)"))
    out.append(_figure("waterfall", plot.fig_waterfall(data.waterfall_labels,
                                                       data.waterfall_gaps),
                       "held-out gap through each added effect"))
    return out


def write_html(report: dict, data: GapFigureData, path: str | Path) -> None:
    """Write the diagnosis as one self-contained HTML page."""
    runs = report.get("runs", [])
    names = ", ".join(r["name"] if isinstance(r, dict) else str(r) for r in runs)
    where = report.get("where", [])
    outside = sorted((w for w in where if w.get("outside")),
                     key=lambda w: -(w.get("distance") or 0.0))
    effects = report.get("effects", [])
    body = [
        f"<h1>virtualgps gap: {html.escape(str(report.get('profile', '')))}</h1>",
        f"<p>Runs: {html.escape(names)}. Held out: "
        f"{html.escape('; '.join(report.get('heldout', [])))}.</p>",
        f"<p>Gap score (held out, lower is better): baseline "
        f"<b>{_fmt(report.get('gap_baseline'))}</b>, with the added effects "
        f"<b>{_fmt(report.get('gap_final'))}</b>. Calibrated profile: "
        f"{html.escape(str(report.get('calibrated_profile', '')))}.</p>",
        "<h2>Figures</h2>", *gap_figures(data),
        "<h2>Effects, ranked by held-out gap</h2>",
        _table([{**e, "params": e.get("params", {})} for e in effects],
               ["name", "accepted", "params", "gap_before", "gap_after", "contribution",
                "heldout_scheme"]),
        "<h2>Located gaps (real outside the ensemble's 2.5-97.5 % band)</h2>",
        _table(outside, ["metric", "segment", "real", "sim_lo", "sim_hi", "distance"]),
        "<details><summary>every statistic</summary>",
        _table(where, ["metric", "segment", "real", "sim_lo", "sim_hi", "outside"],
               lambda r: "outside" if r.get("outside") else ""),
        "</details>",
        "<h2>Unexplained (outside the band with the calibrated profile)</h2>",
        _table(report.get("unexplained", []), ["metric", "segment", "real", "sim_lo", "sim_hi"]),
        "<h2>Not assessed</h2>",
        _table(report.get("not_assessed", []), ["metric", "reason"]),
        "<h2>Runs as read</h2>",
        _table([r for r in runs if isinstance(r, dict)],
               ["name", "real", "truth", "epochs", "skipped", "time_offset_s", "simulated_in",
                "silent_prns"]),
    ]
    Path(path).write_text(_page("virtualgps gap", body), encoding="utf-8")


def write_selfcheck_html(selfcheck: dict, path: str | Path) -> None:
    """Write the self-check (confusion matrix, trials) as one self-contained HTML page."""
    from virtualgps import plot

    conf = selfcheck.get("confusion", {})
    names = list(conf)
    firsts = sorted({f for row in conf.values() for f in row} | set(names))
    counts = [[conf[n].get(f, 0) for f in firsts] for n in names]
    rows = [{"injected": n, **{f: conf[n].get(f, 0) for f in firsts}} for n in names]
    body = [
        "<h1>virtualgps gap --selfcheck</h1>",
        f"<p>{len(selfcheck.get('trials', []))} trials: injected effect ranked first in "
        f"{_fmt(100 * (selfcheck.get('share_ranked_first') or 0.0))} %, another effect in "
        f"{_fmt(100 * (selfcheck.get('share_other_first') or 0.0))} %; added first in "
        f"{_fmt(100 * (selfcheck.get('share_added_first') or 0.0))} %, another effect in "
        f"{_fmt(100 * (selfcheck.get('share_other_added_first') or 0.0))} %.</p>",
        _figure("confusion", plot.fig_confusion(names, firsts, counts),
                "confusion matrix: injected effect x effect ranked first") if names else "",
        "<h2>Confusion matrix</h2>", _table(rows, ["injected", *firsts]),
        "<h2>Trials</h2>",
        _table(selfcheck.get("trials", []), ["injected", "scenario", "params", "ranked_first",
                                             "added_first", "recovered", "gap_before",
                                             "gap_after"]),
    ]
    Path(path).write_text(_page("virtualgps gap self-check", body), encoding="utf-8")
