"""The receiver's reported 1-sigma (GST, ``sigma_enu_m``) against the errors it makes, in open
sky: RMS of the actual east/north/up errors over the RMS of the reported sigmas.

    python tools/sigma_check.py [--profile holux-m1000] [--seeds 5] [--epochs 20000]

A ratio of 1 is a receiver whose GST a robot's filter can trust; a review found 1.6-1.8 for
``holux-m1000`` while its sigma knew only the UERE budget.
"""

from __future__ import annotations

import argparse

import numpy as np

from virtualgps import geodesy
from virtualgps.receiver.core import simulate
from virtualgps.receiver.definition import Georef, Receiver
from virtualgps.receiver.profiles import load_profile
from virtualgps.receiver.state import ReceiverState
from virtualgps.sky.ephemeris import default_tle_path, load_tle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="holux-m1000")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--epochs", type=int, default=20_000)
    args = ap.parse_args()
    eph = load_tle(default_tle_path())
    georef = Georef(52.14, 11.64, 100.0)
    rx = Receiver(load_profile(args.profile), eph, None, georef)
    n = args.epochs
    t = np.floor(eph.epoch_center_unix_s) + np.arange(float(n))
    errs, sigmas = [], []
    for seed in range(args.seeds):
        f, _ = simulate(rx, t, np.zeros((n, 3)), np.zeros((n, 3)), np.ones(n, bool),
                        ReceiverState(), np.random.default_rng(seed))
        ok = f.quality > 0
        ecef = geodesy.geodetic_to_ecef(f.lat_deg[ok], f.lon_deg[ok],
                                        f.alt_msl_m[ok] + f.geoid_sep_m[ok])
        errs.append(geodesy.ecef_to_enu(ecef, georef.lat0_deg, georef.lon0_deg,
                                        georef.alt0_hae_m))
        sigmas.append(f.sigma_enu_m[ok])
    actual = np.sqrt(np.mean(np.concatenate(errs) ** 2, axis=0))
    reported = np.sqrt(np.nanmean(np.concatenate(sigmas) ** 2, axis=0))
    print(f"{args.profile}, open sky, {args.seeds} seeds x {n} epochs:")
    print(f"  actual RMS   E/N/U {actual[0]:.2f} / {actual[1]:.2f} / {actual[2]:.2f} m")
    print(f"  reported RMS E/N/U {reported[0]:.2f} / {reported[1]:.2f} / {reported[2]:.2f} m")
    r = actual / reported
    print(f"  actual / reported  {r[0]:.2f} / {r[1]:.2f} / {r[2]:.2f}")


if __name__ == "__main__":
    main()
