"""Calibrate a phone profile with ``virtualgps gap`` on each shared phone data set, test each fit
on the other, which it never saw, and make one profile of both.

    python tools/calibrate_phone.py [--data ../shared/data] [--seeds 30] [--out phone-cal]
    python tools/calibrate_phone.py --test phone my-phone.toml   # profiles as they stand

The data: the GSDC 2020-05-14 drive (a Pixel 4's chipset fixes, GGA+RMC without GSV, SPAN
truth; its sky GPS alone, no other system's set of that day being at hand) and the Magdeburg
phone's 14 static waypoint logs (2017-03-28, an Android phone, GPS + GLONASS GSV/GSA; truth:
the map markers, as ``tools/gap_cases.py``; the campus scene; that day's GPS and GLONASS sets).
The base: ``tools/phone-base.toml`` (GPS + GLONASS, ``holux-m1000``'s error models, no C/N0
model of its own). For each data set the diagnosis of the base fits what it needs (its
calibrated profile); then each fit is diagnosed on the other data set, beside the base. The
held-out gap of a profile as it stands is the outer test's ``gap_baseline``.

Then both together: each effect a fit added is tried, as that fit set it, on the other data
set, and kept where it does not raise that data set's held-out gap above the base's; the kept
ones make ``joint/phone.toml``, diagnosed on both. The built-in ``phone`` profile is that file
(with its description); docs/profiles.md ("A phone profile") holds the numbers of the last run.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from virtualgps.gap import diagnose as dg
from virtualgps.gap import tool

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "magdeburg-campus"
BASE = ROOT / "tools" / "phone-base.toml"


def magdeburg(data: Path, profile: str) -> tool.GapInputs:
    """The Magdeburg waypoint logs with their marker truths, GPS and GLONASS sets."""
    from mtk_calibration import waypoint_truths

    from virtualgps.sky.scene import load_scene

    logs, truths = waypoint_truths(data, load_scene(SCENE))
    tle = tuple(str(data / "magdeburg-campus" / "tle" / f"{g}.2017-03-28.tle.txt")
                for g in ("gps-ops", "glo-ops"))
    return tool.GapInputs(real=tuple(str(p) for p in logs), truth=tuple(truths),
                          scene=str(SCENE), tle=tle, profile=profile)


def gsdc(data: Path, profile: str) -> tool.GapInputs:
    """The GSDC drive with its SPAN truth and that day's GPS set."""
    d = data / "gsdc-2020-05-14-mtv"
    return tool.GapInputs(real=(str(d / "Pixel4_chipset.nmea"),),
                          truth=(str(d / "SPAN_Pixel4_1Hz.nmea"),), scene="none",
                          tle=str(d / "gps-ops_2020-05-14T22Z.tle"), profile=profile)


def run(inp: tool.GapInputs, seeds: int, out: Path, label: str) -> dict:
    """One diagnosis, written to ``out``; prints its summary."""
    t0 = time.perf_counter()
    report, figures, calibrated = tool.diagnose(inp, dg.Options(seeds=seeds))
    tool.write_outputs(report, figures, calibrated, report["profile"], out, None, None)
    print(f"== {label} ({time.perf_counter() - t0:.0f} s): {out}", flush=True)
    for line in tool.summary_lines(report):
        print(line, flush=True)
    return report


# profile tables of effects whose table has another name
TABLE_OF = {"elevation_mask": "sky", "noise_level": "noise"}


def with_effect(base: dict, fitted: dict, effect: str) -> dict:
    """The base profile table with one effect's table as a fit set it."""
    table = TABLE_OF.get(effect, effect)
    out = dict(base)
    out[table] = {**base.get(table, {}), **fitted[table]}
    return out


def write_profile(table: dict, name: str, path: Path) -> Path:
    """A profile table as a TOML file."""
    from virtualgps.gap.effects import to_toml

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(to_toml({**table, "name": name}), encoding="utf-8")
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--out", default="phone-cal")
    ap.add_argument("--test", nargs="+", metavar="PROFILE",
                    help="only diagnose these profiles (names or TOML paths) as they stand on "
                         "both data sets: their held-out gaps, nothing fitted into a profile")
    args = ap.parse_args()
    data, out = Path(args.data), Path(args.out)
    cases = {"gsdc": gsdc, "magdeburg": magdeburg}
    if args.test:
        for k, prof in enumerate(args.test):
            for name, make in cases.items():
                r = run(make(data, prof), args.seeds, out / f"as-is-{k}-{name}",
                        f"{prof} as it stands on {name}")
                print(f"  {name}: {prof} {r['gap_baseline']:.3f}", flush=True)
        return
    held = {}
    for name, make in cases.items():
        r = run(make(data, str(BASE)), args.seeds, out / f"fit-{name}", f"fit on {name}")
        held[name, "phone-base"] = r["gap_baseline"]
    for name, make in cases.items():
        other = next(n for n in cases if n != name)
        fitted = out / f"fit-{other}" / "calibrated.toml"
        r = run(make(data, str(fitted)), args.seeds, out / f"test-{name}",
                f"test on {name}: the fit on {other}")
        held[name, f"fit on {other}"] = r["gap_baseline"]
    # Both data sets together: an effect one fit added is kept when, as that fit set it, it
    # does not raise the other data set's held-out gap above the base's there (that data set
    # never saw the fit: its figure is the test); the kept ones make the joint profile.
    import tomllib

    base = tomllib.loads(BASE.read_text())
    reports = {n: (out / f"fit-{n}" / "report.json") for n in cases}
    kept = []
    for name in cases:
        other = next(n for n in cases if n != name)
        fitted = tomllib.loads((out / f"fit-{name}" / "calibrated.toml").read_text())
        added = [e["name"] for e in json.loads(reports[name].read_text())["effects"]
                 if e.get("accepted")]
        for effect in added:
            path = write_profile(with_effect(base, fitted, effect), f"phone-base+{effect}",
                                 out / "joint" / f"{name}-{effect}.toml")
            r = run(cases[other](data, str(path)), args.seeds, out / "joint" / f"{other}-with-"
                    f"{effect}", f"test on {other}: the base with {name}'s {effect}")
            held[other, f"base + {name}'s {effect}"] = r["gap_baseline"]
            if r["gap_baseline"] <= held[other, "phone-base"]:
                kept.append((name, effect, fitted))
    joint = dict(base)
    for _, effect, fitted in kept:
        joint = with_effect(joint, fitted, effect)
    path = write_profile(joint, "phone", out / "joint" / "phone.toml")
    print(f"joint profile {path}: {', '.join(f'{e} ({n})' for n, e, _ in kept) or 'the base'}")
    for name, make in cases.items():
        r = run(make(data, str(path)), args.seeds, out / "joint" / f"test-{name}",
                f"the joint profile on {name}")
        held[name, "joint"] = r["gap_baseline"]
    print("held-out gap of each profile as it stands (outer test):")
    for (name, prof), g in held.items():
        print(f"  {name}: {prof} {g:.3f}")


if __name__ == "__main__":
    main()
