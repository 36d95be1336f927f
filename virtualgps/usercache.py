"""The user's cache folder (XDG Base Directory): fetched TLE sets, parsed meshes.

Everything in it can be rebuilt: deleting it costs time, never results.
"""

from __future__ import annotations

import os
from pathlib import Path


def user_cache_dir(name: str) -> Path:
    """``$XDG_CACHE_HOME/virtualgps/<name>``, else ``~/.cache/virtualgps/<name>``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "virtualgps" / name
