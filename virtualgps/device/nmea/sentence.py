"""NMEA 0183 framing, shared by the writer and the reader: the checksum, ``$body*HH\\r\\n``,
splitting a line into its address and fields, and NMEA's units. No I/O."""

from __future__ import annotations

MPS_TO_KNOTS = 3600.0 / 1852.0  # international nautical mile, 1852 m (NMEA speeds in knots)
MPS_TO_KMH = 3.6
UNIX_EPOCH_ORDINAL = 719163  # date(1970, 1, 1).toordinal(): NMEA dates <-> Unix days

_SUFFIX = [f"*{c:02X}\r\n" for c in range(256)]
_FOLD_MASKS = [(w, (1 << w) - 1) for w in (512, 256, 128, 64, 32, 16, 8)]


def _xor_bytes(b: bytes) -> int:
    """XOR of all bytes: the integer is folded in halves (about 1 us for 80 bytes)."""
    x = int.from_bytes(b, "little")
    while x.bit_length() > 1024:  # only for bodies longer than NMEA's 82 characters
        x = (x >> 1024) ^ (x & ((1 << 1024) - 1))
    for width, mask in _FOLD_MASKS:
        x = (x >> width) ^ (x & mask)
    return x


def nmea_checksum(body: str) -> str:
    """NMEA 0183 checksum of a sentence body: XOR of the characters between ``$`` and ``*``.

    Parameters
    ----------
    body : the text between ``$`` and ``*``, e.g. ``"GPGSA,A,1,,,,,,,,,,,,,,,"``

    Returns
    -------
    checksum : two upper-case hexadecimal digits, e.g. ``"1E"``
    """
    return f"{_xor_bytes(body.encode('ascii')):02X}"


def format_sentence(body: str) -> str:
    """Wrap a sentence body as ``$body*HH\\r\\n`` with its checksum.

    Parameters
    ----------
    body : the text between ``$`` and ``*``

    Returns
    -------
    sentence : str, ``$`` + body + ``*`` + checksum + CR LF
    """
    return "$" + body + _SUFFIX[_xor_bytes(body.encode("ascii"))]


def parse_sentence(line: str, require_checksum: bool = True) -> tuple[str, list[str]] | None:
    """Split one NMEA sentence into its address and fields, checking its checksum.

    Any text before the last ``$`` is ignored (phone logs prefix each line with a time stamp,
    e.g. Magdeburg ``2:52:16:587 Nachm. 03/28/17 - $GPGSV,...``); ``$`` never occurs inside a
    sentence (NMEA 0183 reserved character). So is text after the checksum that a separator
    sets off (Android's GnssLogger appends ``,<Unix ms>``); a checksum followed by a letter
    or digit is a corrupted one.

    Parameters
    ----------
    line : one line of text, with or without CR LF
    require_checksum : reject a sentence without ``*HH`` (NMEA 0183 makes it optional)

    Returns
    -------
    (address, fields) : e.g. ``("GPGGA", ["123519.000", "4807.0380", ...])``, or None when the
        line holds no sentence, is not ASCII, or its checksum is wrong
    """
    start = line.rfind("$")
    if start < 0:
        return None
    s = line[start + 1 :].rstrip("\r\n\t \x00")
    star = s.rfind("*")
    if star >= 0:
        body, given, after = s[:star], s[star + 1 : star + 3], s[star + 3 :]
        # text after the checksum, set off by a separator, is a logger's: Android's GnssLogger
        # writes ``NMEA,$GPGGA,...*5A,1513187753149`` (the phone's Unix milliseconds)
        if len(given) != 2 or (after and after[0].isalnum()):
            return None
        try:
            want = int(given, 16)
            got = _xor_bytes(body.encode("ascii"))
        except (ValueError, UnicodeEncodeError):
            return None
        if got != want:
            return None
    else:
        if require_checksum:
            return None
        body = s
        if not body.isascii():
            return None
    parts = body.split(",")
    if not parts[0]:
        return None
    return parts[0], parts[1:]
