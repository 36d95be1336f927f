"""One rule picks the TLE set (issue #21): ``--tle`` wins, else the set whose epoch lies nearest
the run's start among the scene's, the bundled and the fetched sets; ``run`` and ``replay`` say
which in one line, and choose as :func:`virtualgps.sky.skytime.choose_tle_set` does. Also: a plain
install draws figures, yet importing the command never imports matplotlib."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from virtualgps.exceptions import ConfigError
from virtualgps.run.config import parse_time
from virtualgps.sky import ephemeris as eph
from virtualgps.sky import skytime

REPO = Path(__file__).resolve().parents[1]
EPH = REPO / "ephemeris"
MAGDEBURG = REPO / "scenes" / "magdeburg-campus"
# The bundled sets' epoch centres (ephemeris/README.md): 2017-03-25T16:08, 2017-03-26T14:13
# (the file of 03-28) and 2020-05-15T02:36.
SET_0325, SET_0326, SET_2020 = "gps-ops-2017-03-26.tle", "gps-ops-2017-03-28.tle", \
    "gps-ops-2020-05-14T22Z.tle"
T_0328 = parse_time("2017-03-28T14:52:48Z")  # the Magdeburg waypoint logs


@pytest.fixture
def sets(tmp_path, monkeypatch):
    """A bundled folder of its own (the 03-26 and 2020 sets), an empty cache, and the 03-25
    set as the scene's: every candidate under the test's control."""
    bundled = tmp_path / "bundled"
    bundled.mkdir()
    for name in (SET_0326, SET_2020):
        shutil.copy(EPH / name, bundled / name)
    (bundled / "gps-ops-NORAD-PRN.t").write_text("not a TLE set, and not a candidate\n")
    monkeypatch.setattr(eph, "BUNDLED_EPHEMERIS_DIR", bundled)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    scene_tle = tmp_path / "scene" / "scene.tle"
    scene_tle.parent.mkdir()
    shutil.copy(EPH / SET_0325, scene_tle)
    return bundled, scene_tle, tmp_path / "cache" / "virtualgps" / "tle"


def _cache(folder: Path, source: Path, fetched_unix_s: float) -> Path:
    """Put ``source`` in the TLE cache as ``virtualgps ephemeris fetch`` would."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"gps-ops-{int(fetched_unix_s)}.tle"
    shutil.copy(source, path)
    path.with_suffix(".json").write_text(json.dumps(
        {"url": "https://example.org/gps.tle", "fetched_unix_s": fetched_unix_s,
         "epoch_center_unix_s": eph.load_tle(source).epoch_center_unix_s, "n_sat": 31}))
    return path


def test_explicit_tle_wins(sets):
    _, scene_tle, _ = sets
    path, line = skytime.choose_tle_set("my.tle", scene_tle, T_0328)
    assert path == Path("my.tle") and line == "ephemeris: --tle my.tle"


def test_the_nearest_epoch_wins_among_the_scene_and_bundled_sets(sets):
    bundled, scene_tle, _ = sets
    path, line = skytime.choose_tle_set(None, scene_tle, T_0328)
    assert path == bundled / SET_0326, line
    assert line == (f"ephemeris: {SET_0326} (a bundled set; epoch 2017-03-26, 2.0 days from the "
                    "run's start, the nearest of 3 sets)")
    path, line = skytime.choose_tle_set(None, scene_tle, parse_time("2017-03-11T00:00:00Z"))
    assert path == scene_tle and "(the scene's set; epoch 2017-03-25, 14.7 days" in line
    assert skytime.choose_tle_set(None, scene_tle, parse_time("2020-05-14T22:00Z"))[0] == \
        bundled / SET_2020
    # A live run (no start time) starts now: the newest set is the nearest.
    assert skytime.choose_tle_set(None, scene_tle, None)[0] == bundled / SET_2020
    assert skytime.choose_tle_set(None, None, T_0328)[0] == bundled / SET_0326


def test_fetched_sets_are_candidates_and_ties_go_scene_then_fetched_then_bundled(sets):
    bundled, scene_tle, cache = sets
    fetched = _cache(cache, EPH / SET_2020, parse_time("2020-05-16T00:00Z"))
    path, line = skytime.choose_tle_set(None, scene_tle, parse_time("2020-05-14T22:00Z"))
    assert path == fetched, line  # the same epoch as the bundled 2020 set: the fetched one
    assert "(a TLE set fetched " in line and "https://example.org/gps.tle" in line
    assert "the nearest of 4 sets" in line
    # The scene's set against a bundled copy of it, and against a fetched one.
    shutil.copy(scene_tle, bundled / "copy-of-the-scene-set.tle")
    _cache(cache, scene_tle, parse_time("2017-03-27T00:00Z"))
    path, line = skytime.choose_tle_set(None, scene_tle, parse_time("2017-03-11T00:00:00Z"))
    assert path == scene_tle and "the scene's set" in line, line


def test_each_system_gets_its_own_nearest_set_and_one_without_any_is_left_out(sets):
    """:func:`skytime.choose_system_sets` (run, replay, gap and the self-check's trials): GPS
    among the scene's and the bundled sets, GLONASS among its own group's alone; BeiDou and
    QZSS, of which nothing is at hand here, are named as missing, not raised."""
    bundled, scene_tle, _ = sets
    shutil.copy(EPH / "glo-ops-2017-03-28.tle", bundled / "glo-ops-2017-03-28.tle")
    found, missing = skytime.choose_system_sets("GRCJ", parse_time("2017-03-11T00:00:00Z"),
                                                scene_tle)
    assert [path for path, _ in found] == [scene_tle, bundled / "glo-ops-2017-03-28.tle"]
    assert "(the scene's set;" in found[0][1] and "the nearest of 1 sets" in found[1][1]
    assert [name for name, _ in missing] == ["BeiDou", "QZSS"]
    assert "no beidou TLE set is at hand" in str(missing[0][1])
    assert "no QZSS TLE sets are bundled" in str(missing[1][1])
    assert skytime.choose_system_sets("R", T_0328, scene_tle)[0][0][0].name.startswith("glo-ops")


def test_unreadable_candidates_are_skipped(sets):
    bundled, scene_tle, _ = sets
    scene_tle.write_text("this is no TLE set\n")
    (bundled / "broken.tle").write_text("1 24876U 97035A   17084.80454529  .00000006  0000\n")
    (bundled / "gone.tle").symlink_to(bundled / "missing.tle")
    path, line = skytime.choose_tle_set(None, scene_tle, parse_time("2017-03-11T00:00:00Z"))
    assert path == bundled / SET_0326 and "the nearest of 2 sets" in line, line
    assert skytime.choose_tle_set(None, bundled / "missing.tle", T_0328)[0] == bundled / SET_0326
    for name in (SET_0326, SET_2020):
        (bundled / name).unlink()
    with pytest.raises(ConfigError, match="give --tle"):
        skytime.choose_tle_set(None, scene_tle, T_0328)


def test_epochs_are_read_once_per_file_version(sets, monkeypatch):
    _, scene_tle, _ = sets
    loads = []
    real = eph.load_ephemeris_file
    monkeypatch.setattr(eph, "load_ephemeris_file",
                        lambda p, *a: loads.append(p) or real(p, *a))
    first = skytime.epoch_center_unix_s(scene_tle)
    assert skytime.epoch_center_unix_s(scene_tle) == first and len(loads) == 1
    shutil.copy(EPH / SET_2020, scene_tle)  # a new file at the same path: read again
    st = scene_tle.stat()
    os.utime(scene_tle, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    assert skytime.epoch_center_unix_s(scene_tle) == pytest.approx(
        parse_time("2020-05-15T02:36:05Z"), abs=1.0)
    assert len(loads) == 2


def test_a_february_log_gets_the_february_set_of_shared_data(shared_data, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    feb = shared_data / "magdeburg-campus" / "tle" / "gps-ops.2017-02-02.current.tle"
    path, line = skytime.choose_tle_set(None, feb, parse_time("2017-02-03T12:00:00Z"))
    assert path == feb and "the scene's set; epoch 2017-02-0" in line, line
    # A March log keeps the bundled March set.
    assert skytime.choose_tle_set(None, feb, T_0328)[0].name == SET_0326


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    # (The tests' own empty TLE cache, XDG_CACHE_HOME of conftest, is inherited.)
    return subprocess.run([sys.executable, "-m", "virtualgps", *args], capture_output=True,
                          text=True, timeout=120, cwd=cwd)


def _ephemeris_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.startswith("virtualgps: ephemeris: ")]
    assert len(lines) == 1, stderr  # said once
    return lines[0].removeprefix("virtualgps: ")


def test_replay_and_run_choose_as_choose_tle_set_and_say_so(tmp_path):
    from virtualgps.sky.scene import load_scene

    scene_tle = load_scene(MAGDEBURG).tle_path
    poses = tmp_path / "walk.jsonl"
    poses.write_text("".join(json.dumps({"t": T_0328 + i, "lat": 52.14007, "lon": 11.64324,
                                         "alt": 97.0}) + "\n" for i in range(5)))
    rep = _cli("replay", str(poses), "--scene", str(MAGDEBURG), "--out", "walk.nmea",
               cwd=tmp_path)
    assert rep.returncode == 0, rep.stderr
    path, line = skytime.choose_tle_set(None, scene_tle, T_0328)
    assert path.name == SET_0326 and _ephemeris_line(rep.stderr) == line
    # run, on the same day: the device is still stdout's first line.
    run = _cli("run", "--duration", "1", "--poses", "demo", "--link", "./gps", "--scene",
               str(MAGDEBURG), "--start-time", "2017-03-28T14:52:48Z", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[0].startswith("device: ")
    assert _ephemeris_line(run.stderr).startswith(f"ephemeris: {SET_0326} (a bundled set;")
    # --tle wins, and says so.
    given = _cli("replay", str(poses), "--scene", str(MAGDEBURG), "--out", "walk.nmea", "--tle",
                 str(EPH / SET_2020), cwd=tmp_path)
    assert _ephemeris_line(given.stderr) == f"ephemeris: --tle {EPH / SET_2020}"


def test_importing_the_command_imports_no_matplotlib():
    # Every module, as the command imports them lazily; figures import matplotlib when drawn.
    code = ("import importlib, pkgutil, sys, virtualgps, virtualgps.cli\n"
            "assert 'matplotlib' not in sys.modules, 'virtualgps.cli'\n"
            "for m in pkgutil.walk_packages(virtualgps.__path__, 'virtualgps.'):\n"
            "    if m.name != 'virtualgps.__main__':\n"
            "        importlib.import_module(m.name)\n"
            "        assert 'matplotlib' not in sys.modules, m.name\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
