"""The u-blox UBX core: framing, the input splitter, output messages and the command link.

Every frame we emit is decoded by pyubx2 (an independent UBX implementation) and compared with
the fix record it came from; commands are built by pyubx2 too, as a driver would send them.
The fix records are built by hand so that nothing here depends on the simulation.
"""

from __future__ import annotations

import io
import math
import struct
from datetime import UTC, datetime

import numpy as np
import pymap3d
import pytest
import pyubx2
from pyubx2 import POLL, SET, UBXMessage, UBXReader

from virtualgps.device.nmea import format_sentence
from virtualgps.device.ubx import keys as K
from virtualgps.device.ubx import messages as M
from virtualgps.device.ubx.frame import (
    MAX_INPUT_PAYLOAD_BYTES,
    MAX_LINE_BYTES,
    InputSplitter,
    checksum,
    decode,
    encode,
)
from virtualgps.device.ubx.link import UbxLink, default_settings
from virtualgps.device.ubx.settings import MON_VER_M8, MON_VER_M9
from virtualgps.receiver.records import Fixes

ONE_E7_DEG = 1.5e-7  # lat/lon LSB (1e-7 deg) plus rounding
ONE_MM = 1.0  # mm fields: LSB 1 mm

# Satellites of every system (virtualgps.sky.systems numbering) with their UBX identities,
# written out from the u-blox M8 protocol specification's satellite numbering appendix:
# prn -> (gnssId, svId, NAV-SVINFO svid or None).
SATS = {
    5: (0, 5, 5),          # GPS G05
    131: (1, 131, 131),    # SBAS S31 (PRN 131)
    311: (2, 11, 221),     # Galileo E11
    403: (3, 3, 161),      # BeiDou C03 (B1-B5 -> 159-163)
    420: (3, 20, 47),      # BeiDou C20 (B6-B37 -> 33-64)
    445: (3, 45, None),    # BeiDou C45: no "UBX" svid in NAV-SVINFO
    194: (5, 2, 194),      # QZSS J02
    70: (6, 6, 70),        # GLONASS slot 6
}
T0_UNIX_S = datetime(2024, 3, 28, 12, 46, 40, 200_000, tzinfo=UTC).timestamp()


def make_fixes() -> Fixes:
    """Three epochs: a 3D SBAS fix with the receiver's own sigma, a 2D fix with only a range
    RMS, and no fix (NaN) with satellites still tracked."""
    prn = np.array(list(SATS))
    k = len(prn)
    az = np.array([[10.0, 200.4, 95.5, 300.0, 45.0, 359.7, 180.0, 270.0]] * 3)
    el = np.array([[60.0, 35.5, 20.4, 44.0, 70.0, 15.0, 8.0, 50.0]] * 3)
    el[2, 6] = np.nan  # one satellite with no known position
    cn0 = np.array([[45.0, 38.0, 40.2, 42.0, 33.0, 30.0, np.nan, 41.0]] * 3)
    used = np.zeros((3, k), bool)
    used[0, [0, 2, 3, 4, 7]] = True
    used[1, [0, 3, 7]] = True
    return Fixes(
        t_unix_s=T0_UNIX_S + np.array([0.0, 0.2, 0.4]),
        lat_deg=np.array([52.1405123, -33.8688197, np.nan]),
        lon_deg=np.array([11.6401234, 151.2092955, np.nan]),
        alt_msl_m=np.array([55.123, 12.0, np.nan]),
        geoid_sep_m=np.array([40.5, 22.2, np.nan]),
        quality=np.array([2, 1, 0], np.int8),
        mode=np.array([3, 2, 1], np.int8),
        hdop=np.array([0.9, 1.4, np.nan]),
        vdop=np.array([1.3, 2.0, np.nan]),
        pdop=np.array([1.58, 2.44, np.nan]),
        speed_mps=np.array([3.25, 0.0, np.nan]),
        course_deg=np.array([123.45, np.nan, np.nan]),
        prn=prn, az_deg=az, el_deg=el, cn0_dbhz=cn0,
        in_view=np.isfinite(el) | np.isfinite(cn0), used=used,
        truth_lat_deg=np.zeros(3), truth_lon_deg=np.zeros(3), truth_alt_hae_m=np.zeros(3),
        sigma_enu_m=np.array([[1.2, 1.6, 2.5], [np.nan] * 3, [np.nan] * 3]),
        range_rms_m=np.array([3.0, 3.5, np.nan]),
    )


def parse(frame: bytes):
    """pyubx2's reading of one output frame (raises on a bad checksum or unknown message)."""
    return UBXReader.parse(frame)


def frames_of(data: bytes) -> list[bytes]:
    """Split concatenated UBX frames (and nothing else) by their length fields."""
    out, i = [], 0
    while i < len(data):
        assert data[i : i + 2] == b"\xb5\x62", f"not a frame at byte {i}"
        n = data[i + 4] | (data[i + 5] << 8)
        out.append(data[i : i + n + 8])
        i += n + 8
    return out


def gps_itow_ms(t_unix_s: float) -> int:
    """GPS time of week, ms, by datetime arithmetic (GPS - UTC = 18 s after 2017-01-01)."""
    gps_epoch = datetime(1980, 1, 6, tzinfo=UTC).timestamp()
    return round((t_unix_s - gps_epoch + 18.0) * 1000.0) % 604_800_000


# --- framing ---------------------------------------------------------------------------------


def fletcher8(body: bytes) -> tuple[int, int]:
    a = b = 0
    for x in body:
        a = (a + x) % 256
        b = (b + a) % 256
    return a, b


def test_checksum_matches_the_fletcher_loop_and_known_frames():
    rng = np.random.default_rng(1)
    for n in (0, 1, 2, 7, 100, 1000):
        body = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert checksum(body) == fletcher8(body)
    # Frames every u-blox user knows: the MON-VER poll, ACK-ACK of CFG-PRT, CFG-RATE 5 Hz.
    assert encode(0x0A, 0x04) == bytes.fromhex("b5620a0400000e34")
    assert encode(0x05, 0x01, b"\x06\x00") == bytes.fromhex("b5620501020006000e37")
    assert encode(0x06, 0x08, bytes.fromhex("c80001000100")) == bytes.fromhex(
        "b56206080600c800010001 00de6a".replace(" ", ""))


def test_encode_decode_round_trip_and_pyubx2_agrees():
    f = encode(0x06, 0x08, struct.pack("<HHH", 200, 1, 1))
    assert decode(f) == (0x06, 0x08, struct.pack("<HHH", 200, 1, 1))
    assert decode(f[:-1] + bytes([f[-1] ^ 1])) is None
    m = UBXReader.parse(f, msgmode=SET)
    assert (m.identity, m.measRate, m.navRate) == ("CFG-RATE", 200, 1)
    assert UBXMessage("CFG", "CFG-RATE", SET, measRate=200, navRate=1, timeRef=1).serialize() == f


# --- the splitter ----------------------------------------------------------------------------


def stream() -> tuple[bytes, list[bytes]]:
    """NMEA and UBX interleaved with noise, and the items the splitter must return."""
    f1 = UBXMessage("CFG", "CFG-RATE", SET, measRate=100, navRate=1, timeRef=0).serialize()
    f2 = encode(0x0A, 0x04)
    f3 = encode(0x06, 0x8A, bytes(range(40)))
    l1 = b"$PUBX,41,1,0007,0003,19200,0*25"
    l2 = b"$PMTK000*32"
    data = (b"\x00\xffjunk" + f1 + l1 + b"\r\n" + b"\xb5" + f2 + l2 + b"\n\r" + f3
            + b"\x62\xb5\x00" + f1)
    return data, [f1, l1, f2, l2, f3, f1]


def test_splitter_separates_ubx_and_nmea_at_every_byte_boundary():
    data, want = stream()
    for cut in range(len(data) + 1):
        sp = InputSplitter()
        assert sp.feed(data[:cut]) + sp.feed(data[cut:]) == want, cut
        assert sp.bad_checksum == 0
    sp = InputSplitter()
    got = []
    for b in data:
        got += sp.feed(bytes([b]))
    assert got == want
    # leading junk (6), the LF after CR LF and the CR after LF CR (1 + 1), the lone 0xB5 (1),
    # the noise after the third frame (3)
    assert sp.skipped_bytes == 6 + 1 + 1 + 1 + 3


def test_splitter_drops_bad_checksums_and_finds_the_frame_behind_a_truncated_one():
    good = encode(0x06, 0x08, struct.pack("<HHH", 200, 1, 1))
    bad = good[:-1] + bytes([good[-1] ^ 0x55])
    truncated = encode(0x06, 0x24, bytes(36))[:20]  # its length field reaches into `good`
    sp = InputSplitter()
    assert sp.feed(bad + truncated + good + good) == [good, good]
    # the bad frame, and the truncated one whose announced length swallowed the next frame
    assert sp.bad_checksum == 2
    sp = InputSplitter()
    assert sp.feed(bad + good) == [good] and sp.bad_checksum == 1


def test_splitter_resyncs_on_oversized_length_and_bounds_its_buffer():
    good = encode(0x0A, 0x04)
    false_sync = b"\xb5\x62\x06\x00" + struct.pack("<H", MAX_INPUT_PAYLOAD_BYTES + 1)
    sp = InputSplitter()
    assert sp.feed(false_sync + good) == [good]
    # A frame announcing the maximum payload waits; what is held stays bounded.
    sp = InputSplitter()
    sp.feed(b"\xb5\x62\x06\x8a" + struct.pack("<H", MAX_INPUT_PAYLOAD_BYTES) + bytes(500))
    assert len(sp._buf) <= MAX_INPUT_PAYLOAD_BYTES + 8
    sp = InputSplitter()
    sp.feed(b"$" + b"A" * 10_000)
    assert len(sp._buf) <= MAX_LINE_BYTES + 1 and sp.dropped_lines == 1
    assert sp.feed(b"\r\n$PUBX,00*33\r\n") == [b"$PUBX,00*33"]


def test_splitter_line_broken_by_a_ubx_frame():
    good = encode(0x0A, 0x04)
    sp = InputSplitter()
    assert sp.feed(b"$GPGGA,12" + good + b"$PUBX,00*33\r\n") == [good, b"$PUBX,00*33"]
    assert sp.dropped_lines == 1


# --- output messages -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fixes() -> Fixes:
    return make_fixes()


@pytest.fixture(scope="module")
def sol(fixes):
    return M.solution(fixes)


def all_epoch_frames(sol, i, protver=18.0) -> list[bytes]:
    return [M.nav_pvt(sol, i, protver), M.nav_posllh(sol, i), M.nav_velned(sol, i),
            M.nav_sol(sol, i), M.nav_status(sol, i, 1234, 5678), M.nav_dop(sol, i),
            M.nav_timeutc(sol, i), M.nav_timegps(sol, i), M.nav_sat(sol, i),
            M.nav_svinfo(sol, i), M.nav_eoe(sol, i)]


@pytest.mark.parametrize("i", [0, 1, 2])
def test_every_frame_parses_with_zero_errors(sol, i):
    frames = all_epoch_frames(sol, i) + all_epoch_frames(sol, i, 32.01) + [
        M.mon_hw(), M.mon_rf(), M.mon_ver(MON_VER_M8[0], MON_VER_M8[1], MON_VER_M8[2]),
        M.mon_ver(*MON_VER_M9), M.ack(6, 0), M.nak(6, 0x8A)]
    sizes = {"NAV-PVT": 92, "NAV-POSLLH": 28, "NAV-VELNED": 36, "NAV-SOL": 52,
             "NAV-STATUS": 16, "NAV-DOP": 18, "NAV-TIMEUTC": 20, "NAV-TIMEGPS": 16,
             "NAV-EOE": 4, "MON-HW": 60, "MON-RF": 28, "ACK-ACK": 2, "ACK-NAK": 2}
    for f in frames:
        m = parse(f)
        n = len(f) - 8
        if m.identity in sizes:
            assert n == sizes[m.identity], m.identity
    # and as one stream through pyubx2's reader, raising on anything it cannot parse
    rd = UBXReader(io.BytesIO(b"".join(frames)), quitonerror=2)
    assert sum(1 for _ in rd) == len(frames)


def test_nav_pvt_fields_equal_the_fix_record(fixes, sol):
    for i in (0, 1):
        m = parse(M.nav_pvt(sol, i))
        assert m.iTOW == gps_itow_ms(fixes.t_unix_s[i])
        utc = datetime.fromtimestamp(fixes.t_unix_s[i], UTC)
        assert (m.year, m.month, m.day, m.hour, m.min, m.second) == (
            utc.year, utc.month, utc.day, utc.hour, utc.minute, utc.second)
        assert abs(m.nano - utc.microsecond * 1000) <= 1_000_000
        assert m.fixType == (3 if i == 0 else 2) and m.gnssFixOk == 1
        assert m.diffSoln == (1 if i == 0 else 0)
        assert m.numSV == fixes.used[i].sum()
        assert abs(m.lat - fixes.lat_deg[i]) <= ONE_E7_DEG
        assert abs(m.lon - fixes.lon_deg[i]) <= ONE_E7_DEG
        hae_mm = (fixes.alt_msl_m[i] + fixes.geoid_sep_m[i]) * 1000
        assert abs(m.height - hae_mm) <= ONE_MM
        assert abs(m.hMSL - fixes.alt_msl_m[i] * 1000) <= ONE_MM
        assert m.pDOP == pytest.approx(fixes.pdop[i], abs=0.005)
        assert m.validDate == m.validTime == m.fullyResolved == 1
    m = parse(M.nav_pvt(sol, 0))
    s = fixes.sigma_enu_m[0]
    assert abs(m.hAcc - math.hypot(s[0], s[1]) * 1000) <= ONE_MM  # receiver's own sigma
    assert abs(m.vAcc - s[2] * 1000) <= ONE_MM
    c = math.radians(fixes.course_deg[0])
    assert abs(m.velN - 3250 * math.cos(c)) <= ONE_MM and abs(m.velE - 3250 * math.sin(c)) <= ONE_MM
    assert (m.velD, m.gSpeed) == (0, 3250)
    assert m.headMot == pytest.approx(123.45, abs=1e-5)
    m = parse(M.nav_pvt(sol, 1))
    assert abs(m.hAcc - 1.4 * 3.5 * 1000) <= ONE_MM  # HDOP x range RMS where no sigma
    assert abs(m.vAcc - 2.0 * 3.5 * 1000) <= ONE_MM


def test_no_fix_epoch_is_written_as_a_module_before_its_fix(sol):
    m = parse(M.nav_pvt(sol, 2, protver=32.01))
    assert (m.fixType, m.gnssFixOk, m.numSV, m.lat, m.lon, m.height) == (0, 0, 0, 0, 0, 0)
    assert m.hMSL == -17000 and m.hAcc == m.vAcc == m.tAcc == 0xFFFFFFFF
    assert m.pDOP == 99.99 and m.headAcc == 180.0 and m.invalidLlh == 1
    assert m.fullyResolved == 0 and m.validTime == 1  # satellites tracked: time known
    for f in all_epoch_frames(sol, 2):
        parse(f)
    d = parse(M.nav_dop(sol, 2))
    assert d.hDOP == d.vDOP == d.gDOP == 99.99
    s = parse(M.nav_status(sol, 2, 0, 400))
    assert (s.gpsFix, s.gpsFixOk) == (0, 0)


def test_secondary_nav_messages_agree_with_pvt(fixes, sol):
    pvt = parse(M.nav_pvt(sol, 0))
    llh = parse(M.nav_posllh(sol, 0))
    assert (llh.iTOW, llh.lat, llh.lon, llh.height, llh.hMSL, llh.hAcc) == (
        pvt.iTOW, pvt.lat, pvt.lon, pvt.height, pvt.hMSL, pvt.hAcc)
    vel = parse(M.nav_velned(sol, 0))
    assert abs(vel.velN * 10 - pvt.velN) <= 10 and vel.gSpeed == 325
    assert vel.heading == pytest.approx(123.45, abs=1e-5)
    solm = parse(M.nav_sol(sol, 0))
    x, y, z = pymap3d.geodetic2ecef(fixes.lat_deg[0], fixes.lon_deg[0],
                                    fixes.alt_msl_m[0] + fixes.geoid_sep_m[0])
    assert abs(solm.ecefX - x * 100) <= 1 and abs(solm.ecefY - y * 100) <= 1
    assert abs(solm.ecefZ - z * 100) <= 1
    gps_epoch = datetime(1980, 1, 6, tzinfo=UTC).timestamp()
    assert solm.week == int((fixes.t_unix_s[0] - gps_epoch + 18) // 604800)
    assert (solm.gpsFix, solm.numSV, solm.gpsfixOK) == (3, 5, 1)
    tu = parse(M.nav_timeutc(sol, 0))
    assert (tu.iTOW, tu.hour, tu.min, tu.sec, tu.nano) == (pvt.iTOW, 12, 46, 40, 200_000_000)
    assert tu.validUTC == 1
    tg = parse(M.nav_timegps(sol, 0))
    assert (tg.iTOW, tg.week, tg.leapS) == (pvt.iTOW, solm.week, 18)
    dop = parse(M.nav_dop(sol, 0))
    assert (dop.hDOP, dop.vDOP, dop.pDOP) == (0.9, 1.3, 1.58)
    assert dop.nDOP ** 2 + dop.eDOP ** 2 == pytest.approx(0.81, abs=0.02)
    assert dop.gDOP == pytest.approx(math.hypot(dop.pDOP, dop.tDOP), abs=0.015)


def test_nav_dop_closed_form():
    # Zenith plus three horizon satellites 120 deg apart: HDOP = VDOP = 2/sqrt(3); with one
    # clock, TDOP = 1/sqrt(3) and nDOP = eDOP = sqrt(2/3), GDOP = sqrt(3).
    h = 2 / math.sqrt(3)
    f = Fixes(
        t_unix_s=np.array([T0_UNIX_S]), lat_deg=np.array([0.0]), lon_deg=np.array([0.0]),
        alt_msl_m=np.array([0.0]), geoid_sep_m=np.array([0.0]), quality=np.array([1]),
        mode=np.array([3]), hdop=np.array([h]), vdop=np.array([h]),
        pdop=np.array([math.hypot(h, h)]), speed_mps=np.array([0.0]),
        course_deg=np.array([0.0]), prn=np.array([1, 2, 3, 4]),
        az_deg=np.array([[0.0, 0.0, 120.0, 240.0]]), el_deg=np.array([[90.0, 0.0, 0.0, 0.0]]),
        cn0_dbhz=np.full((1, 4), 40.0), in_view=np.ones((1, 4), bool),
        used=np.ones((1, 4), bool), truth_lat_deg=np.zeros(1), truth_lon_deg=np.zeros(1),
        truth_alt_hae_m=np.zeros(1))
    d = parse(M.nav_dop(M.solution(f), 0))
    assert d.tDOP == pytest.approx(1 / math.sqrt(3), abs=0.006)
    assert d.nDOP == pytest.approx(math.sqrt(2 / 3), abs=0.006)
    assert d.eDOP == pytest.approx(math.sqrt(2 / 3), abs=0.006)
    assert d.gDOP == pytest.approx(math.sqrt(3), abs=0.006)


def test_nav_sat_lists_every_satellite_with_its_identity(fixes, sol):
    for i in range(3):
        m = parse(M.nav_sat(sol, i))
        listed = [j for j in range(len(fixes.prn))
                  if fixes.in_view[i, j] or np.isfinite(fixes.cn0_dbhz[i, j])]
        assert m.numSvs == len(listed)
        got = {}
        for k in range(1, m.numSvs + 1):
            gid = getattr(m, f"gnssId_{k:02d}")
            got[(gid, getattr(m, f"svId_{k:02d}"))] = k
        order = list(got)
        assert order == sorted(order)  # gnssId, then svId
        for j in listed:
            prn = int(fixes.prn[j])
            k = got[SATS[prn][:2]]
            cn0, el, az = fixes.cn0_dbhz[i, j], fixes.el_deg[i, j], fixes.az_deg[i, j]
            assert getattr(m, f"cno_{k:02d}") == (round(cn0) if np.isfinite(cn0) else 0)
            if np.isfinite(el):
                assert getattr(m, f"elev_{k:02d}") == round(el)
                assert getattr(m, f"azim_{k:02d}") == round(az) % 360
            else:
                assert getattr(m, f"elev_{k:02d}") == -91  # "unknown if out of range"
            assert getattr(m, f"svUsed_{k:02d}") == int(fixes.used[i, j])
            assert getattr(m, f"qualityInd_{k:02d}") == (
                7 if fixes.used[i, j] else 4 if np.isfinite(cn0) else 1)
            assert getattr(m, f"diffCorr_{k:02d}") == int(fixes.used[i, j] and i == 0)


def test_nav_svinfo_uses_the_single_number_svids(fixes, sol):
    m = parse(M.nav_svinfo(sol, 0))
    assert m.chipGen == 4
    svids = {getattr(m, f"svid_{k:02d}") for k in range(1, m.numCh + 1)}
    assert svids == {v[2] for v in SATS.values() if v[2] is not None}
    for k in range(1, m.numCh + 1):
        prn = next(p for p, v in SATS.items() if v[2] == getattr(m, f"svid_{k:02d}"))
        j = list(fixes.prn).index(prn)
        assert getattr(m, f"svUsed_{k:02d}") == int(fixes.used[0, j])


def test_ubx_numbers_read_back_to_ours():
    """Every satellite number of every system goes to its gnssId/svId and NAV-SVINFO svid and
    back (what the UBX and gpsd log readers rely on); IMES and an unknown GLONASS slot (255)
    name none, nor does an svid outside the appendix's ranges."""
    from virtualgps.sky.systems import SYSTEMS

    nums = np.concatenate([np.arange(s.first, s.last + 1) for s in SYSTEMS])
    gnss, sv, svinfo = M.ubx_ids(nums)
    np.testing.assert_array_equal(M.numbers_of_ubx_ids(gnss, sv), nums)
    has = svinfo > 0  # (BeiDou above C37 has no NAV-SVINFO number)
    np.testing.assert_array_equal(M.numbers_of_svinfo_ids(svinfo[has]), nums[has])
    assert (nums[~has] > 437).all()
    np.testing.assert_array_equal(M.numbers_of_ubx_ids([4, 6, 0], [1, 255, 40]), [0, 0, 0])
    np.testing.assert_array_equal(M.numbers_of_svinfo_ids([0, 97, 255, 210]), [0, 0, 0, 0])


def test_mon_ver_strings():
    m = parse(M.mon_ver(*MON_VER_M8))
    assert m.swVersion.rstrip(b"\0") == b"ROM CORE 3.01 (107888)"
    assert m.hwVersion.rstrip(b"\0") == b"00080000"
    assert m.extension_02.rstrip(b"\0") == b"PROTVER=18.00"


# --- the link --------------------------------------------------------------------------------


def cfg(name: str, **kw) -> bytes:
    return UBXMessage("CFG", name, SET, **kw).serialize()


def poll(cls: str, name: str, **kw) -> bytes:
    return UBXMessage(cls, name, POLL, **kw).serialize()


def replies(resps) -> list:
    return [parse(f) for r in resps for f in frames_of(r.reply)]


def acked(resp, name: str) -> bool:
    ms = [parse(f) for f in frames_of(resp.reply)]
    return ms[-1].identity == "ACK-ACK" and pyubx2.UBX_MSGIDS[
        bytes([ms[-1].clsID, ms[-1].msgID])] == name


def test_px4_like_m8_sequence():
    link = UbxLink(default_settings("M8"))
    # PX4 first tries CFG-VALSET (protocol 27+); an M8 NAKs it.
    probe = UBXMessage.config_set(1, 0, [("CFG_UART1INPROT_UBX", 1)]).serialize()
    (r,) = link.feed(probe)
    assert replies([r])[0].identity == "ACK-NAK"
    # CFG-PRT for UART1 and USB in one message, UBX in/out only, at 38400.
    one = UBXMessage("CFG", "CFG-PRT", SET, portID=1, charLen=3, parity=4, baudRate=38400,
                     inUBX=1, inRTCM=1, outUBX=1).payload
    usb = UBXMessage("CFG", "CFG-PRT", SET, portID=3, baudRate=38400, inUBX=1, inRTCM=1,
                     outUBX=1).payload
    (r,) = link.feed(encode(0x06, 0x00, one + usb))
    assert acked(r, "CFG-PRT")
    assert r.settings is not None and r.settings.baud == 38400  # applied after the ACK
    assert not link.nmea_enabled()
    steps = [cfg("CFG-RATE", measRate=200, navRate=1, timeRef=0),
             cfg("CFG-NAV5", dyn=1, posFixMode=1, dynModel=8, fixMode=3),
             encode(0x06, 0x01, bytes([0x01, 0x07, 1])),  # CFG-MSG, this port's rate
             poll("MON", "MON-VER")]
    rs = link.feed(b"".join(steps))
    assert [r.command for r in rs] == ["CFG-RATE", "CFG-NAV5", "CFG-MSG", "MON-VER"]
    assert all(acked(r, r.command) for r in rs[:3])
    ver = parse(rs[3].reply)
    assert ver.hwVersion.rstrip(b"\0") == b"00080000"
    exts = [getattr(ver, f"extension_{k:02d}").rstrip(b"\0") for k in range(1, 5)]
    assert b"PROTVER=18.00" in exts and b"FWVER=SPG 3.01" in exts
    s = link.settings
    assert (s.baud, s.meas_rate_ms, s.nav_rate, s.dyn_model) == (38400, 200, 1, 8)
    assert s.rate(0x01, 0x07) == 1 and s.ports[3].out_proto == 1
    # The epoch output is NAV-PVT only (UBX out, NMEA off), every solution.
    f = make_fixes()
    out = link.output(f, 0, 0, nmea=b"$GPGGA,...\r\n")
    assert [parse(x).identity for x in frames_of(out)] == ["NAV-PVT"]


def test_ardupilot_like_sequence():
    link = UbxLink(default_settings("M8"))
    rs = link.feed(poll("CFG", "CFG-PRT", portID=1))
    prt = replies(rs)
    assert (prt[0].identity, prt[0].portID, prt[0].baudRate) == ("CFG-PRT", 1, 9600)
    assert prt[1].identity == "ACK-ACK"
    rs = link.feed(encode(6, 0x24) + encode(6, 0x3E) + encode(6, 0x16) + encode(6, 0x08))
    nav5, gnss, sbas, rate = (replies([r])[0] for r in rs)
    assert (nav5.dynModel, nav5.minElev) == (0, 5)
    assert gnss.numConfigBlocks == 7 and sbas.enabled == 1 and rate.measRate == 1000
    # Change the engine as ArduPilot does: the polled NAV5 back with a mask; GNSS with
    # Galileo on; message rates by the 3-byte CFG-MSG; then save.
    nav_back = bytearray(frames_of(rs[0].reply)[0][6:-2])
    nav_back[0:2] = (0x0001 | 0x0002).to_bytes(2, "little")
    nav_back[2] = 7
    nav_back[12] = 10
    g = bytearray(frames_of(rs[1].reply)[0][6:-2])
    for j in range(4, len(g), 8):
        if g[j] == 2:  # Galileo
            g[j + 4] |= 1
    cmds = [encode(6, 0x24, bytes(nav_back)), encode(6, 0x3E, bytes(g)),
            cfg("CFG-RATE", measRate=200, navRate=1, timeRef=0)]
    for mid in (0x02, 0x03, 0x06, 0x12, 0x04, 0x07, 0x20):
        cmds.append(encode(6, 0x01, bytes([0x01, mid, 1])))
    cmds += [encode(6, 0x01, bytes([0x0A, 0x09, 2])), poll("MON", "MON-VER"),
             encode(6, 0x31), encode(6, 0x09, struct.pack("<IIIB", 0, 0xFFFF, 0, 0x17))]
    rs = link.feed(b"".join(cmds))
    assert len(rs) == len(cmds)
    assert all(acked(r, r.command) for r in rs if r.command.startswith("CFG"))
    assert [m.identity for m in replies(rs[-3:-1])] == ["MON-VER", "CFG-TP5", "ACK-ACK"]
    s = link.settings
    assert (s.dyn_model, s.nav5.min_elev_deg) == (7, 10)
    assert "Galileo" in s.enabled_gnss and link.saved == s
    # CFG-MSG poll answers the 8-byte form with the UART1 rate.
    (r,) = link.feed(poll("CFG", "CFG-MSG", msgClass=0x01, msgID=0x12))
    m = replies([r])[0]
    assert (m.identity, m.rateUART1) == ("CFG-MSG", 1)
    f = make_fixes()
    out = link.output(f, 0, 0, nmea=b"")
    ids = [parse(x).identity for x in frames_of(out)]
    assert ids == ["NAV-POSLLH", "NAV-STATUS", "NAV-DOP", "NAV-SOL", "NAV-PVT", "NAV-VELNED",
                   "NAV-TIMEGPS", "MON-HW"]
    ids = [parse(x).identity for x in frames_of(link.output(f, 1, 1, nmea=b""))]
    assert "MON-HW" not in ids  # rate 2


def test_output_order_rates_and_nmea_placement():
    link = UbxLink(default_settings("M8"))
    for mid in (0x35, 0x07, 0x61, 0x21):
        link.feed(encode(6, 0x01, bytes([0x01, mid, 1 if mid != 0x35 else 3])))
    f = make_fixes()
    nmea = b"$GPGGA,x*00\r\n"
    out0 = link.output(f, 0, 0, nmea=nmea)
    k = out0.index(nmea)
    head, tail = out0[:k], out0[k + len(nmea):]
    assert [parse(x).identity for x in frames_of(head)] == ["NAV-PVT", "NAV-TIMEUTC", "NAV-SAT"]
    assert [parse(x).identity for x in frames_of(tail)] == ["NAV-EOE"]
    out1 = link.output(f, 1, 1, nmea=nmea)
    ids = [parse(x).identity for x in frames_of(out1[: out1.index(nmea)])]
    assert ids == ["NAV-PVT", "NAV-TIMEUTC"]  # NAV-SAT at rate 3: epochs 0, 3, 6, ...
    assert link.nmea_every() == {s: 1 for s in ("GGA", "GLL", "GSA", "GSV", "RMC", "VTG")}
    # NAV-STATUS carries ms since the first epoch and the time to first fix; a NAV poll
    # answers for the last epoch output.
    link.output(f, 2, 2)
    (r,) = link.feed(encode(1, 3))
    st = parse(r.reply)
    assert (st.msss, st.ttff, st.gpsFix) == (400, 0, 0)


def test_m9_valset_valget_and_unknown_key():
    link = UbxLink(default_settings("M9"))
    assert link.settings.baud == 38400
    msg = UBXMessage.config_set(1, 0, [("CFG_UART1_BAUDRATE", 115200),
                                       ("CFG_MSGOUT_UBX_NAV_PVT_UART1", 1),
                                       ("CFG_RATE_MEAS", 100)]).serialize()
    (r,) = link.feed(msg)
    assert acked(r, "CFG-VALSET") and r.settings.baud == 115200
    s = link.settings
    assert (s.baud, s.rate(1, 7), s.meas_rate_ms) == (115200, 1, 100)
    (r,) = link.feed(UBXMessage.config_poll(0, 0, ["CFG_UART1_BAUDRATE",
                                                   "CFG_MSGOUT_UBX_NAV_PVT_UART1",
                                                   "CFG_RATE_MEAS"]).serialize())
    got, ack_msg = replies([r])
    assert ack_msg.identity == "ACK-ACK"
    assert (got.CFG_UART1_BAUDRATE, got.CFG_MSGOUT_UBX_NAV_PVT_UART1, got.CFG_RATE_MEAS) == (
        115200, 1, 100)
    before = link.settings
    bad = UBXMessage.config_set(1, 0, [("CFG_RATE_MEAS", 200),
                                       ("CFG_NAVHPG_DGNSSMODE", 3)]).serialize()
    (r,) = link.feed(bad)
    assert replies([r])[0].identity == "ACK-NAK" and link.settings is before
    invalid = UBXMessage.config_set(1, 0, [("CFG_NAVSPG_DYNMODEL", 1)]).serialize()
    (r,) = link.feed(invalid)
    assert replies([r])[0].identity == "ACK-NAK" and link.settings is before


def test_m9_px4_probe_layers_valdel_and_transactions():
    link = UbxLink(default_settings("M9"))
    probe = UBXMessage.config_set(1, 0, [
        ("CFG_UART1_STOPBITS", 1), ("CFG_UART1_DATABITS", 0), ("CFG_UART1_PARITY", 0),
        ("CFG_UART1INPROT_UBX", 1), ("CFG_UART1INPROT_NMEA", 0),
        ("CFG_UART1OUTPROT_UBX", 1), ("CFG_UART1OUTPROT_NMEA", 0)]).serialize()
    (r,) = link.feed(probe)
    assert acked(r, "CFG-VALSET") and not link.nmea_enabled()
    cfg2 = UBXMessage.config_set(1, 0, [
        ("CFG_NAVSPG_FIXMODE", 3), ("CFG_NAVSPG_UTCSTANDARD", 3), ("CFG_NAVSPG_DYNMODEL", 8),
        ("CFG_ODO_USE_ODO", 0), ("CFG_ITFM_ENABLE", 1), ("CFG_RATE_MEAS", 125),
        ("CFG_RATE_NAV", 1), ("CFG_RATE_TIMEREF", 0), ("CFG_MSGOUT_UBX_NAV_SAT_UART1", 10),
        ("CFG_MSGOUT_UBX_MON_RF_UART1", 1), ("CFG_MSGOUT_UBX_RXM_RTCM_UART1", 1),
        ("CFG_SIGNAL_GAL_ENA", 0), ("CFG_USBINPROT_NMEA", 0)]).serialize()
    (r,) = link.feed(cfg2)
    assert acked(r, "CFG-VALSET")
    assert link.settings.dyn_model == 8 and "Galileo" not in link.settings.enabled_gnss
    (r,) = link.feed(UBXMessage.config_poll(0, 0, ["CFG_ITFM_ENABLE"]).serialize())
    assert replies([r])[0].CFG_ITFM_ENABLE == 1
    # BBR only: RAM unchanged; VALGET of BBR sees it; VALDEL brings back the default.
    (r,) = link.feed(UBXMessage.config_set(2, 0, [("CFG_RATE_MEAS", 500)]).serialize())
    assert acked(r, "CFG-VALSET") and r.settings is None and link.settings.meas_rate_ms == 125
    (r,) = link.feed(UBXMessage.config_poll(1, 0, ["CFG_RATE_MEAS"]).serialize())
    assert replies([r])[0].CFG_RATE_MEAS == 500
    (r,) = link.feed(UBXMessage.config_del(2, 0, ["CFG_RATE_MEAS"]).serialize())
    assert acked(r, "CFG-VALDEL") and link.saved.meas_rate_ms == 1000
    # A transaction: nothing applies until the last message.
    start = UBXMessage.config_set(1, 1, [("CFG_RATE_MEAS", 200)]).serialize()
    more = UBXMessage.config_set(1, 2, [("CFG_RATE_NAV", 2)]).serialize()
    end = UBXMessage.config_set(1, 3, [("CFG_NAVSPG_DYNMODEL", 4)]).serialize()
    rs = link.feed(start + more)
    assert all(acked(r, "CFG-VALSET") for r in rs) and link.settings.meas_rate_ms == 125
    (r,) = link.feed(end)
    s = link.settings
    assert acked(r, "CFG-VALSET") and (s.meas_rate_ms, s.nav_rate, s.dyn_model) == (200, 2, 4)
    # Wildcard: every RATE key; an unknown key NAKs the VALGET.
    (r,) = link.feed(encode(6, 0x8B, bytes(4) + (0x0021FFFF).to_bytes(4, "little")))
    m = replies([r])[0]
    assert (m.CFG_RATE_MEAS, m.CFG_RATE_NAV) == (200, 2)
    (r,) = link.feed(encode(6, 0x8B, bytes(4) + (0x40140011).to_bytes(4, "little")))
    assert replies([r])[0].identity == "ACK-NAK"
    # The legacy messages still work on M9 (drivers send them), and VALGET sees their effect.
    (r,) = link.feed(cfg("CFG-RATE", measRate=250, navRate=1, timeRef=1))
    assert acked(r, "CFG-RATE")
    (r,) = link.feed(UBXMessage.config_poll(0, 0, ["CFG_RATE_MEAS"]).serialize())
    assert replies([r])[0].CFG_RATE_MEAS == 250
    # M9 output: NAV-SVINFO/SOL are not M9 messages; MON-RF is.
    link.feed(encode(6, 0x01, bytes([0x01, 0x30, 1])))
    out = link.output(make_fixes(), 0, 0)
    ids = [parse(x).identity for x in frames_of(out)]
    assert ids == ["NAV-SAT", "MON-RF"]


def test_cfg_rst_restarts_without_reply():
    link = UbxLink(default_settings("M8"))
    kinds = []
    for mask, mode in ((0x0000, 2), (0x0001, 2), (0xFFFF, 1), (0x0010, 2)):
        (r,) = link.feed(encode(6, 0x04, struct.pack("<HBx", mask, mode)))
        assert r.reply == b""
        kinds.append(r.restart)
    assert kinds == ["hot", "warm", "cold", "cold"]
    (r,) = link.feed(encode(6, 0x04, struct.pack("<HBx", 0, 8)))
    assert r.stop and link.output(make_fixes(), 0, 0, nmea=b"$X\r\n") == b""
    (r,) = link.feed(encode(6, 0x04, struct.pack("<HBx", 0, 9)))
    assert r.restart == "hot" and link.output(make_fixes(), 0, 0, nmea=b"$X\r\n") == b"$X\r\n"
    (r,) = link.feed(encode(6, 0x04, b"\x00"))
    assert replies([r])[0].identity == "ACK-NAK"


def test_pubx41_and_pubx40():
    link = UbxLink(default_settings("M8"))
    (r,) = link.feed(b"$PUBX,41,1,0003,0001,115200,0*1E\r\n")
    assert r.reply == b"" and r.settings.baud == 115200 and not link.nmea_enabled()
    assert link.feed(b"$PUBX,41,1,0003,0003,57600,0*00\r\n") == []  # wrong checksum
    link.feed(format_sentence("PUBX,40,GSV,0,5,0,0,0,0").encode())
    assert link.settings.rate(0xF0, 0x03) == 5
    # With NMEA input switched off, $PUBX is ignored.
    link.feed(encode(6, 0x00, UBXMessage("CFG", "CFG-PRT", SET, portID=1, charLen=3,
                                          parity=4, baudRate=115200, inUBX=1,
                                          outUBX=1).payload))
    assert link.feed(format_sentence("PUBX,41,1,0003,0003,9600,0").encode()) == []
    assert link.settings.baud == 115200


def test_unknown_and_malformed():
    link = UbxLink(default_settings("M8"))
    (r,) = link.feed(encode(6, 0x77, b"\x01"))
    assert replies([r])[0].identity == "ACK-NAK"
    assert link.feed(encode(0x42, 0x42, b"x")) == []
    assert link.feed(encode(0x01, 0x07)) == []  # a NAV poll before any epoch: silence
    for mid, payload in ((0x08, b"\x01\x02"), (0x24, bytes(35)), (0x00, bytes(21)),
                         (0x01, bytes(5)), (0x3E, b"\x00\x20\x20\x02" + bytes(8)),
                         (0x08, struct.pack("<HHH", 10, 1, 0)),
                         (0x00, struct.pack("<BxHIIHHH2x", 1, 0, 0x8C0, 12345, 1, 1, 0))):
        (r,) = link.feed(encode(6, mid, payload))
        assert replies([r])[0].identity == "ACK-NAK", hex(mid)
    # With UBX input switched off, UBX commands are ignored.
    link.feed(b"$PUBX,41,1,0002,0003,9600,0*15\r\n")
    assert link.settings.ports[1].in_proto == 2
    assert link.feed(poll("MON", "MON-VER")) == []
    assert link.internal_errors == 0


def test_fuzz_never_raises():
    rng = np.random.default_rng(24)
    for generation in ("M8", "M9"):
        link = UbxLink(default_settings(generation))
        f = make_fixes()
        for step in range(400):
            if step % 2:
                data = rng.integers(0, 256, int(rng.integers(0, 200)), dtype=np.uint8).tobytes()
            else:
                cls = int(rng.choice([0x01, 0x05, 0x06, 0x06, 0x06, 0x0A, 0xF0]))
                mid = int(rng.choice([0x00, 0x01, 0x04, 0x08, 0x09, 0x16, 0x24, 0x3E, 0x8A,
                                      0x8B, 0x8C, 0x23, 0x31, 0x02, 0x07, 0x35,
                                      int(rng.integers(0, 256))]))
                n = int(rng.choice([0, 1, 2, 3, 4, 6, 8, 12, 20, 36, 40, int(rng.integers(0, 90))]))
                data = encode(cls, mid, rng.integers(0, 256, n, dtype=np.uint8).tobytes())
            for r in link.feed(data):
                for fr in frames_of(r.reply):
                    parse(fr)
            if link.settings.ports[1].in_proto & 1 == 0:  # locked out: start again
                link = UbxLink(default_settings(generation))
            out = link.output(f, step % 3, step)
            for fr in frames_of(out):
                parse(fr)
        assert link.internal_errors == 0


def test_keys_table_matches_pyubx2():
    from pyubx2.ubxtypes_configdb import UBX_CONFIG_DATABASE

    for key in K.KEYS.values():
        name = key.name.replace("-", "_")
        assert UBX_CONFIG_DATABASE[name][0] == key.key_id, key.name
