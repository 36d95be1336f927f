"""Where poses come from: UDP, TCP, stdin (DESIGN section 4's messages, as raw bytes).

Pose sources (:class:`PoseSource`) are non-blocking: ``poll()`` returns the raw messages that
arrived since the last call with their arrival time; ``fileno()`` lets the daemon sleep in
``select`` until the next epoch or the next message. :func:`open_pose_source` builds one from a
``--poses`` spec (``udp://HOST:PORT``, ``tcp://HOST:PORT``, ``-``). Nothing here parses pose
JSON: bytes in (:mod:`virtualgps.poses.pose` reads them).
"""

from __future__ import annotations

import abc
import contextlib
import logging
import os
import select
import socket
import time
from collections.abc import Callable
from urllib.parse import urlsplit

from virtualgps.exceptions import ConfigError, VirtualGPSError

__all__ = [
    "MAX_MESSAGE_BYTES",
    "PoseSource",
    "StdinPoseSource",
    "TcpPoseSource",
    "UdpPoseSource",
    "open_pose_source",
]

log = logging.getLogger(__name__)

#: Largest pose message accepted: one UDP datagram (the IPv4 payload limit is 65,507 bytes, so a
#: 64 KiB receive never truncates), or one TCP/stdin line.
MAX_MESSAGE_BYTES = 65536

# Caps per poll() so one flooding sender cannot keep the daemon from emitting its next epoch.
_MAX_DATAGRAMS_PER_POLL = 10000
_MAX_READ_BYTES_PER_POLL = 1 << 20

_UDP_RCVBUF_BYTES = 4 << 20  # the kernel caps it at net.core.rmem_max
_TCP_MAX_CLIENTS = 64

class PoseSource(contextlib.AbstractContextManager, abc.ABC):
    """Raw pose messages from the network or stdin, read without waiting.

    Attributes
    ----------
    received_messages : int
        Messages returned by ``poll`` so far.
    dropped_messages : int
        Messages discarded for exceeding MAX_MESSAGE_BYTES (lines, or TCP clients cut off).
    """

    received_messages: int = 0
    dropped_messages: int = 0

    @abc.abstractmethod
    def poll(self) -> list[tuple[bytes, float]]:
        """Return the messages that arrived since the last call, oldest first; never wait.

        Returns
        -------
        list of (bytes, float)
            Each raw message (a datagram, or a line without its line ending) and its arrival
            time ``t_unix_s`` (``time.time()``).
        """

    @abc.abstractmethod
    def fileno(self) -> int:
        """Return a descriptor that turns readable when ``poll`` may have messages."""

    def fileno_list(self) -> list[int]:
        """Return the descriptors worth selecting on now (empty once the source has ended).

        Returns
        -------
        list of int
        """
        return [self.fileno()]

    @abc.abstractmethod
    def describe(self) -> str:
        """Return the source as a spec, e.g. ``udp://127.0.0.1:5600``."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release sockets; calling it again does nothing."""

    def __exit__(self, *exc: object) -> None:
        self.close()


class _LineSplitter:
    """Split a byte stream into lines, refusing lines longer than MAX_MESSAGE_BYTES."""

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.skipping = False  # inside an over-long line: discard up to its newline

    def feed(self, data: bytes) -> tuple[list[bytes], int]:
        """Return the complete lines in ``data`` and how many over-long lines were cut."""
        self.buffer += data
        lines: list[bytes] = []
        n_long = 0
        start = 0
        while True:
            end = self.buffer.find(b"\n", start)
            if end < 0:
                break
            line = bytes(self.buffer[start:end])
            start = end + 1
            if self.skipping:
                self.skipping = False
                continue
            if len(line) > MAX_MESSAGE_BYTES:
                n_long += 1
                continue
            line = line.rstrip(b"\r")
            if line.strip():
                lines.append(line)
        del self.buffer[:start]
        if len(self.buffer) > MAX_MESSAGE_BYTES:
            # No newline within 64 KiB: never buffer an unbounded line.
            if not self.skipping:
                n_long += 1
            self.skipping = True
            self.buffer.clear()
        return lines, n_long

    def finish(self) -> bytes | None:
        """Return the last line if the stream ended without a newline."""
        rest = None if self.skipping else bytes(self.buffer).rstrip(b"\r")
        self.buffer.clear()
        self.skipping = False
        return rest if rest and rest.strip() else None


def _resolve(host: str, port: int, kind: socket.SocketKind) -> tuple:
    try:
        infos = socket.getaddrinfo(host or None, port, type=kind, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise VirtualGPSError(f"cannot resolve host {host!r}: {exc}") from exc
    return infos[0]


def _listening_socket(scheme: str, host: str, port: int, kind: socket.SocketKind,
                      configure: Callable[[socket.socket, tuple], None]) -> socket.socket:
    """A non-blocking socket for ``host:port``, set up by ``configure(sock, address)`` (its
    options, the bind and, for TCP, listen); one clear error, naming the ``--poses`` spec,
    when that fails."""
    family, kind, proto, _, addr = _resolve(host, port, kind)
    sock = socket.socket(family, kind, proto)
    try:
        configure(sock, addr)
        sock.setblocking(False)
    except OSError as exc:
        sock.close()
        raise VirtualGPSError(
            f"cannot listen on {scheme}://{host}:{port}: {exc.strerror or exc}; choose another "
            f"address with --poses {scheme}://HOST:PORT"
        ) from exc
    return sock


def _spec(scheme: str, address: tuple) -> str:
    host, port = address[0], address[1]
    return f"{scheme}://[{host}]:{port}" if ":" in host else f"{scheme}://{host}:{port}"


class UdpPoseSource(PoseSource):
    """One pose message per UDP datagram.

    Parameters
    ----------
    host : str
        Address to bind (``127.0.0.1``, ``0.0.0.0``, ``::``); empty for all interfaces.
    port : int
        UDP port; 0 picks a free one (see ``address``).

    Attributes
    ----------
    address : tuple
        The bound (host, port, ...) address.

    Raises
    ------
    VirtualGPSError
        If the address cannot be bound (in use, not local).
    """

    def __init__(self, host: str, port: int) -> None:
        def configure(sock: socket.socket, addr: tuple) -> None:
            # A large buffer rides out bursts while the daemon computes an epoch.
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _UDP_RCVBUF_BYTES)
            sock.bind(addr)

        self._sock = _listening_socket("udp", host, port, socket.SOCK_DGRAM, configure)
        self.address = self._sock.getsockname()
        self.received_messages = 0
        self.dropped_messages = 0

    def describe(self) -> str:
        """Return ``udp://HOST:PORT`` as bound."""
        return _spec("udp", self.address)

    def fileno(self) -> int:
        """Return the socket's descriptor."""
        return self._sock.fileno()

    def poll(self) -> list[tuple[bytes, float]]:
        """Return every datagram waiting (up to 10,000 per call), each with its arrival time.

        Returns
        -------
        list of (bytes, float)
        """
        messages: list[tuple[bytes, float]] = []
        if self._sock.fileno() < 0:
            return messages
        while len(messages) < _MAX_DATAGRAMS_PER_POLL:
            try:
                data = self._sock.recv(MAX_MESSAGE_BYTES)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                log.debug("udp receive failed: %s", exc)  # e.g. ICMP errors; keep listening
                continue
            if data:
                messages.append((data, time.time()))
        self.received_messages += len(messages)
        return messages

    def close(self) -> None:
        """Close the socket."""
        self._sock.close()


class TcpPoseSource(PoseSource):
    """Newline-delimited pose messages from any number of TCP clients.

    A client that sends more than 64 KiB without a newline is disconnected and counted in
    ``dropped_clients`` (and its line in ``dropped_messages``) instead of being buffered. A last
    line without newline is delivered when its client disconnects. ``fileno()`` is an epoll
    descriptor over the listener and all clients, so one ``select`` covers them all.

    Parameters
    ----------
    host : str
        Address to listen on; empty for all interfaces.
    port : int
        TCP port; 0 picks a free one (see ``address``).

    Attributes
    ----------
    address : tuple
        The bound (host, port, ...) address.
    clients : int
        Connected clients.
    dropped_clients : int

    Raises
    ------
    VirtualGPSError
        If the address cannot be bound.
    """

    def __init__(self, host: str, port: int) -> None:
        def configure(sock: socket.socket, addr: tuple) -> None:
            # A restart must not wait for the previous run's connections in TIME_WAIT.
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(addr)
            sock.listen(16)

        self._listener = _listening_socket("tcp", host, port, socket.SOCK_STREAM, configure)
        self.address = self._listener.getsockname()
        self._epoll = select.epoll()
        self._epoll.register(self._listener.fileno(), select.EPOLLIN)
        self._clients: dict[int, tuple[socket.socket, _LineSplitter]] = {}
        self._closed = False
        self.received_messages = 0
        self.dropped_messages = 0
        self.dropped_clients = 0

    @property
    def clients(self) -> int:
        """Return the number of connected clients."""
        return len(self._clients)

    def describe(self) -> str:
        """Return ``tcp://HOST:PORT`` as bound."""
        return _spec("tcp", self.address)

    def fileno(self) -> int:
        """Return the epoll descriptor (readable when a client connects or sends)."""
        return self._epoll.fileno()

    def _accept(self) -> None:
        while True:
            try:
                conn, peer = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                log.debug("accept failed: %s", exc)
                return
            if len(self._clients) >= _TCP_MAX_CLIENTS:
                log.warning("refusing pose client %s: %d already connected", peer, _TCP_MAX_CLIENTS)
                conn.close()
                continue
            conn.setblocking(False)
            self._clients[conn.fileno()] = (conn, _LineSplitter())
            self._epoll.register(conn.fileno(), select.EPOLLIN)
            log.info("pose client %s connected", peer)

    def _drop(self, fd: int) -> None:
        conn, _ = self._clients.pop(fd)
        with contextlib.suppress(OSError):
            self._epoll.unregister(fd)
        conn.close()

    def poll(self) -> list[tuple[bytes, float]]:
        """Accept new clients and return the complete lines every client sent.

        Returns
        -------
        list of (bytes, float)
            Lines without their ``\\n`` or ``\\r\\n``; empty lines are skipped.
        """
        messages: list[tuple[bytes, float]] = []
        if self._closed:
            return messages
        for fd, _ in self._epoll.poll(0):
            if fd == self._listener.fileno():
                self._accept()
                continue
            if fd not in self._clients:
                continue
            conn, splitter = self._clients[fd]
            total = 0
            while total < _MAX_READ_BYTES_PER_POLL:
                try:
                    data = conn.recv(MAX_MESSAGE_BYTES)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    data = b""  # reset by peer: treat as a disconnect
                t_unix_s = time.time()
                if not data:
                    last = splitter.finish()
                    if last is not None:
                        messages.append((last, t_unix_s))
                    self._drop(fd)
                    break
                total += len(data)
                lines, n_long = splitter.feed(data)
                messages.extend((line, t_unix_s) for line in lines)
                if n_long:
                    self.dropped_messages += n_long
                    self.dropped_clients += 1
                    log.warning(
                        "dropping a pose client that sent %d bytes without a newline",
                        MAX_MESSAGE_BYTES,
                    )
                    self._drop(fd)
                    break
        self.received_messages += len(messages)
        return messages

    def close(self) -> None:
        """Disconnect every client and stop listening."""
        if self._closed:
            return
        self._closed = True
        for fd in list(self._clients):
            self._drop(fd)
        self._epoll.close()
        self._listener.close()


class StdinPoseSource(PoseSource):
    """Newline-delimited pose messages from stdin (or another readable descriptor).

    Reads only when ``select`` says the descriptor is readable, so it never waits, without
    setting O_NONBLOCK (which would change stdin for every process sharing it, e.g. the shell).
    At end of input ``eof`` turns True; the descriptor then stays readable, so the daemon must
    stop selecting on it.

    Parameters
    ----------
    fd : int or None
        Descriptor to read; None for stdin (descriptor 0). Not closed by ``close()``.

    Attributes
    ----------
    eof : bool
    """

    def __init__(self, fd: int | None = None) -> None:
        # fd 0 itself, not sys.stdin.fileno(): sys.stdin may be replaced (e.g. under pytest).
        self._fd = 0 if fd is None else fd
        self._splitter = _LineSplitter()
        self.eof = False
        self.received_messages = 0
        self.dropped_messages = 0

    def describe(self) -> str:
        """Return ``-``."""
        return "-"

    def fileno(self) -> int:
        """Return the descriptor read."""
        return self._fd

    def fileno_list(self) -> list[int]:
        """Return ``[fileno()]``, or ``[]`` after end of input (it would stay readable)."""
        return [] if self.eof else [self._fd]

    def poll(self) -> list[tuple[bytes, float]]:
        """Return the complete lines available now; at end of input also an unterminated one.

        Returns
        -------
        list of (bytes, float)
        """
        messages: list[tuple[bytes, float]] = []
        total = 0
        while not self.eof and total < _MAX_READ_BYTES_PER_POLL:
            readable, _, _ = select.select([self._fd], [], [], 0)
            if not readable:
                break
            try:
                data = os.read(self._fd, MAX_MESSAGE_BYTES)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                log.warning("reading poses from stdin failed: %s", exc)
                data = b""
            t_unix_s = time.time()
            if not data:
                self.eof = True
                last = self._splitter.finish()
                if last is not None:
                    messages.append((last, t_unix_s))
                break
            total += len(data)
            lines, n_long = self._splitter.feed(data)
            self.dropped_messages += n_long
            messages.extend((line, t_unix_s) for line in lines)
        self.received_messages += len(messages)
        return messages

    def close(self) -> None:
        """Stop reading (the descriptor is left open: it is not ours)."""
        self.eof = True


def open_pose_source(spec: str) -> PoseSource | None:
    """Open the network or stdin pose source named by a ``--poses`` spec.

    Parameters
    ----------
    spec : str
        ``udp://HOST:PORT``, ``tcp://HOST:PORT`` (IPv6 hosts in brackets, ``udp://[::1]:5600``;
        an empty host listens on all interfaces), or ``-`` for stdin.

    Returns
    -------
    PoseSource or None
        None for anything without a ``scheme:`` prefix (a pose log path, or ``demo``): those
        are the daemon's to handle.

    Raises
    ------
    ConfigError
        For a ``udp:``/``tcp:`` spec without a valid port, or another URL scheme.
    VirtualGPSError
        If the address cannot be bound.
    """
    text = spec.strip()
    if text == "-":
        return StdinPoseSource()
    scheme, sep, _ = text.partition(":")
    is_url = sep and scheme.isalpha() and len(scheme) > 1 and "/" not in scheme
    if not is_url:
        return None
    scheme = scheme.lower()
    hint = "expected udp://HOST:PORT, tcp://HOST:PORT, -, a pose log file or demo"
    if scheme not in ("udp", "tcp"):
        raise ConfigError(f"--poses {spec!r}: unknown scheme {scheme!r}; {hint}")
    parts = urlsplit(text)
    try:
        port = parts.port
    except ValueError:
        port = None
    if (
        not text.lower().startswith(f"{scheme}://")
        or port is None
        or parts.path not in ("", "/")
        or parts.query
        or parts.fragment
        or parts.username
    ):
        raise ConfigError(f"--poses {spec!r}: not a valid {scheme} address; {hint}")
    host = parts.hostname or ""
    if scheme == "udp":
        return UdpPoseSource(host, port)
    return TcpPoseSource(host, port)
