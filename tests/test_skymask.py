"""Sky masks (``[sky_mask]``, the learned part of ``foliage``): the bin lookup by hand, the
receiver attenuating or blocking exactly the masked satellite, per-cell masks, and setting
errors that name the file, line and key."""

from __future__ import annotations

import json

import numpy as np
import pynmeagps
import pytest

from tests.test_receiver import GEOREF, FixedSky
from virtualgps.cli import main, sky_rows
from virtualgps.device import nmea
from virtualgps.exceptions import InputFileError
from virtualgps.receiver.core import simulate
from virtualgps.receiver.definition import Receiver
from virtualgps.receiver.profiles import load_profile
from virtualgps.receiver.skyview import compute_sky
from virtualgps.receiver.state import ReceiverState
from virtualgps.sky import skymask
from virtualgps.tomlfile import read_toml

INF = float("inf")
# Five satellites in 90 x 30 deg bins: PRN 1 alone in (el 0-30, az 0-90), PRN 3 alone in
# (el 30-60, az 180-270).
SKY = FixedSky([45.0, 135.0, 200.0, 300.0, 100.0], [20.0, 15.0, 40.0, 25.0, 75.0])
CLEAR = [0.0, 0.0, 0.0, 0.0]


def _mask(atten_db, **over):
    return {"sky_mask": {"enabled": True, "az_bin_deg": 90.0, "el_bin_deg": 30.0,
                         "atten_db": atten_db, **over}}


def _run(prof, n_t=1, pos=(0.0, 0.0, 0.0), seed=1):
    rx = Receiver(profile=prof, ephemeris=SKY, scene=None, georef=GEOREF)
    t = 1.49e9 + np.arange(n_t, dtype=float)
    enu = np.broadcast_to(np.asarray(pos, float), (n_t, 3))
    return simulate(rx, t, enu, np.zeros((n_t, 3)), np.ones(n_t, bool), ReceiverState(),
                    np.random.default_rng(seed))[0]


def _gsa_prns(fixes, i=0):
    text = nmea.epoch_sentences(fixes, i, nmea.NmeaFormat()).decode()
    for line in text.splitlines():
        m = pynmeagps.NMEAReader.parse(line, validate=pynmeagps.VALCKSUM, msgmode=pynmeagps.GET)
        if m.msgID == "GSA":
            return {getattr(m, f"svid_{k:02d}") for k in range(1, 13)} - {""}  # PRNs, int
    raise AssertionError("no GSA")


def test_lookup_bins_by_hand():
    mask = load_profile("ideal", _mask([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]])).sky_mask
    az = np.array([[0.0, 89.999, 90.0, 359.9999, -1e-17, 720.0 + 95.0, 10.0, 10.0, np.nan]])
    el = np.array([[0.0, 29.999, 30.0, 45.0, 10.0, 10.0, 61.0, 90.0, 10.0]])
    got = skymask.attenuation_db(mask, az, el, np.zeros((1, 3)))
    # rows above the two given (el >= 60) are clear; el 90 falls in the top row
    np.testing.assert_array_equal(got, [[1.0, 1.0, 6.0, 8.0, 4.0, 2.0, 0.0, 0.0, 0.0]])


def test_cells_pick_their_grid_by_floor_of_position():
    prof = load_profile("ideal", _mask([CLEAR], cell_m=10.0,
                                       cells={"1,-1": [[9.0, 0.0, 0.0, 0.0]]}))
    az, el = np.full((4, 1), 45.0), np.full((4, 1), 10.0)
    ant = np.array([[15.0, -5.0, 0.0], [10.0, -10.0, 9.0], [9.99, -5.0, 0.0], [15.0, 0.0, 0.0]])
    assert skymask.cell_of(ant, 10.0)[0].tolist() == [1, 1, 0, 1]
    got = skymask.attenuation_db(prof.sky_mask, az, el, ant)
    np.testing.assert_array_equal(got[:, 0], [9.0, 9.0, 0.0, 0.0])


def test_mask_bin_attenuates_exactly_that_satellite():
    over = {"cn0_tracking": {"enabled": True, "fade_sigma_db": 0.0, "acq_dbhz": 10.0,
                             "track_dbhz": 5.0}}
    plain = _run(load_profile("ideal", over), n_t=4)
    masked_prof = load_profile("ideal", {**over, **_mask([[12.5, 0, 0, 0]])})
    masked = _run(masked_prof, n_t=4)
    drop = plain.cn0_dbhz[-1] - masked.cn0_dbhz[-1]
    np.testing.assert_allclose(drop, [12.5, 0.0, 0.0, 0.0, 0.0], atol=1e-12)
    # the sky command shows it as attenuated, the others as visible
    rx = Receiver(profile=masked_prof, ephemeris=SKY, scene=None, georef=GEOREF)
    rows = sky_rows(rx, compute_sky(rx, np.array([1.49e9]), np.zeros((1, 3))))
    assert {r["prn"]: r["state"] for r in rows} == {1: "attenuated", 2: "visible",
                                                    3: "visible", 4: "visible", 5: "visible"}


@pytest.mark.parametrize("value", [INF, 20.0])
def test_blocking_bin_removes_the_satellite_from_gsa(value):
    # PRN 3 (el 40, az 200): bin (el 30-60, az 180-270); block_db 20 makes 20 dB a wall too
    fixes = _run(load_profile("ideal", _mask([CLEAR, [0, 0, value, 0]], block_db=20.0)))
    assert fixes.quality[0] == 1 and fixes.sats_used[0] == 4
    assert _gsa_prns(fixes) == {1, 2, 4, 5}
    assert fixes.in_view[0, 2] and np.isnan(fixes.cn0_dbhz[0, 2])  # GSV lists it, no SNR
    just_below = _run(load_profile("ideal", _mask([CLEAR, [0, 0, 19.9, 0]], block_db=20.0)))
    assert _gsa_prns(just_below) == {1, 2, 3, 4, 5}


def test_per_cell_mask_applies_only_in_its_cell():
    prof = load_profile("ideal", _mask([], cell_m=10.0, cells={"1,0": [[INF, 0, 0, 0]]}))
    inside = _run(prof, pos=(15.0, 5.0, 0.0))
    outside = _run(prof, pos=(5.0, 5.0, 0.0))
    assert _gsa_prns(inside) == {2, 3, 4, 5}
    assert _gsa_prns(outside) == {1, 2, 3, 4, 5}


def test_sky_command_shows_masked_satellites(tmp_path, capsys):
    cfg = tmp_path / "mask.toml"
    rows = ", ".join(["[" + ", ".join(["inf"] * 36) + "]"] + ["[" + ", ".join(["0"] * 36) + "]"])
    cfg.write_text(f"[sky_mask]\nenabled = true\nel_bin_deg = 30.0\natten_db = [{rows}]\n")
    assert main(["sky", "--scene", "none", "--lla", "0,0,0", "--time", "2020-05-14T22:00:00Z",
                 "--profile", "ideal", "--config", str(cfg), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    low = [r for r in out if 5.0 <= r["el_deg"] < 30.0]
    assert low and all(r["state"] == "blocked" and r["cn0_dbhz"] is None for r in low)
    assert all(r["state"] == "visible" for r in out if r["el_deg"] >= 30.0)


@pytest.mark.parametrize(
    ("table", "line", "words"),
    [
        ('az_bin_deg = 90.0\nel_bin_deg = 30.0\natten_db = [[0, 1, 2]]\n', 4,
         "sky_mask.atten_db row 1 has 3 values; expected 4"),
        ('az_bin_deg = 90.0\nel_bin_deg = 30.0\natten_db = [[0, 0, 0, 0]] \n'
         'block_db = 0.0\n', 5, "sky_mask.block_db must be > 0"),
        ('az_bin_deg = 90.0\nel_bin_deg = 45.0\natten_db = [[0,0,0,0],[0,0,0,0],[0,0,0,0]]\n', 4,
         "sky_mask.atten_db has 3 rows, more than the 2 elevation bins"),
        ('az_bin_deg = 90.0\nel_bin_deg = 30.0\natten_db = [[0, -1, 0, 0]]\n', 4,
         "sky_mask.atten_db row 1 column 2 must be an attenuation >= 0 dB"),
        ('az_bin_deg = 90.0\nel_bin_deg = 30.0\natten_db = [[0, nan, 0, 0]]\n', 4,
         "row 1 column 2"),
        ('az_bin_deg = 90.0\nel_bin_deg = 30.0\natten_db = [0, 0, 0, 0]\n', 4,
         "sky_mask.atten_db must be a list of at most 3 rows"),
        ('az_bin_deg = 7.0\n', 2, "sky_mask.az_bin_deg must divide 360 deg into whole bins"),
        ('el_bin_deg = "ten"\n', 2, "sky_mask.el_bin_deg must be a number"),
        ('az_bin_deg = 90.0\nel_bin_deg = 30.0\n[sky_mask.cells]\n"1,2" = [[0, 0, 0, 0]]\n', 4,
         "sky_mask.cells needs sky_mask.cell_m > 0"),
        ('az_bin_deg = 90.0\nel_bin_deg = 30.0\ncell_m = 5.0\n[sky_mask.cells]\n'
         '"1;2" = [[0, 0, 0, 0]]\n', 6, 'sky_mask.cells."1;2": a cell is written "i,j"'),
        ('az_bin_deg = 90.0\nel_bin_deg = 30.0\ncell_m = 5.0\n[sky_mask.cells]\n'
         '"0,0" = [[0, 0, 0, 0]]\n"-1,3" = [[0, 0, 0]]\n', 7,
         'sky_mask.cells."-1,3" row 1 has 3 values; expected 4'),
    ],
)
def test_bad_sky_mask_names_file_line_and_key(tmp_path, table, line, words):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[sky_mask]\n" + table)
    with pytest.raises(InputFileError) as exc:
        load_profile("ideal", read_toml(cfg), cfg)
    msg = str(exc.value)
    assert msg.startswith(f"{cfg}:{line}: ") and words in msg, msg
