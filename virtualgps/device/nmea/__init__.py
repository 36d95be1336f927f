"""NMEA 0183 text: fixes -> sentences as a MediaTek (MTK) receiver writes them, and back.

- :mod:`~virtualgps.device.nmea.sentence`: the framing both directions share (checksum,
  ``$body*HH``, splitting a line into address and fields) and NMEA's units;
- :mod:`~virtualgps.device.nmea.writer`: the output format of a receiver profile
  (:class:`NmeaFormat`) and the rendering of fixes in MTK firmware's habits;
- :mod:`~virtualgps.device.nmea.reader`: the one reader of NMEA logs, ours and real receivers'.

The names below are the API (``from virtualgps import nmea; nmea.render_batch(...)``).
"""

from virtualgps.device.nmea.reader import (
    NmeaEpochs,
    NmeaFixLog,
    UndatedLogError,
    nmea_epochs_from_lines,
    nmea_fixes_from_lines,
    read_log_bytes,
    read_nmea_epochs,
    read_nmea_fixes,
    read_text_lines,
    text_lines,
)
from virtualgps.device.nmea.sentence import (
    MPS_TO_KMH,
    MPS_TO_KNOTS,
    format_sentence,
    nmea_checksum,
    parse_sentence,
)
from virtualgps.device.nmea.writer import (
    GSA_SLOTS,
    MTK_PLACEHOLDER_ALT_MSL_M,
    MTK_PLACEHOLDER_GEOID_SEP_M,
    MTK_PLACEHOLDER_LAT_DEG,
    epoch_sentences,
    render_batch,
)
from virtualgps.receiver.nmea_format import GSV_MAX_SATS, NO_FIX_STYLES, SENTENCE_TYPES, NmeaFormat

__all__ = [
    "GSA_SLOTS",
    "GSV_MAX_SATS",
    "MPS_TO_KMH",
    "MPS_TO_KNOTS",
    "MTK_PLACEHOLDER_ALT_MSL_M",
    "MTK_PLACEHOLDER_GEOID_SEP_M",
    "MTK_PLACEHOLDER_LAT_DEG",
    "NO_FIX_STYLES",
    "SENTENCE_TYPES",
    "NmeaEpochs",
    "NmeaFixLog",
    "NmeaFormat",
    "UndatedLogError",
    "epoch_sentences",
    "format_sentence",
    "nmea_checksum",
    "nmea_epochs_from_lines",
    "nmea_fixes_from_lines",
    "parse_sentence",
    "read_log_bytes",
    "read_nmea_epochs",
    "read_nmea_fixes",
    "read_text_lines",
    "render_batch",
    "text_lines",
]
