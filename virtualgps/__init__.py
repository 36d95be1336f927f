"""virtualgps: a virtual GPS receiver for robots.

Poses in; satellites from real ephemeris (SGP4); lines of sight ray-cast against a 3D scene;
errors like a real consumer receiver; Holux M-1000 (MediaTek) NMEA out on a pseudo-terminal.
See README.md for usage and DESIGN.md (in the steering repository) for the architecture.
"""

__version__ = "0.1.0"
