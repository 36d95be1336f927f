"""The self-check table of docs/gap.md from a ``selfcheck.json`` (``virtualgps gap --selfcheck``).

    python tools/selfcheck_table.py sc/selfcheck.json

Per trial label (an injected effect, a pair, a null trial, a real-log base): how often the diagnosis
was right, what it ranked first where it was wrong (``nothing``: no effect added), the main
parameter injected against recovered (medians, the median absolute error, and how often the
recovered interval held the injected value), and the median outer-test shrinkage of the gap (1 -
gap_after / gap_before; and in how many trials an added effect showed in data the outer test
could not hold out from its choice, ``outer_not_judged``); how often the outer test confirmed
what was added, for right and wrong trials; then the band's calibration under the null.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

from virtualgps.gap.selfcheck import summary_lines

# The parameter shown per effect (the one its signature pins down), with its unit.
MAIN_PARAM = {
    "correlated_error": ("tau_s", "s"), "cold_start": ("ttff_cold_s", "s"),
    "cn0_tracking": ("cn0_zenith_dbhz", "dB-Hz"), "nlos": ("reflection_loss_db", "dB"),
    "multipath": ("sigma_m", "m"), "latency": ("latency_s", "s"), "nav_filter": ("tau_s", "s"),
    "static_hold": ("threshold_mps", "m/s"), "elevation_mask": ("elevation_mask_deg", "°"),
    "noise_level": ("scale", "× usarsim's noise"), "dop_error": ("scale", "× the UERE budget"),
}


def _blocked_bins(params: dict) -> set[tuple[int, int]]:
    """(row, column) of the blocked bins of a sky mask (JSON writes inf as null)."""
    rows = params.get("atten_db") or []
    return {(i, j) for i, row in enumerate(rows) for j, v in enumerate(row)
            if v is None or v >= 100.0}


def _param_cell(effect: str, trials: list[dict]) -> str:
    if effect == "sky_mask":
        hit = total = 0
        for t in trials:
            learned, injected = _blocked_bins(t["recovered"]), _blocked_bins(t["params"])
            hit += len(learned & injected)
            total += len(learned)
        return f"{hit} of the {total} learned bins lie in the blocked sector"
    if effect == "truth_offset":
        pairs = [(np.hypot(t["params"]["east_m"], t["params"]["north_m"]),
                  np.hypot(t["recovered"]["east_m"], t["recovered"]["north_m"]))
                 for t in trials if t.get("recovered")]
        if not pairs:
            return "offset not named"
        inj, rec = np.array(pairs).T
        return f"offset {np.median(inj):.3g} → {np.median(rec):.3g} m"
    if effect not in MAIN_PARAM:
        return "(on/off)"
    key, unit = MAIN_PARAM[effect]
    pairs = [(t["params"][key], t["recovered"][key]) for t in trials
             if key in t["params"] and key in t.get("recovered", {})]
    if not pairs:
        return f"`{key}`: not recovered"
    inj, rec = np.array(pairs, dtype=float).T
    cov = [t["covered"][key] for t in trials if key in t.get("covered", {})]
    return (f"`{key}` {np.median(inj):.4g} → {np.median(rec):.4g} {unit} "
            f"(median error {np.median(np.abs(rec - inj)):.2g}; interval holds it "
            f"{sum(cov)}/{len(cov)})")


def _change(fraction: float) -> str:
    """A relative change as a signed percentage: −92 %, +5 %, 0 % (no "−-0 %")."""
    pct = round(100 * fraction)
    return f"−{-pct} %" if pct < 0 else f"+{pct} %" if pct > 0 else "0 %"


def table(result: dict) -> str:
    """The markdown table of one self-check result."""
    out = ["| trials | right | ranked first where wrong | parameter: injected → recovered, "
           "median | outer-test gap, median shrink |",
           "|---|---|---|---|---|"]
    for label, s in result["summary"].items():
        trials = [t for t in result["trials"] if t["injected"] == label]
        wrong = Counter(t["ranked_first"] for t in trials if not t["success"])
        instead = ", ".join(f"`{k}` {v}" for k, v in sorted(wrong.items())) or "—"
        shrink = [1.0 - t["gap_after"] / t["gap_before"] for t in trials
                  if t["gap_before"] and t["gap_after"] is not None and t["gap_before"] > 0]
        effect = trials[0]["effects"][0] if trials[0]["effects"] else None
        cell = _param_cell(effect, trials) if effect and s["kind"] != "pair" else "—"
        blind = sum(bool(t.get("outer_not_judged")) for t in trials)
        out.append(f"| `{label}` | {s['success']}/{s['trials']} | {instead} | {cell} | "
                   + (_change(-float(np.median(shrink))) if shrink else "—")
                   + (f" (an added effect not judgeable in {blind}/{len(trials)})" if blind
                      else "") + " |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("selfcheck_json", type=Path)
    args = ap.parse_args()
    result = json.loads(args.selfcheck_json.read_text(encoding="utf-8"))
    cal = result["null_calibration"]
    lines = summary_lines(result)
    print(lines[0].removeprefix("self-check: "))
    print("".join(x.strip() + "\n" for x in lines if x.startswith("  outer test confirms")),
          end="")
    if cal["reports"]:
        lo, hi = cal["report_share_interval"]
        print(f"null: {cal['reports_with_any_row_outside']}/{cal['reports']} reports with any "
              f"row outside (95 %: {100 * lo:.0f}-{100 * hi:.0f} %), {cal['rows_outside']}/"
              f"{cal['rows']} rows; {cal['effects_added']} with an effect added\n")
    print(table(result))


if __name__ == "__main__":
    main()
