"""What bounds a fleet's size: the system's pseudo-terminals and the process's open files.

A fleet has no fixed cap of its own. Each receiver's pty is one pseudo-terminal of the system's
(``/proc/sys/kernel/pty/max``, 4096 by default on Linux) and one open file of the process that
serves it (a fleet's devices are stepped by one loop, so each holds just its master). The
open-file limit is raised to what the fleet needs where the hard limit allows (as servers
such as gpsd or nginx do); past either limit the run stops before making a device, with one
line naming the limit and how to raise it.
"""

from __future__ import annotations

import contextlib
import resource
from pathlib import Path

from virtualgps.exceptions import ConfigError

# Descriptors a process holds besides its devices: the interpreter, the scene's files, the pose
# source, the epoll loop, pipes to a parent, a few for files opened on the way.
RESERVED_FDS = 64
FDS_PER_DEVICE = 1  # a pty stepped by the fleet's loop holds its master alone
_PTY_DIR = Path("/proc/sys/kernel/pty")


def ptys_free() -> tuple[int, int] | None:
    """The system's pseudo-terminal limit and how many are in use, or None where unknown.

    Returns
    -------
    (max, in_use) : ``kernel.pty.max`` and ``kernel.pty.nr``
    """
    try:
        return (int((_PTY_DIR / "max").read_text()), int((_PTY_DIR / "nr").read_text()))
    except (OSError, ValueError):
        return None


def check_limits(n_devices: int, ptys: bool = True) -> None:
    """Make room for ``n_devices`` devices in this process, or say which limit is in the way.

    Raises the soft open-file limit (``RLIMIT_NOFILE``) up to what ``n_devices`` need, within
    the hard limit.

    Parameters
    ----------
    n_devices : the devices this process will open
    ptys : whether they are pseudo-terminals (else serial ports: no pty limit)

    Raises
    ------
    ConfigError
        one line: the limit, its value, and how to raise it (or split the fleet).
    """
    if ptys:
        check_ptys(n_devices)
    check_open_files(n_devices)


def check_ptys(n_devices: int) -> None:
    """Raise ConfigError (one line) unless the system has ``n_devices`` pseudo-terminals free.
    """
    got = ptys_free()
    if got is not None and n_devices > got[0] - got[1]:
        limit, used = got
        raise ConfigError(
            f"{n_devices} receivers need {n_devices} pseudo-terminals; the system allows "
            f"{limit} ({used} in use): raise it (as root: sysctl -w kernel.pty.max="
            f"{max(2 * limit, used + n_devices + 1024)}) or split the fleet across hosts "
            "with --ids")


def check_open_files(n_devices: int) -> None:
    """Raise this process's soft open-file limit to what ``n_devices`` devices need, within
    the hard limit; past it raise ConfigError (one line)."""
    need = RESERVED_FDS + FDS_PER_DEVICE * n_devices
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or need <= soft:
        return
    if hard == resource.RLIM_INFINITY or need <= hard:
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
            return
    raise ConfigError(
        f"{n_devices} receivers need ~{need} open files in one process; this one may open "
        f"{hard} at most (the hard limit, ulimit -Hn): raise it (LimitNOFILE= in a systemd "
        "unit, nofile in /etc/security/limits.conf), use more worker processes (--workers), "
        "or split the fleet across hosts with --ids")


def pty_error(exc: OSError, made: int, n_devices: int) -> ConfigError:
    """The one line for a pseudo-terminal that could not be made (the limits moved since
    :func:`check_limits`, or another process took the last ones).

    exc : the error of ``os.openpty``; made : devices made before it; n_devices : all wanted
    """
    got = ptys_free()
    where = "" if got is None else f"; the system allows {got[0]}, {got[1]} in use"
    return ConfigError(
        f"cannot make the pseudo-terminal of receiver {made + 1} of {n_devices}: "
        f"{exc.strerror or exc}{where} (raise kernel.pty.max or the open-file limit, "
        "ulimit -n, or split the fleet with --ids)")
