"""Fresh null checks of ``virtualgps gap``: logs made by the profile under test itself, at
trial indices the self-check does not use, each diagnosed against that profile. There is
nothing to find: no effect should be added, and about none of the where-rows outside.

    python tools/null_drives.py [--seeds 30] [--work null-drives] \\
        nothing@holux-m1000:5 nothing@holux-m1000:9 nothing@usarsim:3 ...

A trial ``LABEL:INDEX`` is the self-check's (:func:`virtualgps.gap.synthetic.make_trial`): its
trajectory, time and seeds are drawn from the label and the index, its scenario is the label's
scenarios cycled by the index (``nothing@holux-m1000``: static_open, moving_open, static_built,
moving_built; ``nothing@usarsim``: static_open, moving_open), so indices 1, 5, 9, 13, 17 of
``holux-m1000`` and 1, 3, 5 of ``usarsim`` are drives (``moving_open``: legs at 2-10 m/s). The
self-check's own runs use indices 0 to ``--trials`` - 1. One line per trial: the scenario, the
effects added, the where-rows outside of all, the ``smoothing_s`` rows (real, seeds' median),
and the bands checked on the seeds themselves (``band.seed_holdout``: how many of the seeds,
each taken as the real log, would show a located gap). ``--bands-only`` judges the rows and
holds the seeds out in turn, and offers no effect (``--effects none``): a quick check of the
bands alone.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from virtualgps.gap import diagnose as dg
from virtualgps.gap import synthetic, tool
from virtualgps.run.config import BUNDLED_SCENES_DIR, DEFAULT_SCENE
from virtualgps.sky.ephemeris import default_tle_path
from virtualgps.sky.scene import load_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trials", nargs="+", help="LABEL:INDEX, e.g. nothing@holux-m1000:9")
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--work", default="null-drives", help="where the trials' logs are written")
    ap.add_argument("--bands-only", action="store_true",
                    help="judge the located gaps and the seeds held out in turn; no effects")
    args = ap.parse_args()
    scene_dir = str(BUNDLED_SCENES_DIR / DEFAULT_SCENE)
    scene = load_scene(scene_dir)
    added_any = outside_all = rows_all = held_n = held_k = 0
    for spec in args.trials:
        label, index = spec.rsplit(":", 1)
        tr = synthetic.make_trial(label, int(index), Path(args.work), scene, scene_dir,
                                  str(scene.tle_path), str(default_tle_path()))
        inp = tool.GapInputs(real=(str(tr.real),), truth=(tr.truth,), scene=tr.scene or "none",
                             tle=tuple(tr.tle.split(os.pathsep)), profile=str(tr.profile))
        opts = dg.Options(seeds=args.seeds, jobs=args.jobs,
                          effects=() if args.bands_only else None)
        report, _, _ = tool.diagnose(inp, opts)
        added = [e["name"] for e in report["effects"] if e.get("accepted")]
        rows = report["where"]
        outside = sum(bool(w["outside"]) for w in rows)
        smooth = [(w.get("real"), w.get("sim_median")) for w in rows
                  if w["metric"] == "smoothing_s"]
        added_any += bool(added)
        outside_all += outside
        rows_all += len(rows)
        held = report["band"]["seed_holdout"]
        held_n += held["reports"]
        held_k += held["reports_with_any_row_outside"]
        print(f"{spec} {tr.scenario}: added {added or 'nothing'}; {outside} of {len(rows)} "
              f"rows outside; smoothing_s (real, seeds' median) {smooth}; seeds held out: "
              f"{held['reports_with_any_row_outside']} of {held['reports']} with a located gap "
              f"{held['metrics'] or ''}", flush=True)
    print(f"{len(args.trials)} trials: {added_any} with an effect added; {outside_all} of "
          f"{rows_all} rows outside; seeds held out in turn: {held_k} of {held_n} with a "
          "located gap", flush=True)


if __name__ == "__main__":
    main()
