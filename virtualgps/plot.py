"""Figures. matplotlib is imported lazily, inside each function, so the core never needs it."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

STATE_STYLE = {
    "visible": ("tab:green", "o"),
    "blocked": ("tab:red", "x"),
    "below_mask": ("tab:gray", "v"),
    "nlos": ("tab:orange", "s"),
    "attenuated": ("tab:olive", "D"),
}


# RINEX 3 names from the NMEA IDs of ``virtualgps sky`` rows: (letter, NMEA ID - number); the
# systems' own table is virtualgps.sky.systems, a layer above this module
_RINEX = {"GPS": ("G", 0), "GLONASS": ("R", 64), "Galileo": ("E", 0), "BeiDou": ("C", 0),
          "QZSS": ("J", 0), "SBAS": ("S", 13)}


def sat_label(row: dict[str, Any], several_systems: bool) -> str:
    """A satellite's label on a skyplot: its NMEA ID alone for one system, else its RINEX name
    (``G12``, ``R10`` for GLONASS slot 10 = NMEA 74, ``E11``, ``S23`` for SBAS NMEA 36)."""
    if not several_systems:
        return str(row["prn"])
    code, off = _RINEX.get(row.get("system", "GPS"), ("?", 0))
    return f"{code}{row['prn'] - off:02d}"


def skyplot(rows: Sequence[dict[str, Any]], path: Path, title: str = "") -> None:
    """Draw a polar skyplot of satellites (north up, azimuth clockwise, zenith at the centre).

    Parameters
    ----------
    rows : dicts with ``prn``, ``az_deg``, ``el_deg``, ``state`` and optionally ``system`` (as
        ``virtualgps sky`` prints them); with more than one system each satellite is labelled
        by its RINEX name (``G12``, ``R10`` for GLONASS slot 10, ``E11``: the IDs of different
        systems overlap)
    path : PNG file to write
    title : figure title
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig = plt.figure(figsize=(6, 6.4))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_rlim(0, 90)
    ax.set_rticks([0, 30, 60, 90], labels=["90°", "60°", "30°", "0°"])
    several = len({r.get("system", "GPS") for r in rows}) > 1
    seen = set()
    for r in rows:
        color, marker = STATE_STYLE.get(r["state"], ("black", "."))
        label = r["state"] if r["state"] not in seen else None
        seen.add(r["state"])
        theta, radius = np.radians(r["az_deg"]), 90.0 - r["el_deg"]
        ax.plot(theta, radius, marker=marker, color=color, markersize=10, linestyle="", label=label)
        ax.annotate(sat_label(r, several), (theta, radius), textcoords="offset points",
                    xytext=(6, 6), fontsize=9)
    ax.legend(loc="lower left", bbox_to_anchor=(-0.1, -0.12), ncol=3, frameon=False)
    ax.set_title(title or "sky", pad=18)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


# --- the gap report's figures (each returns PNG bytes) -------------------------------------


def _figure(w: float = 7.5, h: float = 4.0, polar: bool = False):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(w, h))
    ax = fig.add_subplot(projection="polar" if polar else None)
    return plt, fig, ax


def _png(plt, fig) -> bytes:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="gray")


def _band(ax, x, runs, color: str, label: str) -> None:
    """The median and 2.5-97.5 % band over seeds of (s, n) series, NaN ignored."""
    import warnings

    import numpy as np

    a = np.asarray(runs, dtype=float)
    if a.size == 0 or not np.isfinite(a).any():
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, med, hi = _column_quantiles(a, (0.025, 0.5, 0.975))
    ax.fill_between(x, lo, hi, color=color, alpha=0.25, linewidth=0)
    ax.plot(x, med, color=color, linewidth=1.0, label=label)


def _column_quantiles(a: Any, qs: Sequence[float]) -> list:
    """Quantiles (linear interpolation) of each column of (s, n) data, NaN left out; NaN for
    an empty column. (``numpy.nanpercentile`` along an axis loops over the columns in Python:
    seconds for an hour's ensemble.)"""
    import numpy as np

    x = np.sort(np.asarray(a, dtype=float), axis=0)  # NaN sort last
    n = np.isfinite(x).sum(axis=0)
    cols = np.arange(x.shape[1])
    out = []
    for q in qs:
        pos = q * np.maximum(n - 1, 0)
        lo = np.floor(pos).astype(int)
        hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
        v = x[lo, cols] + (pos - lo) * (x[hi, cols] - x[lo, cols])
        out.append(np.where(n > 0, v, np.nan))
    return out


def fig_track(run: Any) -> bytes:
    """The paper's Fig. 5: truth, real and simulated fixes in metres east/north of the first
    truth point (one seed of the profile under test, and of the calibrated profile)."""
    import numpy as np

    plt, fig, ax = _figure(6.5, 6.0)
    ok = np.isfinite(run.truth_lat_deg)
    if not ok.any():
        _empty(ax, "no truth")
        return _png(plt, fig)
    lat0, lon0 = run.truth_lat_deg[ok][0], run.truth_lon_deg[ok][0]

    def en(lat, lon):
        r = 6371000.0
        return (np.radians(lon - lon0) * r * np.cos(np.radians(lat0)),
                np.radians(lat - lat0) * r)

    ax.plot(*en(run.real_lat_deg, run.real_lon_deg), ".", color="tab:red", markersize=3,
            label="real")
    ax.plot(*en(run.sim_lat_deg[0], run.sim_lon_deg[0]), ".", color="tab:blue", markersize=3,
            alpha=0.6, label="simulated (profile under test, seed 0)")
    if run.final_lat_deg is not None:
        ax.plot(*en(run.final_lat_deg[0], run.final_lon_deg[0]), ".", color="tab:green",
                markersize=3, alpha=0.6, label="simulated (calibrated, seed 0)")
    ax.plot(*en(run.truth_lat_deg, run.truth_lon_deg), "-", color="black", linewidth=1.2,
            label="truth")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8, loc="best")
    ax.set_title(f"{run.name}: track (paper Fig. 5)")
    return _png(plt, fig)


def fig_error_time(run: Any) -> bytes:
    """The paper's Fig. 6: horizontal error over time, real against the ensemble's band; and
    its Eq. 4 (real vs simulated coordinates, degrees) below."""
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(7.5, 5.5), sharex=True)
    x = run.t_unix_s - run.t_unix_s[0]
    if np.isfinite(run.real_err_h_m).any() or np.isfinite(run.sim_err_h_m).any():
        _band(ax, x, run.sim_err_h_m, "tab:blue", "simulated (2.5-97.5 %, median)")
        if run.final_err_h_m is not None:
            _band(ax, x, run.final_err_h_m, "tab:green", "calibrated")
        ax.plot(x, run.real_err_h_m, color="tab:red", linewidth=0.8, label="real")
        ax.legend(fontsize=8)
    else:
        _empty(ax, "no fix")
    ax.set_ylabel("horizontal error (m)")
    ax.set_title(f"{run.name}: error over time (paper Fig. 6)")
    if np.isfinite(run.eq4_deg).any():
        _band(ax2, x, run.eq4_deg, "tab:purple", "Eq. 4, real vs simulated (seeds)")
        ax2.legend(fontsize=8)
    else:
        _empty(ax2, "no pair of fixes")
    ax2.set_ylabel("Eq. 4 distance (deg)")
    # the same distance in metres (a degree of latitude: 111.32 km) for robot builders
    ax2.secondary_yaxis("right", functions=(lambda d: d * 111_320.0,
                                            lambda m: m / 111_320.0)).set_ylabel("≈ metres")
    ax2.set_xlabel("time since the log's start (s)")
    return _png(plt, fig)


def fig_satellites(run: Any) -> bytes:
    """The paper's Fig. 7: satellites used over time, real against the ensemble's band."""
    import numpy as np

    plt, fig, ax = _figure()
    x = run.t_unix_s - run.t_unix_s[0]
    _band(ax, x, run.sim_sats_used, "tab:blue", "simulated (2.5-97.5 %, median)")
    if run.final_sats_used is not None:
        _band(ax, x, run.final_sats_used, "tab:green", "calibrated")
    if np.isfinite(run.real_sats_used).any():
        ax.step(x, run.real_sats_used, where="post", color="tab:red", linewidth=0.9,
                label="real")
    else:
        _empty(ax, "the real log gives no count of satellites used")
    ax.set_xlabel("time since the log's start (s)")
    ax.set_ylabel("satellites used")
    ax.legend(fontsize=8)
    ax.set_title(f"{run.name}: satellites over time (paper Fig. 7)")
    return _png(plt, fig)


def fig_sky_disagreement(az_deg: Any, el_deg: Any, disagreement: Any) -> bytes:
    """Skyplot of satellite passes coloured by real minus simulated tracked share (red: the
    real receiver tracks what the simulation loses)."""
    import numpy as np

    plt, fig, ax = _figure(6.5, 6.0, polar=True)
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_rlim(0, 90)
    ax.set_rticks([0, 30, 60, 90], labels=["90°", "60°", "30°", "0°"])
    az, el, d = (np.asarray(a, dtype=float) for a in (az_deg, el_deg, disagreement))
    if az.size == 0:
        _empty(ax, "no GSV in the real logs")
    else:
        sc = ax.scatter(np.radians(az), 90.0 - el, c=d, cmap="RdBu_r", vmin=-1, vmax=1, s=40,
                        edgecolors="black", linewidths=0.3)
        fig.colorbar(sc, ax=ax, shrink=0.7, label="real - simulated tracked share")
    ax.set_title("per-pass tracking disagreement", pad=18)
    return _png(plt, fig)


def fig_error_cdf(real_err_m: Any, sim_err_m: Any) -> bytes:
    """The real horizontal error's CDF against the ensemble's 2.5-97.5 % band of CDFs.

    real_err_m : (n,) metres; sim_err_m : (s, m) metres (NaN ignored)"""
    import numpy as np

    plt, fig, ax = _figure(6.5, 4.2)
    r = np.asarray(real_err_m, dtype=float)
    r = np.sort(r[np.isfinite(r)])
    sims = [np.sort(s[np.isfinite(s)]) for s in np.asarray(sim_err_m, dtype=float)]
    sims = [s for s in sims if s.size]
    if r.size == 0 or not sims:
        _empty(ax, "no fix")
        return _png(plt, fig)
    grid = np.linspace(0.0, max(np.percentile(r, 99), max(np.percentile(s, 99) for s in sims)),
                       200)
    cdfs = np.stack([np.searchsorted(s, grid, side="right") / s.size for s in sims])
    lo, hi = np.percentile(cdfs, [2.5, 97.5], axis=0)
    ax.fill_between(grid, lo, hi, color="tab:blue", alpha=0.3, label="simulated band")
    ax.plot(r, np.arange(1, r.size + 1) / r.size, color="tab:red", label="real")
    ax.set_xlabel("horizontal error (m)")
    ax.set_ylabel("share of fixes")
    ax.legend(fontsize=8)
    ax.set_title("error CDF")
    return _png(plt, fig)


def fig_autocorrelation(lags_s: Any, real: Any, sim: Any, final: Any = None) -> bytes:
    """Autocorrelation of the horizontal error: real against the ensemble's band."""
    import numpy as np

    plt, fig, ax = _figure(6.5, 4.2)
    lags = np.asarray(lags_s, dtype=float)
    if not np.isfinite(np.asarray(real, dtype=float)).any():
        _empty(ax, "no error series")
        return _png(plt, fig)
    _band(ax, lags, sim, "tab:blue", "simulated")
    if final is not None:
        _band(ax, lags, final, "tab:green", "calibrated")
    ax.plot(lags, real, color="tab:red", label="real")
    ax.axhline(np.exp(-1.0), color="gray", linewidth=0.6, linestyle=":")
    ax.set_xlabel("lag (s)")
    ax.set_ylabel("autocorrelation")
    ax.legend(fontsize=8)
    ax.set_title("error autocorrelation (1/e dotted)")
    return _png(plt, fig)


def fig_waterfall(labels: Sequence[str], gaps: Sequence[float]) -> bytes:
    """The held-out gap through each added effect: the baseline bar, then each step's change."""
    import numpy as np

    plt, fig, ax = _figure(max(5.0, 1.2 * len(labels) + 2), 4.2)
    g = np.asarray(gaps, dtype=float)
    x = np.arange(len(g))
    bottoms = np.concatenate([[0.0], np.minimum(g[:-1], g[1:])])
    heights = np.concatenate([[g[0]], np.abs(np.diff(g))])
    colors = ["tab:gray"] + ["tab:green" if d <= 0 else "tab:red" for d in np.diff(g)]
    ax.bar(x, heights, bottom=bottoms, color=colors, width=0.6)
    for i, v in enumerate(g):
        ax.text(i, v, f"{v:.3f}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x, labels, rotation=30, ha="right")
    ax.set_ylabel("held-out gap (lower is better)")
    ax.set_title("the gap through each added effect")
    return _png(plt, fig)


def fig_confusion(names: Sequence[str], firsts: Sequence[str], counts: Any) -> bytes:
    """Self-check confusion matrix: injected effect (rows) x effect ranked first (columns)."""
    import numpy as np

    c = np.asarray(counts, dtype=float)
    plt, fig, ax = _figure(1.0 + 0.55 * len(firsts) + 2, 1.0 + 0.45 * len(names) + 1)
    ax.imshow(c, cmap="Blues")
    ax.set_xticks(range(len(firsts)), firsts, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    for i in range(c.shape[0]):
        for j in range(c.shape[1]):
            if c[i, j]:
                ax.text(j, i, f"{c[i, j]:.0f}", ha="center", va="center", fontsize=8)
    ax.set_xlabel("ranked first")
    ax.set_ylabel("injected")
    ax.set_title("self-check: injected x ranked first")
    return _png(plt, fig)
