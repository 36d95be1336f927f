"""virtualgps: a virtual GPS receiver for robots.

Poses in; satellites from real ephemeris (SGP4); lines of sight ray-cast against a 3D scene;
errors like a real consumer receiver; Holux M-1000 (MediaTek) NMEA out on a pseudo-terminal.
See README.md and docs/ for usage; docs/development.md for the layout of the code.
"""

__version__ = "0.1.0"
