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
import time
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from virtualgps.exceptions import ConfigError

T = TypeVar("T")
R = TypeVar("R")

DASK_CONNECT_TIMEOUT_S = 10.0

_POOLS: dict[int, ProcessPoolExecutor] = {}
_CLIENTS: dict[str, Any] = {}


_LIMITS: list[Any] = []
# Objects every worker needs for many jobs (a run's epochs, its real log, its units), shared
# once instead of travelling with each job: local workers inherit them when forked (the pool
# is forked again after they change), Dask workers receive them once each (Client.run).
_SHARED: dict[str, Any] = {}
_SHARED_VERSION = [0]
_POOL_VERSION: dict[int, int] = {}
_CLIENT_VERSION: dict[str, int] = {}


def share(objects: dict[str, Any]) -> None:
    """Make ``objects`` available to every worker as :func:`shared` (key -> object)."""
    _SHARED.update(objects)
    _SHARED_VERSION[0] += 1


def unshare(keys: list[str]) -> None:
    """Forget shared objects (workers forked later, or a later :func:`share`, drop them)."""
    for k in keys:
        _SHARED.pop(k, None)


def shared(key: str) -> Any:
    """An object given to :func:`share`, in whichever process the job runs."""
    return _SHARED[key]


def _install(objects: dict[str, Any]) -> None:
    _SHARED.update(objects)


def prepare_worker() -> None:
    """Set up a worker process for ensemble jobs (run once in each, before its first job).

    * BLAS/OpenMP pools held to one thread (threadpoolctl): a worker is one of many on the
      machine, and each job's small matrix products gain nothing from threads that only
      contend with the other workers.
    * glibc's malloc keeps freed blocks for reuse (:func:`virtualgps.run.replay.
      keep_freed_memory`): every job allocates and frees the same numpy temporaries. Dask's
      nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also freezes
      glibc's mmap threshold at 128 kB, so each temporary was a fresh mmap, zero-filled page
      by page: a job of 4 seeds over the MT3339 hour took 0.42-0.48 s and 425,000 page faults
      in such a process against 0.25-0.28 s and 89,000 without it, and 0.25 s and 55,000 with
      this call (2026-11-26, three jobs each, alternately).
    """
    from virtualgps.run.replay import keep_freed_memory

    keep_freed_memory()
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # (a core dependency; the guard keeps an odd install working)
        return
    _LIMITS.append(threadpool_limits(limits=1))


def _pool(n: int) -> ProcessPoolExecutor:
    pool = _POOLS.get(n)
    if pool is not None and _POOL_VERSION.get(n) != _SHARED_VERSION[0]:
        pool.shutdown(wait=True)  # its workers were forked before the shared objects changed
        pool = None
    if pool is None:
        # fork: workers start with this process's modules imported and its caches filled
        ctx = multiprocessing.get_context("fork") if hasattr(os, "fork") else None
        pool = ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=prepare_worker)
        _POOLS[n] = pool
        _POOL_VERSION[n] = _SHARED_VERSION[0]
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
    _CLIENT_VERSION.clear()


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
    client.run(prepare_worker)  # every worker of the cluster, once
    _CLIENTS[address] = client
    return client


def worker_count(jobs: int | None = None, dask_address: str | None = None) -> int:
    """How many jobs run at once: the Dask cluster's worker threads, else ``jobs`` local
    workers (None: one per core). Batches are shaped to several jobs per worker (to
    ``STATS["shape_for"]`` workers where the benchmark sets it)."""
    if STATS["shape_for"]:
        return int(STATS["shape_for"])
    if dask_address is not None:
        return max(1, sum(_client(dask_address).nthreads().values()))
    return _local_workers(jobs)


def _local_workers(jobs: int | None) -> int:
    return jobs or os.cpu_count() or 1


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
    t0 = time.perf_counter()
    timed = []
    try:
        timed = _map(_Timed(fn), list(items), jobs, dask_address, progress)
        return [r for r, _ in timed]
    finally:
        STATS["batches"].append(len(items))
        STATS["job_s"].append([s for _, s in timed])
        STATS["batch_s"].append(time.perf_counter() - t0)
        STATS["wall_s"] += STATS["batch_s"][-1]


class _Timed:
    """A job function that also returns its own run time, s (measured where it runs)."""

    def __init__(self, fn: Callable[[Any], Any]) -> None:
        self.fn = fn

    def __call__(self, item: Any) -> tuple[Any, float]:
        t0 = time.perf_counter()
        out = self.fn(item)
        return out, time.perf_counter() - t0


# For the benchmark: time spent in map_jobs (the parallel part), each batch's size, wall time
# and its jobs' own run times; ``shape_for``: shape batches for this many workers, whatever runs
# them (0: the workers that run them), so that a batch's jobs on many workers can be timed on
# few (tools/bench_gap.py --model).
STATS: dict[str, Any] = {"batches": [], "job_s": [], "batch_s": [], "wall_s": 0.0,
                         "shape_for": 0}


def reset_stats() -> None:
    """Start counting :data:`STATS` afresh (``shape_for`` stays)."""
    STATS["batches"] = []
    STATS["job_s"] = []
    STATS["batch_s"] = []
    STATS["wall_s"] = 0.0


def _map(fn: Callable[[T], R], items: list[T], jobs: int | None, dask_address: str | None,
         progress: Callable[[int, int], None] | None) -> list[R]:
    total = len(items)
    if dask_address is not None:
        client = _client(dask_address)
        if _CLIENT_VERSION.get(dask_address) != _SHARED_VERSION[0]:
            client.run(_install, dict(_SHARED))
            _CLIENT_VERSION[dask_address] = _SHARED_VERSION[0]
        with warnings.catch_warnings():
            # (a batch's items are sent with it, e.g. the report's figures' arrays: Dask warns
            # about graphs over 10 MB, which here are a one-off payload, not a repeated one)
            warnings.filterwarnings("ignore", message="Sending large graph")
            futures = client.map(fn, items, pure=False)
        out = client.gather(futures)
        if progress is not None:
            progress(total, total)
        return list(out)
    n = _local_workers(jobs)
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
