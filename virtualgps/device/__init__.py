"""The device: what a receiver puts on the wire and answers; no simulation.

:mod:`.nmea` (sentences, the writer and the one reader), :mod:`.mtk` (the MTK command link),
:mod:`.output` (the output devices' one interface; files and stdout), :mod:`.pty`
(pseudo-terminals) and :mod:`.serialport` (serial ports). Imports the receiver's fix records and
the base modules only.
"""
