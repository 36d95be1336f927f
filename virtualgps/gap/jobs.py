"""Where the gap tool's ensemble jobs run: in this process, on local worker processes (the
default: one per core), or on a Dask cluster (``--dask tcp://HOST:8786``).

Jobs are deterministic functions of their item (each carries its seeds), so the three give the
same results in the same order. Local workers are forked once per process and reused: the gap
tool maps hundreds of small batches while fitting, and workers keep module-level caches (a
run's sky, the loaded scene and TLE set) between jobs.
"""

from __future__ import annotations

import atexit
import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from virtualgps.exceptions import ConfigError

T = TypeVar("T")
R = TypeVar("R")

DASK_CONNECT_TIMEOUT_S = 10.0

_POOLS: dict[int, ProcessPoolExecutor] = {}
_CLIENTS: dict[str, Any] = {}


def _pool(n: int) -> ProcessPoolExecutor:
    pool = _POOLS.get(n)
    if pool is None:
        # fork: workers start with this process's modules imported and its caches filled
        ctx = multiprocessing.get_context("fork") if hasattr(os, "fork") else None
        pool = ProcessPoolExecutor(max_workers=n, mp_context=ctx)
        _POOLS[n] = pool
    return pool


def shutdown(wait: bool = True) -> None:
    """Stop the local worker pools and close the Dask clients of this process."""
    for pool in _POOLS.values():
        pool.shutdown(wait=wait, cancel_futures=True)
    _POOLS.clear()
    for client in _CLIENTS.values():
        try:
            client.close()
        except Exception:  # noqa: BLE001 - closing a client whose scheduler went away
            pass
    _CLIENTS.clear()


atexit.register(shutdown, wait=False)


def _client(address: str) -> Any:
    client = _CLIENTS.get(address)
    if client is not None:
        return client
    try:
        from dask.distributed import Client
    except ImportError:
        raise ConfigError("--dask needs dask.distributed: install the dask extra "
                          "(pip install 'virtualgps[dask]')") from None
    try:
        client = Client(address, timeout=DASK_CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise ConfigError(f"--dask {address}: cannot reach the Dask scheduler within "
                          f"{DASK_CONNECT_TIMEOUT_S:.0f} s ({exc})") from None
    _CLIENTS[address] = client
    return client


def map_jobs(
    fn: Callable[[T], R],
    items: Sequence[T],
    jobs: int | None = None,
    dask_address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[R]:
    """Apply ``fn`` to every item, in parallel where asked; results in the items' order.

    Parameters
    ----------
    fn : a module-level (picklable) function
    items : picklable job descriptions
    jobs : local worker processes (None: all cores; 1: in this process)
    dask_address : a Dask scheduler (``tcp://HOST:8786``): the jobs go there instead
    progress : called with (done, total) as results arrive

    Returns
    -------
    results : ``[fn(item) for item in items]``

    Raises
    ------
    Whatever ``fn`` raised, for the first failing item (the other jobs are not waited for).
    """
    items = list(items)
    total = len(items)
    if dask_address is not None:
        client = _client(dask_address)
        futures = client.map(fn, items, pure=False)
        out = client.gather(futures)
        if progress is not None:
            progress(total, total)
        return list(out)
    n = jobs or os.cpu_count() or 1
    if n <= 1 or total <= 1:
        out = []
        for i, item in enumerate(items):
            out.append(fn(item))
            if progress is not None:
                progress(i + 1, total)
        return out
    pool = _pool(n)
    futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
    results: list[Any] = [None] * total
    for done, fut in enumerate(as_completed(futures), start=1):
        results[futures[fut]] = fut.result()
        if progress is not None:
            progress(done, total)
    return results
