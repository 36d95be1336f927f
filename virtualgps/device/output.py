"""Where NMEA goes: the output devices' one interface, and a file or stdout.

Output devices share one small interface (:class:`OutputDevice`): ``write_epoch`` (never waits
for the client, but for a file), ``read_available`` (what the client sent us, e.g. gpsd's
``$PMTK`` probes), ``close``, ``path`` / ``describe()``, and use as a context manager.

- :class:`QueuedLine` — what a line at a baud rate shares: the bounded queue of epochs and its
  drop counts; :class:`~virtualgps.device.pty.PtyDevice` (a pseudo-terminal) and
  :class:`~virtualgps.device.serialport.SerialDevice` (a real serial port) are its two kinds.
- :class:`FileSink` — a file, or stdout for ``-``.

Where poses come from is :mod:`virtualgps.poses.posesource`. Only the device modules, the
daemon and the CLI touch ptys, serial ports and sockets. Nothing here parses NMEA: bytes in,
bytes out.
"""

from __future__ import annotations

import abc
import logging
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import BinaryIO, Self

from virtualgps.exceptions import ConfigError, VirtualGPSError

log = logging.getLogger(__name__)

# Largest backlog of client-to-device bytes (PMTK commands) kept for read_available(); a client
# that floods us loses its oldest bytes rather than growing our memory.
_RX_MAX_BYTES = 65536

# How often an idle pty writer looks for a reader attaching or leaving. Linux gives no event for
# "POLLHUP cleared" (poll() reports POLLHUP at once while it holds), so this is polled; 50 ms is
# far below one epoch at any rate a GPS emits.
_IDLE_POLL_S = 0.05
# Most client bytes read per wake-up, so a flooding client cannot hold the writer.
_MAX_READ_BYTES_PER_POLL = 1 << 20


class _Closing:
    """Context-manager support for anything with ``close()``."""

    def close(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class OutputDevice(_Closing, abc.ABC):
    """Where NMEA bytes go: one epoch at a time, without ever making the caller wait.

    Attributes
    ----------
    dropped_bytes : int
        Bytes handed to ``write_epoch`` that never reached the client (dropped from the queue,
        flushed from the kernel as stale, or refused by a full port).
    dropped_epochs : int
        Whole epochs dropped before any of their bytes were sent.
    """

    dropped_bytes: int = 0
    dropped_epochs: int = 0

    @property
    @abc.abstractmethod
    def path(self) -> str:
        """Return what a client opens (link, device, file path, or ``-``)."""

    @abc.abstractmethod
    def describe(self) -> str:
        """Return a one-line description of the device for the user."""

    @abc.abstractmethod
    def write_epoch(self, data: bytes) -> None:
        """Queue one epoch's bytes for output; return at once.

        Parameters
        ----------
        data : bytes
            The epoch (or a reply such as ``$PMTK001``), sent whole and in order.
        """

    def read_available(self) -> bytes:
        """Return what the client sent since the last call, without waiting (``b""`` if none).

        Returns
        -------
        bytes
            Raw bytes, possibly ending mid-line; the caller assembles lines.
        """
        return b""

    def fileno(self) -> int | None:
        """Return a descriptor that turns readable when ``read_available`` has data, or None.

        Returns
        -------
        int or None
            For ``select``; None where the device has no input.
        """
        return None

    def set_baud(self, baud: int) -> None:
        """Change the line rate at run time (a client's ``$PMTK251``); no-op where there is none.

        Parameters
        ----------
        baud : int
            Bits per second, 8N1.
        """
        return None

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device; calling it again does nothing."""


@dataclass
class _Epoch:
    data: bytes
    t_enqueued_s: float  # time.monotonic() when write_epoch received it
    offset: int = 0  # bytes already handed to the kernel


class _EpochQueue:
    """Epochs waiting to be written, bounded by size and age; the oldest whole epochs go first.

    Not thread-safe: the owning device guards it with its lock. An epoch whose first bytes were
    already sent is never dropped by ``trim`` (finishing it keeps the client's sentences whole);
    ``drop_started`` drops its remainder when the client is known to have lost the beginning.
    """

    def __init__(self, max_bytes: int, max_age_s: float) -> None:
        self.max_bytes = max_bytes
        self.max_age_s = max_age_s
        self.epochs: deque[_Epoch] = deque()
        self.queued_bytes = 0
        self.dropped_bytes = 0
        self.dropped_epochs = 0

    def __bool__(self) -> bool:
        return bool(self.epochs)

    def put(self, data: bytes, now_s: float) -> None:
        self.epochs.append(_Epoch(data, now_s))
        self.queued_bytes += len(data)

    def put_back(self, epochs: list[_Epoch]) -> None:
        """Queue whole epochs again ahead of the rest, in their order (their bytes were
        discarded from the kernel unread)."""
        for e in reversed(epochs):
            self.epochs.appendleft(_Epoch(e.data, e.t_enqueued_s))
            self.queued_bytes += len(e.data)

    def trim(self, now_s: float, kernel_bytes: int) -> None:
        """Drop the oldest unstarted epochs while the backlog is too large or too old.

        The backlog is ``queued_bytes + kernel_bytes`` (unread in the kernel). The newest epoch
        is kept unless it is itself older than ``max_age_s``: an epoch larger than the whole
        budget is still sent rather than never.
        """
        while True:
            first = 1 if self.epochs and self.epochs[0].offset else 0
            if first >= len(self.epochs):
                return
            oldest = self.epochs[first]
            too_old = now_s - oldest.t_enqueued_s > self.max_age_s
            too_big = self.queued_bytes + kernel_bytes > self.max_bytes
            if not too_old and (not too_big or first == len(self.epochs) - 1):
                return
            del self.epochs[first]
            self.queued_bytes -= len(oldest.data)
            self.dropped_bytes += len(oldest.data)
            self.dropped_epochs += 1

    def drop_started(self) -> None:
        """Drop the unsent rest of an epoch whose beginning was already sent."""
        if self.epochs and self.epochs[0].offset:
            head = self.epochs.popleft()
            rest = len(head.data) - head.offset
            self.queued_bytes -= rest
            self.dropped_bytes += rest

    def peek(self, max_bytes: int) -> bytes:
        head = self.epochs[0]
        return head.data[head.offset : head.offset + max_bytes]

    def advance(self, n_bytes: int) -> None:
        head = self.epochs[0]
        head.offset += n_bytes
        self.queued_bytes -= n_bytes
        if head.offset >= len(head.data):
            self.epochs.popleft()


class QueuedLine(OutputDevice):
    """An output device that sends queued epochs down a line of ``baud`` bits per second (8N1:
    10 bits per byte) from a writer of its own, so that ``write_epoch`` never waits.

    What a pty and a serial port share: the bounded queue (at most ``max_backlog_s`` of line
    time, counting bytes the line holds unread; the oldest whole epochs go first), the counts of
    what was dropped, and a baud rate that can change while running. A subclass owns the line:
    how big a slice it writes (:meth:`_slice_bytes`), how many bytes wait in it unread
    (:meth:`_line_unread_bytes`) and how its writer is woken (:meth:`_wake_writer`).

    Attributes
    ----------
    baud : int
    max_backlog_s : float
    max_backlog_bytes : int
        ``max_backlog_s`` of line time, in bytes.
    written_bytes : int
        Bytes handed to the line.
    """

    def __init__(self, baud: int, max_backlog_s: float) -> None:
        if not max_backlog_s > 0:
            raise ConfigError(f"max_backlog_s must be positive seconds, not {max_backlog_s!r}")
        self.max_backlog_s = float(max_backlog_s)
        self._lock = threading.Lock()
        self._closed = False
        self.written_bytes = 0
        self._line_dropped_bytes = 0  # sent to the line, then discarded there as stale
        self._queue = _EpochQueue(1, self.max_backlog_s)
        self._set_rate(baud)

    @staticmethod
    def check_baud(baud: int) -> None:
        """Raise ConfigError unless ``baud`` is a positive integer."""
        if isinstance(baud, bool) or not isinstance(baud, int) or baud <= 0:
            raise ConfigError(f"baud must be a positive integer, not {baud!r}")

    def _set_rate(self, baud: int) -> None:
        """Take ``baud`` as the line's rate: backlog and slice sizes follow (caller holds the
        lock, or is the constructor)."""
        self.baud = baud
        self._bytes_per_s = baud / 10.0  # 8N1: start + 8 data + stop bits per byte
        self.max_backlog_bytes = max(1, int(self.max_backlog_s * self._bytes_per_s))
        self._chunk_bytes = self._slice_bytes(self._bytes_per_s)
        self._queue.max_bytes = self.max_backlog_bytes

    @abc.abstractmethod
    def _slice_bytes(self, bytes_per_s: float) -> int:
        """Bytes the writer hands to the line at once, at ``bytes_per_s``."""

    def _line_unread_bytes(self) -> int:
        """Bytes already in the line that the client has not read (part of the backlog)."""
        return 0

    def set_baud(self, baud: int) -> None:
        """Change the line's rate (a client's ``$PMTK251``): when, the kind of line says.

        Parameters
        ----------
        baud : int
            Bits per second, 8N1; positive.

        Raises
        ------
        ConfigError
            For a baud that is not a positive integer.
        """
        self.check_baud(baud)
        self._change_rate(baud)

    @abc.abstractmethod
    def _change_rate(self, baud: int) -> None:
        """Take the valid rate ``baud``."""

    @abc.abstractmethod
    def _wake_writer(self) -> None:
        """Tell the writer that an epoch or a new rate is waiting."""

    @property
    def dropped_bytes(self) -> int:  # type: ignore[override]
        """Return bytes that never reached the client (queue drops, stale line output)."""
        return self._queue.dropped_bytes + self._line_dropped_bytes

    @property
    def dropped_epochs(self) -> int:  # type: ignore[override]
        """Return whole epochs dropped before any byte of them was sent."""
        return self._queue.dropped_epochs

    @property
    def queued_bytes(self) -> int:
        """Return bytes waiting in our queue (not yet handed to the line)."""
        return self._queue.queued_bytes

    def write_epoch(self, data: bytes) -> None:
        """Queue one epoch; return at once, dropping the oldest epochs if the backlog is full.

        Parameters
        ----------
        data : bytes
            The epoch's bytes, sent whole and in order at the line's rate.

        Raises
        ------
        VirtualGPSError
            If the device was closed.
        """
        if self._closed:
            raise VirtualGPSError(f"{self.describe()} is closed")
        if not data:
            return
        with self._lock:
            now_s = time.monotonic()
            self._queue.put(bytes(data), now_s)
            self._queue.trim(now_s, self._line_unread_bytes())
        self._wake_writer()


class FileSink(OutputDevice):
    """NMEA to a file, or to stdout for ``-`` (binary, unchanged).

    For ``replay``: writes are synchronous, so a slow pipe makes the caller wait (back-pressure,
    no bytes lost, output byte-identical); this is the one device whose ``write_epoch`` may
    wait. Use a pty or serial device for live output.

    Parameters
    ----------
    path : Path or str
        File to create (truncated), or ``-`` for stdout.
    flush_each_epoch : bool
        Flush after every epoch (for ``tail -f`` or a live pipe); off for throughput.

    Raises
    ------
    VirtualGPSError
        If the file cannot be created.
    """

    def __init__(self, path: Path | str, flush_each_epoch: bool = False) -> None:
        self._name = str(path)
        self.flush_each_epoch = flush_each_epoch
        self.written_bytes = 0
        self._closed = False
        self._stream: BinaryIO
        if self._name == "-":
            self._stream = sys.stdout.buffer
            self._owned = False
        else:
            try:
                self._stream = open(path, "wb")  # noqa: SIM115 - closed in close()
            except OSError as exc:
                raise VirtualGPSError(f"cannot write {path}: {exc}") from exc
            self._owned = True

    @property
    def path(self) -> str:
        """Return the file path, or ``-`` for stdout."""
        return self._name

    def describe(self) -> str:
        """Return the file path, or ``stdout``."""
        return "stdout" if self._name == "-" else self._name

    def write_epoch(self, data: bytes) -> None:
        """Write one epoch's bytes.

        Parameters
        ----------
        data : bytes

        Raises
        ------
        VirtualGPSError
            If the sink was closed or the write failed (disk full, closed pipe).
        """
        if self._closed:
            raise VirtualGPSError(f"{self.describe()} is closed")
        try:
            self._stream.write(data)
            if self.flush_each_epoch:
                self._stream.flush()
        except OSError as exc:
            raise VirtualGPSError(f"cannot write {self.describe()}: {exc}") from exc
        self.written_bytes += len(data)

    def close(self) -> None:
        """Flush, and close the file (stdout is flushed, not closed)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._stream.flush()
        except OSError as exc:
            log.warning("flushing %s failed: %s", self.describe(), exc)
        finally:
            if self._owned:
                self._stream.close()
