"""The receiver: poses + sky + profile + state + random numbers -> fixes + new state.

Pure numerics, vectorised over time, receivers and seeds: :mod:`.profiles` (TOML profiles and
their effects; :mod:`.nmea_format`, the profile's ``[nmea]`` table), :mod:`.definition` (one
receiver: profile, ephemeris, scene, georeference), :mod:`.skyview` (the sky at the antenna),
:mod:`.signals` (C/N0, attenuation, reflections), :mod:`.errors` (error processes),
:mod:`.solution` (satellites used, DOP, the fix's errors), :mod:`.output` (latency, filter,
holds), :mod:`.state` (what is carried from epoch to epoch), :mod:`.core` (tracking and
:func:`~.core.simulate`) and :mod:`.records` (fix records). Imports :mod:`virtualgps.sky` and
the base modules only.
"""
