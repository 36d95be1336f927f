"""Delays and filters beyond the self-check's: what ``virtualgps gap`` makes of a pure output
delay or a first-order filter of a size and on a log the self-check does not draw.

    python tools/lag_checks.py [--data ../shared/data] [--seeds 50] [--jobs 2] [--work DIR] \\
        gsdc:latency:0.7 gsdc:nav_filter:1.0 rate10:nothing rate10:latency:1 ...

``gsdc:EFFECT:VALUE`` injects the effect into the GSDC Pixel 4 drive's fixes as the
self-check's real-log bases do (:func:`virtualgps.gap.selfcheck_real.inject`: ``latency``
seconds, ``nav_filter`` tau seconds) and diagnoses it against ``holux-m1000`` with the SPAN
truth. ``rate10:...`` is a 20-minute, 10 Hz drive (a 400 m x 200 m loop at 10 m/s near the
bundled scene's origin, open sky, 2017-03-26) that ``ublox-m8n`` itself logs at 10 Hz:
``rate10:nothing`` as it is, ``rate10:latency:L`` with its poses L seconds late (every fix
where the antenna was L seconds before), ``rate10:nav_filter:TAU`` with the profile's
first-order ``nav_filter`` of TAU seconds; each is diagnosed against ``ublox-m8n``. One line
per case: the effects added with their intervals, the equally good explanation where there is
one, the lag the causes measured and the outer test's held-out gaps.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from virtualgps.device.nmea import read_text_lines
from virtualgps.gap import diagnose as dg
from virtualgps.gap import effects as fx
from virtualgps.gap import selfcheck_real as sr
from virtualgps.gap import tool
from virtualgps.gap.ingest import read_real_log
from virtualgps.receiver.profiles import load_profile_dict

ROOT = Path(__file__).resolve().parents[1]
T0_UNIX_S = 1490500000.0  # 2017-03-26 03:46:40 UTC, inside the bundled TLE sets
LAT0_DEG, LON0_DEG = 52.1400665, 11.643243  # the bundled scene's origin


def gsdc_case(data: Path, effect: str, value: float, work: Path) -> tuple[tool.GapInputs, str]:
    """The GSDC drive with ``effect`` at ``value`` injected into its fixes."""
    d = data / sr.GSDC
    real = d / "Pixel4_chipset.nmea"
    ep, *_ = read_real_log(real)
    fix = (ep.quality > 0) & np.isfinite(ep.lat_deg)
    t, lat, lon = ep.t_unix_s[fix], ep.lat_deg[fix], ep.lon_deg[fix]
    new_lat, new_lon = sr.inject(effect, value, t, lat, lon, np.nan_to_num(ep.speed_mps[fix]))
    path = work / f"gsdc-{effect}-{value:g}.nmea"
    path.write_text("\n".join(sr.rewrite_fixes(read_text_lines(real), t, new_lat, new_lon))
                    + "\n")
    return tool.GapInputs(real=(str(path),), truth=(str(d / "SPAN_Pixel4_1Hz.nmea"),),
                          scene="none", tle=str(d / "gps-ops_2020-05-14T22Z.tle"),
                          profile=sr.BASE_PROFILE), "holux-m1000"


def _loop_truth(path: Path, late_s: float = 0.0) -> None:
    """The 10 Hz loop's poses as CSV (``late_s``: every time that much later)."""
    dt, speed, a, b = 0.1, 10.0, 400.0, 200.0
    t = np.arange(int(1200.0 / dt)) * dt
    p = (speed * t) % (2 * (a + b))
    x = np.select([p < a, p < a + b, p < 2 * a + b], [p, a, 2 * a + b - p], 0.0)
    y = np.select([p < a, p < a + b, p < 2 * a + b], [0.0, p - a, b], 2 * (a + b) - p)
    lat = LAT0_DEG + y / 111320.0
    lon = LON0_DEG + x / (111320.0 * np.cos(np.radians(LAT0_DEG)))
    path.write_text("t,lat,lon,alt\n" + "".join(
        f"{T0_UNIX_S + late_s + ti:.2f},{la:.9f},{lo:.9f},100.0\n"
        for ti, la, lo in zip(t, lat, lon, strict=True)))


def rate10_case(effect: str, value: float, work: Path) -> tuple[tool.GapInputs, str]:
    """The 10 Hz loop logged by ``ublox-m8n`` (late, or filtered)."""
    from virtualgps.cli import main as cli

    truth = work / "rate10-truth.csv"
    _loop_truth(truth)
    poses, profile = truth, "ublox-m8n"
    if effect == "latency":
        poses = work / f"rate10-late-{value:g}.csv"
        _loop_truth(poses, value)
    elif effect == "nav_filter":
        table, _ = load_profile_dict("ublox-m8n")
        table["nav_filter"] = {"enabled": True, "tau_s": value}
        profile = str(work / f"rate10-filter-{value:g}.toml")
        Path(profile).write_text(fx.to_toml(table))
    elif effect != "nothing":
        raise ValueError(effect)
    real = work / f"rate10-{effect}-{value:g}.nmea"
    rc = cli(["replay", str(poses), "--scene", "none", "--profile", profile, "--rate", "10",
              "--seed", "7", "--out", str(real)])
    if rc:
        raise SystemExit(f"replay failed ({rc})")
    return tool.GapInputs(real=(str(real),), truth=(str(truth),), scene="none", tle=None,
                          profile="ublox-m8n"), "ublox-m8n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="+", help="gsdc:EFFECT:VALUE or rate10:EFFECT[:VALUE]")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--work", default="lag-checks", help="where the logs are written")
    args = ap.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    for spec in args.cases:
        base, effect, *value = spec.split(":")
        v = float(value[0]) if value else 0.0
        inp, _ = (gsdc_case(Path(args.data), effect, v, work) if base == "gsdc"
                  else rate10_case(effect, v, work))
        report = tool.diagnose(inp, dg.Options(seeds=args.seeds, jobs=args.jobs))[0]
        added = [f"{e['name']} {e['params']} {(e.get('fit') or {}).get('intervals')}"
                 for e in report["effects"] if e.get("accepted")]
        alt = report.get("alternative")
        lag = [round(c["lag_s"], 2) for c in report["causes"] if c["name"] == "time_offset"]
        print(f"{spec}: added {added or 'nothing'}; alternative "
              f"{alt['effects'] if alt else None}"
              + (f" ({alt['gap_after']:.3f} against {alt['chosen_gap_after']:.3f})"
                 if alt else "")
              + f"; lag {lag}; outer test {report['gap_baseline']:.3f} -> "
              f"{report['gap_final']:.3f}", flush=True)


if __name__ == "__main__":
    main()
