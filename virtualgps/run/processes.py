"""Worker processes that end with the process that made them (the fleet's receivers' workers,
the gap tool's ensemble workers). No I/O."""

from __future__ import annotations

import contextlib
import ctypes
import signal

_PR_SET_PDEATHSIG = 1  # prctl(2)


def die_with_parent() -> None:
    """Ask the kernel for SIGTERM when the parent dies (Linux ``prctl``; nothing elsewhere),
    so a killed parent leaves no worker behind: a fleet worker holding its ptys, or a pool
    worker waiting for jobs forever (a gap run killed for memory left both its workers so,
    holding the terminal's pipe open)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
