"""Rebuild virtualgps/data/egm96-30min.npz from PROJ's EGM96 15' grid (Debian package proj-data).

Usage: python tools/make_geoid_grid.py [/usr/share/proj/egm96_15.gtx]

The .gtx format (NOAA VDatum): a big-endian header of four float64 (lower-left latitude,
lower-left longitude, latitude step, longitude step, degrees) and two int32 (rows, columns),
then rows x columns float32 geoid heights in metres, south row first.
We keep every second node (30' spacing, exact EGM96 values at the kept nodes) and store
centimetres as int16 (range -107..+86 m fits), ~0.5 MB.
"""

import struct
import sys
from pathlib import Path

import numpy as np

src = Path(sys.argv[1] if len(sys.argv) > 1 else "/usr/share/proj/egm96_15.gtx")
raw = src.read_bytes()
lat0, lon0, dlat, dlon, rows, cols = struct.unpack(">4d2i", raw[:40])
grid = np.frombuffer(raw[40:], dtype=">f4").reshape(rows, cols).astype(np.float64)
assert (lat0, lon0, dlat, dlon) == (-90.0, -180.0, 0.25, 0.25), "unexpected grid layout"
sub = grid[::2, ::2]  # 361 x 720: lat -90..90, lon -180..179.5
out = Path(__file__).resolve().parents[1] / "virtualgps" / "data" / "egm96-30min.npz"
np.savez_compressed(out, geoid_cm=np.round(sub * 100).astype(np.int16), step_deg=0.5)
print(f"wrote {out} {sub.shape} from {src}")
