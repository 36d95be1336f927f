"""Shared fixtures: the real data in ../shared/data, and a guard against leaked resources."""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
# The profile calibration on the shared MTK logs lives in tools/ (it carries their paths and
# what was fitted on them; nothing in the package may): its tests import it from there.
sys.path.insert(0, str(REPO / "tools"))

# Fetched TLE sets in the user's cache take precedence where they fit a run's time: the tests
# (and the commands they start) see an empty cache of their own, never the user's.
os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp(prefix="virtualgps-test-cache-")
atexit.register(shutil.rmtree, os.environ["XDG_CACHE_HOME"], ignore_errors=True)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real receiver logs, mesh and ephemerides in ../shared/data.

    Skips where ../shared is absent, but fails under CI (``CI`` set), where it must be present.
    """
    if not SHARED_DATA.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"{SHARED_DATA} is missing; CI must run with ../shared beside the clone")
        pytest.skip(f"{SHARED_DATA} not present")
    return SHARED_DATA


@pytest.fixture(autouse=True)
def no_leaked_fds():
    """Fail a test that leaves file descriptors open (ptys, sockets, files)."""
    fd_dir = Path("/proc/self/fd")
    before = set(os.listdir(fd_dir)) if fd_dir.is_dir() else set()
    yield
    if not before:
        return
    import gc

    gc.collect()
    leaked = set(os.listdir(fd_dir)) - before
    real = []
    for fd in leaked:
        try:
            target = os.readlink(fd_dir / fd)
        except OSError:
            continue  # closed meanwhile (the listing's own fd)
        if target.endswith((".ttf", ".otf", ".afm")):
            continue  # matplotlib's font cache keeps its fonts open for the process's life
        real.append(f"{fd}->{target}")
    if real:
        pytest.fail(f"test leaked file descriptors: {', '.join(sorted(real))}")
