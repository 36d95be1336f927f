"""C/N0 by elevation of the one u-blox record in ``../shared/data``, beside a profile's model.

Usage: ``python tools/ublox_cn0.py [SHARED_DATA_DIR] [--profile ublox-m8n]``

The smartLoc Berlin drive (TU Chemnitz, CC BY-SA 4.0; ``smartloc-berlin/``) holds a u-blox
M8T's raw measurements on a car in an urban canyon, 283 s: per satellite and epoch its
elevation and C/N0, no fixes (so ``virtualgps gap`` cannot take it as a receiver's log). This
prints, per elevation bin and system (GPS, GLONASS), the 10th, 50th and 90th percentiles of the
reported C/N0 and the profile's ``cn0_tracking`` level at the bin's middle (zenith level plus
the patch antenna's gain; fades and losses behind walls left out). Among buildings many
signals arrive reflected and weaker (the dataset labels 263 of 545 measurements of its first
6.6 s non-line-of-sight), so the 90th percentile is the nearer to a clear sky's level.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from virtualgps.receiver import signals
from virtualgps.receiver.profiles import load_profile

ROOT = Path(__file__).resolve().parents[1]
BINS_DEG = ((5, 15), (15, 30), (30, 45), (45, 60), (60, 90))
SYSTEMS = {1: "GPS", 4: "GLONASS"}  # the dataset's system codes


def read_pseudoranges(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(system code, elevation in degrees, C/N0 in dB-Hz), one row per ``pseudorange3`` line
    of the smartLoc input file (columns as its readme.txt lists them)."""
    rows = [line.split() for line in path.read_text().splitlines()
            if line.startswith("pseudorange3")]
    a = np.array([[float(r[8]), float(r[9]), float(r[10])] for r in rows])
    return a[:, 0].astype(int), a[:, 1], a[:, 2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--profile", default="ublox-m8n")
    a = ap.parse_args()
    system, el_deg, cn0_dbhz = read_pseudoranges(
        Path(a.data) / "smartloc-berlin" / "Berlin_Potsdamer_Platz_Input.txt")
    ct = load_profile(a.profile).cn0_tracking
    print(f"u-blox M8T, smartLoc Berlin: {system.size} satellite-epochs; "
          f"{a.profile}: zenith {ct.cn0_zenith_dbhz} dB-Hz, horizon loss {ct.horizon_loss_db} dB")
    print("| elevation | system | n | C/N0 10 / 50 / 90 % (dB-Hz) | profile at mid-bin |")
    print("|---|---|---|---|---|")
    for lo, hi in BINS_DEG:
        model = ct.cn0_zenith_dbhz + signals.antenna_gain_db(np.array((lo + hi) / 2),
                                                              ct.horizon_loss_db)
        for code, name in SYSTEMS.items():
            k = (system == code) & (el_deg >= lo) & (el_deg < hi)
            if k.any():
                p10, p50, p90 = np.percentile(cn0_dbhz[k], [10, 50, 90])
                print(f"| {lo}–{hi}° | {name} | {k.sum()} | {p10:.0f} / {p50:.0f} / {p90:.0f} "
                      f"| {float(model):.1f} |")


if __name__ == "__main__":
    main()
