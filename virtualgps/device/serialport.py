"""A real serial port, or any pyserial URL such as ``loop://`` (:class:`SerialDevice`): the
receiver on a wire, for hardware in the loop.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time

import serial

from virtualgps.device.output import (
    _IDLE_POLL_S,
    _MAX_READ_BYTES_PER_POLL,
    _RX_MAX_BYTES,
    QueuedLine,
)
from virtualgps.exceptions import VirtualGPSError

log = logging.getLogger(__name__)

# How long SerialDevice's writer waits for a stuck port (hardware flow control held, USB adapter
# gone) before dropping the rest of an epoch. Only the writer thread waits, never the caller.
_SERIAL_WRITE_TIMEOUT_S = 0.5


class SerialDevice(QueuedLine):
    """A real serial port (or any pyserial URL such as ``loop://``) driven 8N1 at ``baud``.

    A writer thread sends queued epochs; ``write_epoch`` only appends to a queue bounded like
    :class:`PtyDevice`'s (``max_backlog_s`` of line time, counting the port's own output queue
    where pyserial reports it). The UART paces the bytes itself. Writes that stall longer than
    0.5 s (hardware flow control held, adapter unplugged) are dropped and counted; when the
    port's output queue holds more than the backlog, it is discarded as stale.

    pyserial's own non-blocking mode (``write_timeout=0``) is not used: on POSIX ports it spins
    while the kernel buffer is full, and ``loop://`` raises SerialTimeoutException for every
    write. Only the writer thread ever waits.

    Parameters
    ----------
    port : str
        Device (``/dev/ttyUSB0``) or pyserial URL (``loop://``, ``socket://host:port``).
    baud : int
        Line rate in bits per second.
    max_backlog_s : float
        Most output, in seconds of line time, that may wait to be sent.

    Raises
    ------
    VirtualGPSError
        If the port cannot be opened.
    """

    def __init__(self, port: str, baud: int, max_backlog_s: float = 2.0) -> None:
        self.check_baud(baud)
        self.port = port
        super().__init__(baud, max_backlog_s)
        self._has_data = threading.Condition(self._lock)
        self._pending_baud: int | None = None
        self._error_logged = False
        try:
            self._serial = serial.serial_for_url(
                port,
                baudrate=baud,
                bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_ONE,
                timeout=0,  # reads return at once
                write_timeout=_SERIAL_WRITE_TIMEOUT_S,
                xonxoff=False,
                rtscts=False,
                dsrdtr=False,
            )
        except (serial.SerialException, ValueError, OSError) as exc:
            raise VirtualGPSError(
                f"cannot open serial port {port} at {baud} baud: {exc}. Check the device name "
                f"and that you may use it (on Linux, membership of the dialout group)"
            ) from exc
        self.alive = True
        self._thread = threading.Thread(
            target=self._run, name=f"virtualgps-serial-{port}", daemon=True
        )
        self._thread.start()

    @property
    def path(self) -> str:
        """Return the port name or URL."""
        return self.port

    def describe(self) -> str:
        """Return ``PORT at BAUD baud``."""
        return f"{self.port} at {self.baud} baud"

    def read_available(self) -> bytes:
        """Return what arrived on the port since the last call, without waiting.

        Returns
        -------
        bytes
            At most the newest 64 KiB of it.
        """
        if self._closed:
            return b""
        try:
            data = self._serial.read(max(self._serial.in_waiting, 0))
            while len(data) < _MAX_READ_BYTES_PER_POLL and self._serial.in_waiting:
                data += self._serial.read(self._serial.in_waiting)
        except (serial.SerialException, OSError) as exc:
            self._log_error("read", exc)
            return b""
        return bytes(data[-_RX_MAX_BYTES:])

    def fileno(self) -> int | None:
        """Return the port's descriptor (readable on input) where it has one, else None."""
        if self._closed:
            return None
        try:
            return self._serial.fileno()
        except (AttributeError, NotImplementedError, OSError, ValueError,
                serial.SerialException):  # (pyserial's URL handlers: io.UnsupportedOperation)
            return None

    def close(self) -> None:
        """Stop the writer and close the port."""
        if self._closed:
            return
        self._closed = True
        with self._has_data:
            self.alive = False
            self._has_data.notify()
        with contextlib.suppress(AttributeError, serial.SerialException):
            self._serial.cancel_write()  # wake a writer stalled on a held port
        self._thread.join(timeout=5.0)
        with contextlib.suppress(serial.SerialException, OSError):
            self._serial.close()

    def _change_rate(self, baud: int) -> None:
        """Switch the port to ``baud`` once what is queued now has been sent: the writer applies
        it when its queue runs empty, after the port has transmitted everything (``flush``), so
        a reply queued before (the ``$PMTK001`` of a ``$PMTK251``) leaves at the old rate, as a
        receiver acknowledges before it switches."""
        with self._has_data:
            self._pending_baud = baud
            self._has_data.notify()

    def _slice_bytes(self, bytes_per_s: float) -> int:
        # Slices of ~0.1 s keep each write well inside the write timeout (loop:// refuses a
        # write whose line time exceeds it).
        return int(max(1, bytes_per_s * 0.1))

    def _wake_writer(self) -> None:
        with self._has_data:
            self._has_data.notify()

    def _apply_baud(self, baud: int) -> None:
        try:
            self._serial.flush()
            self._serial.baudrate = baud
        except (serial.SerialException, OSError, ValueError) as exc:
            self._log_error("changing the baud rate", exc)
        with self._lock:
            if self._pending_baud == baud:
                self._pending_baud = None
            self._set_rate(baud)

    def _log_error(self, what: str, exc: BaseException) -> None:
        if not self._error_logged:
            self._error_logged = True
            log.warning("%s on %s failed: %s (further failures not logged)", what, self.port, exc)

    def _port_backlog(self) -> int:
        try:
            return int(self._serial.out_waiting)
        except (AttributeError, NotImplementedError, serial.SerialException, OSError):
            return 0

    def _run(self) -> None:
        try:
            while True:
                with self._has_data:
                    while self.alive and not self._queue and self._pending_baud is None:
                        self._has_data.wait()
                    if not self.alive:
                        return
                    pending = self._pending_baud if not self._queue else None
                if pending is not None:
                    self._apply_baud(pending)
                    continue
                waiting = self._port_backlog()
                if waiting > self.max_backlog_bytes:
                    # Output the line could not send in max_backlog_s: stale, discard it.
                    with contextlib.suppress(serial.SerialException, OSError):
                        self._serial.reset_output_buffer()
                        self._line_dropped_bytes += waiting
                        waiting = 0
                with self._lock:
                    self._queue.trim(time.monotonic(), waiting)
                    if not self._queue:
                        continue
                    chunk = self._queue.peek(self._chunk_bytes)
                try:
                    n_sent = self._serial.write(chunk) or 0
                except (serial.SerialTimeoutException, queue.Full) as exc:
                    # queue.Full: loop:// when its 4 KiB buffer stays full for the timeout.
                    self._log_error("write", exc)
                    with self._lock:
                        self._queue.drop_started()
                        if self._queue and not self._queue.epochs[0].offset:
                            # The port is stuck: drop the epoch whole (pyserial does not say
                            # how much of the slice went out before the timeout).
                            head = self._queue.epochs.popleft()
                            self._queue.queued_bytes -= len(head.data)
                            self._queue.dropped_bytes += len(head.data)
                            self._queue.dropped_epochs += 1
                    continue
                except (serial.SerialException, OSError) as exc:
                    self._log_error("write", exc)
                    time.sleep(_IDLE_POLL_S)  # a vanished port: do not spin
                    continue
                with self._lock:
                    if n_sent:
                        self._queue.advance(n_sent)
                        self.written_bytes += n_sent
        except Exception:
            log.exception("the writer of %s stopped", self.port)
