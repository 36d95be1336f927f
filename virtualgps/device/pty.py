"""A pseudo-terminal that looks like the receiver's serial port (:class:`PtyDevice`), in raw
mode at an explicit baud rate, readable by any user, with a stable symlink to its slave side;
output paced to the baud rate like a real serial line, and stale output dropped when nobody
reads (see the class docstring for the Linux pty behaviour this relies on).
"""

from __future__ import annotations

import contextlib
import fcntl
import itertools
import logging
import math
import os
import select
import struct
import termios
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable
from pathlib import Path

from virtualgps.device.output import (
    _IDLE_POLL_S,
    _MAX_READ_BYTES_PER_POLL,
    _RX_MAX_BYTES,
    QueuedLine,
    _Epoch,
)
from virtualgps.exceptions import ConfigError, VirtualGPSError

log = logging.getLogger(__name__)

# An attached writer with nothing queued and nothing unread sleeps until an event wakes it; this
# is only a safety net.
_IDLE_ATTACHED_S = 1.0
# Longest time between two measurements of the client's unread bytes while output flows (a
# device with longer slices, a fleet's, measures every 5 slices).
_MEASURE_EVERY_S = 0.25
_DEVICES_MADE = itertools.count()


def _early_share(k: int) -> float:
    """The share in [0.5, 1) of the kernel cap at which the ``k``-th device made measures
    its client's unread bytes before an epoch written at once (:meth:`PtyDevice.write_epoch`).

    A fleet's devices write their epochs together, so the bound on what their clients have
    unread grows alike on every one: with one threshold every device measured at the same
    epoch, a thousand slaves opened in one burst every fourth epoch at 10 Hz. Thresholds
    spread by the golden ratio spread the measurements over the epochs.
    """
    return 0.5 + 0.5 * ((k * 0.6180339887498949) % 1.0)

# Output pacing: write the line's bytes in slices of about this duration, at absolute wake times.
# 16 ms is how a USB serial adapter hands bytes over (FTDI's default latency timer, AN232B-04),
# how most GPS mice reach a computer; finer slices cost wake-ups and tell a client nothing more.
_CHUNK_S = 0.016
_MAX_CHUNK_BYTES = 1024

# Most unread bytes we let sit in the pty's kernel buffers. TIOCINQ on the slave counts only the
# line discipline's read buffer (N_TTY_BUF_SIZE = 4096; it reports at most 4095), not the tty
# flip buffers behind it (~16 KiB more). Keeping our unread share below that buffer keeps the
# count exact, so the backlog and the age of unread output are known, not guessed. Between
# measurements what was written counts as unread, so the cap also sets how often a fleet's
# device opens its slave to measure: 2048 let three 650-byte epochs at most go between two
# measurements, 3072 four (300 receivers at 10 Hz: 4.5 -> 2.6 slave opens per device
# and second, counted with strace -c), 1 KiB still short of the line discipline's buffer.
_KERNEL_CAP_BYTES = 3072


def _termios_speed(baud: int) -> int:
    """Return the termios speed constant for ``baud``, or raise ConfigError naming the choices."""
    speed = getattr(termios, f"B{baud}", None) if isinstance(baud, int) and baud > 0 else None
    if speed is None:
        rates = sorted(int(k[1:]) for k in dir(termios) if k[:1] == "B" and k[1:].isdigit())
        raise ConfigError(
            f"baud {baud!r} is not a standard serial rate; use one of "
            f"{', '.join(str(r) for r in rates if r >= 1200)} (the Holux M-1000 uses 38400)"
        )
    return speed


def _baud_of_speed(speed: int) -> int | None:
    for key in dir(termios):
        if key[:1] == "B" and key[1:].isdigit() and getattr(termios, key) == speed:
            return int(key[1:])
    return None


def _set_raw(fd: int, speed: int) -> None:
    """Put the terminal ``fd`` in raw 8N1 mode at ``speed`` (a termios B constant).

    Raw because cooked mode maps the CR of every NMEA ``\\r\\n`` to a newline (ICRNL), so clients
    read ``\\n\\n``, and echoes what the client writes (ECHO), so gpsd would read back its own
    PMTK probes as if the receiver had sent them.
    """
    iflag, oflag, cflag, lflag, _, _, cc = termios.tcgetattr(fd)
    iflag &= ~(
        termios.IGNBRK
        | termios.BRKINT
        | termios.PARMRK
        | termios.ISTRIP
        | termios.INLCR
        | termios.IGNCR
        | termios.ICRNL
        | termios.IXON
        | termios.IXOFF
        | termios.IXANY
        | termios.INPCK
    )
    oflag &= ~termios.OPOST
    lflag &= ~(termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG | termios.IEXTEN)
    cflag &= ~(termios.CSIZE | termios.PARENB | termios.CSTOPB | termios.CRTSCTS)
    cflag |= termios.CS8 | termios.CREAD | termios.CLOCAL
    cc[termios.VMIN] = 1
    cc[termios.VTIME] = 0
    termios.tcsetattr(fd, termios.TCSANOW, [iflag, oflag, cflag, lflag, speed, speed, cc])


def _unread_bytes(fd: int) -> int:
    """Return TIOCINQ (bytes waiting to be read) of the terminal or socket ``fd``."""
    return struct.unpack("i", fcntl.ioctl(fd, termios.TIOCINQ, b"\0\0\0\0"))[0]


def _make_link(link_path: Path, target: Path) -> None:
    """Point the symlink ``link_path`` at ``target``, replacing an old symlink atomically."""
    if os.path.lexists(link_path) and not link_path.is_symlink():
        raise VirtualGPSError(
            f"{link_path} exists and is not a symlink; refusing to replace it. Remove it or "
            f"choose another path with --link"
        )
    # symlink + rename: a client never sees the link missing or half made, even when a previous
    # run's link (dangling after a crash) is being replaced.
    tmp = link_path.with_name(f".{link_path.name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        os.symlink(target, tmp)
        os.replace(tmp, link_path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise VirtualGPSError(f"cannot create the link {link_path} -> {target}: {exc}") from exc


class PtyDevice(QueuedLine):
    """A pseudo-terminal that looks like the receiver's serial port to gpsd and ROS drivers.

    The slave side is put in raw 8N1 mode with ``baud`` in its termios, made readable and
    writable by any user (as gpsd's gpsfake does), and reached through a stable symlink. A writer
    (a thread of its own, or the owner's event loop calling :meth:`step`) sends queued epochs at
    ``baud / 10`` bytes per second (8N1: 10 bits per byte) in small slices at absolute wake
    times; ``write_epoch`` only appends to a bounded queue.

    Linux pty behaviour this relies on (verified on Linux 6.x, see tests/test_transport.py):

    - While no process has the slave open, ``poll()`` on the master reports POLLHUP and reading
      the master fails with EIO (once the client's last bytes are read). This only works if we
      do not keep a slave descriptor open ourselves, so we close ours after configuring it: the
      termios settings persist, since the open master keeps the tty alive.
    - Writes to the master while nobody has the slave open are buffered (about 20 KB: 4095 in the
      line discipline plus the flip buffers), then a non-blocking write fails with EAGAIN and a
      blocking one hangs. Those bytes survive until a reader opens the slave, which then reads
      minutes-old output. So the writer never writes while POLLHUP is set, and flushes the
      slave's input queue (``tcflush(slave, TCIFLUSH)``; it discards the flip buffers too) when
      a reader leaves and when one arrives.
    - ``tcflush`` on the *master* does not discard the slave's unread input, and TIOCOUTQ on the
      master is always 0 (ptys have no ``chars_in_buffer``): the backlog can only be seen and
      discarded from a slave descriptor. We open one briefly (``O_NOCTTY``, microseconds) while a
      reader is attached, read TIOCINQ (unread bytes, at most 4095 and lagging a write by the
      flip-buffer work queue, well under a millisecond) and close it again.
    - Termios calls on the master act on the slave, so ``termios_baud()`` sees the speed a client
      such as gpsd set; the pty passes bytes unchanged whatever the speed.
    - What the client writes arrives on the master (TIOCINQ on the master counts it) and stays
      readable after the client closes.

    Stale output: the backlog (queued bytes + unread bytes in the kernel) is held to
    ``max_backlog_s`` of line time by dropping the oldest whole epochs; queued epochs older than
    ``max_backlog_s`` are dropped too; unread kernel output older than ``max_backlog_s`` (a
    client that holds the port open but stopped reading) is flushed, together with the rest of
    the epoch it belonged to, so the client resumes with fresh epochs.

    Parameters
    ----------
    link_path : Path or None
        Stable symlink to create to the slave (e.g. ``./virtualgps0``); None for none.
    baud : int
        Line rate in bits per second, a standard termios rate (default 38400, the Holux M-1000).
    max_backlog_s : float
        Most output, in seconds of line time, that may wait for a client.
    chunk_s : float
        Line time handed to the kernel per wake-up (default 16 ms, a USB serial adapter's
        latency timer; at most 1 KiB).
    threaded : bool
        Run the writer in a thread of its own (default). False: the owner calls :meth:`step`
        when it is due, as :class:`virtualgps.run.fleet.ptyloop.PtyLoop` does for many devices
        from one thread.

    Attributes
    ----------
    slave_path : Path
        The slave device, e.g. ``/dev/pts/3``.
    link_path : Path or None
    baud : int
    reader_attached : bool
        Whether a process had the slave open at the writer's last look.
    written_bytes : int
        Bytes handed to the kernel.
    kernel_flushes : int
        Times unread output was discarded from the kernel.
    rx_dropped_bytes : int
        Client bytes discarded because read_available was not called for too long.
    alive : bool
        The writer thread runs while this is True.
    watch_master : bool
        Whether the master's events (client bytes, a hang-up) should wake the writer now (set by
        :meth:`step`; False while no reader is attached, when POLLHUP would wake it at once).
    client_log_level : int
        The logging level of "a client opened" / "no client has ... open" (INFO; a large
        fleet's owner sets DEBUG: a thousand clients coming at once are not news)

    Raises
    ------
    ConfigError
        For a non-standard baud rate or a non-positive ``max_backlog_s``.
    VirtualGPSError
        If ``link_path`` exists and is not a symlink, or the pty cannot be made.
    """

    def __init__(self, link_path: Path | None, baud: int = 38400, max_backlog_s: float = 2.0,
                 chunk_s: float = _CHUNK_S, threaded: bool = True):
        speed = _termios_speed(baud)
        if not 0 < chunk_s <= 1.0:
            raise ConfigError(f"chunk_s must be seconds in (0, 1], not {chunk_s!r}")
        self._chunk_s = float(chunk_s)
        self._measure_every_s = max(_MEASURE_EVERY_S, 5.0 * self._chunk_s)
        self._early_bytes = int(_early_share(next(_DEVICES_MADE)) * _KERNEL_CAP_BYTES)
        super().__init__(baud, max_backlog_s)
        # Both the writer thread and read_available() drain the master; one at a time, so the
        # client's bytes keep their order.
        self._rx_lock = threading.Lock()
        self._rx = bytearray()
        self.link_path = Path(link_path) if link_path is not None else None
        self.client_log_level = logging.INFO
        self.reader_attached = False
        self.kernel_flushes = 0
        self.rx_dropped_bytes = 0
        self._kernel_unread = 0
        self._measured_s = -math.inf  # when TIOCINQ was last read (time.monotonic)
        # Bytes written since the last flush, with when their epoch was queued: (t_monotonic_s,
        # cumulative end offset). With TIOCINQ this tells the age of the oldest byte the client
        # has not read yet (an epoch put back after a flush keeps its age).
        self._sent_total = 0
        self._sent_log: deque[tuple[float, int]] = deque()
        # Epochs whose first byte was written since the last flush: (start offset, epoch), so a
        # flush of stale output can put back the recent epochs it discarded with it.
        # (At most _KERNEL_CAP_BYTES are unread, a few dozen epochs: older entries are moot.)
        self._in_kernel: deque[tuple[int, _Epoch]] = deque(maxlen=256)
        self._peer_error_logged = False
        self.watch_master = False
        self._next_send_s = time.monotonic()
        # Called by write_epoch and set_baud instead of the eventfd when an owner drives step().
        self.on_wake: Callable[[PtyDevice], None] | None = None

        master_fd, slave_fd = os.openpty()
        try:
            self.slave_path = Path(os.ttyname(slave_fd))
            _set_raw(slave_fd, speed)
        except BaseException:
            os.close(master_fd)
            raise
        finally:
            # Not kept open: our own slave descriptor would hide POLLHUP (see class docstring).
            os.close(slave_fd)
        try:
            # Any user may open it (gpsd often runs as user gpsd, ROS as another user).
            os.chmod(self.slave_path, 0o666)
        except OSError as exc:
            log.info("cannot make %s readable by all users: %s", self.slave_path, exc)
        os.set_blocking(master_fd, False)
        self._master = master_fd
        self._hup_poll = select.poll()  # (a list in user space: no descriptor of its own)
        self._hup_poll.register(master_fd, select.POLLIN)
        try:
            if self.link_path is not None:
                _make_link(self.link_path, self.slave_path)
            # The writer thread's wake-up, and an event readable when client bytes wait in _rx
            # (for the daemon's select). A device an owner steps (threaded=False) needs neither:
            # one descriptor per device, so a fleet of ten thousand fits the usual limits.
            self._wake = self._rx_event = -1
            if threaded:
                self._wake = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
                self._rx_event = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        except BaseException:
            os.close(master_fd)
            raise
        self.alive = True
        self._thread: threading.Thread | None = None
        if threaded:
            self._thread = threading.Thread(
                target=self._run, name=f"virtualgps-pty-{self.slave_path.name}", daemon=True
            )
            self._thread.start()

    # -- interface ------------------------------------------------------------------------

    @property
    def path(self) -> str:
        """Return what clients open: the link if there is one, else the slave device."""
        return str(self.link_path if self.link_path is not None else self.slave_path)

    def describe(self) -> str:
        """Return ``/dev/pts/N -> LINK`` (or just the slave path without a link)."""
        if self.link_path is None:
            return str(self.slave_path)
        return f"{self.slave_path} -> {self.link_path}"

    def read_available(self) -> bytes:
        """Return the bytes the client wrote to the slave since the last call (``b""`` if none).

        Returns
        -------
        bytes
            At most the newest 64 KiB; older bytes are counted in ``rx_dropped_bytes``.
        """
        if self._closed:
            return b""
        self._read_client()  # also here, so a caller never waits for the writer's next look
        with self._lock:
            data = bytes(self._rx)
            self._rx.clear()
            if self._rx_event >= 0:
                with contextlib.suppress(BlockingIOError):
                    os.eventfd_read(self._rx_event)
        return data

    def fileno(self) -> int | None:
        """Return an event descriptor readable while client bytes wait for read_available
        (None once closed, or for a device its owner steps: its owner knows)."""
        return None if self._closed or self._rx_event < 0 else self._rx_event

    def _change_rate(self, baud: int) -> None:
        """Pace output at ``baud`` from now on (bytes already queued included). The slave's
        termios speed follows where ``baud`` is a standard rate; the pty itself passes bytes at
        any speed, so the pacing is what a client notices."""
        with self._lock:
            self._set_rate(baud)
        speed = getattr(termios, f"B{baud}", None)
        if speed is not None and not self._closed:
            try:
                attrs = termios.tcgetattr(self._master)
                attrs[4] = attrs[5] = speed
                termios.tcsetattr(self._master, termios.TCSANOW, attrs)
            except (OSError, termios.error) as exc:
                log.debug("cannot set the speed of %s: %s", self.slave_path, exc)
        self._wake_writer()

    def termios_baud(self) -> int | None:
        """Return the speed currently set on the slave (a client may change it), in baud.

        Returns
        -------
        int or None
            None if the speed is not a standard rate or the device is closed.
        """
        if self._closed:
            return None
        return _baud_of_speed(termios.tcgetattr(self._master)[5])

    def close(self) -> None:
        """Stop the writer, close the pty (clients then read EOF/EIO) and remove the link."""
        if self._closed:
            return
        self._closed = True
        self.alive = False
        self._signal(self._wake)
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for fd in (self._master, self._wake, self._rx_event):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        if self.link_path is not None:
            try:
                # Only our own link: another run may have taken the name over meanwhile.
                if os.readlink(self.link_path) == str(self.slave_path):
                    os.unlink(self.link_path)
            except OSError:
                pass

    @property
    def master_fd(self) -> int:
        """Return the pty's master descriptor (to watch while :attr:`watch_master`)."""
        return self._master

    @property
    def client_bytes_waiting(self) -> bool:
        """Return whether client bytes wait for :meth:`read_available`."""
        return bool(self._rx)

    # -- writer -----------------------------------------------------------------------------

    def _slice_bytes(self, bytes_per_s: float) -> int:
        return int(min(_MAX_CHUNK_BYTES, max(1, bytes_per_s * self._chunk_s)))

    def _line_unread_bytes(self) -> int:
        return self._kernel_unread

    @staticmethod
    def _signal(event_fd: int) -> None:
        if event_fd >= 0:
            with contextlib.suppress(OSError):
                os.eventfd_write(event_fd, 1)

    def _wake_writer(self) -> None:
        if self.on_wake is not None:
            self.on_wake(self)
        else:
            self._signal(self._wake)

    def step(self, master_quiet: bool = False) -> float:
        """Do what the writer has due now: take the client's bytes, notice a reader arriving or
        leaving, write the next slice of output.

        Parameters
        ----------
        master_quiet : the owner watches the master (:attr:`watch_master`) and it reported no
            event since the last step: no client bytes and no hang-up to look for (two system
            calls saved, the most of a fleet's step)

        Returns
        -------
        float
            Seconds until the writer needs to run again, unless an event comes first: a new
            epoch (:attr:`on_wake`), or the master's events while :attr:`watch_master`.
        """
        now_s = time.monotonic()
        if master_quiet and self.reader_attached and self.watch_master:
            timeout_s, self._next_send_s = self._service(now_s, self._next_send_s)
            return timeout_s
        self._read_client()
        if self._reader_absent():
            if self.reader_attached:
                self._on_detach()
            with self._lock:
                self._queue.trim(now_s, 0)
                self._kernel_unread = 0
            self.watch_master = False  # POLLHUP would wake poll() at once: do not watch
            return _IDLE_POLL_S
        if not self.reader_attached:
            self._on_attach()
            self._next_send_s = now_s
        timeout_s, self._next_send_s = self._service(now_s, self._next_send_s)
        self.watch_master = True  # wake for client bytes (gpsd's probes) and hang-ups
        return timeout_s

    def _reader_absent(self) -> bool:
        """Return True while no process has the slave open (POLLHUP on the master)."""
        return any(ev & select.POLLHUP for _, ev in self._hup_poll.poll(0))

    def _read_client(self) -> None:
        """Move what the client wrote from the master into the bounded ``_rx`` buffer."""
        with self._rx_lock:
            self._read_client_locked()

    def _read_client_locked(self) -> None:
        got = []
        total = 0
        while total < _MAX_READ_BYTES_PER_POLL:
            try:
                chunk = os.read(self._master, 4096)
            except BlockingIOError:
                break
            except OSError:
                break  # EIO: no client and nothing left to read (or closed meanwhile)
            if not chunk:
                break
            got.append(chunk)
            total += len(chunk)
        if not got:
            return
        with self._lock:
            for chunk in got:
                self._rx += chunk
            excess = len(self._rx) - _RX_MAX_BYTES
            if excess > 0:
                del self._rx[:excess]
                self.rx_dropped_bytes += excess
        self._signal(self._rx_event)

    def _open_slave(self) -> int | None:
        """Open the slave briefly for TIOCINQ/tcflush; None if we may not (e.g. TIOCEXCL)."""
        try:
            # O_NOCTTY: never become our controlling terminal; O_NONBLOCK: never wait for it.
            return os.open(self.slave_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            if not self._peer_error_logged:
                self._peer_error_logged = True
                log.warning(
                    "cannot open %s to watch for stale output (%s); a client that stops "
                    "reading may later read old epochs",
                    self.slave_path,
                    exc,
                )
            return None

    def _measure_unread(self) -> int | None:
        fd = self._open_slave()
        if fd is None:
            return None
        try:
            return _unread_bytes(fd)
        except OSError:
            return None
        finally:
            os.close(fd)

    def _flush_kernel(self) -> None:
        """Discard output the client has not read, counting it as dropped."""
        fd = self._open_slave()
        if fd is not None:
            try:
                stale = _unread_bytes(fd)
                termios.tcflush(fd, termios.TCIFLUSH)
                if stale:
                    self._line_dropped_bytes += stale
                    self.kernel_flushes += 1
            except OSError as exc:
                log.debug("flushing %s failed: %s", self.slave_path, exc)
            finally:
                os.close(fd)
        self._sent_log.clear()
        self._in_kernel.clear()
        self._sent_total = 0
        self._kernel_unread = 0

    def _unread_recent(self, now_s: float, unread: int) -> list[_Epoch]:
        """The epochs written whole into the kernel's unread bytes that are not yet stale."""
        first_unread = self._sent_total - unread
        return [e for start, e in self._in_kernel
                if start >= first_unread and now_s - e.t_enqueued_s <= self.max_backlog_s]

    def _forget_read(self, unread: int) -> None:
        """Drop the records of bytes the client has read, ``unread`` bytes being left."""
        first_unread = self._sent_total - unread
        while self._sent_log and self._sent_log[0][1] <= first_unread:
            self._sent_log.popleft()
        while self._in_kernel and self._in_kernel[0][0] < first_unread:
            self._in_kernel.popleft()  # (read, or begun: never sent again)

    def _unread_age_s(self, now_s: float, unread: int) -> float:
        """Return how long ago the oldest unread byte was written (0 if all was read)."""
        self._forget_read(unread)
        if unread <= 0 or not self._sent_log:
            return 0.0
        return now_s - self._sent_log[0][0]

    def _on_attach(self) -> None:
        self.reader_attached = True
        log.log(self.client_log_level, "a client opened %s", self.slave_path)
        self._flush_kernel()  # anything left from before this client is stale to it

    def _on_detach(self) -> None:
        self.reader_attached = False
        log.log(
            self.client_log_level,
            "no client has %s open; holding at most %.1f s of output",
            self.slave_path,
            self.max_backlog_s,
        )
        self._flush_kernel()
        with self._lock:
            self._queue.drop_started()  # the next client must not start mid-epoch

    def _wrote(self, head: _Epoch, start: int, n_sent: int, in_kernel: int) -> None:
        """Account for ``n_sent`` bytes of ``head`` handed to the kernel (``start``: where its
        first byte lies in all bytes sent, -1 if it had begun before)."""
        self.written_bytes += n_sent
        self._kernel_unread = in_kernel + n_sent
        if start >= 0:
            self._in_kernel.append((start, head))
        self._sent_total += n_sent
        self._sent_log.append((head.t_enqueued_s, self._sent_total))  # (the bytes' age)

    def write_epoch(self, data: bytes) -> None:
        """Queue one epoch; return at once (see :meth:`QueuedLine.write_epoch`).

        A device its owner steps writes an epoch at once when it can go whole into the line
        now (a reader attached, nothing queued, the line idle, room below the cap by the
        bound): a fleet's epoch then leaves with its ``write_epoch``, not a step later.
        """
        n = len(data)
        if (self._thread is None and self.reader_attached and self.watch_master
                and not self._closed and 0 < n <= self._chunk_bytes):
            now_s = time.monotonic()
            with self._lock:
                idle = not self._queue and now_s >= self._next_send_s
                if idle and self._kernel_unread + n > self._early_bytes:
                    # The bound on what the client has unread grows with every epoch written
                    # until a measurement: measure now rather than leave the epoch to a step,
                    # which measured too, a step later (every fourth epoch of a fleet of
                    # 2,000 at 10 Hz came 20-30 ms late). The backlog's age is checked by the
                    # step's own measurements (_measured_s); one that finds everything read
                    # stands in for the next of those (nothing unread can be stale): a fleet
                    # whose clients keep up then opens each slave about half as often.
                    unread = self._measure_unread()
                    if unread is not None:
                        self._kernel_unread = unread
                        if unread == 0:
                            self._forget_read(0)
                            self._measured_s = now_s
                if idle and self._kernel_unread + n <= _KERNEL_CAP_BYTES:
                    try:
                        n_sent = os.write(self._master, data)
                    except OSError:
                        n_sent = 0
                    if n_sent == n:
                        self._wrote(_Epoch(bytes(data), now_s), self._sent_total, n,
                                    self._kernel_unread)
                        self._next_send_s = now_s + n / self._bytes_per_s
                        return
                    if n_sent > 0:  # (the rest goes as the writer's next slice)
                        head = _Epoch(bytes(data), now_s, n_sent)
                        self._wrote(head, self._sent_total, n_sent, self._kernel_unread)
                        self._queue.epochs.append(head)
                        self._queue.queued_bytes += n - n_sent
                        self._next_send_s = now_s + n_sent / self._bytes_per_s
                        self._wake_writer()
                        return
        super().write_epoch(data)

    def _service(self, now_s: float, next_send_s: float) -> tuple[float, float]:
        """Write the next slice if it is due; return (seconds to sleep, next send time)."""
        # What the client has left unread is measured (opening the slave for TIOCINQ) when the
        # next slice could pass the cap by the last measurement plus what was written since,
        # an upper bound, and every _measure_every_s for the backlog's age; between, the bound
        # stands in for it. (Each measurement opens the slave: measuring before every write
        # cost a fleet of a thousand more than its epochs' simulation.)
        if ((self._queue and self._kernel_unread + self._chunk_bytes > _KERNEL_CAP_BYTES)
                or now_s - self._measured_s >= self._measure_every_s):
            unread = self._measure_unread()
            self._measured_s = now_s
            fresh = True
        else:
            unread, fresh = self._kernel_unread, False
        if fresh and unread is not None:
            if (
                unread > self.max_backlog_bytes
                or self._unread_age_s(now_s, unread) > self.max_backlog_s
            ):
                # The client holds the port open but stopped reading: what it would read next
                # is stale. Discard it and the rest of its epoch, then queue again the recent
                # epochs the flush took with it (the newest may be all a client gets for a
                # while: nothing else may follow soon).
                recent = self._unread_recent(now_s, unread)
                self._flush_kernel()
                self._line_dropped_bytes -= sum(e.offset for e in recent)  # (back, not lost)
                unread = 0
                with self._lock:
                    if recent and self._queue and self._queue.epochs[0] is recent[-1]:
                        self._queue.epochs.popleft()  # (started: it goes back whole)
                        self._queue.queued_bytes -= len(recent[-1].data) - recent[-1].offset
                    self._queue.drop_started()
                    self._queue.put_back(recent)
        in_kernel = unread if unread is not None else 0
        with self._lock:
            self._kernel_unread = in_kernel
            self._queue.trim(now_s, in_kernel)
            if not self._queue:
                # Nothing to send. Bytes the client has still to read are watched for going
                # stale, which only a fresh measurement can tell: sleep until the next one is
                # due (a 1 Hz daemon woke every 50 ms for nothing); otherwise only a new epoch
                # (the wake event), client bytes or a hang-up (the master's POLLIN/POLLHUP)
                # can need us.
                if in_kernel:
                    return max(0.0, self._measured_s + self._measure_every_s - now_s), next_send_s
                return _IDLE_ATTACHED_S, next_send_s
            if next_send_s < now_s - self._chunk_s:
                next_send_s = now_s  # idle or badly late: restart the line clock, no burst
            if next_send_s > now_s:
                return next_send_s - now_s, next_send_s
            room = _KERNEL_CAP_BYTES - in_kernel
            if room <= 0:
                return self._chunk_s, next_send_s  # the client is not reading; look again soon
            head = self._queue.epochs[0]
            start = self._sent_total if head.offset == 0 else -1
            chunk = self._queue.peek(min(self._chunk_bytes, room))
            try:
                n_sent = os.write(self._master, chunk)
            except BlockingIOError:
                n_sent = 0
            except OSError as exc:
                log.debug("write to %s failed: %s", self.slave_path, exc)
                n_sent = 0
            if n_sent <= 0:
                return self._chunk_s, next_send_s
            self._queue.advance(n_sent)
            self._wrote(head, start, n_sent, in_kernel)
        # Absolute schedule: the next slice is due when this one has left the "line". With
        # nothing more queued, only the next measurement is (a new epoch wakes the writer).
        next_send_s += n_sent / self._bytes_per_s
        now_s = time.monotonic()
        if not self._queue:
            return max(0.0, next_send_s - now_s,
                       self._measured_s + self._measure_every_s - now_s), next_send_s
        return max(0.0, next_send_s - now_s), next_send_s

    def _run(self) -> None:
        poller = select.poll()
        poller.register(self._wake, select.POLLIN)
        watching_master = False
        try:
            while self.alive:
                timeout_s = self.step()
                if self.watch_master != watching_master:
                    if self.watch_master:
                        poller.register(self._master, select.POLLIN)
                    else:
                        poller.unregister(self._master)
                    watching_master = self.watch_master
                for fd, _ in poller.poll(timeout_s * 1000.0):
                    if fd == self._wake:
                        with contextlib.suppress(BlockingIOError):
                            os.eventfd_read(self._wake)
        except Exception:
            log.exception("the writer of %s stopped", self.slave_path)
