"""Reading real receiver logs and their truths for the gap tool: what real logs hold (noise,
bad checksums, clocks not yet set, logs without dates or GGA), the forms they are kept in
(Android GnssLogger's records, gpsd's JSON, u-blox UBX), truth specs, and a log-vs-truth clock
offset found or said."""

from __future__ import annotations

import json
import math
import os
import shutil
import struct
import subprocess

import numpy as np
import pytest

from virtualgps.exceptions import InputFileError
from virtualgps.gap import effects as fx
from virtualgps.gap import where
from virtualgps.gap.ingest import estimate_time_offset_s, load_run, parse_truth, read_real_log
from virtualgps.poses.pose import PoseTrack
from virtualgps.receiver.profiles import build_profile


@pytest.fixture(autouse=True)
def stop_workers():
    """Local worker pools live for the process; a test ends with none (no leaked pipes)."""
    yield
    from virtualgps.gap import jobs

    jobs.shutdown()


def sentence(body: str) -> str:
    """One NMEA sentence with its checksum from its body (no ``$``, no ``*``)."""
    from virtualgps.device.nmea import nmea_checksum

    return f"${body}*{nmea_checksum(body)}"


def test_ingest_survives_what_real_logs_hold(tmp_path):
    lines = [
        "\x00\x8a\x13binary noise",
        sentence("GPGGA,235958.000,5207.0000,N,01138.0000,E,1,08,0.9,50.0,M,44.0,M,,"),
        sentence("GPRMC,235958.000,A,5207.0000,N,01138.0000,E,0.0,0.0,281117,,,A"),
        "2:52:16:587 Nachm. 03/28/17 - " + sentence("GPGSV,1,1,02,05,40,100,35,07,20,200,"),
        sentence("GLGSV,1,1,01,70,30,90,30"),
        sentence("GNGSA,A,3,05,07,,,,,,,,,,,1.5,0.9,1.2"),
        "$GPGGA,235959.000,5207.0001,N,01138.0000,E,1,08,0.9,50.0,M,44.0,M,,*00",  # checksum
        "$GPGGA,235959.000,5207.00",  # truncated
        sentence("GPGGA,000001.000,5207.0002,N,01138.0000,E,7,08,0.9,50.0,M,44.0,M,,"),
        sentence("GPGGA,000001.000,5207.0002,N,01138.0000,E,7,08,0.9,50.0,M,44.0,M,,"),
        sentence("PMTK010,001"),
    ]
    p = tmp_path / "log.nmea"
    p.write_bytes("\r\n".join(lines).encode("latin-1"))
    ep, skipped, sentences, dated_by = read_real_log(p)
    assert len(ep) == 2
    assert ep.t_unix_s[1] - ep.t_unix_s[0] == pytest.approx(3.0)  # across midnight
    assert list(ep.quality) == [1, 7]
    assert skipped["bad_checksum"] == 1 and skipped["truncated"] == 1
    assert skipped["not_nmea"] == 1 and skipped["not_used"] == 1
    assert sentences["GSV"] == 2 and sentences["GGA"] == 3 and dated_by == "log"
    run = load_run(p, "static:52.1166,11.6333,94")
    assert run.has_gsv and run.has_cn0 and run.has_gsa and run.quality_codes == {1: 1, 7: 1}


def test_a_log_without_checksums_is_read_and_said_to_be(tmp_path):
    """NMEA 0183 makes the checksum optional, and some loggers strip it: a log in which no line
    carries one is read without (it was "no GGA, RMC or GLL sentence"), and the report says so;
    where the sentences carry one, a line without is one cut short and is skipped."""
    from virtualgps.gap.ingest import ingest_notes

    body = ["GPGGA,12000{k},5207.000{k},N,01138.0000,E,1,08,0.9,50.0,M,44.0,M,,",
            "GPRMC,12000{k},A,5207.000{k},N,01138.0000,E,0.0,0.0,010318,,,A"]
    p = tmp_path / "bare.nmea"
    p.write_text("junk\n" + "".join(f"${b.format(k=k)}\n" for k in range(5) for b in body))
    run = load_run(p, "static")
    assert len(run.epochs) == 5 and not run.epochs.checksummed
    np.testing.assert_allclose(run.epochs.lat_deg, 52.0 + (7.0 + 1e-4 * np.arange(5)) / 60.0)
    assert run.sentences == {"GGA": 5, "RMC": 5}
    assert any("no sentence carries a checksum" in n for n in ingest_notes(
        {"checksummed": run.epochs.checksummed}))
    assert ingest_notes({"checksummed": True}) == []
    # one checksummed line among them: the bare ones are taken as cut short
    p.write_text(sentence(body[1].format(k=9)) + "\n" + p.read_text())
    ep, skipped, sentences, _ = read_real_log(p)
    assert len(ep) == 1 and ep.checksummed
    assert skipped["truncated"] == 10 and sentences == {"RMC": 1}


def test_epochs_before_a_receivers_clock_is_set_are_left_out(shared_data, tmp_path):
    """mtk-3301.log counts from its RTC's 23:59:46 (dated 050180) until its first fix at
    08:14:36: those five epochs, hours from every fix, are left out and counted; the two
    epochs just before the first fix stay (a start-up). A log whose fixes span weeks is one
    clear error, not a time grid that fills the memory."""
    from datetime import UTC, datetime

    from virtualgps.exceptions import InputFileError

    ep, skipped, *_ = read_real_log(shared_data / "gpsd-mtk" / "mtk-3301.log")
    assert skipped["epochs_clock_not_set"] == 5
    assert datetime.fromtimestamp(ep.t_unix_s[0], UTC) == datetime(2008, 8, 23, 8, 14, 33,
                                                                    591000, tzinfo=UTC)
    assert list(ep.quality) == [0, 0, 1, 1, 1, 1]
    fix = "GPGGA,{},5207.0000,N,01138.0000,E,1,08,0.9,50.0,M,44.0,M,,"
    weeks = [sentence(fix.format("120000.000")),
             sentence("GPRMC,120000.000,A,5207.0000,N,01138.0000,E,0.0,0.0,010318,,,A"),
             sentence(fix.format("120001.000")),
             sentence("GPRMC,120001.000,A,5207.0000,N,01138.0000,E,0.0,0.0,150318,,,A")]
    p = tmp_path / "weeks.nmea"
    p.write_text("\n".join(weeks) + "\n")
    with pytest.raises(InputFileError, match="span 14 days"):
        read_real_log(p)


def test_a_log_without_dates_is_dated_by_its_truth(tmp_path):
    """A GGA-only log (no RMC or ZDA) takes the date of its truth's times: on the day that puts
    its first epoch nearest the truth's first pose (here the day before the truth's date, the
    log starting just before midnight), rolling past the midnight it crosses. With a static
    truth nothing can date it: one clear error."""
    from datetime import UTC, datetime

    from virtualgps.exceptions import InputFileError

    fix = "GPGGA,{},5207.0000,N,01138.0000,E,1,08,0.9,50.0,M,44.0,M,,"
    p = tmp_path / "gga.nmea"
    p.write_text("".join(sentence(fix.format(t)) + "\n"
                         for t in ("235958.000", "235959.000", "000000.000", "000001.000")))
    t0 = datetime(2018, 3, 1, 23, 59, 58, tzinfo=UTC).timestamp()
    truth = tmp_path / "truth.csv"
    truth.write_text("t,lat,lon,alt\n" + "".join(
        f"{t0 + k - 1.0},52.1166,11.6333,94\n" for k in range(6)))
    run = load_run(p, str(truth))
    assert run.dated_by == "truth"
    assert list(run.epochs.t_unix_s - t0) == [0.0, 1.0, 2.0, 3.0]
    ep, _, _, dated_by = read_real_log(p, near_unix_s=t0 + 86400.0 + 7200.0)
    assert dated_by == "truth" and ep.t_unix_s[0] == t0 + 86400.0
    with pytest.raises(InputFileError, match=r"no RMC or ZDA .*\(--truth static cannot\)"):
        load_run(p, "static")


def test_a_log_of_rmc_alone_has_fixes_and_says_what_it_cannot_assess(tmp_path):
    """Without GGA, an RMC position with status A is a fix (quality 1); a void RMC is none.
    Altitude and fix quality are then unknown: the vertical scatter and the DGPS share are
    listed as not assessed, not compared as zeros."""
    from types import SimpleNamespace

    from virtualgps.gap.diagnose import not_assessed

    rmc = "GPRMC,12000{},{},5207.0000,N,01138.0000,E,0.0,0.0,010318,,,A"
    p = tmp_path / "rmc.nmea"
    p.write_text("".join(sentence(rmc.format(k, "A" if k else "V")) + "\n" for k in range(4)))
    ep, _, sentences, _ = read_real_log(p)
    assert list(ep.quality) == [0, 1, 1, 1] and sentences == {"RMC": 4}
    view = SimpleNamespace(assess={"gsv": True, "cn0": True, "gsa": True, "gga": False},
                           real=SimpleNamespace(sats_used=np.ones((1, 4)), hdop=np.ones(4)),
                           reference="truth", speed_mps=np.zeros(4))
    reasons = {n["metric"]: n["reason"]
               for n in not_assessed([SimpleNamespace(view=view, info={})])}
    assert set(reasons) == {"up_p68_m", "dgps_fraction", "lag_s"}
    assert reasons["dgps_fraction"].startswith("no GGA")


def test_a_static_log_without_altitudes_is_measured_about_its_median_fix():
    """RMC or GLL alone prints no altitude. About the log's own median fix (a static run at an
    unknown point) its horizontal errors are what they are with the altitudes, and only Up is
    unknown (the median's height was NaN, and so was every error: CEP50 and R95 went missing
    from the report of the MT3339 hour with its GGA lines taken out)."""
    from dataclasses import replace
    from types import SimpleNamespace

    from virtualgps.gap.observed import Obs

    rng = np.random.default_rng(5)
    n = 300
    ones = np.ones((1, n))
    obs = Obs(lat_deg=52.1 + rng.normal(0.0, 2e-5, (1, n)),
              lon_deg=11.6 + rng.normal(0.0, 3e-5, (1, n)),
              alt_hae_m=140.0 + rng.normal(0.0, 4.0, (1, n)), quality=ones.astype(int),
              hdop=ones, sats_used=8 * ones, speed_mps=0 * ones,
              tracked=np.zeros((1, n, 0), bool), cn0_dbhz=np.zeros((1, n, 0)),
              used=np.zeros((1, n, 0), bool))
    view = SimpleNamespace(reference="median")
    with_alt = where.errors_enu(view, obs)
    without = where.errors_enu(view, replace(obs, alt_hae_m=np.full((1, n), np.nan)))
    assert np.isfinite(with_alt).all() and np.isnan(without[..., 2]).all()
    np.testing.assert_allclose(without[..., :2], with_alt[..., :2], atol=0.01)
    assert 1.0 < np.median(np.hypot(*without[0, :, :2].T)) < 5.0


def test_a_clock_offset_taken_out_at_ingest_is_said(tmp_path):
    """A log whose clock runs 30 s behind its truth's is matched at ingest (estimate_time_offset_s)
    and judged after; the terminal and the page say that it was, not only the lag that
    remains (GSDC's SPAN truth moved 30 s: -29.99 s found)."""
    from virtualgps.gap import report as rp
    from virtualgps.gap import tool

    clock = {"name": "time_offset", "kind": "clock", "run": "drive", "lag_s": -0.015,
             "blocks": 9, "interval_s": [-0.03, 0.1], "ingest_best_s": -29.99,
             "applied_s": -29.99, "what": "the fixes lag the truth by this much"}
    report = {"headline": [], "outer": {}, "design": {"scheme": "", "warnings": []},
              "runs": [], "effects": [], "located": [], "profile": "holux-m1000",
              "gap_baseline": 1.0, "causes": [clock]}
    said = "the clock of drive's log runs 29.99 s behind its truth's: taken out before judging"
    assert f"  cause: {said}" in tool.summary_lines(report)
    assert said in rp._cause_rows(report)[0]["what"]
    # what no effect explained is named on the terminal too, each metric once
    report["unexplained"] = [{"metric": "ttff_s", "segment": "all"},
                             {"metric": "hdop_median", "segment": "all"},
                             {"metric": "ttff_s", "segment": "startup"}]
    assert tool.summary_lines(report)[-1] == (
        "  unexplained (outside the final ensemble): ttff_s, hdop_median")
    report["causes"] = [dict(clock, applied_s=0.0, lag_s=1.2)]
    lines = tool.summary_lines(report)
    assert not any("the clock of" in ln for ln in lines)
    assert "  cause?: the fixes lag the truth of drive by 1.20 s: a clock offset or an output " \
        "latency" in lines
    # once the diagnosis has chosen, the lag is said as what it added reads it: a filter smooths
    # the fixes too (a clock offset does not); a pure delay and a clock offset stay aliased
    report["causes"][0]["read_as"] = ["nav_filter"]
    assert "by 1.20 s: read as a navigation filter's lag" in "\n".join(tool.summary_lines(report))
    assert "here read as a navigation filter's lag" in rp._cause_rows(report)[0]["what"]
    report["causes"][0]["or_read_as"] = ["latency"]
    assert "read as a navigation filter's lag: nav_filter was added, the fixes being smoothed " \
        "as well, which a clock offset does not do (or as latency: an equally good " \
        "explanation, see alternative)" in "\n".join(tool.summary_lines(report))
    del report["causes"][0]["or_read_as"]
    report["causes"][0]["read_as"] = ["latency"]
    assert "read as an output latency (latency was added); a log-vs-truth clock offset of the " \
        "same size moves the fixes alike" in "\n".join(tool.summary_lines(report))
    # a velocity-aided filter follows the motion and smooths only the error: added, it reads
    # no lag (the GSDC drive with a 0.3 s delay injected added one, and the lag stood unread)
    from virtualgps.gap import causes as cz

    aided = {"name": "nav_filter", "params": {"tau_s": 2.5, "velocity_aided": True}}
    assert not cz.lags_motion(aided)
    assert cz.lags_motion(dict(aided, params={"tau_s": 2.5, "velocity_aided": False}))
    assert cz.lags_motion({"name": "latency", "params": {"latency_s": 0.4}})
    report["causes"][0]["read_as"] = []
    assert ("by 1.20 s: a clock offset or an output latency: no effect that lags the fixes "
            "was added") in "\n".join(tool.summary_lines(report))


def test_bad_truth_specs_are_clear_errors():
    from virtualgps.exceptions import ConfigError

    for spec in ("static:1,2", "static:95,0,0", "no/such/file.csv"):
        with pytest.raises(ConfigError):
            parse_truth(spec)
    assert parse_truth("static:-33.86,151.21,50").lat_deg == -33.86


def test_time_offset_recovered_on_a_moving_track():
    rng = np.random.default_rng(5)
    t = 1.6e9 + np.arange(600.0)
    heading = 0.01 * t
    lat = 37.4 + np.cumsum(10 * np.cos(heading)) / 111e3
    lon = -122.1 + np.cumsum(10 * np.sin(heading)) / (111e3 * np.cos(np.radians(37.4)))
    truth = PoseTrack(t, "geodetic", np.stack([lat, lon, np.zeros_like(t)], 1),
                      np.full((600, 3), np.nan))
    noise = rng.normal(0, 3.0 / 111e3, (2, 600))
    # the real log's clock runs 7.7 s ahead of the truth's
    real_lat = np.interp(t - 7.7, t, lat) + noise[0]
    real_lon = np.interp(t - 7.7, t, lon) + noise[1]
    off, info = estimate_time_offset_s(t, real_lat, real_lon, truth)
    assert info["applied"] and off == pytest.approx(7.7, abs=0.2)
    # lags of seconds are reported (they could be the receiver's latency or its navigation
    # filter's lag), not applied
    for lag in (1.2, 3.3):
        off, info = estimate_time_offset_s(t, np.interp(t - lag, t, lat) + noise[0],
                                           np.interp(t - lag, t, lon) + noise[1], truth)
        assert off == 0.0 and not info["applied"]
        assert info["best_s"] == pytest.approx(lag, abs=0.2)


def test_a_clock_offset_beyond_the_first_window_is_found_or_said():
    """The search widens while its best lies at the grid's end: 95 s is found (the first
    window, +-30 s, ended at -29.99 s before and took that out); 900 s, beyond the widest
    window, is not taken out, and the report says why."""
    from virtualgps.gap.ingest import OFFSET_WINDOWS_S, ingest_notes

    rng = np.random.default_rng(6)
    n = 2400
    t = 1.6e9 + np.arange(float(n))
    heading = 0.6 * np.sin(t / 60.0)  # (a wavy road: no place passed twice)
    lat = 37.4 + np.cumsum(10 * np.cos(heading)) / 111e3
    lon = -122.1 + np.cumsum(10 * np.sin(heading)) / (111e3 * np.cos(np.radians(37.4)))
    truth = PoseTrack(t, "geodetic", np.stack([lat, lon, np.zeros_like(t)], 1),
                      np.full((n, 3), np.nan))
    noise = rng.normal(0, 3.0 / 111e3, (2, n))
    for shift, found in ((95.0, True), (900.0, False)):
        real = slice(1000, 1900)  # the log: 15 minutes inside the truth's 40
        off, info = estimate_time_offset_s(
            t[real], np.interp(t[real] - shift, t, lat) + noise[0, real],
            np.interp(t[real] - shift, t, lon) + noise[1, real], truth)
        assert info["applied"] is found and info["at_edge"] is not found
        if found:
            assert off == pytest.approx(shift, abs=0.2)
        else:
            assert off == 0.0 and info["searched_s"][1] == OFFSET_WINDOWS_S[-1]
            note = ingest_notes({"offset": info})[0]
            assert "the end of the 600 s searched: no offset was taken out" in note


def test_real_logs_load(shared_data):
    mt = load_run(shared_data / "mt3339-static" / "hour_test_1.txt", "static")
    assert mt.has_gsv and mt.skipped.get("not_nmea", 0) >= 1  # binary noise at the start
    first_fix = mt.epochs.t_unix_s[np.argmax(mt.epochs.quality > 0)] - mt.epochs.t_unix_s[0]
    assert 25.0 < first_fix < 40.0
    d = shared_data / "gsdc-2020-05-14-mtv"
    gs = load_run(d / "Pixel4_chipset.nmea", str(d / "SPAN_Pixel4_1Hz.nmea"))
    assert not gs.has_gsv and not gs.has_gsa and gs.quality_codes == {7: len(gs.epochs)}
    assert abs(gs.time_offset_s) < 2.0, gs.offset_info


def test_a_phone_log_kept_by_gnsslogger_reads_as_its_nmea(shared_data, tmp_path):
    """Android's GnssLogger keeps the chipset's NMEA among its own records, each sentence
    between ``NMEA,`` and ``,<Unix ms>``: the GSDC Pixel 4 drive written so gives the same
    epochs as its plain NMEA (a suffix after the checksum had made every sentence one with a
    bad checksum, and the log one without any fix)."""
    plain = shared_data / "gsdc-2020-05-14-mtv" / "Pixel4_chipset.nmea"
    header = ["#", "# Header Description:", "#",
              "# Version: v3.0.5.6 Platform: 11 Manufacturer: Google Model: Pixel 4", "#",
              "# Fix,Provider,LatitudeDegrees,LongitudeDegrees,AltitudeMeters,SpeedMps,"
              "AccuracyMeters,BearingDegrees,UnixTimeMillis", "# NMEA,NMEA,UnixTimeMillis", "#"]
    kept = list(header)
    for k, line in enumerate(plain.read_text().splitlines()):
        kept.append(f"NMEA,{line},{1589493646000 + 500 * k}")
        if k % 2:
            kept.append(f"Fix,gps,37.42358,-122.09412,-2.8,0.0,3.9,0.0,{1589493646000 + 500 * k}")
    logged = tmp_path / "gnss_log.txt"
    logged.write_text("\n".join(kept) + "\n")
    ep, skipped, sentences, _ = read_real_log(logged)
    ref, ref_skipped, ref_sentences, _ = read_real_log(plain)
    assert len(ep) == len(ref) > 1000 and sentences == ref_sentences
    np.testing.assert_array_equal(ep.t_unix_s, ref.t_unix_s)
    np.testing.assert_array_equal(ep.lat_deg, ref.lat_deg)
    np.testing.assert_array_equal(ep.alt_msl_m, ref.alt_msl_m)
    assert skipped["not_nmea"] == sum(1 for line in kept if not line.startswith("NMEA,"))
    assert {k: n for k, n in skipped.items() if k != "not_nmea"} == ref_skipped


GPSFAKE = shutil.which("gpsfake")


@pytest.mark.skipif(GPSFAKE is None and not os.environ.get("CI"), reason="gpsd not installed")
@pytest.mark.parametrize("source", ["holux-m1000", "ublox-m8n", "mt3339-static"])
def test_a_gpsd_json_log_reads_as_its_nmea(tmp_path, request, source):
    """A robot that runs gpsd keeps ``gpspipe -w``'s JSON: gpsd 3.22 itself (gpsfake) fed NMEA
    (a replay in the MTK order, holux-m1000, and in u-blox's, RMC first with GN talkers, GPS
    and GLONASS; and the shared MT3339's first 1,400 lines, a real receiver whose SBAS
    satellites have no elevation yet) reports TPVs and SKYs that read as the same epochs as the
    NMEA: times, positions to gpsd's 1e-9 degrees, altitudes, fix quality and mode, DOPs,
    satellites used and in view, and each satellite's elevation, azimuth, C/N0 and use. The
    cycles before the first fix, which gpsd 3.22 reports without a time, are counted as TPVs
    without a time (the MT3339's first 31 s); the last epoch of a cut log is left out of the
    comparison (gpsd reports the sky of the last whole cycle)."""
    assert GPSFAKE, "gpsd-clients must be installed in CI (the README's test command does)"
    from virtualgps.cli import main

    nmea, log = tmp_path / "drive.nmea", tmp_path / "drive.json"
    if source == "mt3339-static":
        hour = request.getfixturevalue("shared_data") / "mt3339-static" / "hour_test_1.txt"
        nmea.write_bytes(b"".join(hour.read_bytes().splitlines(keepends=True)[:1400]))
    else:
        poses = tmp_path / "drive.jsonl"
        poses.write_text("".join(json.dumps({"t": 1589536800.0 + 0.1 * i, "x": 0.15 * i,
                                             "y": 0.0, "z": 0.0}) + "\n" for i in range(401)))
        assert main(["replay", str(poses), "--profile", source, "--scene", "none", "--origin",
                     "52.14,11.64,100", "--out", str(nmea)]) == 0
    with open(log, "w") as f:
        subprocess.run([GPSFAKE, "-1", "-q", "-p", "-c", "0.005", "-r",
                        '?WATCH={"enable":true,"json":true}', str(nmea)], stdout=f,
                       stderr=subprocess.DEVNULL, timeout=120, check=True)
    ref, _, _, _ = read_real_log(nmea)
    got, skipped, objects, dated_by = read_real_log(log)
    first_fix_s = ref.t_unix_s[np.argmax(ref.quality > 0)] - ref.t_unix_s[0]
    assert objects["TPV"] > len(got) >= len(ref) - first_fix_s - 4
    assert objects["SKY"] >= len(got) - 1 and dated_by == "log"
    assert skipped["tpv_without_time"] >= 1
    t, i, j = np.intersect1d(ref.t_unix_s, got.t_unix_s, return_indices=True)
    assert t.size == len(got)
    i, j = i[:-1], j[:-1]
    np.testing.assert_allclose(got.lat_deg[j], ref.lat_deg[i], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.lon_deg[j], ref.lon_deg[i], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.speed_mps[j], ref.speed_mps[i], rtol=0, atol=1e-3)
    np.testing.assert_array_equal(got.prn, ref.prn)
    for name in ("alt_msl_m", "geoid_sep_m", "quality", "mode", "hdop", "pdop", "vdop",
                 "sats_used", "sats_in_view", "el_deg", "az_deg", "cn0_dbhz", "used",
                 "in_view"):
        np.testing.assert_array_equal(getattr(got, name)[j], getattr(ref, name)[i],
                                      err_msg=name)
    run = load_run(log, "static")
    assert run.has_gsv and run.has_cn0 and run.has_gsa and run.sentences["TPV"] > 0


def test_gpsd_json_of_several_devices_or_with_time_stamps(tmp_path):
    """``gpspipe -t`` puts a time stamp before each object: read past it. A log holding the
    fixes of two devices is one clear error naming them."""
    tpv = {"class": "TPV", "device": "/dev/ttyACM0", "mode": 3, "lat": 52.14, "lon": 11.64,
           "altMSL": 50.0, "altHAE": 94.0}
    lines = [f"Dec 07 16:00:{k:02d}: " + json.dumps(tpv | {"time": f"2026-12-07T16:00:{k:02d}Z",
                                                          "lat": 52.14 + 1e-6 * k})
             for k in range(5)]
    p = tmp_path / "t.json"
    p.write_text("\n".join(lines) + "\n")
    ep, skipped, objects, _ = read_real_log(p)
    assert len(ep) == 5 and objects == {"TPV": 5} and not skipped
    np.testing.assert_allclose(ep.lat_deg, 52.14 + 1e-6 * np.arange(5))
    np.testing.assert_array_equal(ep.quality, 1)
    assert np.isnan(ep.hdop).all() and (ep.sats_used == -1).all()  # no SKY: not known
    other = json.dumps(tpv | {"device": "/dev/ttyUSB1", "time": "2026-12-07T16:00:09Z"})
    p.write_text("\n".join(lines + [other]) + "\n")
    with pytest.raises(InputFileError, match="several devices .*/dev/ttyACM0, /dev/ttyUSB1"):
        read_real_log(p)


def _ubx_epoch(k: int, fix: bool = True, diff: bool = False, timed: bool = True) -> bytes:
    """NAV-PVT, NAV-DOP and NAV-SAT of one epoch ``k`` s after 2024-06-01 10:00:00 UTC, as
    pyubx2 (an independent encoder) writes them."""
    from pyubx2 import GET, UBXMessage

    itow = 540000000 + 1000 * k  # (the iTOW ties an epoch's messages; its value is not read)
    pvt = UBXMessage("NAV", "NAV-PVT", GET, iTOW=itow, year=2024, month=6, day=1, hour=10,
                     min=0, second=k, validDate=int(timed), validTime=int(timed),
                     fullyResolved=int(fix), fixType=3 if fix else 0, gnssFixOk=int(fix),
                     diffSoln=int(diff), numSV=9, lon=11.6401 + 1e-5 * k, lat=52.1405,
                     height=141250, hMSL=100250, gSpeed=5000, headMot=45.0, pDOP=1.5)
    dop = UBXMessage("NAV", "NAV-DOP", GET, iTOW=itow, hDOP=0.9, vDOP=1.2, pDOP=1.5)
    sats = ((0, 5, 40, 45, 100, 1), (6, 3, 35, 20, 200, 1), (2, 11, 0, 30, 300, 0),
            (6, 255, 30, 10, 10, 0))  # GPS 5, GLONASS slot 3, Galileo E11 (not tracked), ?
    sat = UBXMessage("NAV", "NAV-SAT", GET, iTOW=itow, version=1, numSvs=len(sats), **{
        f"{name}_{j + 1:02d}": v for j, row in enumerate(sats)
        for name, v in zip(("gnssId", "svId", "cno", "elev", "azim", "svUsed"), row,
                           strict=True)})
    return pvt.serialize() + dop.serialize() + sat.serialize()


def test_a_u_blox_ubx_log_reads_as_its_fixes(tmp_path):
    """A u-blox module logging UBX (u-center's .ubx, or a port set to UBX as flight stacks set
    it): NAV-PVT, NAV-DOP and NAV-SAT, written by pyubx2, among an NMEA TXT line and noise, read
    as epochs: times, positions, altitude and separation, fix quality (DGPS from diffSoln),
    satellites numbered as here (GLONASS slot 3 is 67, Galileo E11 311; a GLONASS slot not yet
    known is left out), C/N0 (0: not tracked) and use; a NAV-PVT whose time is not valid is
    counted. With NMEA fixes among the frames the log is read as NMEA."""
    pytest.importorskip("pyubx2")
    from virtualgps.device.nmea import nmea_checksum

    txt = "GNTXT,01,01,02,u-blox AG - www.u-blox.com"
    data = (_ubx_epoch(0, fix=False, timed=False) + b"\x00\xff\xb5noise"
            + f"${txt}*{nmea_checksum(txt)}\r\n".encode()
            + b"".join(_ubx_epoch(k, fix=k != 4, diff=k == 2) for k in range(1, 6)))
    log = tmp_path / "module.ubx"
    log.write_bytes(data)
    ep, skipped, messages, dated_by = read_real_log(log)
    t0 = 1717236000.0  # 2024-06-01 10:00:00 UTC
    np.testing.assert_array_equal(ep.t_unix_s, t0 + np.arange(1, 6))
    assert messages == {"NAV-PVT": 6, "NAV-DOP": 6, "NAV-SAT": 6} and dated_by == "log"
    assert skipped == {"pvt_without_time": 1}
    np.testing.assert_array_equal(ep.quality, [1, 2, 1, 0, 1])
    np.testing.assert_array_equal(ep.mode, [3, 3, 3, 1, 3])
    fix = ep.quality > 0
    np.testing.assert_allclose(ep.lon_deg[fix], 11.6401 + 1e-5 * np.array([1, 2, 3, 5]),
                               rtol=0, atol=1e-9)
    assert np.isnan(ep.lat_deg[~fix]).all()
    np.testing.assert_allclose(ep.alt_msl_m[fix], 100.25)
    np.testing.assert_allclose(ep.geoid_sep_m[fix], 41.0)
    np.testing.assert_allclose(ep.hdop[fix], 0.9)
    np.testing.assert_allclose(ep.pdop[fix], 1.5)
    np.testing.assert_allclose(ep.speed_mps[fix], 5.0)
    np.testing.assert_allclose(ep.course_deg[fix], 45.0)
    np.testing.assert_array_equal(ep.sats_used, 9)
    np.testing.assert_array_equal(ep.prn, [5, 67, 311])
    np.testing.assert_array_equal(ep.used, np.tile([True, True, False], (5, 1)))
    np.testing.assert_array_equal(ep.cn0_dbhz[0], [40.0, 35.0, np.nan])
    np.testing.assert_array_equal(ep.el_deg[0], [45.0, 20.0, 30.0])
    np.testing.assert_array_equal(ep.in_view, True)
    run = load_run(log, "static")
    assert run.has_gsv and run.has_cn0 and run.has_gsa
    rmc = "GPRMC,100001.00,A,5208.4300,N,01138.4066,E,9.72,45.0,010624,,,A"
    log.write_bytes(data + f"${rmc}*{nmea_checksum(rmc)}\r\n".encode())
    assert read_real_log(log)[2] == {"TXT": 1, "RMC": 1}


def test_the_emulated_m8s_ubx_output_reads_as_its_epochs(tmp_path):
    """The u-blox M8 emulation (``tests/ubx_uart.py``; itself checked against gpsd, PX4's and
    ArduPilot's drivers) set to UBX only, with NAV-PVT, NAV-DOP and NAV-SVINFO (no NAV-SAT, as
    PX4 sets an M8 for its satellite information): its bytes as a log read back as the epochs
    it emitted, NAV-SVINFO's single svid numbered as here (Galileo E3 is 303, SBAS 131)."""
    from ubx_uart import (
        CFG_MSG,
        CFG_PRT,
        CLS_CFG,
        CLS_NAV,
        NAV_DOP,
        NAV_PVT,
        NAV_SVINFO,
        SKY,
        T0_UNIX_S,
        Module,
        fix_at,
        ubx,
    )

    mod = Module("M8", no_fix=(3.0, 4.0))
    port = struct.pack("<BBHIIHHHH", 1, 0, 0, 0x8D0, mod.baud, 0x01, 0x01, 0, 0)  # UBX only
    mod.write(ubx(CLS_CFG, CFG_PRT, port), mod.baud, 0.0)
    for msg in (NAV_PVT, NAV_DOP, NAV_SVINFO):
        mod.write(ubx(CLS_CFG, CFG_MSG, bytes((CLS_NAV, msg, 1))), mod.baud, 0.0)
    log = tmp_path / "m8.ubx"
    log.write_bytes(mod.read(mod.baud, 8.0))
    ep, skipped, messages, _ = read_real_log(log)
    te = 0.5 + np.arange(8.0)
    np.testing.assert_allclose(ep.t_unix_s, T0_UNIX_S + te)
    assert messages["NAV-PVT"] == messages["NAV-SVINFO"] == 8 and "NAV-SAT" not in messages
    fix = (te < 3.0) | (te >= 4.0)
    np.testing.assert_array_equal(ep.quality > 0, fix)
    refs = [fix_at(t) for t in te[fix]]
    np.testing.assert_allclose(ep.lat_deg[fix], [r.lat_deg[0] for r in refs], rtol=0, atol=1e-7)
    np.testing.assert_allclose(ep.lon_deg[fix], [r.lon_deg[0] for r in refs], rtol=0, atol=1e-7)
    np.testing.assert_allclose(ep.alt_msl_m[fix], refs[0].alt_msl_m[0], atol=1e-3)
    np.testing.assert_allclose(ep.hdop[fix], 0.8)
    np.testing.assert_array_equal(ep.prn, sorted(s[0] for s in SKY))
    order = np.argsort([s[0] for s in SKY])
    np.testing.assert_array_equal(ep.used[fix][0], np.array([s[4] for s in SKY])[order])
    np.testing.assert_array_equal(ep.cn0_dbhz[0], np.array([s[3] for s in SKY])[order])
    np.testing.assert_array_equal(ep.el_deg[0], np.array([s[2] for s in SKY])[order])


def test_the_simulated_receiver_runs_on_through_short_gaps_in_the_truth(shared_data):
    """The GSDC drive's SPAN truth drops out 31 times (quality 0 for 3-68 epochs). No epoch in
    a gap is compared, but the simulated receiver runs on through those of up to
    SIM_MAX_GAP_S on the straight line between the truth's ends, as the real one did: a
    navigation filter carries its lag across (restarted after each gap, it lagged by nothing
    at the first epochs after it, where a real filter lagged ~35 m); beyond, it has no
    position. And an epoch after a gap has the truth's speed: it read 0 and counted as
    stationary at 25 m/s."""
    from virtualgps.gap import tool
    from virtualgps.gap.ensemble import EnsembleJob, simulate_job
    from virtualgps.gap.ingest import TRUTH_MAX_GAP_S
    from virtualgps.gap.runs import SIM_MAX_GAP_S, prepare_runs, sim_obs

    d = shared_data / "gsdc-2020-05-14-mtv"
    inp = tool.GapInputs(real=(str(d / "Pixel4_chipset.nmea"),),
                         truth=(str(d / "SPAN_Pixel4_1Hz.nmea"),), scene="none",
                         tle=str(d / "gps-ops_2020-05-14T22Z.tle"), profile="holux-m1000")
    runs_in, scene, scene_dir, tle, table, source = tool.load_inputs(inp)
    run = prepare_runs(runs_in, scene, scene_dir, tle, build_profile(table, source),
                       lambda t0: 0.0, 1, None)[0]
    setup, view = run.setup, run.view
    t, valid = view.t_unix_s, view.valid
    k = np.flatnonzero(valid)
    gap = np.flatnonzero(np.diff(t[k]) > TRUTH_MAX_GAP_S)  # (the truth's own gaps)
    before, after = k[gap], k[gap + 1]
    bridged = t[after] - t[before] <= SIM_MAX_GAP_S
    assert gap.size >= 25 and 15 <= bridged.sum() < gap.size
    for b, a, br in zip(before, after, bridged, strict=True):
        assert setup.pose_valid[b:a + 1].all() == br
    # speeds: known at every compared epoch but one alone between gaps (unknown: in neither
    # segment), and an epoch counts as stationary only where the truth's own steps about it
    # are slow
    speed, posed = view.speed_mps, setup.pose_valid
    alone = posed & ~np.r_[False, posed[:-1]] & ~np.r_[posed[1:], False]
    assert np.isfinite(speed[valid & ~alone]).all() and np.isnan(speed[alone]).all()
    en = view.truth_en_m
    step = np.full(t.size, np.nan)
    step[k[1:]] = np.hypot(*np.diff(en[k], axis=0).T) / np.diff(t[k])
    still = where.segments(view)["stationary"]
    assert still.sum() > 30 and np.nanmax(step[still]) < 1.0
    assert (speed[after] > 10.0).sum() >= 20
    # a 2 s filter lags a steady v by v a / (1 - a) seconds at 1 Hz (a = e^-0.5): 1.54 s
    nf = fx.apply(table, {"nav_filter": {"enabled": True, "tau_s": 2.0,
                                         "velocity_aided": False}})
    sims = sim_obs(simulate_job(EnsembleJob(setup, build_profile(nf, source), (0, 1, 2))),
                   view)
    err = np.hypot(*where.errors_enu(view, sims)[..., :2].transpose(2, 0, 1))
    fast = bridged & (speed[after] > 10.0)
    lag_m = speed[after[fast]] * math.exp(-0.5) / (1.0 - math.exp(-0.5))
    assert fast.sum() >= 15
    assert np.median(err[:, after[fast]] / lag_m) > 0.8, err[:, after[fast]] / lag_m
