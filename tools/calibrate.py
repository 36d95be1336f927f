"""Check a receiver profile against the real MTK logs: the calibration table, real vs simulated.

Usage::

    python tools/calibrate.py [--profile holux-m1000] [--config extra.toml] [--seeds 8]
                              [--site tools/mt3339-site.toml] [--data ../shared/data]
                              [--readme docs/profiles.md] [--plot cal.png]

The real column comes from :func:`mtk_logs.real_calibration_stats` (also
printed by tools/real_stats.py), the simulated one from
:func:`mtk_calibration.sim_calibration_stats`: the profile replayed where and when
each log was recorded, its NMEA read back and summarised exactly like the real log's (see
tools/mtk_calibration.py), the MT3339 hour with its site's obstruction (``--site``, learned
by ``virtualgps gap``) on top of the profile. The simulated value is the median
over the seeds, with the seeds' range beside it. ``--readme`` rewrites the table between the
``<!-- calibration:start -->`` and ``<!-- calibration:end -->`` lines of that file (and the
antenna and waypoint tables between theirs); ``--plot``
draws the distributions behind the numbers (seed 0 against the real logs). The exit status is
1 when a calibrated statistic lies outside its tolerance.

To fit a changed model, edit the profile's parameters (or pass ``--config`` with overrides) and
rerun; the whole run takes a few seconds per seed.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from mtk_calibration import (
    CALIBRATION_TLE,
    DEFAULT_SEEDS,
    M241_SITE,
    Row,
    blocked_pattern,
    capture_bins,
    compare,
    days_to_epoch_s,
    m241_setup,
    mt3339_setup,
    replay_epochs,
    sim_blocked_pattern,
    sim_calibration_stats,
    site_profile,
    waypoint_sky,
)
from mtk_logs import (
    M241_MOVING_MIN_SPEED_MPS,
    M241_TRACK_CSV,
    MT3339_STATIC_LOG,
    read_mtk_logger_csv,
    real_calibration_stats,
)

from virtualgps.device.nmea import read_nmea_epochs
from virtualgps.gap.metrics import (
    autocorrelation,
    errors_enu_m,
    horizontal_error_m,
    median_position,
    to_regular_grid,
)
from virtualgps.receiver.profiles import load_profile
from virtualgps.run.config import BUNDLED_SCENES_DIR
from virtualgps.sky.ephemeris import load_tle
from virtualgps.sky.scene import load_scene

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
START, END = "<!-- calibration:start -->", "<!-- calibration:end -->"
WP_START, WP_END = "<!-- waypoints:start -->", "<!-- waypoints:end -->"
ANT_START, ANT_END = "<!-- antenna:start -->", "<!-- antenna:end -->"
DEFAULT_SITE = Path(__file__).resolve().parent / "mt3339-site.toml"
# The phone's tracking sensitivity: it reports SNR down to 12 dB-Hz (an MTK stops at ~14).
PHONE_TRACKING = {"cn0_tracking": {"acq_dbhz": 12.0, "track_dbhz": 9.0}}
LOG_NAMES = {"mt3339_static": "MT3339 static hour", "m241_moving": "M-241 car track, moving"}


def _num(x: float) -> str:
    if not np.isfinite(x):
        return "-"
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.2f}" if abs(x) < 10 else f"{x:.1f}"


def markdown(rows: list[Row], n_seeds: int, command: str) -> str:
    """The calibration table as Markdown, with the command that made it."""
    out = [
        f"| log | statistic | real | simulated (median of {n_seeds} seeds) | seeds' range "
        "| sim / real | within |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        tol, atol = r.stat.tolerance, r.stat.abs_tolerance
        span = (f"+-{atol:g}" + (" dB" if "dbhz" in r.stat.key else "")) if atol is not None \
            else f"+-{tol:.0%}" if tol is not None else None
        verdict = "(not calibrated)" if span is None else f"{'yes' if r.ok else 'NO'} ({span})"
        out.append(
            f"| {LOG_NAMES[r.stat.log]} | {r.stat.label} | {_num(r.real)} | {_num(r.sim_median)} "
            f"| {_num(r.sim_min)}-{_num(r.sim_max)} | {r.ratio:.2f} | {verdict} |"
        )
    out.append("")
    out.append(f"Made by `{command}`.")
    return "\n".join(out)


def rewrite_readme(path: Path, table: str, start: str = START, end: str = END) -> None:
    """Put ``table`` between the ``start`` and ``end`` markers of ``path`` (which must hold
    them)."""
    text = path.read_text()
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise SystemExit(f"{path}: no {start} ... {end} block to rewrite")
    path.write_text(pattern.sub(lambda _: f"{start}\n{table}\n{end}", text))


def waypoint_table(profile_name: str, config: str | None, data: Path) -> str:
    """Satellites whose direct path crosses a building at the Magdeburg waypoints: the phone's
    logs against the profile (with and without ``nlos``, and with the phone's sensitivity)."""
    scene = load_scene(BUNDLED_SCENES_DIR / "magdeburg-campus")
    runs = [("phone (real logs)", {}, "real"),
            (profile_name, {}, "sim"),
            (f"{profile_name}, nlos off", {"nlos": {"enabled": False}}, "sim"),
            (f"{profile_name}, the phone's tracking sensitivity", PHONE_TRACKING, "sim")]
    out = ["| receiver | building-crossing satellite-epochs tracked | clear ones tracked "
           "| tracked crossing ones weaker by (dB, per PRN) |", "|---|---|---|---|"]
    for name, over, which in runs:
        prof = load_profile(profile_name, over, overrides_path=config)
        p = (blocked_pattern(waypoint_sky(prof, data, scene), "real") if which == "real"
             else sim_blocked_pattern(prof, data, scene))
        weaker = "-" if not np.isfinite(p["weaker_db"]) else f"{p['weaker_db']:.1f}"
        out.append(f"| {name} | {p['tracked_blocked']:.0%} | {p['tracked_clear']:.0%} "
                   f"| {weaker} |")
    out.append("")
    out.append(f"{int(p['n_blocked'])} building-crossing satellite-epochs above 5 deg at markers "
               "5-18; simulated rows: medians of 5 seeds; made by `python tools/calibrate.py`.")
    return "\n".join(out)


def antenna_table(profile, data: Path) -> str:
    """The profile's open-sky C/N0 against the gpsd MTK captures, per elevation bin."""
    out = ["| elevation | captures' satellite-epochs | captures' SNR, median (their own medians) "
           "| open-sky model at the same satellites | model - captures |", "|---|---|---|---|---|"]
    for b in capture_bins(profile, data):
        out.append(f"| {b['lo_deg']}-{b['hi_deg']} deg | {b['n']} | {b['real_median_dbhz']:.1f} "
                   f"({b['real_min_dbhz']:.0f}-{b['real_max_dbhz']:.0f}) dB-Hz "
                   f"| {b['model_median_dbhz']:.1f} dB-Hz "
                   f"| {b['model_median_dbhz'] - b['real_median_dbhz']:+.1f} dB |")
    out.append("")
    out.append("The five gpsd-mtk captures pooled; made by `python tools/calibrate.py`.")
    return "\n".join(out)


def _errors_h_m(ep) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal errors about the median fix (m) and the ENU errors on the 1 s grid."""
    fixed = (ep.quality > 0) & np.isfinite(ep.lat_deg)
    alt = ep.alt_msl_m + np.nan_to_num(ep.geoid_sep_m)
    ref = median_position(ep.lat_deg[fixed], ep.lon_deg[fixed], alt[fixed])
    enu = errors_enu_m(ep.lat_deg[fixed], ep.lon_deg[fixed], alt[fixed], *ref)
    _, grid = to_regular_grid(ep.t_unix_s[fixed], enu, 1.0)
    return horizontal_error_m(enu), grid


def plot(profile, data: Path, path: Path, site=None, car=None) -> None:
    """Four panels, real vs simulated (seed 0): horizontal error CDF, error autocorrelation,
    median C/N0 by elevation (MT3339, with its site ``site``, and the open-sky antenna) and
    HDOP CDF (both logs; the M-241 with its site ``car``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eph = load_tle(data / CALIBRATION_TLE)
    real = read_nmea_epochs(data / MT3339_STATIC_LOG)
    georef, track = mt3339_setup(data)
    sim = replay_epochs(site or profile, eph, georef, track, 0)
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    edges = np.arange(0, 91, 5)
    for ep, name, style in ((real, "MT3339 (real)", "k-"), (sim, "simulated", "C1-")):
        err_h, grid = _errors_h_m(ep)
        x = np.sort(err_h)
        ax[0, 0].plot(x, np.linspace(0, 1, x.size), style, label=name)
        lags = np.arange(601)
        ax[0, 1].plot(lags, autocorrelation(grid[:, :2], 600), style, label=name)
        gps = (ep.prn >= 1) & (ep.prn <= 32)
        el = ep.el_deg[:, gps][ep.quality > 0].ravel()
        cn0 = ep.cn0_dbhz[:, gps][ep.quality > 0].ravel()
        k = np.digitize(el, edges) - 1
        med = [np.median(cn0[(k == i) & np.isfinite(cn0)]) if ((k == i) & np.isfinite(cn0)).any()
               else np.nan for i in range(edges.size - 1)]
        ax[1, 0].step(edges[:-1], med, style, where="post", label=name)
        h = np.sort(ep.hdop[(ep.quality > 0) & np.isfinite(ep.hdop)])
        ax[1, 1].plot(h, np.linspace(0, 1, h.size), style, label=f"{name}, static")
    georef, trk, speed = m241_setup(data)
    shift = days_to_epoch_s(eph, float(trk.t_unix_s[0]))
    sim = replay_epochs(car or profile, eph, georef, replace(trk, t_unix_s=trk.t_unix_s + shift), 0)
    real_m = read_mtk_logger_csv(data / M241_TRACK_CSV)
    for h, name, style in (
        (real_m.hdop[real_m.speed_mps >= M241_MOVING_MIN_SPEED_MPS], "M-241 (real)", "k--"),
        (sim.hdop, "simulated", "C1--"),
    ):
        h = np.sort(h[np.isfinite(h)])
        ax[1, 1].plot(h, np.linspace(0, 1, h.size), style, label=f"{name}, moving")
    ax[0, 0].set(xlabel="horizontal error about the median fix (m)", ylabel="CDF", xlim=(0, 20))
    ax[0, 1].axhline(np.exp(-1), color="0.6", lw=0.8)
    ax[0, 1].set(xlabel="lag (s)", ylabel="autocorrelation of the E/N error")
    from virtualgps.receiver.signals import antenna_gain_db

    ct = profile.cn0_tracking
    el = np.linspace(0, 90, 91)
    ax[1, 0].plot(el, ct.cn0_zenith_dbhz + antenna_gain_db(el, ct.horizon_loss_db), "C0:",
                  label="antenna, open sky (no fades)")
    ax[1, 0].set(xlabel="elevation (deg)", ylabel="median GSV SNR (dB-Hz)")
    ax[1, 1].set(xlabel="HDOP", ylabel="CDF", xlim=(0.5, 3))
    for a in ax.ravel():
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(f"{profile.name}: real MTK logs vs simulated")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="holux-m1000", help="profile name or TOML path")
    ap.add_argument("--config", help="a TOML file of profile overrides")
    ap.add_argument("--seeds", type=int, default=len(DEFAULT_SEEDS), help="number of seeds")
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="the ../shared/data folder")
    ap.add_argument("--site", type=Path, default=DEFAULT_SITE,
                    help="the MT3339 site's [sky_mask] (learned by virtualgps gap)")
    ap.add_argument("--readme", type=Path, help="rewrite the calibration table in this file")
    ap.add_argument("--plot", type=Path, help="draw the distributions into this PNG")
    args = ap.parse_args(argv)
    if not (args.data / MT3339_STATIC_LOG).exists():
        print(f"calibrate: no real logs under {args.data} (give --data)", file=sys.stderr)
        return 2
    profile = load_profile(args.profile, overrides_path=args.config)
    site = site_profile(args.profile, args.site, args.config)
    car = site_profile(args.profile, M241_SITE, args.config)
    t0 = time.monotonic()
    real = real_calibration_stats(args.data)
    sim = sim_calibration_stats(
        profile, args.data, range(args.seeds),
        progress=lambda what: print(f"  {what} ({time.monotonic() - t0:.1f} s)", file=sys.stderr),
        mt3339_profile=site, m241_profile=car,
    )
    rows = compare(real, sim)
    command = "python tools/calibrate.py" + "".join(
        f" --{k} {v}" for k, v in (("profile", args.profile), ("config", args.config))
        if v and v != "holux-m1000"
    ) + (f" --seeds {args.seeds}" if args.seeds != len(DEFAULT_SEEDS) else "")
    table = markdown(rows, args.seeds, command)
    print(table)
    antenna = antenna_table(profile, args.data)
    print()
    print(antenna)
    waypoints = waypoint_table(args.profile, args.config, args.data)
    print()
    print(waypoints)
    if args.readme:
        rewrite_readme(args.readme, table)
        rewrite_readme(args.readme, antenna, ANT_START, ANT_END)
        rewrite_readme(args.readme, waypoints, WP_START, WP_END)
        print(f"wrote the tables into {args.readme}", file=sys.stderr)
    if args.plot:
        plot(profile, args.data, args.plot, site, car)
        print(f"wrote {args.plot}", file=sys.stderr)
    bad = [r for r in rows if r.ok is False]
    for r in bad:
        print(f"calibrate: {LOG_NAMES[r.stat.log]}: {r.stat.label}: simulated {r.sim_median:.3g} "
              f"vs real {r.real:.3g} ({r.ratio:.2f}x) is outside +-{r.stat.tolerance:.0%}",
              file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
