"""Today's sky: ``virtualgps ephemeris fetch`` from a local HTTP server on 127.0.0.1, the cache,
and runs that pick the fetched set that fits their time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from virtualgps.sky import tlecache
from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR, default_tle_path

T_2020 = "2020-05-14T22:30:00Z"  # the bundled 2020 set's day


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # no request lines in the test output
        pass


@pytest.fixture
def server(tmp_path):
    """An HTTP server on 127.0.0.1 serving a GPS TLE set, a web page and nothing else."""
    root = tmp_path / "www"
    root.mkdir()
    (root / "gps.tle").write_bytes(default_tle_path().read_bytes())
    (root / "galileo.tle").write_bytes(
        (BUNDLED_EPHEMERIS_DIR / "galileo-2017-03-28.tle").read_bytes())
    (root / "page.html").write_text("<html><body>Service unavailable</body></html>\n")
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), partial(_Quiet, directory=str(root)))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    httpd.server_close()
    thread.join()


def _cli(cache: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, XDG_CACHE_HOME=str(cache))
    return subprocess.run([sys.executable, "-m", "virtualgps", *args], capture_output=True,
                          text=True, timeout=120, env=env)


def test_fetch_keeps_good_sets_only_and_runs_use_the_one_that_fits(server, tmp_path):
    cache = tmp_path / "cache"
    r = _cli(cache, "ephemeris", "fetch", "--url", f"{server}/gps.tle")
    assert r.returncode == 0, r.stderr
    (tle,) = (cache / "virtualgps" / "tle").glob("gps-ops-*.tle")
    assert tle.read_bytes() == default_tle_path().read_bytes()
    meta = json.loads(tle.with_suffix(".json").read_text())
    assert meta["url"] == f"{server}/gps.tle" and meta["n_sat"] == 31
    # A web page, a missing file and a closed port: one line each, the good set kept.
    for url, words in ((f"{server}/page.html", "did not give a GPS TLE set"),
                       (f"{server}/missing.tle", "404"),
                       ("http://127.0.0.1:9/gps.tle", "cannot fetch")):
        r = _cli(cache, "ephemeris", "fetch", "--url", url)
        errors = [ln for ln in r.stderr.splitlines() if "error" in ln]
        assert r.returncode != 0 and len(errors) == 1 and words in errors[0], r.stderr
        assert "Traceback" not in r.stderr
    assert [c.path for c in tlecache.cached_sets(cache / "virtualgps" / "tle")] == [tle]
    listed = _cli(cache, "ephemeris", "list")
    assert str(tle) in listed.stdout and "31 satellites" in listed.stdout
    # The sky at the set's time comes from it (and says so); the sky of 2017 does not.
    lla = ["--scene", "none", "--lla", "37.42,-122.08,0", "--json"]
    fetched = _cli(cache, "sky", "--time", T_2020, *lla)
    assert fetched.returncode == 0 and "TLE set fetched" in fetched.stderr, fetched.stderr
    given = _cli(tmp_path / "empty", "sky", "--time", T_2020, "--tle", str(default_tle_path()),
                 *lla)
    assert json.loads(fetched.stdout) == json.loads(given.stdout)
    old = _cli(cache, "sky", "--time", "2017-03-28T14:52:48Z", *lla)
    assert old.returncode == 0 and "TLE set fetched" not in old.stderr
    # A replay dates itself by its log's first pose.
    log = tmp_path / "drive.jsonl"
    log.write_text("".join(json.dumps({"t": 1589495400.0 + i, "lat": 37.42, "lon": -122.08,
                                       "alt": 0.0}) + "\n" for i in range(5)))
    rep = _cli(cache, "replay", str(log), "--scene", "none", "--out", str(tmp_path / "d.nmea"))
    assert rep.returncode == 0 and "TLE set fetched" in rep.stderr, rep.stderr


def test_cached_sets_come_newest_fetch_first(tmp_path):
    # (Which set a run takes, fetched or not: tests/test_tlechoice.py.)
    sets = []
    for i, epoch in enumerate((1.0e9, 1.0e9 + 10 * 86400.0)):
        path = tmp_path / f"gps-ops-{i}.tle"
        path.write_text("")
        path.with_suffix(".json").write_text(json.dumps(
            {"url": "u", "fetched_unix_s": epoch + 3600.0, "epoch_center_unix_s": epoch,
             "n_sat": 31}))
        sets.append(path)
    (tmp_path / "gps-ops-2.json").write_text("{}")  # no set beside it, no fields: left out
    assert [c.path for c in tlecache.cached_sets(tmp_path)] == sets[::-1]


def test_each_group_is_fetched_on_its_own_and_sky_takes_it(server, tmp_path):
    cache = tmp_path / "cache"
    r = _cli(cache, "ephemeris", "fetch", "--groups", "galileo", "--url", f"{server}/galileo.tle")
    assert r.returncode == 0 and "18 satellites" in r.stdout, r.stderr
    (tle,) = (cache / "virtualgps" / "tle").glob("galileo-*.tle")
    # a GPS set is not a Galileo set; --url names one group
    bad = _cli(cache, "ephemeris", "fetch", "--groups", "galileo", "--url", f"{server}/gps.tle")
    assert bad.returncode != 0 and "did not give a Galileo TLE set" in bad.stderr
    two = _cli(cache, "ephemeris", "fetch", "--groups", "galileo,glo-ops", "--url", "x")
    assert two.returncode == 2 and "--url fetches one group" in two.stderr
    listed = _cli(cache, "ephemeris", "list")
    assert str(tle) in listed.stdout and "18 satellites" in listed.stdout
    sky = _cli(cache, "sky", "--time", "2017-03-28T14:52:48Z", "--scene", "none", "--lla",
               "52.14,11.64,100", "--json", "--systems", "Galileo")
    assert sky.returncode == 0 and "TLE set fetched" in sky.stderr, sky.stderr
    assert {r["system"] for r in json.loads(sky.stdout)} == {"Galileo"}
