"""End to end: the MTK command link of ``virtualgps run`` through a real pty, probed by gpsd and
driven by a raw client.

gpsd runs without ``-b``, so it probes: with ``command_link = "mtk"`` it must identify the device
as MTK-3301 (our ``$PMTK705``) and keep reporting fixes after sending its configuration
(``$PMTK320/300/314/301/313``); with ``"none"`` it must stay on its generic NMEA0183 driver.
"""

from __future__ import annotations

import os
import select
import time
import tty
from pathlib import Path

import pytest
from test_e2e import GPSD, Daemon, watch_gpsd

pytestmark = pytest.mark.e2e

OPEN_SKY = ["--scene", "none", "--origin", "52.14,11.64,100", "--poses", "demo"]


def write_config(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "run.toml"
    path.write_text(text)
    return path


def drivers(messages: list[dict]) -> list[str]:
    return [m["driver"] for m in messages if m.get("class") == "DEVICE" and "driver" in m]


def fixes_after_mtk(messages: list[dict]) -> int:
    seen = False
    n = 0
    for m in messages:
        if m.get("class") == "DEVICE" and m.get("driver") == "MTK-3301":
            seen = True
        elif seen and m.get("class") == "TPV" and m.get("mode") == 3:
            n += 1
    return n


@pytest.mark.skipif(GPSD is None and not os.environ.get("CI"), reason="gpsd not installed")
def test_gpsd_identifies_mtk3301_and_keeps_fixing_after_configuring(tmp_path):
    assert GPSD, "gpsd must be installed in CI"
    cfg = write_config(tmp_path, 'command_link = "mtk"\n')
    daemon = Daemon(tmp_path, "--config", str(cfg), *OPEN_SKY)
    try:
        messages = watch_gpsd(tmp_path, daemon.link, 30, lambda ms: fixes_after_mtk(ms) >= 5)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    devices = [m for m in messages if m.get("class") == "DEVICE" and m.get("driver")]
    mtk_dev = [d for d in devices if d["driver"] == "MTK-3301"]
    assert mtk_dev, f"gpsd never identified MTK-3301: {drivers(messages)}; daemon: {err}"
    # gpsd's subtype is our PMTK705 release and build id.
    assert mtk_dev[0].get("subtype", "").startswith("AXN_1.30-0000")
    assert fixes_after_mtk(messages) >= 5, "no 3D fixes after gpsd configured the receiver"
    # gpsd configured us (its MTK-3301 driver sends PMTK320/300/314/301/313, then PMTK424): the
    # daemon logs the link's settings at exit, with gpsd's sentence rates.
    assert "rates=(0, 1, 0, 1, 1, 5, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0)" in err, err


@pytest.mark.skipif(GPSD is None and not os.environ.get("CI"), reason="gpsd not installed")
def test_gpsd_treats_a_silent_receiver_as_generic_nmea(tmp_path):
    assert GPSD, "gpsd must be installed in CI"
    cfg = write_config(tmp_path, 'command_link = "none"\n')
    daemon = Daemon(tmp_path, "--config", str(cfg), *OPEN_SKY)
    t_first: list[float] = []

    def done(ms: list[dict]) -> bool:
        if not t_first and "NMEA0183" in drivers(ms):
            t_first.append(time.monotonic())
        # gpsd sends its probes (the MTK one among them) within the first few sentences: give
        # it 6 s more to (wrongly) switch drivers.
        return bool(t_first) and time.monotonic() > t_first[0] + 6.0

    try:
        messages = watch_gpsd(tmp_path, daemon.link, 30, done)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    assert "NMEA0183" in drivers(messages), drivers(messages)
    assert "MTK-3301" not in drivers(messages)
    assert any(m.get("class") == "TPV" and m.get("mode") == 3 for m in messages)
    assert "MTK command link" not in err


def read_until(fd: int, buf: bytearray, pred, seconds: float) -> list[tuple[float, str]]:
    """Read lines (with their arrival time) until ``pred(lines)`` or ``seconds`` pass."""
    lines: list[tuple[float, str]] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end and not pred(lines):
        r, _, _ = select.select([fd], [], [], 0.05)
        if not r:
            continue
        buf += os.read(fd, 65536)
        now = time.monotonic()
        while b"\r\n" in buf:
            line, _, rest = bytes(buf).partition(b"\r\n")
            buf[:] = rest
            lines.append((now, line.decode("ascii", "replace")))
    return lines


def gga_quality(line: str) -> int:
    return int(line.split(",")[6])


def test_raw_client_probe_and_cold_start_on_the_pty(tmp_path):
    ttff_s = 3.0
    cfg = write_config(
        tmp_path,
        f'command_link = "mtk"\n[cold_start]\nttff_cold_s = {ttff_s}\nttff_sd_frac = 0.0\n',
    )
    daemon = Daemon(tmp_path, "--config", str(cfg), "--rate", "5", *OPEN_SKY)
    fd = os.open(daemon.link, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        buf = bytearray()
        start = read_until(
            fd, buf,
            lambda ls: sum(1 for _, ln in ls if ln.startswith("$GPGGA") and gga_quality(ln)) >= 5,
            10,
        )
        texts = [ln for _, ln in start]
        assert texts[0] == "$PMTK010,001*2E", texts[:3]  # the start-up message comes first
        # Power-on (a hot start, then acquisition): no-fix epochs, then fixes that stay.
        q = [gga_quality(ln) for ln in texts if ln.startswith("$GPGGA")]
        assert q == sorted(q) and set(q) <= {0, 1}, q

        t_sent = time.monotonic()
        os.write(fd, b"$PMTK605*31\r\n")
        probe = read_until(fd, buf, lambda ls: any(ln.startswith("$PMTK705,") for _, ln in ls), 3)
        answer = [(t, ln) for t, ln in probe if ln.startswith("$PMTK705,")]
        assert answer == [(answer[0][0], "$PMTK705,AXN_1.30,0000,HOLUX M-1000 (virtualgps),*07")]
        # Answered between epochs, not at the next one: well under the 200 ms period plus the
        # line time of one epoch (~0.13 s at 38400 baud).
        assert answer[0][0] - t_sent < 0.3

        os.write(fd, b"$PMTK103*30\r\n")
        after = read_until(fd, buf, lambda ls: False, ttff_s + 3.0)
        texts = [ln for _, ln in after]
        i_ack = texts.index("$PMTK001,103,3*32")
        assert texts[i_ack + 1] == "$PMTK010,001*2E"  # the restart is made
        q = [gga_quality(ln) for ln in texts[i_ack:] if ln.startswith("$GPGGA")]
        t_gga = [t for t, ln in after[i_ack:] if ln.startswith("$GPGGA")]
        n_nofix = q.index(1) if 1 in q else len(q)
        assert all(v == 0 for v in q[:n_nofix]) and all(v == 1 for v in q[n_nofix:])
        # About TTFF of no-fix epochs at 5 Hz (the first epochs may already be in flight).
        assert abs(n_nofix / 5.0 - ttff_s) <= 0.5, q
        assert len(q) - n_nofix >= 5, "fixes must come back after the TTFF"
        assert t_gga[-1] - t_gga[0] > ttff_s
    finally:
        os.close(fd)
        code, err = daemon.stop()
    assert code == 0, err
