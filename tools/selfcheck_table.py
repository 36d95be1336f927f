"""The README's self-check table from a ``selfcheck.json`` (``virtualgps gap --selfcheck``).

    python tools/selfcheck_table.py sc/selfcheck.json

Per injected effect: how often it was ranked first and added first, what was ranked first
instead, its main parameter injected against recovered (medians, and the median absolute
error), and the median held-out shrinkage of the gap (1 - gap_after / gap_before).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

# The parameter shown per effect (the one its signature pins down), with its unit.
MAIN_PARAM = {
    "correlated_error": ("tau_s", "s"), "cold_start": ("ttff_cold_s", "s"),
    "cn0_tracking": ("cn0_zenith_dbhz", "dB-Hz"), "nlos": ("reflection_loss_db", "dB"),
    "multipath": ("sigma_m", "m"), "latency": ("latency_s", "s"), "nav_filter": ("tau_s", "s"),
    "static_hold": ("threshold_mps", "m/s"), "elevation_mask": ("elevation_mask_deg", "°"),
    "noise_level": ("max_noise_m", "m"),
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
    if effect not in MAIN_PARAM:
        return "(on/off)"
    key, unit = MAIN_PARAM[effect]
    pairs = [(t["params"][key], t["recovered"][key]) for t in trials
             if key in t["params"] and key in t.get("recovered", {})]
    if not pairs:
        return f"`{key}`: not recovered"
    inj, rec = np.array(pairs, dtype=float).T
    return (f"`{key}` {np.median(inj):.4g} → {np.median(rec):.4g} {unit} "
            f"(median error {np.median(np.abs(rec - inj)):.2g})")


def table(result: dict) -> str:
    """The markdown table of one self-check result."""
    out = ["| injected | ranked first | added first | ranked first instead | parameter: "
           "injected → recovered, median | held-out gap, median shrink |",
           "|---|---|---|---|---|---|"]
    for effect, s in result["summary"].items():
        trials = [t for t in result["trials"] if t["injected"] == effect]
        others = {k: v for k, v in result["confusion"][effect].items() if k != effect}
        instead = ", ".join(f"`{k}` {v}" for k, v in sorted(others.items())) or "—"
        shrink = np.median([1.0 - t["gap_after"] / t["gap_before"] for t in trials
                            if t["gap_before"] > 0])
        out.append(f"| `{effect}` | {s['ranked_first']}/{s['trials']} | "
                   f"{s['added_first']}/{s['trials']} | {instead} | "
                   f"{_param_cell(effect, trials)} | −{100 * shrink:.0f} % |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("selfcheck_json", type=Path)
    args = ap.parse_args()
    result = json.loads(args.selfcheck_json.read_text(encoding="utf-8"))
    n = len(result["trials"])
    print(f"{n} trials: ranked first {100 * result['share_ranked_first']:.0f} % (another "
          f"effect {100 * result['share_other_first']:.0f} %), added first "
          f"{100 * result['share_added_first']:.0f} % (another effect "
          f"{100 * result['share_other_added_first']:.0f} %)\n")
    print(table(result))


if __name__ == "__main__":
    main()
