"""The command line: replay output against independent NMEA parsers and its own CSV, determinism,
sky output, settings precedence and one-line errors naming the bad file."""

from __future__ import annotations

import csv
import json
import logging
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pynmea2
import pytest
from pynmeagps import NMEAReader

from virtualgps.cli import main
from virtualgps.run import config, replay
from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR

T0 = 1490712768.0  # 2017-03-28T14:52:48Z, the 2017-03-28 Magdeburg waypoint logs


def write_walk(path: Path, n: int = 400, dt_s: float = 0.5) -> Path:
    """A straight walk across the Magdeburg campus between buildings, 1.5 m above the ground."""
    with open(path, "w") as f:
        for i in range(n):
            f.write(json.dumps({"t": T0 + i * dt_s, "x": -60.0 + 0.7 * i * dt_s / 0.5,
                                "y": -80.0, "z": 55.0}) + "\n")
    return path


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("replay")
    poses = write_walk(tmp / "walk.jsonl")
    out, fixes = tmp / "out.nmea", tmp / "fixes.csv"
    args = ["replay", str(poses), "--out", str(out), "--fixes", str(fixes), "--seed", "4"]
    assert main(args) == 0
    return poses, out, fixes


def _epochs(nmea_path: Path) -> list[list[str]]:
    """Sentences grouped by epoch (a GGA starts each epoch)."""
    epochs: list[list[str]] = []
    for line in nmea_path.read_bytes().split(b"\r\n"):
        if not line:
            continue
        text = line.decode("ascii")
        if text.startswith("$GPGGA"):
            epochs.append([])
        epochs[-1].append(text)
    return epochs


def test_every_sentence_parses_and_equals_the_fixes_csv(replayed):
    _, out, fixes_csv = replayed
    raw = out.read_bytes()
    assert raw.endswith(b"\r\n") and b"\n\n" not in raw
    rows = list(csv.DictReader(open(fixes_csv)))
    epochs = _epochs(out)
    assert len(epochs) == len(rows) > 100
    n_fix = 0
    for sentences, row in zip(epochs, rows, strict=True):
        kinds = [s[3:6] for s in sentences]
        n_gsv = kinds.count("GSV")
        assert kinds == ["GGA", "GSA"] + ["GSV"] * n_gsv + ["RMC", "VTG"]
        parsed = {}
        for s in sentences:
            # pynmeagps with checksum validation, and pynmea2 with check=True.
            msg = NMEAReader.parse(s.encode() + b"\r\n", validate=1)
            p2 = pynmea2.parse(s, check=True)
            parsed.setdefault(msg.msgID, []).append((msg, p2))
        gga, gga2 = parsed["GGA"][0]
        rmc, _ = parsed["RMC"][0]
        gsa, _ = parsed["GSA"][0]
        t = float(row["t_unix_s"])
        assert float(gga2.timestamp.hour * 3600 + gga2.timestamp.minute * 60
                     + gga2.timestamp.second + gga2.timestamp.microsecond / 1e6) == pytest.approx(
                         t % 86400.0, abs=1e-3)
        assert int(gga.quality) == int(row["quality"])
        used = [int(p) for p in row["used_prns"].split()] if row["used_prns"] else []
        gsa_prns = [int(getattr(gsa, f"svid_{i:02d}")) for i in range(1, 13)
                    if getattr(gsa, f"svid_{i:02d}") not in ("", None)]
        assert sorted(gsa_prns) == sorted(used)
        gsv_prns = [int(getattr(m, f"svid_{k:02d}")) for m, _ in parsed["GSV"]
                    for k in range(1, 5) if getattr(m, f"svid_{k:02d}", "") not in ("", None)]
        assert len(gsv_prns) == int(row["sats_in_view"]) == int(gsa2_total(parsed))
        assert set(used) <= set(gsv_prns)
        if row["quality"] != "0":
            n_fix += 1
            assert int(gga.numSV) == int(row["sats_used"]) == len(used)
            assert gga.lat == pytest.approx(float(row["lat_deg"]), abs=1e-4 / 60 * 1.01)
            assert gga.lon == pytest.approx(float(row["lon_deg"]), abs=1e-4 / 60 * 1.01)
            assert gga.alt == pytest.approx(float(row["alt_msl_m"]), abs=0.051)
            assert gga.sep == pytest.approx(float(row["geoid_sep_m"]), abs=0.051)
            assert gga.HDOP == pytest.approx(float(row["hdop"]), abs=0.0051)
            assert float(gsa.PDOP) == pytest.approx(float(row["pdop"]), abs=0.0051)
            assert rmc.status == "A"
            # (half the printed 0.01 kn, plus the CSV's 0.0005 m/s rounding: 0.001 kn)
            assert rmc.spd == pytest.approx(float(row["speed_mps"]) * 3600 / 1852, abs=0.0061)
        else:
            assert rmc.status == "V"
    assert n_fix > len(rows) // 2


def gsa2_total(parsed) -> int:
    """The satellites-in-view count every GSV sentence carries."""
    totals = {int(m.numSV) for m, _ in parsed["GSV"]}
    assert len(totals) == 1
    return totals.pop()


def test_replay_is_byte_identical_for_the_same_seed_and_differs_for_another(replayed, tmp_path):
    poses, out, _ = replayed
    again = tmp_path / "again.nmea"
    assert main(["replay", str(poses), "--out", str(again), "--seed", "4"]) == 0
    assert again.read_bytes() == out.read_bytes()
    other = tmp_path / "other.nmea"
    assert main(["replay", str(poses), "--out", str(other), "--seed", "5"]) == 0
    assert other.read_bytes() != out.read_bytes()


def test_replay_does_not_depend_on_the_chunk_size(replayed, tmp_path, monkeypatch):
    poses, out, _ = replayed
    monkeypatch.setattr(replay, "CHUNK_EPOCHS", 7)
    small = tmp_path / "small.nmea"
    assert main(["replay", str(poses), "--out", str(small), "--seed", "4"]) == 0
    assert small.read_bytes() == out.read_bytes()


def test_an_error_in_the_sky_thread_reaches_the_caller(replayed, tmp_path, monkeypatch):
    # Multi-chunk replays compute the next chunk's sky in a second thread: its error must
    # surface, after the chunks before it were written.
    poses, out, _ = replayed
    monkeypatch.setattr(replay, "CHUNK_EPOCHS", 7)
    calls = []
    real = replay.compute_sky

    def failing(rx, t, ant):
        calls.append(threading.current_thread().name)
        if len(calls) == 3:
            raise RuntimeError("sky failed")
        return real(rx, t, ant)

    monkeypatch.setattr(replay, "compute_sky", failing)
    part = tmp_path / "part.nmea"
    with pytest.raises(RuntimeError, match="sky failed"):
        main(["replay", str(poses), "--out", str(part), "--seed", "4"])
    assert all(name.startswith("virtualgps-sky") for name in calls)
    # The two chunks before it are there, as in the full run.
    assert part.read_bytes() and out.read_bytes().startswith(part.read_bytes())


def test_an_interrupted_replay_says_how_far_it_got_and_leaves_whole_epochs(tmp_path):
    import re
    import signal
    import time

    poses = write_walk(tmp_path / "long.jsonl", n=20_000)  # 10,000 s: ~100,000 epochs at 10 Hz
    out = tmp_path / "o.nmea"
    # A shell's background job starts with SIGINT ignored, and a child inherits that (Python
    # then installs no KeyboardInterrupt handler): restore the default, as a terminal has it.
    proc = subprocess.Popen([sys.executable, "-m", "virtualgps", "replay", str(poses), "--rate",
                             "10", "--out", str(out)], stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60.0
    while not (out.exists() and out.stat().st_size) and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    m = re.fullmatch(r"virtualgps: replay interrupted: (\d+) of (\d+) epochs written to (.+)",
                     last)
    assert m and m.group(3) == str(out), last
    data = out.read_bytes()
    assert 0 < int(m.group(1)) < int(m.group(2))
    assert data.count(b"$GPGGA") == int(m.group(1)) and data.endswith(b"\r\n")


FAULTS = """
import resource, sys
import numpy as np
from virtualgps.run.replay import keep_freed_memory
applied = keep_freed_memory() if sys.argv[1] == "keep" else None
np.ones(1)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):  # a chunk's temporaries: twenty 2 MB blocks alive at once, then freed
    blocks = [np.ones(262144) for _ in range(20)]
    del blocks
print(applied, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_long_replays_reuse_freed_memory_instead_of_faulting_in_new_pages():
    out = {}
    for mode in ("keep", "default"):
        res = subprocess.run([sys.executable, "-c", FAULTS, mode], capture_output=True,
                             text=True, check=True)
        applied, faults = res.stdout.split()
        out[mode] = (applied, int(faults))
    assert out["keep"][0] == "True"
    # By default the heap is trimmed after each round, and the next round's 40 MB are new
    # pages (~10,000 faults a round); kept, only the first round faults.
    assert out["default"][1] > 10 * 10_000
    assert out["keep"][1] < out["default"][1] / 5


def test_start_time_shifts_the_log(replayed, tmp_path):
    poses, _, _ = replayed
    fixes = tmp_path / "f.csv"
    assert main(["replay", str(poses), "--out", str(tmp_path / "o.nmea"), "--fixes", str(fixes),
                 "--start-time", "2017-03-28T15:00:00Z"]) == 0
    rows = list(csv.DictReader(open(fixes)))
    assert float(rows[0]["t_unix_s"]) == config.parse_time("2017-03-28T15:00:00Z")


def test_sky_json_lists_states_and_plot_draws(tmp_path, capsys):
    png = tmp_path / "sky.png"
    assert main(["sky", "--time", "2017-03-28T14:52:48Z", "--at=-60,-80,55", "--json",
                 "--plot", str(png)]) == 0
    rows = json.loads(capsys.readouterr().out)
    states = {r["state"] for r in rows}
    assert rows and states <= {"visible", "blocked", "nlos", "attenuated", "below_mask"}
    for r in rows:
        assert set(r) == {"system", "prn", "az_deg", "el_deg", "state", "cn0_dbhz"}
        assert r["system"] == "GPS" and 1 <= r["prn"] <= 32
        assert 0 <= r["el_deg"] <= 90 and 0 <= r["az_deg"] < 360
        # a signal arrives directly, off a facade or through foliage; a blocked one has none
        assert (r["cn0_dbhz"] is not None) == (r["state"] in ("visible", "nlos", "attenuated"))
        assert (r["state"] == "below_mask") == (r["el_deg"] < 5.0)
    # between the campus buildings: some lines of sight are blocked, received off a facade
    assert "nlos" in states
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sky_lists_every_system_of_its_tle_sets_with_nmea_ids(tmp_path, capsys, caplog):
    sets = [str(BUNDLED_EPHEMERIS_DIR / f"{g}-2017-03-28.tle")
            for g in ("gps-ops", "glo-ops", "galileo")]
    args = ["sky", "--scene", "none", "--lla", "52.14,11.64,100", "--time",
            "2017-03-28T14:52:48Z", "--json"] + [f"--tle={p}" for p in sets]
    assert main(args) == 0
    rows = json.loads(capsys.readouterr().out)
    by = {}
    for r in rows:
        by.setdefault(r["system"], []).append(r["prn"])
    assert set(by) == {"GPS", "GLONASS", "Galileo"}
    assert all(1 <= p <= 32 for p in by["GPS"]) and all(65 <= p <= 88 for p in by["GLONASS"])
    assert all(1 <= p <= 36 for p in by["Galileo"])  # as GAGSV writes them (NMEA 4.11)
    assert main(args + ["--systems", "GLONASS"]) == 0
    assert {r["system"] for r in json.loads(capsys.readouterr().out)} == {"GLONASS"}
    # without --tle, each system's bundled set nearest the time
    caplog.set_level(logging.INFO)
    assert main(args[:8] + ["--systems", "GPS,Galileo"]) == 0
    picked = capsys.readouterr()
    assert {r["system"] for r in json.loads(picked.out)} == {"GPS", "Galileo"}
    assert "galileo-2017-03-28.tle (a bundled set" in caplog.text
    assert main(args[:8] + ["--systems", "BeiDou"]) == 2
    assert "no beidou TLE set is at hand: give one with --tle" in capsys.readouterr().err
    # beside another system, a system with no set at hand is left out with a warning
    assert main(args[:8] + ["--systems", "GPS,BeiDou"]) == 0
    assert {r["system"] for r in json.loads(capsys.readouterr().out)} == {"GPS"}
    assert "BeiDou satellites left out (no beidou TLE set is at hand" in caplog.text
    assert main(args[:8] + ["--systems", "QZSS"]) == 2
    assert "no QZSS TLE sets are bundled" in capsys.readouterr().err
    assert main(args + ["--systems", "Glonas"]) == 2
    assert "--systems: unknown satellite system 'Glonas'" in capsys.readouterr().err
    # the receivers track GPS: a GLONASS set alone is refused with a reason
    poses = write_walk(tmp_path / "walk.jsonl", n=10)
    assert main(["replay", str(poses), "--out", str(tmp_path / "o.nmea"), "--tle",
                 sets[1]]) == 2
    assert "holds no GPS satellite (GLONASS: 24)" in capsys.readouterr().err


def test_sky_open_sky_blocks_nothing(capsys):
    assert main(["sky", "--scene", "none", "--lla", "0,0,0", "--time", "2020-05-14T22:00:00Z",
                 "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert "blocked" not in {r["state"] for r in rows} and len(rows) >= 6


def test_precedence_defaults_profile_config_flags(tmp_path):
    cfg_file = tmp_path / "c.toml"
    cfg_file.write_text('profile = "usarsim"\nseed = 9\n[noise]\nmax_noise_m = 6.0\n'
                        '[georef]\nlat_deg = 10.0\nlon_deg = 20.0\nalt_hae_m = 5.0\n')
    cfg = config.resolve({"config": str(cfg_file)})
    assert cfg.profile.name == "usarsim" and cfg.seed == 9
    assert cfg.profile.noise.max_noise_m == 6.0 and cfg.profile.noise.min_noise_m == 2.0
    assert cfg.origin == (10.0, 20.0, 5.0)
    cfg = config.resolve({"config": str(cfg_file), "seed": 3, "profile": "ideal", "rate": 5.0,
                          "origin": "1,2,3"})
    assert cfg.seed == 3 and cfg.profile.name == "ideal" and cfg.profile.rate_hz == 5.0
    assert cfg.profile.noise.max_noise_m == 6.0  # config still overrides the (new) profile
    assert cfg.origin == (1.0, 2.0, 3.0)
    assert config.resolve({}).profile.name == "holux-m1000"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "virtualgps", *args], capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize(
    ("name", "content", "expect"),
    [
        ("bad.jsonl", '{"t": 1, "x": 1, "y": 2, "z": 3}\n{"t": 2, "x": 1, "y": "two", "z": 3}\n',
         "bad.jsonl:2"),
        ("bad.csv", "t,x,y\n1,2,3\n", "bad.csv"),
    ],
)
def test_bad_pose_log_is_one_error_line_naming_file_and_line(tmp_path, name, content, expect):
    p = tmp_path / name
    p.write_text(content)
    r = _cli("replay", str(p), "--out", str(tmp_path / "o.nmea"))
    assert r.returncode != 0
    lines = [ln for ln in r.stderr.splitlines() if "error" in ln]
    assert len(lines) == 1 and expect in lines[0], r.stderr
    assert "Traceback" not in r.stderr


def test_bad_tle_profile_and_config_are_clear_errors(tmp_path):
    tle = tmp_path / "bad.tle"
    tle.write_text("GPS X (PRN 1)\n1 24876U 97035A   17084.80454529  .00000006  00000-0  0000\n")
    r = _cli("sky", "--tle", str(tle), "--time", "2017-03-26T00:00:00Z")
    assert r.returncode != 0 and "bad.tle:2" in r.stderr and "Traceback" not in r.stderr
    bad_cfg = tmp_path / "c.toml"
    bad_cfg.write_text("[noise]\nmax_noise_m = 'loud'\n")
    r = _cli("sky", "--config", str(bad_cfg))
    assert r.returncode != 0 and "c.toml:2" in r.stderr and "max_noise_m" in r.stderr
    bad_cfg.write_text("seed = 1\n[nmea]\ntalker = 5\n")
    r = _cli("sky", "--config", str(bad_cfg))
    assert r.returncode != 0 and "c.toml:3" in r.stderr and "talker" in r.stderr
    r = _cli("sky", "--rate", "50")
    assert r.returncode != 0 and "rate" in r.stderr and "Traceback" not in r.stderr
    bad_cfg.write_text("[noise\n")
    r = _cli("sky", "--config", str(bad_cfg))
    assert r.returncode != 0 and "c.toml" in r.stderr and "line 1" in r.stderr
    r = _cli("sky", "--profile", "no-such-profile")
    assert r.returncode != 0 and "no-such-profile" in r.stderr


def test_ideal_replay_reports_the_true_position(tmp_path):
    poses = write_walk(tmp_path / "w.jsonl", n=40)
    fixes = tmp_path / "f.csv"
    assert main(["replay", str(poses), "--out", str(tmp_path / "o.nmea"), "--fixes", str(fixes),
                 "--profile", "ideal"]) == 0
    rows = [r for r in csv.DictReader(open(fixes)) if r["quality"] != "0"]
    assert rows
    for r in rows:
        assert float(r["lat_deg"]) == pytest.approx(float(r["truth_lat_deg"]), abs=1e-9)
        alt_hae = float(r["alt_msl_m"]) + float(r["geoid_sep_m"])
        assert alt_hae == pytest.approx(float(r["truth_alt_hae_m"]), abs=1e-3)
    assert np.isclose(float(rows[0]["speed_mps"]), 1.4)


def test_sky_reports_nlos_with_its_weaker_cn0(tmp_path, capsys):
    cfg = tmp_path / "nlos.toml"
    cfg.write_text("[nlos]\nenabled = false\n")
    args = ["sky", "--time", "2017-03-28T14:52:48Z", "--at=-60,-80,55", "--json"]
    assert main(args) == 0  # holux-m1000 models nlos
    rows = {r["prn"]: r for r in json.loads(capsys.readouterr().out)}
    assert main(args + ["--config", str(cfg)]) == 0
    plain = {r["prn"]: r for r in json.loads(capsys.readouterr().out)}
    nlos = [p for p, r in rows.items() if r["state"] == "nlos"]
    assert nlos, "a reflected satellite between the campus buildings"
    for p in nlos:
        assert plain[p]["state"] == "blocked" and plain[p]["cn0_dbhz"] is None
        assert rows[p]["cn0_dbhz"] is not None
    for p, r in rows.items():  # the effect changes nothing else
        if p not in nlos:
            assert r == plain[p]


def _tle_line(body: str) -> str:
    """A TLE line with its mod-10 checksum (digits count their value, '-' counts 1)."""
    body = body.ljust(68)
    return body + str(sum(int(c) if c.isdigit() else c == "-" for c in body) % 10)


BAD_ARGUMENTS = [
    # (arguments with {tmp}, {walk}, {empty}, {binary}, {iss}; exit 0 or the error's words)
    (["sky", "--scene", "none", "--lla", "-33.86,151.21,50"], 0),
    (["sky", "--scene", "none", "--origin", "-33.86,151.21,50", "--at", "-3,-4,1.5"], 0),
    (["sky", "--scene", "none", "--lla", "95,11,0"], "out of range"),
    (["sky", "--scene", "none", "--lla", "-33.86,151.21"], "LAT,LON,ALT_HAE"),
    (["sky", "--scene", "none", "--origin", "-91,0,0"], "out of range"),
    (["sky", "--tle", "{iss}"], "no PRN"),
    (["sky", "--profile", "no-such-profile"], "no-such-profile"),
    (["replay", "{walk}", "--out", "{tmp}/no/such/dir/x.nmea"], "No such file or directory"),
    (["replay", "{walk}", "--out", "{tmp}"], "Is a directory"),
    (["replay", "{walk}", "--out", "{tmp}/x.nmea", "--fixes", "{tmp}"], "Is a directory"),
    (["replay", "{empty}", "--out", "{tmp}/x.nmea"], "no poses"),
    (["replay", "{binary}", "--out", "{tmp}/x.nmea"], "binary.jsonl:1"),
    (["replay", "{tmp}", "--out", "{tmp}/x.nmea"], "Is a directory"),
    (["replay", "{walk}", "--out", "{tmp}/x.nmea", "--origin", "-33.86,151.21,50",
      "--scene", "none"], 0),
    (["run", "--duration", "1", "--poses", "{tmp}/no-such.jsonl"], "No such file or directory"),
    (["run", "--duration", "0", "--poses", "demo"], "--duration must be positive"),
    (["run", "--duration", "-1", "--poses", "demo"], "--duration must be positive"),
    (["replay", "{walk}", "--out", "{tmp}/x.nmea", "--seed", "-5"], "non-negative integer"),
    (["replay", "{walk}", "--out", "{tmp}/x.nmea", "--config", "{seedcfg}"],
     "seed must be a non-negative integer"),
]


@pytest.mark.parametrize(("args", "expect"), BAD_ARGUMENTS, ids=lambda v: " ".join(v)
                         if isinstance(v, list) else str(v))
def test_bad_arguments_are_one_clear_line_and_valid_ones_run(tmp_path, args, expect):
    """Issue #9: every subcommand against bad arguments and paths: one line on stderr naming
    the problem and a non-zero exit, never a traceback; negative coordinates work as typed."""
    files = {"tmp": tmp_path, "walk": write_walk(tmp_path / "walk.jsonl", n=6),
             "empty": tmp_path / "empty.jsonl", "binary": tmp_path / "binary.jsonl",
             "iss": tmp_path / "iss.tle", "seedcfg": tmp_path / "seed.toml"}
    files["empty"].write_bytes(b"")
    files["seedcfg"].write_text("seed = 1.5\n")
    files["binary"].write_bytes(b"\xff\xfe\x00{\"t\": 1}\n")
    files["iss"].write_text("ISS (ZARYA)\n"
                            + _tle_line("1 25544U 98067A   17084.52385417  .00002182  00000-0  "
                                        "40864-4 0  999") + "\n"
                            + _tle_line("2 25544  51.6420 239.0547 0007205 315.9837 156.5627 "
                                        "15.54163513 4861") + "\n")
    r = _cli(*[a.format(**files) for a in args])
    assert "Traceback" not in r.stderr, r.stderr
    if expect == 0:
        assert r.returncode == 0, r.stderr
        return
    errors = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert r.returncode != 0 and len(errors) == 1 and expect in errors[0], r.stderr


def test_a_live_run_says_where_poses_go_and_when_none_has_come(tmp_path, monkeypatch, caplog):
    """A user who starts `run` and sends nothing must learn where poses are expected, and
    after a while that none has arrived (else: a receiver without a fix and no word why)."""
    from virtualgps import cli

    monkeypatch.setattr(cli, "NO_POSE_WARNING_S", 0.5)
    args = ["run", "--scene", "none", "--origin", "52.14,11.64,100", "--rate", "5",
            "--link", str(tmp_path / "gps"), "--duration", "1.5"]
    with caplog.at_level("INFO", logger="virtualgps"):
        assert main([*args, "--poses", "udp://127.0.0.1:0"]) == 0
    said = [r.getMessage() for r in caplog.records]
    where = [m for m in said if m.startswith("poses: udp://127.0.0.1:")]
    assert len(where) == 1 and "no fix before the first" in where[0], said
    port = re.match(r"poses: udp://127\.0\.0\.1:(\d+),", where[0])
    assert port and int(port[1]) > 0  # the port bound, which a sender needs
    assert sum("no pose has arrived on udp://127.0.0.1:" in m for m in said) == 1
    caplog.clear()
    with caplog.at_level("INFO", logger="virtualgps"):
        assert main([*args, "--poses", "demo"]) == 0
    assert not any(r.getMessage().startswith(("poses:", "no pose")) for r in caplog.records)


def test_a_run_whose_line_cannot_carry_its_rate_says_so_and_counts_the_loss(tmp_path, caplog):
    """10 Hz at 9600 baud with a client reading: the line warning, and the closing line counts
    the epochs dropped unread; a run nobody reads counts none (nobody missed them)."""
    from virtualgps.run import live

    live._LINE_WARNED.clear()
    link = tmp_path / "gps"
    got = bytearray()

    def read() -> None:
        for _ in range(200):
            if link.exists():
                break
            threading.Event().wait(0.02)
        fd = os.open(link, os.O_RDONLY | os.O_NOCTTY)
        try:
            while chunk := os.read(fd, 4096):
                got.extend(chunk)
        except OSError:
            pass  # EIO: the daemon closed the pty
        finally:
            os.close(fd)

    args = ["run", "--scene", "none", "--origin", "52.14,11.64,100", "--poses", "demo",
            "--rate", "10", "--link", str(link), "--duration", "2.5"]
    reader = threading.Thread(target=read)
    reader.start()
    with caplog.at_level("INFO", logger="virtualgps"):
        assert main([*args, "--baud", "9600"]) == 0
    reader.join(timeout=10)
    said = [r.getMessage() for r in caplog.records]
    assert any("needs" in m and "the 9600-baud line carries" in m for m in said), said
    dropped = re.search(r"stopped after (\d+) epochs .*, (\d+) dropped unread\)", said[-1])
    assert dropped and int(dropped[2]) > int(dropped[1]) // 2, said[-1]
    assert got.count(b"$GPGGA") < int(dropped[1]) - int(dropped[2]) + 2  # what got through
    caplog.clear()
    with caplog.at_level("INFO", logger="virtualgps"):
        assert main([*args, "--baud", "115200"]) == 0  # no reader now
    assert "dropped" not in caplog.records[-1].getMessage()


@pytest.mark.parametrize(("duration", "rate", "epochs"), [("1", "5", 5), ("1.5", "2", 3)])
def test_a_run_of_s_seconds_sends_s_times_rate_epochs(tmp_path, caplog, duration, rate, epochs):
    """`--duration S` sends the epochs due within S s: S × rate of them, wherever in the second
    the run starts (a wall-clock timer sent 3 or 4 in 3 s, as it raced the whole seconds)."""
    args = ["run", "--scene", "none", "--origin", "52.14,11.64,100", "--poses", "demo",
            "--rate", rate, "--link", str(tmp_path / "gps"), "--duration", duration]
    with caplog.at_level("INFO", logger="virtualgps"):
        assert main(args) == 0
    assert f"stopped after {epochs} epochs" in caplog.records[-1].getMessage()


def test_a_run_counts_its_duration_from_the_first_epoch_however_long_the_set_up(
        tmp_path, caplog, monkeypatch):
    """A set-up that goes on past the receivers' first epoch (a fresh install's first imports)
    does not add one: `--duration 1` at 5 Hz is 5 epochs. (Counted from the clock read just
    before the loop, the epoch already due made it 6; a fresh venv's test saw 4 in 3 s.)"""
    from virtualgps.run.fleet import run as fleet_run

    build = fleet_run.build_fleet

    def slow_build(*args, **kwargs):
        fleet = build(*args, **kwargs)
        first_unix_s = min(r.t_next_unix_s for r in fleet.receivers)
        while fleet.clock.now_unix_s() < first_unix_s + 0.06:  # (0.3 of a period late)
            time.sleep(0.01)
        return fleet

    monkeypatch.setattr(fleet_run, "build_fleet", slow_build)
    args = ["run", "--scene", "none", "--origin", "52.14,11.64,100", "--poses", "demo",
            "--rate", "5", "--link", str(tmp_path / "gps"), "--duration", "1"]
    with caplog.at_level("INFO", logger="virtualgps"):
        assert main(args) == 0
    assert "stopped after 5 epochs" in caplog.records[-1].getMessage()


def test_a_long_gap_run_logs_where_it_is_when_its_output_is_not_a_terminal(monkeypatch):
    """`gap` into a log or a pipe (CI, nohup) writes a plain progress line at most every 15 s,
    and nothing in a run shorter than that, so its one error line or its result stays alone;
    on a terminal it keeps one line up to date and clears it before the result."""
    import io

    from virtualgps import cli

    clock = [100.0]
    monkeypatch.setattr(cli.time, "monotonic", lambda: clock[0])
    log = io.StringIO()
    status = cli._GapStatus(log)
    status("reading")
    clock[0] += 14.0
    status("baseline: 50 seeds")
    assert log.getvalue() == ""
    clock[0] += 2.0
    status("choosing effects: 3 selection(s) under way")
    status("choosing effects: 2 selection(s) under way")
    status.clear()
    assert log.getvalue() == "virtualgps: choosing effects: 3 selection(s) under way\n"

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    term = Terminal()
    status = cli._GapStatus(term)
    status("x" * 200)
    status("y")
    status.clear()
    assert term.getvalue() == "\r\x1b[K" + "x" * 120 + "\r\x1b[Ky" + "\r\x1b[K"
