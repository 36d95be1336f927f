"""The package as users get it (issue #9): a wheel built from the checkout, installed into a
fresh virtual environment, run from a folder that knows nothing of the repository."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _run(cmd: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    # (Without PYTHONPATH: a checkout on it would be imported instead of the installed wheel.)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\n{r.stdout}\n{r.stderr}"
    return r


@pytest.mark.slow
def test_wheel_runs_outside_the_checkout(tmp_path):
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist), str(REPO)],
         cwd=tmp_path)
    (wheel,) = dist.glob("virtualgps-*.whl")
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    _run([str(py), "-m", "pip", "install", "-q", str(wheel)], cwd=tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    exe = str(env_dir / "bin" / "virtualgps")
    # The installed package, not the checkout, is what runs.
    where = _run([str(py), "-c", "import virtualgps.bundled as b; print(b.bundled_dir('scenes'))"],
                 cwd=elsewhere).stdout.strip()
    assert where.startswith(str(env_dir)) and (Path(where) / "magdeburg-campus").is_dir()
    # At a fixed time (the bundled TLE set's day): at the scene's origin, between buildings,
    # the sky of "now" may leave as few as two satellites visible; this one has seven.
    sky = _run([exe, "sky", "--json", "--time", "2017-03-28T14:52:48Z"], cwd=elsewhere)
    assert sum(s["state"] == "visible" for s in json.loads(sky.stdout)) >= 4
    poses = elsewhere / "walk.jsonl"
    poses.write_text("".join(json.dumps({"t": 1490712768.0 + i, "x": -60.0 + i, "y": -80.0,
                                         "z": 55.0}) + "\n" for i in range(10)))
    _run([exe, "replay", "walk.jsonl", "--out", "walk.nmea"], cwd=elsewhere)
    assert (elsewhere / "walk.nmea").read_bytes().count(b"$GPGGA") == 10
    run = _run([exe, "run", "--duration", "3", "--poses", "demo", "--link", "./gps"],
               cwd=elsewhere, timeout=60)
    assert "stopped after 3 epochs" in run.stderr
