"""UBX framing: the frame layout, its checksum, and the splitter for what a client writes.

A UBX frame (u-blox 8 / u-blox M8 receiver description UBX-13003221, "UBX frame structure";
u-blox M9 SPG 4.04 interface description, "UBX frame structure") is::

    0xB5 0x62 | class | id | length (uint16, little-endian) | payload (length bytes) | CK_A CK_B

The checksum (UBX-13003221, "UBX checksum") is the 8-bit Fletcher algorithm of
RFC 1145 over class, id, length and payload: ``CK_A += byte; CK_B += CK_A``, both modulo 256.

A client writes UBX frames and NMEA-style lines (``$PUBX,41,...``) on one port, interleaved.
:class:`InputSplitter` separates them from any pieces of the byte stream, keeps a partial frame
across calls, skips garbage, drops frames whose checksum is wrong (counted), and never buffers
more than :data:`MAX_INPUT_PAYLOAD_BYTES` plus the frame overhead. Pure: no I/O.
"""

from __future__ import annotations

from itertools import accumulate

SYNC = b"\xb5\x62"  # u-blox's "\xb5" (micro sign) "b"
SYNC1, SYNC2 = 0xB5, 0x62
HEADER_BYTES = 6  # sync (2), class, id, length (2)
CHECKSUM_BYTES = 2
OVERHEAD_BYTES = HEADER_BYTES + CHECKSUM_BYTES

#: Longest payload accepted from a client, bytes. The longest input a driver sends is a
#: CFG-VALSET of 64 eight-byte values (4 + 64 * 12 = 772 bytes; M9 interface description,
#: UBX-CFG-VALSET: "limited to ... 64 key-value pairs"); MGA assistance messages are shorter.
#: A header announcing more is taken as garbage (a false sync), so a corrupt length field
#: cannot make the splitter wait for kilobytes before it resynchronises.
MAX_INPUT_PAYLOAD_BYTES = 1024

#: Longest NMEA-style line accepted from a client, bytes (as the MTK link: NMEA 0183 allows 82,
#: ``$PUBX`` commands are shorter; 255 leaves room for proprietary sentences).
MAX_LINE_BYTES = 255


def checksum(body: bytes) -> tuple[int, int]:
    """The UBX checksum (8-bit Fletcher, RFC 1145) of ``body``.

    Parameters
    ----------
    body : the bytes from class to the end of the payload (the frame without sync and
        checksum)

    Returns
    -------
    (ck_a, ck_b) : two ints in 0..255
    """
    # CK_A after byte k is the running sum of bytes 0..k, and CK_B the sum of those running
    # sums: both are sums taken modulo 256 once at the end (C-speed, ~50x a byte loop).
    return sum(body) & 0xFF, sum(accumulate(body)) & 0xFF


def encode(msg_class: int, msg_id: int, payload: bytes = b"") -> bytes:
    """One UBX frame: sync, class, id, little-endian length, payload, checksum.

    Parameters
    ----------
    msg_class, msg_id : 0..255
    payload : at most 65535 bytes

    Returns
    -------
    frame : bytes, ``len(payload) + 8`` long
    """
    n = len(payload)
    if not 0 <= n <= 0xFFFF:
        raise ValueError(f"UBX payload of {n} bytes; at most 65535 fit the length field")
    body = bytes((msg_class & 0xFF, msg_id & 0xFF, n & 0xFF, n >> 8)) + bytes(payload)
    return SYNC + body + bytes(checksum(body))


def decode(frame: bytes) -> tuple[int, int, bytes] | None:
    """Class, id and payload of one complete frame, or None if it is not a valid frame.

    Parameters
    ----------
    frame : bytes starting with the sync characters

    Returns
    -------
    (msg_class, msg_id, payload), or None: wrong sync, length or checksum
    """
    if len(frame) < OVERHEAD_BYTES or frame[:2] != SYNC:
        return None
    n = frame[4] | (frame[5] << 8)
    if len(frame) != n + OVERHEAD_BYTES:
        return None
    if checksum(frame[2 : HEADER_BYTES + n]) != (frame[-2], frame[-1]):
        return None
    return frame[2], frame[3], bytes(frame[HEADER_BYTES : HEADER_BYTES + n])


class InputSplitter:
    """Split a client's byte stream into complete UBX frames and ``$...`` lines.

    Rules (chosen to match what a receiver's input parser can know):

    - A UBX frame starts at ``B5 62``. Once its header is in, the frame is complete after
      ``length + 8`` bytes; a header announcing more than ``max_payload`` bytes is a
      false sync: its first byte is dropped and the search goes on. A frame whose checksum is
      wrong is dropped (``bad_checksum``) and the search restarts one byte after its sync, so a
      valid frame hidden behind a truncated one is still found.
    - A line starts at ``$`` and ends at CR or LF (the terminator is not returned). A ``$`` or a
      ``0xB5`` inside a line starts something new (NMEA is 7-bit ASCII and ``$`` is reserved,
      in NMEA 0183, so the earlier bytes were a broken line); a line longer than
      :data:`MAX_LINE_BYTES` is dropped.
    - Bytes outside both (noise, other protocols such as RTCM) are skipped and counted.

    Pieces may arrive in any number of calls; at most ``max_payload + 8`` bytes are buffered.

    max_payload : the longest payload taken for a frame (default
        :data:`MAX_INPUT_PAYLOAD_BYTES`, a client's; a receiver's log holds longer ones)

    Attributes
    ----------
    frames, lines : complete UBX frames and lines returned so far
    bad_checksum : UBX frames dropped for a wrong checksum
    dropped_lines : lines dropped for being too long or broken by a new start
    skipped_bytes : bytes outside any frame or line (including false syncs)
    """

    def __init__(self, max_payload: int = MAX_INPUT_PAYLOAD_BYTES) -> None:
        self.max_payload = max_payload
        self._buf = bytearray()
        self.frames = 0
        self.lines = 0
        self.bad_checksum = 0
        self.dropped_lines = 0
        self.skipped_bytes = 0

    def feed(self, data: bytes) -> list[bytes]:
        """Return the complete frames and lines in ``data`` and what came before, in order.

        Parameters
        ----------
        data : raw bytes from the client, any length

        Returns
        -------
        items : list of bytes, each either a whole UBX frame (starting ``B5 62``, checksum
            verified) or a line starting with ``$`` (without CR/LF)
        """
        buf = self._buf
        buf += data
        out: list[bytes] = []
        while buf:
            first = buf[0]
            if first == SYNC1:
                if len(buf) < 2:
                    break
                if buf[1] != SYNC2:
                    self._skip(1)
                    continue
                if len(buf) < HEADER_BYTES:
                    break
                n = buf[4] | (buf[5] << 8)
                if n > self.max_payload:
                    self._skip(1)  # a false sync (or a frame too long to be a command)
                    continue
                if len(buf) < n + OVERHEAD_BYTES:
                    break
                end = n + OVERHEAD_BYTES
                if checksum(buf[2 : end - 2]) == (buf[end - 2], buf[end - 1]):
                    out.append(bytes(buf[:end]))
                    self.frames += 1
                    del buf[:end]
                else:
                    self.bad_checksum += 1
                    self._skip(1)
                continue
            if first == 0x24:  # '$'
                k = _first_of(buf, (b"\r", b"\n", b"$", b"\xb5"), 1)
                if k < 0:
                    if len(buf) > MAX_LINE_BYTES:
                        self.dropped_lines += 1
                        self._skip(len(buf), count=False)
                    break
                if k > MAX_LINE_BYTES:
                    self.dropped_lines += 1
                elif buf[k] in (0x0D, 0x0A):
                    out.append(bytes(buf[:k]))
                    self.lines += 1
                    del buf[: k + 1]
                    continue
                else:
                    self.dropped_lines += 1  # broken by a new '$' or a UBX sync
                del buf[:k]
                continue
            # Noise: skip to the next possible start.
            k = _first_of(buf, (b"$", b"\xb5"), 0)
            self._skip(len(buf) if k < 0 else k)
        return out

    def _skip(self, n: int, count: bool = True) -> None:
        if count:
            self.skipped_bytes += n
        del self._buf[:n]


def _first_of(buf: bytearray, needles: tuple[bytes, ...], start: int) -> int:
    """Index of the first occurrence of any of ``needles`` at or after ``start``, or -1."""
    best = -1
    for needle in needles:
        p = buf.find(needle, start)
        if p >= 0 and (best < 0 or p < best):
            best = p
    return best
