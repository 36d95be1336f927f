"""Pose sources through real sockets and pipes: UDP, TCP, stdin, and their specs."""

from __future__ import annotations

import os
import select
import socket
import time

import pytest

from virtualgps.exceptions import VirtualGPSError
from virtualgps.poses.posesource import (
    MAX_MESSAGE_BYTES,
    StdinPoseSource,
    TcpPoseSource,
    UdpPoseSource,
    open_pose_source,
)


def poll_until(source, n_messages: int, timeout_s: float = 2.0) -> list[tuple[bytes, float]]:
    got: list[tuple[bytes, float]] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n_messages and time.monotonic() < deadline:
        select.select([source.fileno()], [], [], 0.05)
        got += source.poll()
    return got


def test_udp_source() -> None:
    with UdpPoseSource("127.0.0.1", 0) as source:
        assert source.poll() == []
        big = b'{"t": 1, "pad": "' + b"p" * 60000 + b'"}'
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for message in (b'{"x": 1}', b'{"x": 2}', big):
                sender.sendto(message, source.address)
        t_sent = time.time()
        got = poll_until(source, 3)
    assert [m for m, _ in got] == [b'{"x": 1}', b'{"x": 2}', big]
    assert all(abs(t - t_sent) < 1.0 for _, t in got)
    assert source.describe().startswith("udp://127.0.0.1:")


def test_tcp_source_two_clients_and_partial_lines() -> None:
    with TcpPoseSource("127.0.0.1", 0) as source:
        a = socket.create_connection(source.address[:2])
        b = socket.create_connection(source.address[:2])
        try:
            a.sendall(b'{"a": 1}\n{"a": 2')
            b.sendall(b'{"b": 1}\r\n')
            got = poll_until(source, 2)
            assert sorted(m for m, _ in got) == [b'{"a": 1}', b'{"b": 1}']
            assert source.clients == 2
            a.sendall(b'5}\n\n{"a": 3}')  # completes the partial line; empty lines skipped
            got = poll_until(source, 1)
            assert [m for m, _ in got] == [b'{"a": 25}']
            a.close()  # the last line, without newline, is delivered at disconnect
            got = poll_until(source, 1)
            assert [m for m, _ in got] == [b'{"a": 3}']
            b.sendall(b'{"b": 2}\n')
            assert [m for m, _ in poll_until(source, 1)] == [b'{"b": 2}']
            assert source.clients == 1
        finally:
            a.close()
            b.close()


def test_tcp_source_drops_client_with_overlong_line() -> None:
    with TcpPoseSource("127.0.0.1", 0) as source:
        flood = socket.create_connection(source.address[:2])
        good = socket.create_connection(source.address[:2])
        try:
            try:
                flood.sendall(b"y" * (MAX_MESSAGE_BYTES + 10))
            except OSError:
                pass
            deadline = time.monotonic() + 2.0
            while source.dropped_clients == 0 and time.monotonic() < deadline:
                select.select([source.fileno()], [], [], 0.05)
                source.poll()
            assert source.dropped_clients == 1
            good.sendall(b'{"ok": 1}\n')
            assert [m for m, _ in poll_until(source, 1)] == [b'{"ok": 1}']
        finally:
            flood.close()
            good.close()


def test_stdin_source_from_pipe() -> None:
    read_fd, write_fd = os.pipe()
    try:
        source = StdinPoseSource(read_fd)
        assert source.fileno_list() == [read_fd]
        assert source.poll() == []  # nothing yet, and no waiting
        os.write(write_fd, b'{"x": 1}\n{"x"')
        assert [m for m, _ in source.poll()] == [b'{"x": 1}']
        got = []
        # An over-long line, written in pieces: a pipe holds only 64 KiB.
        rest = b": 2}\n" + b"z" * (MAX_MESSAGE_BYTES + 1) + b'\n{"x": 3}'
        for start in range(0, len(rest), 16384):
            os.write(write_fd, rest[start : start + 16384])
            got += source.poll()
        os.close(write_fd)
        write_fd = -1
        got += source.poll()
        assert [m for m, _ in got] == [b'{"x": 2}', b'{"x": 3}']
        assert source.dropped_messages == 1
        assert source.eof
        assert source.fileno_list() == []
        source.close()
    finally:
        os.close(read_fd)
        if write_fd >= 0:
            os.close(write_fd)


@pytest.mark.parametrize(
    ("spec", "kind"),
    [("udp://127.0.0.1:0", UdpPoseSource), ("tcp://127.0.0.1:0", TcpPoseSource)],
)
def test_open_pose_source_good(spec: str, kind: type) -> None:
    source = open_pose_source(spec)
    try:
        assert isinstance(source, kind)
    finally:
        source.close()


def test_open_pose_source_stdin_and_daemon_specs() -> None:
    assert isinstance(open_pose_source("-"), StdinPoseSource)
    assert open_pose_source("demo") is None
    assert open_pose_source("logs/run1.jsonl") is None
    assert open_pose_source("/abs/path/poses.csv") is None


@pytest.mark.parametrize(
    "spec",
    [
        "udp://127.0.0.1",
        "udp://127.0.0.1:notaport",
        "tcp://127.0.0.1:70000",
        "udp:5600",
        "http://127.0.0.1:5600",
        "udp://127.0.0.1:5600/path",
    ],
)
def test_open_pose_source_bad(spec: str) -> None:
    with pytest.raises(VirtualGPSError):
        open_pose_source(spec)


def test_pose_source_port_in_use() -> None:
    with UdpPoseSource("127.0.0.1", 0) as first:
        port = first.address[1]
        with pytest.raises(VirtualGPSError, match="cannot listen"):
            UdpPoseSource("127.0.0.1", port)
