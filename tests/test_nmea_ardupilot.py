"""The NMEA profiles against ArduPilot's NMEA GPS driver (``GPS1_TYPE = 5``, and ``1``, auto).

ArduPilot cannot be installed here: ``ardupilot_nmea.py`` models the part of it that reads an
NMEA receiver (its docstring names the sources read and what the model leaves out). The tests
drive it with the exact bytes the device writes: ``virtualgps replay`` of a drive (accelerate,
turn, stop, a gap in the poses) for each NMEA profile, each epoch's bytes sent from the epoch's
time on a simulated UART at the profile's baud behind the device's own bounded queue, read by
the model every 20 ms on a simulated clock; and, once, the bytes the real daemon writes on its
pty, with the times they arrived.
"""

from __future__ import annotations

import json
import math
import os
import re
import tty
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from ardupilot_nmea import (
    AP_BAUD_TIME_MS,
    AP_BAUDS,
    AP_DELAY_AVG_MAX_MS,
    AP_INIT_BLOB,
    AP_LOOP_MS,
    AP_PORT_BAUD,
    FIX_3D,
    GGA_QUALITY_STATUS,
    GPS_TYPE_AUTO,
    GPS_TYPE_NMEA,
    NMEA_SET_MS,
    NO_FIX,
    NO_GPS,
    ApNmea,
    ArduPilotGps,
    Chunk,
    Report,
    Wire,
    gps_week_ms,
    parse_decimal_100,
    parse_degrees,
)
from nmea_line import DEVICE_MAX_BACKLOG_S, read_timed
from nmea_replay import ORIGIN, replay_epochs
from test_nmea_px4 import FLIGHT_STACK_SENTENCES

from virtualgps.device.nmea import NmeaFormat, nmea_checksum
from virtualgps.receiver.profiles import load_profile

# --- the device's bytes -----------------------------------------------------------------------

T0_UNIX_S = 1717236000.0  # 2024-06-01 10:00:00 UTC: the drive's first pose
AP_START_MS = 3000  # ArduPilot's first AP_GPS::update, before the receiver's first epoch
NMEA_PROFILES = ("holux-m1000", "usarsim", "ideal", "phone", "ublox-m8n", "ublox-m9n")


def _drive(duration_s: float, gap_s: tuple[float, float] | None = None) -> list[dict]:
    """Poses at 10 Hz in scene metres (x east, y north): 10 s standing, 15 s accelerating at
    0.8 m/s^2 to 12 m/s east, a 90 degree left turn over 20 s (60-80 s), braking to a stop
    (120-135 s), standing; no poses within ``gap_s`` (the receiver loses its fix after its
    pose timeout)."""
    x = y = v = 0.0
    heading = 90.0
    out = []
    for i in range(int(duration_s * 10) + 1):
        t = i / 10
        if gap_s is None or not gap_s[0] <= t < gap_s[1]:
            out.append({"t": T0_UNIX_S + t, "x": round(x, 4), "y": round(y, 4), "z": 0.0})
        a = 0.8 if 10 <= t < 25 else -0.8 if 120 <= t < 135 else 0.0
        heading -= 4.5 * 0.1 if 60 <= t < 80 else 0.0
        v = max(0.0, v + a * 0.1)
        x += v * math.sin(math.radians(heading)) * 0.1
        y += v * math.cos(math.radians(heading)) * 0.1
    return out


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> dict[str, Path]:
    """The pose logs (JSONL, ``{"t", "x", "y", "z"}`` a line, docs/formats.md): ``full`` (three
    minutes, no poses from 150 to 160 s) and ``short`` (its first minute, for 5 Hz)."""
    d = tmp_path_factory.mktemp("drives")
    out = {}
    for name, poses in (("full", _drive(180.0, (150.0, 160.0))), ("short", _drive(60.0))):
        out[name] = d / f"{name}.jsonl"
        out[name].write_text("".join(json.dumps(p) + "\n" for p in poses))
    return out


@dataclass
class ApReplay:
    """One ``virtualgps replay`` as ArduPilot's tests read it: each epoch's bytes, its fixes CSV
    row as numbers, the profile's format, baud and command link."""

    name: str
    baud: int
    rate_hz: float
    fmt: NmeaFormat
    command_link: str
    epochs: list[bytes]
    rows: list[dict[str, float]]

    def t_ms(self, lead_ms: float) -> np.ndarray:
        """Epoch times on ArduPilot's clock: the first ``lead_ms`` after its first update."""
        t = np.array([r["t_unix_s"] for r in self.rows])
        return AP_START_MS + lead_ms + (t - t[0]) * 1000.0


_REPLAYS: dict[tuple[str, str, float | None, tuple[str, ...] | None], ApReplay] = {}


def replay(drives: dict[str, Path], name: str, which: str = "full",
           rate: float | None = None, sentences: tuple[str, ...] | None = None) -> ApReplay:
    """The profile ``name``'s replay of drive ``which`` (:func:`nmea_replay.replay_epochs`; at
    ``rate``, else the profile's; ``sentences``, else its own), made once."""
    key = (name, which, rate, sentences)
    if key not in _REPLAYS:
        prof = load_profile(name)
        rep = replay_epochs(drives[which].parent, drives[which], name, rate or prof.rate_hz,
                         list(sentences) if sentences else None, tag=f"{which}-")
        rows = [{k: float(v) if v != "" else math.nan for k, v in r.items() if k != "used_prns"}
                for r in rep.rows]
        _REPLAYS[key] = ApReplay(name, prof.baud, rep.rate_hz, rep.fmt, prof.command_link,
                                 rep.epoch_bytes, rows)
    return _REPLAYS[key]


# --- the checks -------------------------------------------------------------------------------

def _check_report(r: Report, run: ApReplay, e: int, prev_fix: bool) -> None:
    """One report against its epoch's fixes CSV row, within what the sentences print, what
    ArduPilot's parsing keeps (its 1e-7 degrees, cm, its knots * 0.514) and the CSV's own digits
    (9 decimals of a degree, 3 of a metre, of m/s and of a DOP, 2 of the course)."""
    row, fmt, st = run.rows[e], run.fmt, r.state
    quality = int(row["quality"])
    assert st.status == GGA_QUALITY_STATUS.get(quality, FIX_3D), (e, quality, st.status)
    if quality == 0:
        return
    where = f"{run.name} epoch {e}"
    tol_deg = 0.5 * 10.0**-fmt.latlon_decimals / 60 + 2e-7  # printed minutes; 1e-7 truncation
    assert abs(st.lat * 1e-7 - row["lat_deg"]) <= tol_deg, where
    assert abs(st.lng * 1e-7 - row["lon_deg"]) <= tol_deg, where
    assert abs(st.alt_cm / 100 - row["alt_msl_m"]) <= 0.5 * 10.0**-fmt.alt_decimals + 5e-4, where
    assert abs(st.hdop / 100 - row["hdop"]) <= 0.5 * 10.0**-fmt.dop_decimals + 5e-4, where
    assert st.num_sats == int(row["sats_used"]), where
    v = row["speed_mps"]
    knots_tol = 0.5 * 10.0**-fmt.speed_decimals + (0.005 if fmt.speed_decimals > 2 else 0.0)
    # printed knots, ArduPilot's 0.514 for 0.51444 m/s a knot, its whole cm/s
    tol_v = knots_tol * 0.514444 + v * (1 - 0.514 / 0.514444) + 0.01 + 5e-4 + 1e-6
    assert abs(st.ground_speed - v) <= tol_v, (where, st.ground_speed, v)
    tol_c = 0.5 * 10.0**-fmt.course_decimals + (0.005 if fmt.course_decimals > 2 else 0) + 5e-3
    dc = (st.ground_course - row["course_deg"] + 180.0) % 360.0 - 180.0
    assert abs(dc) <= tol_c, (where, st.ground_course, row["course_deg"])
    vn, ve, _ = st.velocity
    assert math.hypot(vn, ve) == pytest.approx(st.ground_speed, abs=1e-6)
    if prev_fix:  # RMC's time is taken while the status (from GGA) is 3D
        assert (st.time_week, st.time_week_ms) == gps_week_ms(row["t_unix_s"]), where


def _rule_spans(wire: Wire, epochs: list[int]) -> dict[int, float]:
    """Per epoch, the ms between the first and the last of its GGA, RMC and VTG's completions on
    the wire: read every 20 ms, ArduPilot sees at most this + 20 ms between them."""
    ends = wire.sentence_ends()
    return {e: max(ends[e].values()) - min(ends[e].values()) for e in epochs}


def _set_sources(ap: ArduPilotGps) -> list[dict[str, int]]:
    """For each report, the epoch of the GGA, RMC and VTG it was made of (the last of each the
    driver took by the report's tick)."""
    out, last, k = [], {}, 0
    for r in ap.reports:
        while k < len(ap.sentences) and ap.sentences[k][1] <= r.t_ms:
            last[ap.sentences[k][0]] = ap.sentences[k][2]
            k += 1
        out.append(dict(last))
    return out


def _mixed_sets(ap: ArduPilotGps, wire: Wire) -> str:
    """'' if every report is made of its own epoch's GGA, RMC and VTG; else how many are not,
    and the first: which epochs' sentences it combined, how far apart they ended on the wire."""
    mixed = [(r, src) for r, src in zip(ap.reports, _set_sources(ap), strict=True)
             if set(src.values()) != {r.epochs[0]}]
    if not mixed:
        return ""
    (r, src), ends = mixed[0], wire.sentence_ends()
    e = r.epochs[0]
    apart = ", ".join(f"its {k} ended {ends[e]['GGA'] - ends[src[k]][k]:.1f} ms before"
                      for k in src if src[k] != e)
    return (f"{len(mixed)} of {len(ap.reports)} reports combine two epochs, the first epoch "
            f"{e}'s GGA with epoch {min(src.values())}'s RMC and VTG ({apart} the GGA)")


def _cross_epoch_sets(wire: Wire) -> list[tuple[float, int, str]]:
    """Where the line lets AP_GPS_NMEA::_have_new_message take two epochs as one message, at
    some phase of its 20 ms loop: at each GGA, RMC or VTG of epoch N+1, the last of each kind
    so far, some of epoch N, ending within 150 + 20 ms of one another. (It happens where
    epoch N's were not taken as a message of their own: after detection took one of them,
    or once it has happened, from then on.) Returns (span ms, epoch N, the set), shortest
    first."""
    ends = wire.sentence_ends()
    out = []
    for n in sorted(ends):
        if n + 1 not in ends or len(ends[n]) < 3:
            continue
        last = {k: (t, n) for k, t in ends[n].items()}
        for k, t in sorted(ends[n + 1].items(), key=lambda kv: kv[1]):
            last[k] = (t, n + 1)
            times = [v[0] for v in last.values()]
            if {v[1] for v in last.values()} == {n, n + 1} and max(times) - min(times) < (
                    NMEA_SET_MS + AP_LOOP_MS):
                out.append((max(times) - min(times), n,
                            "+".join(f"{kk}({v[1]})" for kk, v in sorted(last.items()))))
    return sorted(out)


def _summary(name: str, ap: ArduPilotGps, wire: Wire, run: ApReplay, spans: dict) -> str:
    det_ms, det_baud, det_epoch = ap.detections[0]
    worst = max(spans, key=spans.get)
    return (f"{name}: detected at {det_baud} baud {(det_ms - AP_START_MS) / 1000:.2f} s after "
            f"the first probe (epoch {det_epoch}); {len(ap.reports)} reports of "
            f"{len(run.epochs)} epochs; device dropped {len(wire.dropped)}; GGA/RMC/VTG span "
            f"max {spans[worst]:.1f} ms (epoch {worst}) + {AP_LOOP_MS} ms loop <= "
            f"{NMEA_SET_MS}; timeouts {len(ap.timeouts)}; average delta "
            f"{ap.average_delta_ms:.0f} ms, healthy {ap.is_healthy()}")


#: the receiver's first epoch this long after ArduPilot's first update: four phases of its
#: 20 ms loop (1, 6, 11 and 16 ms after a read); at 1 and 5 Hz every epoch falls on the same one
LEADS_MS = (241.0, 246.0, 251.0, 256.0)


def _drive_ardupilot(run: ApReplay, baud: int | None = None, lead_ms: float = LEADS_MS[0],
                     gps_type: int = GPS_TYPE_NMEA, auto_config: int | None = None,
                     end_ms: float | None = None) -> tuple[ArduPilotGps, Wire]:
    """The replay's bytes on a line at ``baud`` (the profile's), read by the model. GPS_AUTO_CONFIG
    is 0 for the u-blox profiles (their $PUBX,41 would take the blob: see
    test_gps_auto_config_takes_a_u_blox_out_of_nmea), 1 (the default) for the others."""
    t_ms = run.t_ms(lead_ms)
    wire = Wire.from_line(run.epochs, t_ms, baud or run.baud)
    if auto_config is None:
        auto_config = 0 if run.command_link == "ubx" else 1
    ap = ArduPilotGps(wire, gps_type=gps_type, auto_config=auto_config)
    ap.run(AP_START_MS, int(end_ms if end_ms is not None else wire.arrival_ms[-1] + 1000))
    return ap, wire


def _check_every_epoch(run: ApReplay, baud: int | None = None) -> tuple[ArduPilotGps, Wire, dict]:
    """At each of LEADS_MS: detected at the line's baud; every epoch the line delivered after the
    one the detector read is reported once, made of that epoch's own GGA, RMC and VTG, as its
    row says; never a timeout. And at any phase and start: no two adjacent epochs' sentences
    close enough for the driver to take them as one message (_cross_epoch_sets). Returns the
    last phase's model, line and rule spans."""
    baud = baud or run.baud
    mixed = []
    for lead_ms in LEADS_MS:
        ap, wire = _drive_ardupilot(run, baud, lead_ms)
        assert ap.detections and ap.detections[0][1] == baud, ap.detections
        assert not ap.timeouts, ap.timeouts
        det_epoch = ap.detections[0][2]
        assert all(len(r.epochs) == 1 for r in ap.reports), [r.epochs for r in ap.reports]
        reported = [r.epochs[0] for r in ap.reports]
        delivered = sorted(set(wire.epochs.tolist()))
        # The detector ate a sentence of the epoch it read: a GGA-first epoch loses its GGA, an
        # RMC-first its RMC (or both where the probe opened late in it): never reported; where
        # it ate another (a GST first), that epoch is reported.
        assert reported in ([e for e in delivered if e > det_epoch],
                            [e for e in delivered if e >= det_epoch]), (det_epoch, reported[:5])
        spans = _rule_spans(wire, reported)
        assert max(spans.values()) + AP_LOOP_MS <= NMEA_SET_MS, max(spans.values())
        if why := _mixed_sets(ap, wire):
            mixed.append((lead_ms, why))
            continue
        done: set[int] = set()
        for r in ap.reports:
            e = r.epochs[0]
            fixes = (e - 1) in done and min(run.rows[e - 1]["quality"], run.rows[e]["quality"])
            _check_report(r, run, e, bool(fixes))
            done.add(e)
    cross = _cross_epoch_sets(wire)
    where = f"{run.name} at {run.rate_hz:g} Hz, {baud} baud"
    rule = (f"AP_GPS_NMEA::_have_new_message takes any GGA, RMC and VTG ended within "
            f"{NMEA_SET_MS} ms of one another (read every {AP_LOOP_MS} ms) as one new message")
    assert not mixed, (f"{where}: with the receiver's first epoch {mixed[0][0]:.0f} ms after "
                       f"ArduPilot's first read (and at {len(mixed)} of the {len(LEADS_MS)} "
                       f"phases tried), {mixed[0][1]}: {rule}")
    assert not cross, (f"{where}: {len(cross)} pairs of epochs can be taken as one message, "
                       f"the closest {cross[0][2]} ending {cross[0][0]:.1f} ms apart (from "
                       f"epoch {cross[0][1]}); the most, {cross[-1][0]:.1f} ms: {rule}")
    return ap, wire, spans


# --- the model itself -------------------------------------------------------------------------

def _sentence(body: str) -> bytes:
    return f"${body}*{nmea_checksum(body)}\r\n".encode()


def test_the_model_parses_as_ardupilot_does():
    """The model's conversions and rule on hand-made sentences, before it judges the device:
    ``_parse_degrees`` to 1e-7 degrees (truncating: 5208.4000 is 52.1399999), knots at 0.514,
    ``_parse_decimal_100``'s sign from the integer part, a wrong checksum ignored, and the
    150 ms rule: GGA, RMC and VTG (once one was seen) close together make one new message, a
    VTG 160 ms after the GGA none."""
    assert parse_degrees("5208.4000") == 521_399_999
    assert parse_degrees("01138.4000") == 116_399_999
    assert parse_decimal_100("123.456") == 12346 and parse_decimal_100("-0.5") == 50
    gga = _sentence("GPGGA,100000.000,5208.4000,N,01138.4000,W,1,8,0.95,41.5,M,43.0,M,,")
    rmc = _sentence("GPRMC,100000.000,A,5208.4000,N,01138.4000,W,10.00,45.00,010624,,,A")
    vtg = _sentence("GPVTG,45.00,T,,M,10.00,N,18.52,K,A")
    drv = ApNmea(38400, lambda k: 0)
    assert drv.read(Chunk(gga.replace(b"*", b"0*", 1)), 1000) == (False, [])  # bad checksum
    assert drv.bad_checksums == 1 and drv.state.status == NO_FIX
    assert drv.read(Chunk(gga + rmc), 2000) == (True, [0])
    st = drv.state
    assert (st.lat, st.lng, st.alt_cm, st.hdop, st.num_sats) == (
        521_399_999, -116_399_999, 4150, 95, 8)
    assert st.status == FIX_3D and st.ground_speed == pytest.approx(5.14, abs=1e-6)
    assert (st.time_week, st.time_week_ms) == gps_week_ms(T0_UNIX_S)
    assert drv.read(Chunk(vtg), 2010) == (False, [])  # RMC and GGA were taken: nothing new
    assert drv.read(Chunk(gga + rmc), 3000) == (False, [])  # VTG seen once: now it is wanted
    assert drv.read(Chunk(vtg), 3160) == (False, [])  # 160 ms after GGA and RMC
    assert drv.read(Chunk(gga + rmc + vtg), 4000) == (True, [0])


# --- the NMEA profiles ------------------------------------------------------------------------

@pytest.mark.parametrize("name", NMEA_PROFILES)
def test_ardupilot_reports_every_epoch_of_a_drive(name, drives):
    """Three minutes of driving (accelerate, turn, stop; the poses missing for 10 s, so the
    receiver loses its fix and gets it back), replayed on the profile's line at its baud and
    rate. ArduPilot (GPS1_TYPE 5) finds the NMEA at the profile's baud, then reports one new
    message for every epoch after the one its detector read, made of that epoch's GGA, RMC and
    VTG, with its position, altitude, speed, course, HDOP, satellites, status (NO_FIX for the
    epochs without a fix) and time, within the printed digits, at four phases of its 50 Hz loop;
    GGA, RMC and VTG end within 150 ms of each other at any phase; no 4 s timeout. At the
    profiles' 1 Hz AP_GPS::is_healthy is false (it wants a message every 245 ms and 215 on
    average, 5 Hz), as for any 1 Hz receiver."""
    run = replay(drives, name)
    ap, wire, spans = _check_every_epoch(run)
    assert not wire.dropped  # (1 Hz fits every profile's baud)
    order = [b for _, b in ap.probes]
    k = order.index(run.baud)  # the probes before the profile's baud found nothing
    assert ap.detections[0][0] - ap.probes[k][0] <= 1000 / run.rate_hz + 200
    no_fix = [r for r in ap.reports if run.rows[r.epochs[0]]["quality"] == 0]
    assert len(no_fix) >= 9 and all(r.state.status == NO_FIX for r in no_fix)
    fixed = [r.state.status for r in ap.reports if run.rows[r.epochs[0]]["quality"] > 0]
    assert set(fixed) == {FIX_3D}
    assert not ap.is_healthy() and ap.average_delta_ms > AP_DELAY_AVG_MAX_MS
    print(_summary(name, ap, wire, run, spans))


@pytest.mark.parametrize("name, baud", [("holux-m1000", 38400), ("usarsim", 38400),
                                        ("phone", 115200), ("ublox-m8n", 115200)])
def test_ardupilot_takes_5_hz_in_the_flight_stacks_order(name, baud, drives):
    """``--rate 5`` (ArduPilot arms only on a GPS it calls healthy, AP_GPS::is_healthy: a
    message every 245 ms at most and 215 on average), at a baud that carries it (the Holux's
    own 38400: its ~450-byte epochs take 117 ms of the 200; the phone's 115200; the M8N moved
    to 115200, as CFG-PRT or the daemon's ``--baud`` does), with the sentences in the order
    docs/device.md gives for flight stacks (FLIGHT_STACK_SENTENCES: GST, GGA, RMC together,
    then GSA and GSV): every epoch after detection reported, from its own sentences, as its row
    says, healthy, and no two epochs close enough to be taken as one at any phase."""
    run = replay(drives, name, "short", 5.0, FLIGHT_STACK_SENTENCES)
    ap, wire, spans = _check_every_epoch(run, baud)
    assert not wire.dropped
    assert ap.is_healthy() and ap.delayed_count == 0, ap.average_delta_ms
    print(_summary(f"{name} 5 Hz at {baud}", ap, wire, run, spans))


@pytest.mark.parametrize("name, baud", [("holux-m1000", 38400), ("phone", 115200)])
def test_at_5_hz_a_late_rmc_lets_ardupilot_pair_it_with_the_next_gga(name, baud, drives):
    """The profiles' own order at 5 Hz (MTK's GGA, GSA, GSV, RMC, VTG, as a real MTK writes
    it): RMC and VTG end ~80-100 ms after their GGA, so the next epoch's GGA ends within
    150 ms of them (+ the 20 ms loop). Once ArduPilot has taken such a pair (after its detector
    ate a GGA) it goes on so: each report the new GGA's position with the previous epoch's
    RMC/VTG speed, course and time, 200 ms old. ArduPilot's rule with any receiver of this
    order; FLIGHT_STACK_SENTENCES avoid it (test above)."""
    run = replay(drives, name, "short", 5.0)
    ap, wire = _drive_ardupilot(run, baud)
    assert ap.detections and not ap.timeouts and ap.is_healthy()
    assert _cross_epoch_sets(wire), "no two epochs close enough to pair"
    if name == "holux-m1000":  # (the phone's pairs lie within a few ms of the rule's edge)
        assert _mixed_sets(ap, wire).startswith(f"{len(ap.reports)} of {len(ap.reports)}")


def test_ardupilot_on_a_baud_that_cannot_carry_the_rate(drives):
    """``--rate 5`` on the M8N's 9600 baud: its ~700-byte epochs need 3,500 bytes/s of the
    line's 960. The device's queue (2 s of line time) drops the oldest epochs whole; those that
    go out arrive whole, so ArduPilot reports each of them (the 150 ms rule holds within an
    epoch) and only them, up to 2 s after their time, about once a second: never a timeout, but
    AP_GPS::is_healthy false (average time between messages far over 215 ms)."""
    run = replay(drives, "ublox-m8n", "short", 5.0)
    ap, wire, spans = _check_every_epoch(run, 9600)
    assert len(wire.dropped) > len(run.epochs) // 2
    reported = {r.epochs[0] for r in ap.reports}
    det_epoch = ap.detections[0][2]
    missed = [e for e in range(det_epoch + 1, len(run.epochs)) if e not in reported]
    assert missed == [e for e in wire.dropped if e > det_epoch]  # exactly the dropped ones
    t_ms = run.t_ms(LEADS_MS[-1])
    lag = [r.t_ms - t_ms[r.epochs[0]] for r in ap.reports]
    assert 1000 < max(lag) <= DEVICE_MAX_BACKLOG_S * 1000 + 1000
    assert not ap.is_healthy() and ap.average_delta_ms > 500
    print(_summary("ublox-m8n 5 Hz at 9600", ap, wire, run, spans)
          + f"; lag up to {max(lag):.0f} ms")


def test_gps_type_auto_never_takes_an_nmea_receiver(drives):
    """GPS1_TYPE 1 (auto): ``_detect_instance`` runs the NMEA detector only for GPS1_TYPE 5 (and
    the HEMI, AllyStar and Unicore types), so an NMEA-only receiver is never detected, however
    long the probing (here two cycles of the rates: the port's 38400 first, then 115200, 4800,
    ..., 460800, 9600, 1.2 s each); GPS1_TYPE 5 is what these profiles need."""
    run = replay(drives, "holux-m1000")
    ap, _ = _drive_ardupilot(run, gps_type=GPS_TYPE_AUTO, end_ms=AP_START_MS + 22_000)
    assert not ap.detections and not ap.reports and ap.state.status == NO_GPS
    assert [b for _, b in ap.probes[:10]] == [AP_PORT_BAUD, *AP_BAUDS[1:], AP_BAUDS[0], 115200]
    steps = {b[0] - a[0] for a, b in zip(ap.probes, ap.probes[1:], strict=False)}
    assert steps == {AP_BAUD_TIME_MS + AP_LOOP_MS}


class ModulePort:
    """``ubx_uart.Module`` (the pure u-blox link with its NMEA) as the model's port."""

    def __init__(self, module) -> None:
        self.module, self.k = module, 0

    def read(self, baud: int, now_ms: int) -> Chunk:
        data = self.module.read(baud, now_ms / 1000)
        self.k += len(data)
        return Chunk(data, self.k - len(data), float(now_ms))

    def write(self, data: bytes, baud: int, now_ms: int) -> None:
        self.module.write(data, baud, now_ms / 1000)

    def epoch(self, k: int) -> int:
        return -1


@pytest.mark.parametrize("generation, baud", [("M8", 9600), ("M9", 38400)])
def test_gps_auto_config_takes_a_u_blox_out_of_nmea(generation, baud):
    """GPS1_TYPE 5 with GPS_AUTO_CONFIG 1 (the default) still writes AP_GPS's init blob at every
    probed rate; its $PUBX,41 at the module's own baud switches a u-blox (the emulated M8N at
    9600, M9N at 38400) to 230400 baud, UBX out only: no NMEA comes at any rate after it, and
    the NMEA driver is never created (the model writes the blob at once; on the wire it takes
    46 ms at 9600, in which at most one short sentence could pass the detector, and its driver
    would time out 4 s later). With GPS_AUTO_CONFIG 0 the same module is found at its baud. So
    the u-blox profiles over NMEA want GPS_AUTO_CONFIG 0 (or GPS1_TYPE 2, u-blox, over UBX)."""
    from ubx_uart import Module

    mod = Module(generation)
    ap = ArduPilotGps(ModulePort(mod), auto_config=1)
    ap.run(AP_START_MS, AP_START_MS + 25_000)
    assert not ap.detections and not ap.reports
    assert mod.baud == 230400 and not mod.link.nmea_enabled()
    mod = Module(generation)
    ap = ArduPilotGps(ModulePort(mod), auto_config=0)
    ap.run(AP_START_MS, AP_START_MS + 25_000)
    assert ap.detections and ap.detections[0][1] == baud == mod.baud


# --- the real daemon --------------------------------------------------------------------------

@pytest.mark.e2e
def test_ardupilot_reads_the_daemons_pty(tmp_path):
    """``virtualgps run --profile holux-m1000 --scene none --origin ... --poses demo --config
    flightstack.toml`` (docs/device.md's: 5 Hz, FLIGHT_STACK_SENTENCES) on its pty, ArduPilot's
    init blob written to it (GPS_AUTO_CONFIG 1: the MTK link ignores it), its bytes read for
    8 s with the times they arrived and fed to the model: detected at 38400 (the port's first
    probe), then a new message for every whole epoch from its own GGA and RMC, within
    ArduPilot's 150 ms (with its 20 ms loop), the position GGA prints, a 3D fix, and healthy
    (AP_GPS::is_healthy: what arming asks of a GPS)."""
    from test_e2e import Daemon

    cfg = tmp_path / "flightstack.toml"
    cfg.write_text(f"rate = 5\n[nmea]\nsentences = {json.dumps(list(FLIGHT_STACK_SENTENCES))}\n")
    daemon = Daemon(tmp_path, "--profile", "holux-m1000", "--scene", "none", "--origin",
                    ORIGIN, "--poses", "demo", "--duration", "30", "--config", str(cfg))
    try:
        fd = os.open(daemon.link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            tty.setraw(fd)
            os.write(fd, AP_INIT_BLOB)
            reads = read_timed(fd, 8.0)
        finally:
            os.close(fd)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    data = b"".join(d for _, d in reads)
    arrival = np.concatenate([np.full(len(d), 1000.0 * t) for t, d in reads])
    # epochs: from each first sentence on; bytes before the first are epoch -1; the last
    # epoch may be cut
    first = f"$GP{FLIGHT_STACK_SENTENCES[0]},".encode()
    starts = [k for k in range(len(data)) if data.startswith(first, k)]
    epoch = np.full(len(data), -1)
    for i, k in enumerate(starts):
        epoch[k:] = i
    wire = Wire(data, arrival - arrival[0] + AP_START_MS + 5.0, epoch, 38400)
    ap = ArduPilotGps(wire)
    ap.run(AP_START_MS, int(wire.arrival_ms[-1]) + AP_LOOP_MS)
    assert ap.detections and ap.detections[0][1] == 38400 and not ap.timeouts
    det_epoch = ap.detections[0][2]
    # the epochs whose RMC (the last of the message) arrived whole; -1: it read a cut first one
    ends = [*starts[1:], len(data)]
    whole = [i for i in range(max(det_epoch, 0), len(starts))
             if re.search(rb"\$GPRMC,[^\r]*\r\n", data[starts[i]:ends[i]])]
    assert len(whole) >= 25
    assert all(len(r.epochs) == 1 for r in ap.reports)
    reported = [r.epochs[0] for r in ap.reports]
    assert reported in (whole, whole[1:]), (det_epoch, sorted(set(whole) ^ set(reported)))
    assert not _mixed_sets(ap, wire)
    spans = _rule_spans(wire, reported)
    assert max(spans.values()) + AP_LOOP_MS <= NMEA_SET_MS, spans
    for r in ap.reports:
        at = data.index(b"$GPGGA,", starts[r.epochs[0]])
        gga = data[at:].split(b"\r\n", 1)[0].decode().split(",")
        if gga[6] == "0":
            assert r.state.status == NO_FIX
            continue
        lat = int(gga[2][:2]) + float(gga[2][2:]) / 60
        lon = int(gga[4][:3]) + float(gga[4][3:]) / 60
        assert r.state.status == FIX_3D and abs(r.state.lat * 1e-7 - lat) < 2e-7
        assert abs(r.state.lng * 1e-7 - lon) < 2e-7 and abs(lat - 52.14) < 0.01
    assert sum(r.state.status == FIX_3D for r in ap.reports) >= 15
    assert ap.is_healthy(), ap.average_delta_ms
    print(f"e2e holux-m1000 5 Hz: {len(ap.reports)} reports of {len(whole)} whole epochs; "
          f"GGA/RMC span max {max(spans.values()):.1f} ms (+{AP_LOOP_MS} ms loop <= "
          f"{NMEA_SET_MS}); average delta {ap.average_delta_ms:.0f} ms")
