"""Write the seed paper's offline satellite lookup table from a TLE file.

Usage: python tools/make_lookup_table.py TLE --start ISO8601 --duration-s S --step-s S --out FILE

Example: python tools/make_lookup_table.py ephemeris/gps-ops-2020-05-14T22Z.tle
         --start 2020-05-14T22:00:00Z --duration-s 3600 --step-s 60 --out mtv.sat

The format is documented in virtualgps.sky.lookup.write_lookup_table; virtualgps reads it with
read_lookup_table and interpolates between rows (cubic Hermite, ~4 mm at 60 s steps).
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path

from virtualgps.exceptions import VirtualGPSError
from virtualgps.sky.ephemeris import build_lookup_table, load_tle
from virtualgps.sky.lookup import write_lookup_table


def parse_iso_utc(text: str) -> float:
    """UTC Unix seconds of an ISO 8601 time; a time without a zone is taken as UTC."""
    stamp = dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=dt.UTC)
    return stamp.timestamp()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Tabulate satellite ECEF states from a TLE file.")
    ap.add_argument("tle", type=Path, help="TLE file (2-line or 3-line)")
    ap.add_argument("--prn-table", type=Path, default=None, help="NORAD->PRN table (optional)")
    ap.add_argument("--start", required=True, help="UTC start, ISO 8601 (e.g. 2020-05-14T22:00Z)")
    ap.add_argument("--duration-s", type=float, required=True, help="seconds to cover")
    ap.add_argument("--step-s", type=float, default=60.0, help="seconds between rows (60)")
    ap.add_argument("--out", type=Path, required=True, help="output file")
    args = ap.parse_args(argv)
    try:
        start_unix_s = parse_iso_utc(args.start)
    except ValueError:
        print(
            f"error: --start {args.start!r}: expected ISO 8601 like 2020-05-14T22:00:00Z",
            file=sys.stderr,
        )
        return 2
    try:
        constellation = load_tle(args.tle, prn_table=args.prn_table)
        table = build_lookup_table(constellation, start_unix_s, args.duration_s, args.step_s)
        write_lookup_table(table, args.out)
    except (VirtualGPSError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {table.t_unix_s.size} times x {len(table)} satellites to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
