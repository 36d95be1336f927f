"""Print the "real" column of the holux-m1000 calibration table from the real MTK logs.

Usage: ``python tools/real_stats.py [SHARED_DATA_DIR] [--json]`` (default ``../shared/data``
beside the clone). Statistics come from :func:`mtk_logs.real_calibration_stats`
(the same function the calibration script and ``tests/test_metrics.py`` use): the MT3339 static
hour (mt3339-static/hour_test_1.txt) for error statistics, C/N0 and start-up; the Holux M-241
car track (mtk-logger/mtk_logger_m241.csv) for satellites and HDOP while moving. The last
column repeats the facts SOURCES.md states for the MT3339 hour.

How the statistics are defined (see virtualgps/gap/metrics.py):
- errors are ENU metres about the component-wise median of the fixed positions (no survey);
- CEP50 / R95: median / 95th percentile of the horizontal error; 1-sigma: standard deviation
  per axis about the mean;
- autocorrelation time: first lag where the normalised autocorrelation falls below 1/e, per
  axis mean removed, epochs placed on the 1 s grid (the 5 min output gap left out pair by
  pair); "h" pools E and N. Removing a linear trend instead of the mean roughly halves it
  (printed below): the error holds a slow drift over the hour, and a finite record biases any
  such estimate low by about 2 tau / T;
- satellites, HDOP, C/N0: over the epochs with a fix; C/N0 over all satellite-epochs with an
  SNR in GSV; "in view" is GSV's count, which on the MT3339 includes SBAS PRNs (33-51) and
  channels still searching (``34,,,``); "GPS in view" counts PRN 1-32 listed with an elevation,
  which is what the simulator lists;
- first fix: from the first epoch the log holds (the receiver was on a little earlier).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from mtk_logs import (
    MT3339_SOURCES_AUTOCORR_RANGE_S,
    MT3339_SOURCES_FACTS,
    MT3339_STATIC_LOG,
    real_calibration_stats,
)

from virtualgps.device.nmea import read_nmea_epochs
from virtualgps.gap.metrics import summary

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _fmt(x: float, digits: int = 1) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def table(stats: dict[str, dict[str, float]], detrended_h_s: float) -> list[str]:
    """Rows of the real column as Markdown table lines (statistic, MT3339, M-241, SOURCES.md)."""
    mt, mv = stats["mt3339_static"], stats["m241_moving"]
    f = MT3339_SOURCES_FACTS
    lo, hi = MT3339_SOURCES_AUTOCORR_RANGE_S
    rows = [
        ("CEP50 (m)", _fmt(mt["cep50_m"]), "-", _fmt(f["cep50_m"])),
        ("R95 (m)", _fmt(mt["r95_m"]), "-", _fmt(f["r95_m"])),
        (
            "1-sigma E/N/U (m)",
            "/".join(_fmt(mt[f"sigma_{a}_m"]) for a in "enu"),
            "-",
            "/".join(_fmt(f[f"sigma_{a}_m"]) for a in "enu"),
        ),
        (
            "error autocorrelation 1/e, h (E/N/U) (s)",
            f"{_fmt(mt['autocorr_h_s'], 0)} "
            f"({'/'.join(_fmt(mt[f'autocorr_{a}_s'], 0) for a in 'enu')})",
            "-",
            f"{lo:.0f}-{hi:.0f}",
        ),
        ("  same, linear trend removed, h (s)", _fmt(detrended_h_s, 0), "-", "-"),
        (
            "satellites used, median (range)",
            f"{_fmt(mt['sats_used_median'], 0)} ({_fmt(mt['sats_used_min'], 0)}-"
            f"{_fmt(mt['sats_used_max'], 0)})",
            f"{_fmt(mv['sats_used_median'], 0)} ({_fmt(mv['sats_used_min'], 0)}-"
            f"{_fmt(mv['sats_used_max'], 0)})",
            f"{f['sats_used_median']:.0f} ({f['sats_used_min']:.0f}-{f['sats_used_max']:.0f})",
        ),
        (
            "satellites used, mean; changes per min",
            f"{_fmt(mt['sats_used_mean'], 2)}; {_fmt(mt['sats_used_changes_per_min'], 1)}",
            f"{_fmt(mv['sats_used_mean'], 2)}; {_fmt(mv['sats_used_changes_per_min'], 1)}",
            "-",
        ),
        (
            "satellites in view (GSV count), median (range)",
            f"{_fmt(mt['sats_in_view_median'], 0)} ({_fmt(mt['sats_in_view_min'], 0)}-"
            f"{_fmt(mt['sats_in_view_max'], 0)})",
            f"{_fmt(mv['sats_in_view_median'], 0)} ({_fmt(mv['sats_in_view_min'], 0)}-"
            f"{_fmt(mv['sats_in_view_max'], 0)})",
            f"~{f['sats_in_view_median']:.0f}",
        ),
        (
            "GPS satellites in view (PRN 1-32 with el.), median (range)",
            f"{_fmt(mt['sats_in_view_gps_median'], 0)} ({_fmt(mt['sats_in_view_gps_min'], 0)}-"
            f"{_fmt(mt['sats_in_view_gps_max'], 0)})",
            "-",
            "-",
        ),
        (
            "HDOP median (5-95 %)",
            f"{_fmt(mt['hdop_median'], 2)} ({_fmt(mt['hdop_p05'], 2)}-{_fmt(mt['hdop_p95'], 2)})",
            f"{_fmt(mv['hdop_median'], 2)} ({_fmt(mv['hdop_p05'], 2)}-{_fmt(mv['hdop_p95'], 2)})",
            _fmt(f["hdop_median"], 2),
        ),
        (
            "C/N0 median (25-75 %) (dB-Hz)",
            f"{_fmt(mt['cn0_median_dbhz'], 0)} ({_fmt(mt['cn0_p25_dbhz'], 0)}-"
            f"{_fmt(mt['cn0_p75_dbhz'], 0)})",
            "-",
            _fmt(f["cn0_median_dbhz"], 0),
        ),
        ("fix fraction", _fmt(mt["fix_fraction"], 3), _fmt(mv["fix_fraction"], 3), "-"),
        ("first fix (s)", _fmt(mt["ttff_s"], 1), "-", f"~{f['ttff_s']:.0f}"),
    ]
    head = [
        "| statistic | MT3339 static hour | M-241 moving | SOURCES.md (MT3339) |",
        "|---|---|---|---|",
    ]
    return head + [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", type=Path, default=DEFAULT_DATA, help="../shared/data")
    ap.add_argument("--json", action="store_true", help="print all statistics as JSON")
    args = ap.parse_args()
    stats = real_calibration_stats(args.data)
    detrended = summary(read_nmea_epochs(args.data / MT3339_STATIC_LOG), "median", "linear")
    if args.json:
        stats["mt3339_static_linear_detrend"] = detrended
        print(json.dumps(stats, indent=1, allow_nan=True))
        return
    print("\n".join(table(stats, detrended["autocorr_h_s"])))
    mt = stats["mt3339_static"]
    print(
        f"\nMT3339: {mt['n_epochs']:.0f} epochs over {mt['duration_s']:.0f} s, "
        f"{mt['n_fixed']:.0f} fixed, {mt['n_bad_lines']:.0f} corrupt line(s) skipped; "
        f"M-241 moving: {stats['m241_moving']['n_epochs']:.0f} of "
        f"{stats['m241_all']['n_epochs']:.0f} records (speed >= 2 m/s)."
    )


if __name__ == "__main__":
    main()
