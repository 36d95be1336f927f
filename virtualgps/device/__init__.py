"""The device: what a receiver puts on the wire and answers; no simulation.

:mod:`.nmea` (sentences, the writer and the one reader), :mod:`.mtk` (the MTK command link) and
:mod:`.transport` (pseudo-terminals, serial ports, files). Imports the receiver's fix records and
the base modules only.
"""
