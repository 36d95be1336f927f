"""Where the bundled data lives: the scenes and TLE sets that ship with virtualgps.

In the repository they are the top-level ``scenes/`` and ``ephemeris/`` folders (their source
of truth, with their READMEs and licences). A wheel carries them inside the package, as
``virtualgps/_bundled/scenes`` and ``virtualgps/_bundled/ephemeris``, copied there at build
time by ``setup.py``; an installed package finds them with :mod:`importlib.resources`, a
checkout (editable install, or the source tree on ``sys.path``) beside the package.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def bundled_dir(name: str) -> Path:
    """The folder of bundled ``name`` data ("scenes" or "ephemeris").

    Returns
    -------
    path : the packaged copy where the package carries one, else the repository's folder
    """
    packaged = resources.files("virtualgps") / "_bundled" / name
    if packaged.is_dir():
        return Path(str(packaged))
    return Path(__file__).resolve().parents[1] / name
