"""The gap report renders in a real browser (headless Chromium): every figure decodes, nothing
is fetched from outside the file."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from virtualgps.gap import report as rp

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
PROBE = """<script>window.addEventListener('load', () => {
  const imgs = [...document.querySelectorAll('figure.vgps-figure img')];
  document.body.setAttribute('data-widths', JSON.stringify(imgs.map(i => i.naturalWidth)));
});</script></body>"""


def _run(n_t: int, s: int, rng: np.random.Generator, fixes: bool = True) -> rp.RunFigureData:
    t = 1.6e9 + np.arange(n_t, dtype=float)
    lat = 52.14 + np.cumsum(rng.normal(0, 1e-6, n_t))
    lon = 11.64 + np.cumsum(rng.normal(0, 1e-6, n_t))
    real_lat = lat + rng.normal(0, 3e-5, n_t) if fixes else np.full(n_t, np.nan)
    sim_lat = lat + rng.normal(0, 3e-5, (s, n_t))
    err = np.abs(rng.normal(3, 1, (s, n_t)))
    return rp.RunFigureData(
        name="run" if fixes else "no-fix", t_unix_s=t, truth_lat_deg=lat, truth_lon_deg=lon,
        real_lat_deg=real_lat, real_lon_deg=lon.copy(), sim_lat_deg=sim_lat,
        sim_lon_deg=np.tile(lon, (s, 1)),
        real_err_h_m=np.abs(rng.normal(4, 2, n_t)) if fixes else np.full(n_t, np.nan),
        sim_err_h_m=err, real_sats_used=np.full(n_t, 8.0) if fixes else np.full(n_t, np.nan),
        sim_sats_used=rng.integers(6, 10, (s, n_t)).astype(float),
        eq4_deg=np.abs(real_lat - sim_lat), final_lat_deg=sim_lat,
        final_lon_deg=np.tile(lon, (s, 1)), final_err_h_m=err * 1.2,
        final_sats_used=np.full((s, n_t), 8.0))


def _rendered_widths(page: Path, tmp_path: Path) -> list[int]:
    if CHROMIUM is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is missing (tools/test.sh installs Debian's chromium)")
        pytest.skip("chromium not installed")
    probe = tmp_path / f"probe-{page.name}"
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", PROBE),
                     encoding="utf-8")
    out = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'chromium'}",
                          "--virtual-time-budget=10000", "--dump-dom", probe.as_uri()],
                         capture_output=True, text=True, timeout=120)
    m = re.search(r'data-widths="([^"]*)"', out.stdout)
    assert m, f"chromium rendered nothing: {out.stderr[-2000:]}"
    return json.loads(m.group(1).replace("&quot;", '"'))


def test_gap_report_renders_every_figure(tmp_path):
    rng = np.random.default_rng(0)
    runs = (_run(400, 5, rng), _run(300, 5, rng, fixes=False))
    data = rp.GapFigureData(
        runs=runs, sky_az_deg=rng.uniform(0, 360, 40), sky_el_deg=rng.uniform(5, 90, 40),
        sky_disagreement=rng.uniform(-1, 1, 40), acf_lags_s=np.arange(61.0),
        real_acf=np.exp(-np.arange(61.0) / 20), sim_acf=np.exp(-np.arange(61.0) / 15)[None]
        * rng.uniform(0.9, 1.1, (5, 1)), waterfall_labels=("baseline", "+nlos", "+latency"),
        waterfall_gaps=(1.2, 0.8, 0.7))
    report = {"runs": [{"name": "run", "epochs": 400}], "profile": "usarsim", "heldout": ["run"],
              "gap_baseline": 1.2, "gap_final": 0.7, "calibrated_profile": "calibrated.toml",
              "where": [{"metric": "cep50_m", "segment": "all", "real": 4.0, "sim_lo": 1.0,
                         "sim_hi": 2.0, "outside": True, "distance": 1.0}],
              "effects": [{"name": "nlos", "params": {"scattering": True}, "gap_before": 1.2,
                           "gap_after": 0.8, "heldout": "run", "accepted": True}],
              "not_assessed": [{"metric": "bias_m", "reason": "static <unknown> point"}],
              "unexplained": [], "nan": float("nan")}
    page = tmp_path / "report.html"
    rp.write_html(report, data, page)
    rp.write_json(report, tmp_path / "report.json")
    assert json.loads((tmp_path / "report.json").read_text())["nan"] is None
    text = page.read_text(encoding="utf-8")
    assert not re.search(r'(src|href)="(?!data:)', text)  # self-contained
    assert "static &lt;unknown&gt; point" in text  # escaped
    widths = _rendered_widths(page, tmp_path)
    # track, error and satellites per run, then skyplot, CDF, autocorrelation, waterfall
    assert len(widths) == 3 * len(runs) + 4
    assert all(w > 100 for w in widths), widths


def test_selfcheck_report_renders(tmp_path):
    sc = {"trials": [{"injected": "latency", "scenario": "moving_open", "params": {"latency_s":
                      1.0}, "ranked": ["latency"], "ranked_first": "latency",
                      "recovered": {"latency_s": 1.0}, "gap_before": 0.5, "gap_after": 0.2}],
          "confusion": {"latency": {"latency": 1}}, "share_ranked_first": 1.0,
          "share_other_first": 0.0}
    page = tmp_path / "report.html"
    rp.write_selfcheck_html(sc, page)
    widths = _rendered_widths(page, tmp_path)
    assert len(widths) == 1 and widths[0] > 100
