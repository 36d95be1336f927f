"""The device's NMEA bytes, epoch by epoch, for the flight-stack and ROS driver models
(``test_nmea_px4.py``, ``test_nmea_ardupilot.py``, ``test_nmea_navsat.py``): ``virtualgps replay``
run in this process with its fixes CSV, each epoch's bytes kept as the writer renders them."""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from virtualgps.device import nmea as nmea_pkg

ORIGIN = "52.14,11.64,100"  # the open-sky origin of the drives (scene metres about it)


@dataclass
class Replay:
    """One replay: per epoch its time, bytes, fixes CSV row (as written) and GST sigmas (lat,
    lon, alt m; None without GST); the profile's format and rate."""

    t_unix_s: np.ndarray
    epoch_bytes: list[bytes]
    rows: list[dict[str, str]]
    sigma_m: np.ndarray | None
    fmt: nmea_pkg.NmeaFormat
    rate_hz: float

    def by_utc(self) -> dict[float, int]:
        """Epoch index by the seconds of its UTC day (as the sentences print it)."""
        return {round(float(t) % 86400.0, 3): k for k, t in enumerate(self.t_unix_s)}


def replay_epochs(tmp: Path, poses: Path, profile: str, rate_hz: float,
               sentences: list[str] | None = None, tag: str = "") -> Replay:
    """``virtualgps replay POSES --profile P --scene none --origin ... --rate R --out X.nmea
    --fixes X.csv [--config C]`` (C sets ``[nmea] sentences``) in-process, keeping each epoch's
    bytes as the writer renders them (``render_batch``), checked against the file; the files
    go in ``tmp``, named by ``tag``, profile, rate and sentences."""
    from virtualgps.cli import main

    name = f"{tag}{profile}-{rate_hz:g}-{'-'.join(sentences or ['default'])}"
    out, fixes = tmp / f"{name}.nmea", tmp / f"{name}.csv"
    args = ["replay", str(poses), "--profile", profile, "--scene", "none", "--origin", ORIGIN,
            "--rate", str(rate_hz), "--out", str(out), "--fixes", str(fixes)]
    if sentences:
        cfg = tmp / f"{name}.toml"
        cfg.write_text(f"[nmea]\nsentences = {json.dumps(list(sentences))}\n")
        args += ["--config", str(cfg)]
    seen, real = [], nmea_pkg.render_batch

    def spy(fixes_, fmt, *a, **k):
        epochs = real(fixes_, fmt, *a, **k)
        sig = fixes_.gst_sigma_m() if "GST" in fmt.sentences else None
        sig = None if sig is None else np.stack([sig["lat_m"], sig["lon_m"], sig["alt_m"]], 1)
        seen.append((fixes_.t_unix_s.copy(), epochs, sig, fmt))
        return epochs

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(nmea_pkg, "render_batch", spy)
        assert main(args) == 0
    epoch_bytes = [b for _, e, _, _ in seen for b in e]
    assert b"".join(epoch_bytes) == out.read_bytes()
    with open(fixes, newline="") as f:
        rows = list(csv.DictReader(f))
    t = np.concatenate([s[0] for s in seen])
    assert len(rows) == len(t) == len(epoch_bytes)
    sig = None if seen[0][2] is None else np.concatenate([s[2] for s in seen])
    return Replay(t, epoch_bytes, rows, sig, seen[0][3], rate_hz)
