"""NMEA 0183 v4.11 output of a receiver tracking several systems (issue 23), checked against
pynmeagps and pynmea2: a GSA per system with its system ID, GSV per talker with the signal ID,
satellites by their NMEA IDs, RMC's navigational status; the scalar and vectorised writers give
the same bytes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_nmea import make_fixes, parse_both, sentences

from virtualgps.device import nmea
from virtualgps.device.nmea import NmeaFormat
from virtualgps.exceptions import ConfigError
from virtualgps.sky import systems

# Satellite numbers here (virtualgps.sky.systems): GPS 5, 12, 29; SBAS PRN 123; GLONASS slots
# 1, 14, 23; Galileo E11, E30; BeiDou C19; QZSS J01 (PRN 193). NMEA 4.11 IDs and talkers:
MIXED = [5, 66, 311, 12, 123, 78, 419, 29, 193, 330, 87]
NMEA_ID = {5: ("GP", 5), 12: ("GP", 12), 29: ("GP", 29), 123: ("GP", 36), 66: ("GL", 66),
           78: ("GL", 78), 87: ("GL", 87), 311: ("GA", 11), 330: ("GA", 30), 419: ("GB", 19),
           193: ("GQ", 1)}
SYSTEM_ID = {"GP": 1, "GL": 2, "GA": 3, "GB": 4, "GQ": 5}  # NMEA 4.11 system IDs
SIGNAL_ID = {"GP": 1, "GL": 1, "GA": 7, "GB": 1, "GQ": 1}  # L1 C/A, L1OF, E1 B/C, B1I, L1 C/A
FMT = NmeaFormat(talker="GN", version="4.11", no_fix_style="empty", dgps_fields="empty")


def mixed_fixes(n_t: int = 3, seed: int = 0, **over: object):
    return make_fixes(n_t=n_t, prn=MIXED, seed=seed, **over)


def test_each_system_has_its_gsa_and_its_gsv_with_ids_as_nmea_4_11_gives_them():
    fx = mixed_fixes()
    for i, epoch in enumerate(nmea.render_batch(fx, FMT)):
        gsa, gsv, other = [], {}, []
        for ln in sentences(epoch):
            a, b = parse_both(ln)  # both references read every sentence, checksums checked
            if a.msgID == "GSA":
                gsa.append(a)
            elif a.msgID == "GSV":
                gsv.setdefault(a.talker, []).append(a)
            else:
                other.append(a)
            assert a.talker == ("GN" if a.msgID in ("GGA", "GSA", "RMC", "VTG") else a.talker)
        # one GSA per system, in system ID order, listing that system's used satellites
        assert [int(m.systemId) for m in gsa] == sorted(SYSTEM_ID.values())
        by_sys = {s: [] for s in SYSTEM_ID.values()}
        for c, p in enumerate(MIXED):
            if fx.used[i, c]:
                talker, ident = NMEA_ID[p]
                by_sys[SYSTEM_ID[talker]].append(ident)
        for m in gsa:
            listed = [getattr(m, f"svid_{k:02d}") for k in range(1, 13)]
            assert [x for x in listed if x != ""] == by_sys[int(m.systemId)]
            assert m.HDOP == pytest.approx(fx.hdop[i], abs=0.005)
        # one run of GSV per talker, every satellite in view under its own talker and ID
        assert sorted(gsv) == sorted(SYSTEM_ID)
        for talker, msgs in gsv.items():
            assert {int(m.signalID) for m in msgs} == {SIGNAL_ID[talker]}
            assert [m.msgNum for m in msgs] == list(range(1, len(msgs) + 1))
            assert {m.numMsg for m in msgs} == {len(msgs)}
            want = sorted(NMEA_ID[p][1] for c, p in enumerate(MIXED)
                          if fx.in_view[i, c] and NMEA_ID[p][0] == talker)
            got = sorted(getattr(m, f"svid_{k:02d}") for m in msgs for k in range(1, 5)
                         if hasattr(m, f"svid_{k:02d}"))
            assert got == want and msgs[0].numSV == len(want)
        rmc = next(m for m in other if m.msgID == "RMC")
        assert rmc.navStatus == "V" and rmc.posMode == "A"


def test_the_paths_agree_and_a_system_with_nothing_in_view_still_writes_its_sentences():
    rng = np.random.default_rng(3)
    n_t = 70  # above the scalar path's batch size
    in_view = rng.random((n_t, len(MIXED))) < 0.7
    in_view[:, [MIXED.index(311), MIXED.index(330)]] = False  # no Galileo in view
    mode = rng.choice([1, 2, 3], n_t).astype(np.int8)
    fx = mixed_fixes(n_t=n_t, seed=3, in_view=in_view, mode=mode)
    fmts = (FMT, NmeaFormat(talker="GN", version="4.11", sentences=nmea.SENTENCE_TYPES))
    for fmt in fmts:
        vec = nmea.render_batch(fx, fmt)
        assert vec == [nmea.epoch_sentences(fx, i, fmt) for i in range(n_t)]
    epoch = nmea.epoch_sentences(fx, 0, FMT)
    assert b"$GAGSV,1,1,00,7*" in epoch
    # with no fix, every system's GSA is mode 1 with empty fields, its system ID kept
    k = int(np.flatnonzero(mode == 1)[0])
    lines = [ln for ln in sentences(nmea.epoch_sentences(fx, k, FMT)) if b"GSA" in ln]
    assert [ln.split(b"*")[0] for ln in lines] == [
        b"$GNGSA,A,1,,,,,,,,,,,,,,," + b",%d" % s for s in range(1, 6)]


def test_version_2_3_and_a_gps_only_receiver_keep_their_bytes():
    gps = make_fixes(n_t=60)
    old = NmeaFormat()
    assert old.version == "2.3"
    # 4.11 on a GPS-only constellation: the same sentences plus the IDs at the end
    new = NmeaFormat(version="4.11")
    for a, b in zip(nmea.render_batch(gps, old), nmea.render_batch(gps, new), strict=True):
        for la, lb in zip(sentences(a), sentences(b), strict=True):
            ba, bb = la.split(b"*")[0], lb.split(b"*")[0]
            tail = {b"GSA": b",1", b"GSV": b",1", b"RMC": b",V"}.get(ba[3:6], b"")
            assert bb == ba + tail
    # 2.3 writes every system's satellites in one GSV run under the profile's talker
    mixed = nmea.epoch_sentences(mixed_fixes(), 0, NmeaFormat(talker="GN"))
    assert b"GLGSV" not in mixed and mixed.count(b"GSA") == 1


def test_our_reader_takes_each_talkers_ids_back_to_the_satellites_numbers():
    from virtualgps.device.nmea.reader import nmea_epochs_from_lines

    fx = mixed_fixes(n_t=4)
    text = b"".join(nmea.render_batch(fx, FMT)).decode().splitlines()
    ep = nmea_epochs_from_lines(text)
    assert set(ep.prn.tolist()) <= set(MIXED)
    for i in range(4):
        view = {int(p) for p, v in zip(ep.prn, ep.in_view[i], strict=True) if v}
        used = {int(p) for p, u in zip(ep.prn, ep.used[i], strict=True) if u}
        assert view == {p for c, p in enumerate(MIXED) if fx.in_view[i, c]}
        assert used == {p for c, p in enumerate(MIXED) if fx.used[i, c]}
        c = MIXED.index(311)
        if fx.in_view[i, c] and np.isfinite(fx.el_deg[i, c]):
            k = int(np.flatnonzero(ep.prn == 311)[0])
            assert ep.el_deg[i, k] == round(fx.el_deg[i, c])
    # NMEA 4.10 and older: GPS and GLONASS numbers under GP/GN/GL stand as they are, BeiDou
    # under BD, QZSS by its PRN
    old = ["$GPGGA,120000.00,5200.0,N,01100.0,E,1,02,0.9,100.0,M,45.0,M,,*",
           "$GPRMC,120000.00,A,5200.0,N,01100.0,E,0.0,0.0,280317,,,A*",
           "$GPGSV,1,1,03,05,40,100,35,36,20,200,30,193,10,50,20*", "$GLGSV,1,1,01,70,30,90,30*",
           "$BDGSV,1,1,01,07,30,90,30*", "$GNGSA,A,3,05,70,,,,,,,,,,,1.5,0.9,1.2*"]
    ep = nmea_epochs_from_lines([nmea.format_sentence(ln[1:-1]) for ln in old])
    assert ep.prn.tolist() == [5, 70, 123, 193, 407]
    assert ep.used[0].tolist() == [True, True, False, False, False]
    # NavIC (talker GI, system ID 6), simulated nowhere here: its IDs 1-14 are no GPS PRNs
    # (before: GI 05 and 09 stood as GPS 5 and 9, and GPS 9 was "used")
    navic = [*old[:3], "$GIGSV,1,1,02,05,60,10,40,09,25,300,33*",
             "$GNGSA,A,3,05,,,,,,,,,,,,1.5,0.9,1.2,1*", "$GNGSA,A,3,05,09,,,,,,,,,,,1.5,0.9,1.2,6*"]
    ep = nmea_epochs_from_lines([nmea.format_sentence(ln[1:-1]) for ln in navic])
    assert ep.prn.tolist() == [5, 123, 193] and ep.used[0].tolist() == [True, False, False]
    assert ep.el_deg[0, 0] == 40 and ep.sats_in_view.tolist() == [3]
    assert ep.sats_used_gsa.tolist() == [1]
    # QZSS under the older talkers QZ (by PRN or by ID) and Quectel's PQ: never GPS 1-10
    qzss = [*old[:2], "$QZGSV,1,1,02,193,50,100,40,02,45,120,38*", "$PQGSV,1,1,01,03,30,200,35*"]
    ep = nmea_epochs_from_lines([nmea.format_sentence(ln[1:-1]) for ln in qzss])
    assert ep.prn.tolist() == [193, 194, 195]


@pytest.mark.parametrize("table, message", [
    ({"version": 4.11}, "nmea.version: expected one of"),
    ({"version": "4.0"}, "nmea.version: expected one of"),
    ({"version": "4.11", "mode_letter": False}, "nmea.mode_letter: expected true with"),
])
def test_a_wrong_version_names_the_key(table, message):
    with pytest.raises(ConfigError, match=message):
        NmeaFormat.from_dict(table)


def test_the_ids_are_those_of_the_systems_table():
    # (independent of the writer: the table's own numbers, as NMEA 4.11 lists them)
    for number, (talker, ident) in NMEA_ID.items():
        s = systems.system_of(number)
        assert (s.talker, number - s.nmea_offset) == (talker, ident)


# --- a receiver that tracks GPS and GLONASS, end to end -------------------------------------


def multi_profile(path, channels: int = 12, systems: tuple[str, ...] = ("GPS", "GLONASS")):
    """``holux-m1000`` tracking GPS and GLONASS (or ``systems``), writing NMEA 4.11 under
    GN."""
    from importlib import resources

    text = (resources.files("virtualgps.receiver") / "profiles" / "holux-m1000.toml").read_text()
    text = text.replace('name = "holux-m1000"', 'name = "two-systems"')
    text = text.replace("max_channels = 12", f"max_channels = {channels}")
    text = text.replace('talker = "GP"', 'talker = "GN"\nversion = "4.11"')
    names = ", ".join(f'"{n}"' for n in systems)
    path.write_text(text + f"\n[constellations]\nenabled = true\nsystems = [{names}]\n")
    return path


def test_a_profile_naming_two_systems_tracks_and_writes_both(tmp_path):
    from test_cli import write_walk

    from virtualgps.cli import main
    from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR

    sets = [f"--tle={BUNDLED_EPHEMERIS_DIR / f'{g}-2017-03-28.tle'}"
            for g in ("gps-ops", "glo-ops")]
    walk = write_walk(tmp_path / "walk.jsonl", n=40, dt_s=1.0)
    out = tmp_path / "out.nmea"
    prof = multi_profile(tmp_path / "two.toml")
    assert main(["replay", str(walk), "--out", str(out), "--profile", str(prof), *sets]) == 0
    used = {1: set(), 2: set()}
    glgsv = []
    for ln in out.read_bytes().splitlines(keepends=True):
        a, _ = parse_both(ln)
        if a.msgID == "GSA":
            used[int(a.systemId)] |= {getattr(a, f"svid_{k:02d}") for k in range(1, 13)} - {""}
        if a.talker == "GL" and a.msgID == "GSV":
            glgsv += [getattr(a, f"svid_{k:02d}") for k in range(1, 5)
                      if hasattr(a, f"svid_{k:02d}")]
    assert glgsv and all(65 <= s <= 96 for s in glgsv)
    assert used[1] and used[2] and all(65 <= s <= 96 for s in used[2])
    assert all(1 <= s <= 32 for s in used[1])
    # more channels than an MTK's 12: more satellites used, still 12 at most per GSA
    wide = tmp_path / "wide.nmea"
    prof = multi_profile(tmp_path / "wide.toml", channels=24)
    assert main(["replay", str(walk), "--out", str(wide), "--profile", str(prof), *sets]) == 0
    n_used = [int(ln.split(b",")[7]) for ln in wide.read_bytes().splitlines() if b"GGA" in ln]
    assert max(n_used) > 12
    # GPS alone (the default) on the same walk: no GLONASS in its sentences
    gps = tmp_path / "gps.nmea"
    assert main(["replay", str(walk), "--out", str(gps), *sets]) == 0
    assert b"GL" not in gps.read_bytes()


@pytest.mark.parametrize("systems_toml, message", [
    ('["GPS", "Glonas"]', "unknown satellite system 'Glonas'"),
    ('"GPS"', "must be a non-empty list of names"),
    ('["GPS", "SBAS"]', "SBAS is not a system tracked"),
])
def test_a_wrong_system_names_the_key(systems_toml, message):
    from virtualgps.receiver.profiles import build_profile

    with pytest.raises(ConfigError, match=message) as e:
        build_profile({"name": "x", "constellations": {"enabled": True,
                                                       "systems": json.loads(systems_toml)}})
    assert e.value.key == "systems"


@pytest.mark.e2e
def test_gpsd_reports_each_systems_satellites_with_its_gnssid(tmp_path):
    import os

    from test_e2e import GPSD, Daemon, sky_after_fix, tpv3, watch_gpsd

    from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR

    if GPSD is None and not os.environ.get("CI"):
        pytest.skip("gpsd not installed")
    assert GPSD, "gpsd must be installed in CI (the README's test command installs it)"
    sets = [f"--tle={BUNDLED_EPHEMERIS_DIR / f'{g}-2017-03-28.tle'}"
            for g in ("gps-ops", "glo-ops", "galileo")]
    prof = multi_profile(tmp_path / "three.toml", channels=24,
                         systems=("GPS", "GLONASS", "Galileo"))
    daemon = Daemon(tmp_path, "--profile", str(prof), "--scene", "none", "--origin",
                    "52.14,11.64,100", "--poses", "demo", *sets)
    try:
        messages = watch_gpsd(
            tmp_path, daemon.link, 60.0,
            lambda m: len(tpv3(m)) >= 3 and sky_after_fix(m, {0, 2, 6}) is not None,
            probe=False)
    finally:
        code, err = daemon.stop()
    assert code == 0, err
    assert len(tpv3(messages)) >= 3, f"gpsd reported no 3D fix; daemon stderr: {err}"
    sky = sky_after_fix(messages, {0, 2, 6})
    # u-blox gnssId numbering, as gpsd reports it: GPS 0, Galileo 2, GLONASS 6
    assert sky is not None, "no SKY listing GPS, Galileo and GLONASS after the fix"
    by = {}
    for s in sky["satellites"]:
        by.setdefault(s["gnssid"], []).append(s)
    assert all(1 <= s["PRN"] <= 32 and s["svid"] == s["PRN"] for s in by[0])
    assert all(65 <= s["PRN"] <= 96 and s["svid"] == s["PRN"] - 64 for s in by[6])
    assert all(1 <= s["svid"] <= 36 and s["PRN"] == 300 + s["svid"] for s in by[2])
    # (gpsd 3.22 marks GPS and GLONASS satellites used from their GSA, not Galileo's: it
    # lists them, used none, though the GSA of system ID 3 names them; docs/device.md)
    assert any(s["used"] for s in by[0]) and any(s["used"] for s in by[6])


def test_the_phone_base_profile_writes_as_the_magdeburg_phone_does(tmp_path):
    from pathlib import Path

    from test_cli import write_walk

    from virtualgps.cli import main
    from virtualgps.sky.ephemeris import BUNDLED_EPHEMERIS_DIR

    base = Path(__file__).resolve().parents[1] / "tools" / "phone-base.toml"
    walk = write_walk(tmp_path / "walk.jsonl", n=30, dt_s=1.0)
    out = tmp_path / "phone.nmea"
    sets = [f"--tle={BUNDLED_EPHEMERIS_DIR / f'{g}-2017-03-28.tle'}"
            for g in ("gps-ops", "glo-ops")]
    assert main(["replay", str(walk), "--out", str(out), "--profile", str(base),
                 "--scene", "none", "--origin", "52.14,11.64,100", *sets]) == 0
    lines = out.read_bytes().splitlines(keepends=True)
    # the Magdeburg phone's digits: hhmmss.s, ddmm.mmmmmm, one decimal of HDOP and altitude
    # (its log: $GPGGA,125212.0,5208.411269,N,01138.470760,E,1,09,0.9,60.0,M,45.0,M,,)
    fixed = [ln.split(b",") for ln in lines
             if ln.startswith(b"$GPGGA") and ln.split(b",")[6] != b"0"]
    assert fixed and all(len(f[1]) == 8 and len(f[2].split(b".")[1]) == 6
                         and len(f[8].split(b".")[1]) == 1 for f in fixed)
    assert any(ln.startswith(b"$GLGSV") for ln in lines)
    assert all(parse_both(ln) for ln in lines)


def test_the_phone_profile_is_the_base_with_the_effects_both_data_sets_keep():
    """``phone`` is ``tools/phone-base.toml`` plus what tools/calibrate_phone.py's joint step
    kept (the Magdeburg fit's cn0_tracking: a weak antenna, 27.3 dB-Hz at the zenith; the GSDC
    fit's velocity-aided nav_filter, which smooths the error and follows a car) and the PDOP
    mask added after the fit (its cost measured, docs/profiles.md), nothing else: its error
    models and NMEA stay the base's, so the documented held-out figures describe this file."""
    import tomllib
    from pathlib import Path

    from virtualgps.receiver.profiles import load_profile, profile_path

    root = Path(__file__).resolve().parents[1]
    base = tomllib.loads((root / "tools" / "phone-base.toml").read_text())
    phone = tomllib.loads(profile_path("phone").read_text())
    kept = {"cn0_tracking", "nav_filter"}
    assert set(phone) - set(base) == kept
    assert phone["sky"].pop("pdop_mask") == 25.0 and "pdop_mask" not in base["sky"]
    assert {k: v for k, v in phone.items() if k not in {"name", "description", *kept}} \
        == {k: v for k, v in base.items() if k not in ("name", "description")}
    prof = load_profile("phone")
    assert prof.cn0_tracking.enabled and prof.cn0_tracking.cn0_zenith_dbhz < 30.0
    # (a plain filter of seconds would lag a car by tens of metres: the drive kept only an
    # aided one)
    assert prof.nav_filter.enabled and prof.nav_filter.velocity_aided
    assert not prof.static_hold.enabled
