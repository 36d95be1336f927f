"""The sky: where the satellites are and what the antenna's lines of sight meet.

Satellites (:mod:`.ephemeris`: TLE sets and SGP4; :mod:`.broadcast`: RINEX navigation files;
:mod:`.satnodes`: the interpolation nodes of the paper's lookup table), which set to use
(:mod:`.skytime`, with the fetched sets of :mod:`.tlecache`), and the place: the 3D scene and its
ray queries (:mod:`.scene`) and sky masks (:mod:`.skymask`). Imports only the modules beside the
package (geodesy, constants, exceptions), never the receiver or anything above it.
"""
