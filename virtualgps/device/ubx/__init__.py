"""The u-blox UBX protocol core (pure: no I/O, no clock, no threads).

:mod:`.frame` (frames, checksum, the client-input splitter), :mod:`.messages` (NAV/MON/ACK
output built from fix records), :mod:`.keys` (the M9 configuration keys, as data),
:mod:`.settings` (what a client may change, and power-on defaults of NEO-M8N / NEO-M9N) and
:mod:`.link` (the command state machine and each epoch's output).
"""
