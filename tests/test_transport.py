"""Output devices through a real pty and pyserial's loop://.

Timing tolerances are loose (machines under load), but every test runs in a few seconds at most.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import stat
import termios
import time
from pathlib import Path

import pytest

from virtualgps.device.output import FileSink
from virtualgps.device.pty import PtyDevice
from virtualgps.device.serialport import SerialDevice
from virtualgps.exceptions import ConfigError, VirtualGPSError

SENTENCE = re.compile(rb"\$EP,(\d{6}),x*\r\n")
ATTACH_S = 0.2  # the writer notices a new client within 50 ms; leave margin


def epoch(i: int, n_bytes: int = 600) -> bytes:
    """Return an epoch of exactly ``n_bytes`` whose one sentence carries the marker ``i``."""
    head = b"$EP,%06d," % i
    return head + b"x" * (n_bytes - len(head) - 2) + b"\r\n"


def open_client(path: Path | str, flags: int = os.O_RDWR) -> int:
    return os.open(path, flags | os.O_NOCTTY | os.O_NONBLOCK)


def read_for(fd: int, duration_s: float, until: int | None = None) -> bytes:
    """Read ``fd`` for ``duration_s`` (or until ``until`` bytes arrived)."""
    data = bytearray()
    deadline = time.monotonic() + duration_s
    while time.monotonic() < deadline and (until is None or len(data) < until):
        readable, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        if readable:
            try:
                data += os.read(fd, 65536)
            except BlockingIOError:
                pass
    return bytes(data)


def drain(fd: int) -> bytes:
    """Everything readable on ``fd`` now, without waiting."""
    data = bytearray()
    while True:
        try:
            got = os.read(fd, 65536)
        except BlockingIOError:
            return bytes(data)
        if not got:
            return bytes(data)
        data += got


def first_marker(data: bytes) -> int:
    match = SENTENCE.search(data)
    assert match, f"no complete sentence in {data[:80]!r}"
    return int(match.group(1))


@contextlib.contextmanager
def fleet_device(tmp_path: Path, **kwargs):
    """A device stepped by a :class:`PtyLoop` (as a fleet's are), with a reading client
    attached: yields (loop, device, client fd)."""
    from virtualgps.run.fleet.ptyloop import PtyLoop

    loop = PtyLoop()
    dev = PtyDevice(tmp_path / "gps0", baud=115200, threaded=False, **kwargs)
    loop.add(dev)
    fd = open_client(tmp_path / "gps0", os.O_RDONLY)
    try:
        deadline = time.monotonic() + 2.0
        while not dev.reader_attached and time.monotonic() < deadline:
            loop.wait(time.monotonic() + 0.05)
        assert dev.reader_attached
        yield loop, dev, fd
    finally:
        os.close(fd)
        loop.close()


def test_a_fleet_device_hands_every_epoch_to_a_reading_client_at_once(tmp_path: Path):
    # A device its owner steps (a fleet's) writes an epoch within write_epoch when the line is
    # idle. What the client left unread is bounded by the bytes written since the last
    # measurement; past the cap the epoch used to wait for the loop's next step: every fourth
    # epoch of a 10 Hz fleet came 20-30 ms late although the client read everything.
    waited = []
    with fleet_device(tmp_path, chunk_s=0.1) as (loop, dev, fd):
        for i in range(20):
            t0 = time.monotonic()
            dev.write_epoch(epoch(i, 450))
            got = read_for(fd, 0.03, until=450)  # (the loop is not stepped meanwhile)
            if not SENTENCE.search(got) or first_marker(got) != i:
                waited.append(i)
            loop.wait(t0 + 0.1)
            drain(fd)
    assert waited == []


def test_a_fleet_devices_client_that_stops_reading_resumes_with_recent_epochs(tmp_path: Path):
    # A fleet's device measures what its client left unread when writing an epoch at once, and
    # a measurement finding everything read stands in for the step's next one: a client that
    # read everything and then stopped must still have its stale output discarded.
    max_backlog_s, period_s = 0.5, 0.05
    with fleet_device(tmp_path, max_backlog_s=max_backlog_s) as (loop, dev, fd):
        written_at: dict[int, float] = {}
        next_s = time.monotonic()
        for i in range(60):  # 3 s of 200-byte epochs at 20 Hz; read for the first second only
            written_at[i] = time.monotonic()
            dev.write_epoch(epoch(i, 200))
            next_s += period_s
            loop.wait(next_s)
            if i < 20:
                drain(fd)
        t_read = time.monotonic()
        data = b""
        while time.monotonic() < t_read + 0.3:  # (the loop writes what the flush put back)
            loop.wait(time.monotonic() + 0.01)
            data += drain(fd)
    marker = first_marker(data)
    assert marker > 40, f"read epoch {marker} of 0..59: stale output was not discarded"
    assert t_read - written_at[marker] < max_backlog_s + 0.3
    assert dev.kernel_flushes >= 1


@pytest.fixture
def pty(tmp_path: Path):
    with PtyDevice(tmp_path / "gps0") as device:
        yield device


# -- pty: device node, link, termios ------------------------------------------------------------


def test_link_points_at_slave_and_is_removed_on_close(tmp_path: Path) -> None:
    link = tmp_path / "gps0"
    device = PtyDevice(link)
    assert link.is_symlink()
    assert os.readlink(link) == str(device.slave_path)
    assert stat.S_ISCHR(os.stat(link).st_mode)
    assert device.describe() == f"{device.slave_path} -> {link}"
    assert device.path == str(link)
    # readable and writable by any user, as gpsfake makes its ptys
    assert stat.S_IMODE(os.stat(device.slave_path).st_mode) == 0o666
    device.close()
    assert not os.path.lexists(link)
    device.close()  # idempotent
    with pytest.raises(VirtualGPSError):
        device.write_epoch(b"late\r\n")


def test_existing_symlink_is_replaced(tmp_path: Path) -> None:
    link = tmp_path / "gps0"
    link.symlink_to("/dev/pts/does-not-exist")  # a crashed run's dangling link
    with PtyDevice(link) as device:
        assert os.readlink(link) == str(device.slave_path)
    assert not os.path.lexists(link)


def test_refuses_to_overwrite_a_regular_file(tmp_path: Path) -> None:
    path = tmp_path / "gps0"
    path.write_text("precious")
    with pytest.raises(VirtualGPSError, match="not a symlink"):
        PtyDevice(path)
    assert path.read_text() == "precious"


def test_without_link(tmp_path: Path) -> None:
    with PtyDevice(None) as device:
        assert device.describe() == str(device.slave_path)
        assert device.path == str(device.slave_path)


def test_non_standard_baud_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="38400"):
        PtyDevice(None, baud=12345)


def test_raw_mode_crlf_unchanged_and_no_echo(pty: PtyDevice) -> None:
    client = open_client(pty.path)
    try:
        attrs = termios.tcgetattr(client)
        assert attrs[4] == attrs[5] == termios.B38400
        assert not attrs[3] & (termios.ICANON | termios.ECHO)
        assert pty.termios_baud() == 38400
        time.sleep(ATTACH_S)
        sentence = b"$GPGGA,123519.000,4807.0380,N,01131.0000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
        pty.write_epoch(sentence)
        assert read_for(client, 2.0, until=len(sentence)) == sentence

        # What the client writes reaches read_available, and is not echoed back to it.
        probe = b"$PMTK605*31\r\n"
        os.write(client, probe)
        got = b""
        deadline = time.monotonic() + 2.0
        while len(got) < len(probe) and time.monotonic() < deadline:
            select.select([pty.fileno()], [], [], 0.1)
            got += pty.read_available()
        assert got == probe
        assert read_for(client, 0.2) == b""
        assert pty.read_available() == b""
    finally:
        os.close(client)


def test_client_speed_change_is_visible(pty: PtyDevice) -> None:
    client = open_client(pty.path)
    try:
        attrs = termios.tcgetattr(client)
        attrs[4] = attrs[5] = termios.B4800  # gpsd's baud hunt does this
        termios.tcsetattr(client, termios.TCSANOW, attrs)
        assert pty.termios_baud() == 4800
    finally:
        os.close(client)


# -- pty: nobody reading, stalled readers, pacing -----------------------------------------------


def test_write_never_blocks_without_reader_and_late_reader_gets_recent_epochs(
    pty: PtyDevice,
) -> None:
    n_epochs = 500
    worst_s = 0.0
    for i in range(n_epochs):
        t0 = time.perf_counter()
        pty.write_epoch(epoch(i))
        worst_s = max(worst_s, time.perf_counter() - t0)
    assert worst_s < 0.005
    assert pty.dropped_epochs > 0 and pty.dropped_bytes >= 600 * pty.dropped_epochs
    # the backlog holds at most max_backlog_s of line time (2 s at 3840 bytes/s)
    assert pty.queued_bytes <= pty.max_backlog_bytes

    client = open_client(pty.path, os.O_RDONLY)
    try:
        data = read_for(client, 0.6)
    finally:
        os.close(client)
    marker = first_marker(data)
    assert marker >= n_epochs - pty.max_backlog_bytes // 600 - 1
    assert data.startswith(b"$EP,")  # starts with a whole epoch, not mid-sentence


def test_stalled_reader_resumes_with_recent_epochs(tmp_path: Path) -> None:
    max_backlog_s = 0.5
    period_s = 0.05
    with PtyDevice(tmp_path / "gps0", max_backlog_s=max_backlog_s) as device:
        client = open_client(device.path, os.O_RDONLY)
        try:
            written_at: dict[int, float] = {}
            next_s = time.monotonic()
            for i in range(40):  # 2 s of 200-byte epochs at 20 Hz; the client reads nothing
                written_at[i] = time.monotonic()
                device.write_epoch(epoch(i, 200))
                next_s += period_s
                time.sleep(max(0.0, next_s - time.monotonic()))
            t_read = time.monotonic()
            data = read_for(client, 0.3)
        finally:
            os.close(client)
        marker = first_marker(data)
        assert marker > 20, f"read epoch {marker} of 0..39: stale output was not discarded"
        assert t_read - written_at[marker] < max_backlog_s + 0.3
        assert device.kernel_flushes >= 1


def test_next_reader_does_not_get_output_written_for_nobody(pty: PtyDevice) -> None:
    first = open_client(pty.path, os.O_RDONLY)
    time.sleep(ATTACH_S)
    pty.write_epoch(epoch(0))
    assert first_marker(read_for(first, 1.0, until=600)) == 0
    os.close(first)
    for i in range(1, 30):  # 3 s of epochs with nobody reading
        pty.write_epoch(epoch(i))
        time.sleep(0.1)
    second = open_client(pty.path, os.O_RDONLY)
    try:
        data = read_for(second, 0.5)
    finally:
        os.close(second)
    assert first_marker(data) >= 29 - 2 / 0.1 + 1  # no older than max_backlog_s (2 s)


def test_output_is_paced_to_the_baud_rate(tmp_path: Path) -> None:
    baud = 115200
    n_bytes = 11520  # one second at 11520 bytes/s (8N1)
    with PtyDevice(tmp_path / "gps0", baud=baud) as device:
        client = open_client(device.path, os.O_RDONLY)
        try:
            time.sleep(ATTACH_S)
            t0 = time.monotonic()
            for i in range(n_bytes // 640):
                device.write_epoch(epoch(i, 640))
            data = bytearray()
            while len(data) < n_bytes and time.monotonic() - t0 < 3.0:
                data += read_for(client, 0.05)
            elapsed_s = time.monotonic() - t0
        finally:
            os.close(client)
    assert len(data) == n_bytes
    expected_s = n_bytes / (baud / 10)
    assert abs(elapsed_s - expected_s) < 0.25 * expected_s, elapsed_s


# -- serial and file ----------------------------------------------------------------------------


def test_serial_device_over_loop() -> None:
    with SerialDevice("loop://", 38400) as device:
        assert device.describe() == "loop:// at 38400 baud"
        data = epoch(1) + epoch(2)
        t0 = time.perf_counter()
        device.write_epoch(data)
        assert time.perf_counter() - t0 < 0.005
        got = b""
        deadline = time.monotonic() + 2.0
        while len(got) < len(data) and time.monotonic() < deadline:
            got += device.read_available()
            time.sleep(0.01)
        assert got == data
        assert device.dropped_bytes == 0


def test_serial_device_never_blocks_without_reader() -> None:
    device = SerialDevice("loop://", 38400)
    try:
        worst_s = 0.0
        for i in range(100):
            t0 = time.perf_counter()
            device.write_epoch(epoch(i))
            worst_s = max(worst_s, time.perf_counter() - t0)
        assert worst_s < 0.005
        assert device.dropped_epochs > 0
    finally:
        t0 = time.perf_counter()
        device.close()
    assert time.perf_counter() - t0 < 2.0


def test_serial_device_on_a_pty(pty: PtyDevice) -> None:
    """A POSIX port through pyserial: here the slave of our own pty, so the bytes are checked."""
    with SerialDevice(pty.path, 38400) as device:
        assert device.fileno() is not None
        device.write_epoch(epoch(7))
        got = b""
        deadline = time.monotonic() + 2.0
        while len(got) < 600 and time.monotonic() < deadline:
            select.select([pty.fileno()], [], [], 0.1)
            got += pty.read_available()
        assert got == epoch(7)
        time.sleep(ATTACH_S)
        pty.write_epoch(b"$PMTK001,605,3*30\r\n")
        got = b""
        deadline = time.monotonic() + 2.0
        while not got.endswith(b"\r\n") and time.monotonic() < deadline:
            select.select([device.fileno()], [], [], 0.1)
            got += device.read_available()
        assert got == b"$PMTK001,605,3*30\r\n"


def test_serial_device_bad_port() -> None:
    with pytest.raises(VirtualGPSError, match="cannot open serial port"):
        SerialDevice("/dev/does-not-exist-gps", 38400)


def test_file_sink(tmp_path: Path) -> None:
    path = tmp_path / "out.nmea"
    with FileSink(path) as sink:
        sink.write_epoch(epoch(1))
        sink.write_epoch(epoch(2))
        assert sink.read_available() == b""
        assert sink.path == str(path)
    assert path.read_bytes() == epoch(1) + epoch(2)


def test_file_sink_stdout(capsysbinary: pytest.CaptureFixture[bytes]) -> None:
    with FileSink("-") as sink:
        assert sink.describe() == "stdout"
        sink.write_epoch(b"$GPRMC\r\n")
    assert capsysbinary.readouterr().out == b"$GPRMC\r\n"


# -- pose sources -------------------------------------------------------------------------------
