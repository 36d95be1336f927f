"""Micro-benchmark of NMEA text building: microseconds per epoch for a batch.

Usage: python tools/bench_nmea.py [N_EPOCHS]

Builds a synthetic batch (1 Hz, 12 satellites in view, 8 used, SNR changing every epoch by
+-1 dB as in the real MTK logs, so GSV text repeats rarely) and times ``render_batch`` for the
default Holux sentences (GGA GSA GSV x3 RMC VTG) and ``epoch_sentences`` for single epochs
(the daemon's path).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from virtualgps.device import nmea
from virtualgps.receiver.records import Fixes


def synthetic_fixes(n_t: int, n_sat: int = 12, n_used: int = 8, seed: int = 1) -> Fixes:
    """A batch of ``n_t`` 1 Hz fix epochs moving slowly near Magdeburg."""
    rng = np.random.default_rng(seed)
    t = 1711630000.0 + np.arange(n_t, dtype=float)
    prn = np.array([2, 5, 6, 9, 12, 14, 17, 19, 24, 25, 29, 31][:n_sat])
    el0 = rng.uniform(5, 85, n_sat)
    az0 = rng.uniform(0, 360, n_sat)
    el = el0 + 0.004 * np.arange(n_t)[:, None]  # about 0.004 deg/s, a GPS satellite's pace
    az = (az0 + 0.008 * np.arange(n_t)[:, None]) % 360
    cn0 = 25 + 20 * np.sin(np.radians(el)) + rng.integers(-1, 2, (n_t, n_sat))
    used = np.zeros((n_t, n_sat), bool)
    used[:, :n_used] = True
    in_view = np.ones((n_t, n_sat), bool)
    lat = 52.14 + 1e-6 * np.cumsum(rng.normal(size=n_t))
    lon = 11.64 + 1e-6 * np.cumsum(rng.normal(size=n_t))
    full = lambda v: np.full(n_t, v, float)  # noqa: E731
    return Fixes(
        t_unix_s=t,
        lat_deg=lat,
        lon_deg=lon,
        alt_msl_m=55 + rng.normal(size=n_t),
        geoid_sep_m=full(44.7),
        quality=np.ones(n_t, np.int8),
        mode=np.full(n_t, 3, np.int8),
        hdop=full(0.94),
        vdop=full(1.31),
        pdop=full(1.58),
        speed_mps=rng.uniform(0, 2, n_t),
        course_deg=rng.uniform(0, 360, n_t),
        prn=prn,
        az_deg=az,
        el_deg=el,
        cn0_dbhz=cn0,
        in_view=in_view,
        used=used,
        truth_lat_deg=lat,
        truth_lon_deg=lon,
        truth_alt_hae_m=full(100.0),
    )


def main() -> None:
    n_t = int(sys.argv[1]) if len(sys.argv) > 1 else 20000
    fixes = synthetic_fixes(n_t)
    fmt = nmea.NmeaFormat()
    nmea.render_batch(fixes, fmt, stop=100)  # warm up
    t0 = time.perf_counter()
    out = nmea.render_batch(fixes, fmt)
    dt = time.perf_counter() - t0
    n_bytes = sum(map(len, out))
    print(
        f"render_batch: {n_t} epochs, {1e6 * dt / n_t:.1f} us/epoch, "
        f"{n_bytes / n_t:.0f} bytes/epoch"
    )
    t0 = time.perf_counter()
    out = nmea.render_batch(fixes, fmt)
    dt = time.perf_counter() - t0
    print(f"render_batch (second run): {1e6 * dt / n_t:.1f} us/epoch")
    n1 = min(n_t, 2000)
    t0 = time.perf_counter()
    for i in range(n1):
        nmea.epoch_sentences(fixes, i, fmt)
    dt = time.perf_counter() - t0
    print(f"epoch_sentences (one epoch per call): {1e6 * dt / n1:.1f} us/epoch")


if __name__ == "__main__":
    main()
