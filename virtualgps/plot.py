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


def skyplot(rows: Sequence[dict[str, Any]], path: Path, title: str = "") -> None:
    """Draw a polar skyplot of satellites (north up, azimuth clockwise, zenith at the centre).

    Parameters
    ----------
    rows : dicts with ``prn``, ``az_deg``, ``el_deg``, ``state`` (as ``virtualgps sky`` prints)
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
    seen = set()
    for r in rows:
        color, marker = STATE_STYLE.get(r["state"], ("black", "."))
        label = r["state"] if r["state"] not in seen else None
        seen.add(r["state"])
        theta, radius = np.radians(r["az_deg"]), 90.0 - r["el_deg"]
        ax.plot(theta, radius, marker=marker, color=color, markersize=10, linestyle="", label=label)
        ax.annotate(
            str(r["prn"]), (theta, radius), textcoords="offset points", xytext=(6, 6), fontsize=9
        )
    ax.legend(loc="lower left", bbox_to_anchor=(-0.1, -0.12), ncol=3, frameon=False)
    ax.set_title(title or "sky", pad=18)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
