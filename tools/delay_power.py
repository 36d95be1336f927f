"""How often ``virtualgps gap`` names a small output delay: the power of the diagnosis at one
delay and output rate, over fresh drives.

    python tools/delay_power.py [--profile ublox-m8n] [--rate 5] [--delay 0.6] [--trials 5] \\
        [--seeds 20] [--jobs 2] [--work DIR]

Each trial is the self-check's moving open-sky drive (15 minutes, a fresh trajectory, time and
place per trial: ``synthetic.make_trial`` at indices 1, 5, 9, ...) logged by the profile at
``--rate`` Hz with a ``latency`` of ``--delay`` seconds, and diagnosed against the same profile
without it, with ``latency`` and ``nav_filter`` as the candidates. One line per trial (the lag
measured, its 95 % band, each candidate's verdict), then how many named the delay with an
interval that holds it.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from virtualgps.gap import diagnose as dg
from virtualgps.gap import effects as fx
from virtualgps.gap import synthetic, tool
from virtualgps.receiver.profiles import load_profile_dict
from virtualgps.sky.ephemeris import default_tle_path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="ublox-m8n")
    ap.add_argument("--rate", type=float, default=5.0, help="output rate, Hz")
    ap.add_argument("--delay", type=float, default=0.6, help="the injected delay, seconds")
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--work", default="delay-power")
    a = ap.parse_args(argv)
    work = Path(a.work) / f"{a.profile}-{a.rate:g}hz-{a.delay:g}s"
    work.mkdir(parents=True, exist_ok=True)
    os.chdir(work)  # (relative labels: a trial's draws follow its label, not the folder)
    table, _ = load_profile_dict(a.profile)
    base = dict(table, name=f"{a.profile}-{a.rate:g}hz", rate_hz=a.rate)
    late = fx.apply(base, {"latency": {"enabled": True, "latency_s": a.delay}})
    Path("base.toml").write_text(fx.to_toml(base), encoding="utf-8")
    Path("late.toml").write_text(fx.to_toml(dict(late, name="late")), encoding="utf-8")
    tle = str(default_tle_path())
    found = 0
    for k in range(a.trials):
        tr = synthetic.make_trial("nothing@late.toml", 1 + 4 * k, Path("w"), None, "", tle, tle)
        inp = tool.GapInputs(real=(str(tr.real),), truth=(tr.truth,), scene=None, tle=tle,
                             profile="base.toml")
        rep, _, _ = tool.diagnose(inp, dg.Options(seeds=a.seeds, jobs=a.jobs,
                                                  effects=("latency", "nav_filter")))
        lag = next(h for h in rep["headline"] if h["metric"] == "lag_s")
        added = [e for e in rep["effects"] if e.get("accepted")]
        span = added[0]["fit"]["spans"].get("latency_s") if added else None
        hit = (bool(added) and added[0]["name"] == "latency"
               and span[0] <= a.delay <= span[1])
        found += hit
        print(json.dumps({
            "index": tr.index, "scenario": tr.scenario, "lag_real_s": round(lag["real"], 3),
            "lag_band_s": [round(lag["sim_lo"], 3), round(lag["sim_hi"], 3)],
            "named": hit, "effects": [
                {"name": e["name"], "added": bool(e.get("accepted")), "params": e["params"],
                 "gap": [round(e["gap_before"], 3), round(e["gap_after"], 3)],
                 "why_not": e.get("accepted_test")} for e in rep["effects"]]}), flush=True)
    print(f"{a.profile} at {a.rate:g} Hz, delay {a.delay:g} s: named (interval holding it) "
          f"in {found} of {a.trials} trials")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
