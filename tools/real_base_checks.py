"""The self-check's real-log trials (:mod:`virtualgps.gap.selfcheck_real`) on another log of
the GSDC drive, a base the self-check itself never diagnoses:

    python tools/real_base_checks.py [--data ../shared/data] [--base Pixel4XLModded_chipset.nmea]
        [--trials 2] [--seeds 50] [--jobs 2] [--out real-bases] [EFFECT ...]

The drive's other phone (a Pixel 4 XL in the same car, against the same SPAN truth) takes the
same injections at the same draws as the self-check's Pixel 4: a pure output delay, a
first-order filter, a static hold, a moved truth, a cold start and a slow offset (EFFECT: any
of ``selfcheck_real.REAL_EFFECTS``; default all). One line per trial as it finishes, a table at
the end, and every row in ``OUT/rows.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from virtualgps.gap import diagnose as dg
from virtualgps.gap import selfcheck_real as sr

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("effects", nargs="*", default=list(sr.REAL_EFFECTS))
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--base", default="Pixel4XLModded_chipset.nmea")
    ap.add_argument("--trials", type=int, default=2)
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="real-bases")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    rows, note = sr.run(Path(a.data), dg.Options(seeds=a.seeds, jobs=a.jobs), a.trials,
                        out / "work",
                        progress=lambda s: print(f"{time.monotonic() - t0:6.0f} s  {s}",
                                                 flush=True),
                        effects=tuple(a.effects), base_log=a.base)
    if note:
        raise SystemExit(note)
    (out / "rows.json").write_text(json.dumps(rows, indent=1, default=str))
    print(f"\n{a.base}: {sum(r['success'] for r in rows)} of {len(rows)} trials right")
    for scenario, added in {r["scenario"]: r["base_accepted"] for r in rows}.items():
        print(f"  untouched, {scenario}: adds {added or 'nothing'}")
    for r in rows:
        print(f"  {r['injected']} {r['params']}: {'right' if r['success'] else 'wrong'}; "
              f"new {r['ranked']}, recovered {r['recovered']} "
              f"{r['recovered_interval'] or ''}")


if __name__ == "__main__":
    main()
