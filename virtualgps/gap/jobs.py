"""Where the gap tool's ensemble jobs run: in this process, on local worker processes (the
default: one per core), or on a Dask cluster (``--dask tcp://HOST:8786``).

Jobs are deterministic functions of their item (each carries its seeds), so the three give the
same results. :func:`map_jobs` runs a list of jobs; a :class:`JobQueue` takes jobs as they
become known and hands each back as it finishes (the gap tool's selections each go on when
their own jobs are back). Local workers are forked once per process and reused: the gap tool
submits thousands of small jobs while fitting, and workers keep module-level caches (a run's
sky, the loaded scene and TLE set) between jobs."""

from __future__ import annotations

import atexit
import concurrent.futures
import multiprocessing
import os
import pickle
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
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


def _start_pool_worker(by_main_thread: bool) -> None:
    """A local pool worker's set-up: :func:`prepare_worker`, and, where the pool was made by
    the main thread, it ends with this process (:func:`virtualgps.run.processes.
    die_with_parent`: a pool worker whose parent was killed, e.g. for memory, otherwise waits
    for jobs forever). The kernel ties that signal to the forking thread, so a pool made by
    another thread, which may end before the pool does, is left without it."""
    from virtualgps.run.processes import die_with_parent

    if by_main_thread:
        die_with_parent()
    prepare_worker()


def _pool(n: int) -> ProcessPoolExecutor:
    pool = _POOLS.get(n)
    if pool is not None and _POOL_VERSION.get(n) != _SHARED_VERSION[0]:
        pool.shutdown(wait=True)  # its workers were forked before the shared objects changed
        pool = None
    if pool is None:
        # fork: workers start with this process's modules imported and its caches filled
        ctx = multiprocessing.get_context("fork") if hasattr(os, "fork") else None
        pool = ProcessPoolExecutor(
            max_workers=n, mp_context=ctx, initializer=_start_pool_worker,
            initargs=(threading.current_thread() is threading.main_thread(),))
        _POOLS[n] = pool
        _POOL_VERSION[n] = _SHARED_VERSION[0]
    return pool


def _noop(_: Any = None) -> None:
    return None


def start_workers(jobs: int | None = None, dask_address: str | None = None) -> None:
    """Fork the local worker processes now (a pool made after the last :func:`share` is
    forked at its first job otherwise). Call it before this process starts a thread of its
    own: a fork copies only the forking thread, and a module another thread is importing
    stays locked in the child, which hangs at its first import of that module (seen in the
    test suite: every worker stuck on ``from scipy.signal import lfilter`` while the located
    gaps' thread imported scipy.signal for the first time). Nothing to do for Dask, one
    worker or the model."""
    if _MODEL or dask_address is not None or _local_workers(jobs) <= 1:
        return
    # (a fork-context pool starts all its workers at its first job)
    _pool(_local_workers(jobs)).submit(_noop).result()


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
    workers (None: one per core), or the benchmark's modelled workers (:func:`model`).
    Ensembles are cut into several jobs per worker."""
    if _MODEL:
        return int(_MODEL["workers"])
    if dask_address is not None:
        return max(1, sum(_client(dask_address).nthreads().values()))
    return _local_workers(jobs)


def _local_workers(jobs: int | None) -> int:
    return jobs or len(os.sched_getaffinity(0))  # (the cores this process may run on)


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
    queue = JobQueue(fn, jobs if len(items) > 1 else 1, dask_address)
    queue.submit(list(enumerate(items)))
    out: list[Any] = [None] * len(items)
    done = 0
    while queue.pending():
        for i, r in queue.wait():
            out[i] = r
            done += 1
            if progress is not None:
                progress(done, len(items))
    return out


class _Timed:
    """A job function that also returns its own run time, s (measured where it runs)."""

    def __init__(self, fn: Callable[[Any], Any]) -> None:
        self.fn = fn

    def __call__(self, item: Any) -> tuple[Any, float]:
        t0 = time.perf_counter()
        out = self.fn(item)
        return out, time.perf_counter() - t0


class JobQueue:
    """Jobs of one function, submitted as they become known and taken back as they finish.

    A caller with several independent strands of work (the gap tool's selections) lets each
    strand go on as soon as its own jobs are back, instead of waiting for the slowest job of a
    batch that holds every strand's work: the workers then stay busy with the next requests
    while a batch's last jobs run. Which jobs run together never changes a result (each job is
    a deterministic function of its item).

    Parameters
    ----------
    fn : a module-level (picklable) function
    jobs : local worker processes (None: all cores; 1: in this process, each job when
        :meth:`wait` needs it); dask_address : a Dask scheduler instead
    """

    def __init__(self, fn: Callable[[Any], Any], jobs: int | None = None,
                 dask_address: str | None = None) -> None:
        self._fn = _Timed(fn)
        self._dask = dask_address
        self._workers = 1 if dask_address is not None else _local_workers(jobs)
        self._inline: list[tuple[Any, Any]] = []  # (tag, item) not yet run (one worker)
        self._futures: dict[Any, Any] = {}  # future -> tag
        self._stream: Any = None  # Dask: the futures as they finish (distributed.as_completed)
        self._modelled: list[tuple[float, int, Any, Any]] = []  # (finish, order, tag, result)

    def submit(self, tagged: list[tuple[Any, Any]]) -> None:
        """Queue (tag, item) pairs; :meth:`wait` returns (tag, result) pairs."""
        STATS["submits"].append(len(tagged))
        if not tagged:
            return
        if _MODEL:
            self._model_run(tagged)
        elif self._dask is not None:
            client = _client(self._dask)
            if _CLIENT_VERSION.get(self._dask) != _SHARED_VERSION[0]:
                client.run(_install, dict(_SHARED))
                _CLIENT_VERSION[self._dask] = _SHARED_VERSION[0]
            with warnings.catch_warnings():
                # (a job's item may carry big arrays, e.g. the report's figures': Dask warns
                # about graphs over 10 MB, which here are a one-off payload, not a repeated one)
                warnings.filterwarnings("ignore", message="Sending large graph")
                futures = client.map(self._fn, [it for _, it in tagged], pure=False)
            self._futures.update(zip(futures, [tag for tag, _ in tagged], strict=True))
            if self._stream is None:
                from distributed import as_completed

                # (results fetched by the client's own thread as jobs finish, so a wait does
                # not make a round trip to the cluster)
                self._stream = as_completed(futures, with_results=True)
            else:
                self._stream.update(futures)
        elif self._workers <= 1:
            self._inline.extend(tagged)
        else:
            pool = _pool(self._workers)
            for tag, item in tagged:
                self._futures[pool.submit(self._fn, item)] = tag

    def pending(self) -> int:
        """Jobs submitted and not yet taken back by :meth:`wait`."""
        return len(self._inline) + len(self._futures) + len(self._modelled)

    def busy(self) -> int:
        """Jobs submitted and not yet done (modelled: not done by the model's clock): the
        work that still keeps the workers busy."""
        if _MODEL:
            now = _model_clock()
            return sum(m[0] > now for m in self._modelled)
        return len(self._inline) + sum(not f.done() for f in self._futures)

    def wait(self) -> list[tuple[Any, Any]]:
        """Block until at least one job is done; every done job's (tag, result), once each.

        Raises whatever a job raised (the queue's other jobs are cancelled)."""
        t0 = time.perf_counter()
        try:
            if _MODEL:
                return self._model_wait()
            if self._inline:
                tag, item = self._inline.pop(0)
                return [(tag, self._take(*self._fn(item)))]
            if not self._futures:
                raise RuntimeError("JobQueue.wait: nothing submitted")
            if self._dask is not None:
                done = self._gather(self._dask_batch)
                return [(self._futures.pop(f), self._take(*v)) for f, v in done]
            done = list(concurrent.futures.wait(
                list(self._futures), return_when=concurrent.futures.FIRST_COMPLETED).done)
            values = self._gather(lambda: [f.result() for f in done])
            return [(self._futures.pop(f), self._take(*v))
                    for f, v in zip(done, values, strict=True)]
        finally:
            STATS["wait_s"] += time.perf_counter() - t0

    def _gather(self, get: Callable[[], list[Any]]) -> list[Any]:
        """The done jobs' results; on a job's error the queue's other jobs are cancelled."""
        try:
            return get()
        except BaseException:
            for f in self._futures:
                f.cancel()
            self._futures.clear()
            raise

    def _dask_batch(self) -> list[tuple[Any, Any]]:
        """(future, result) of every Dask job finished by now, at least one; a job's error
        raised."""
        batch = self._stream.next_batch(block=True)
        for f, res in batch:
            if f.status == "error":  # (only the first of a batch is raised by Dask itself)
                raise res[1].with_traceback(res[2])
        return batch

    @staticmethod
    def _take(result: Any, job_s: float) -> Any:
        STATS["job_s"] += job_s
        STATS["jobs"] += 1
        return result

    # --- the benchmark's model of many workers (see :func:`model`) ---

    def _model_run(self, tagged: list[tuple[Any, Any]]) -> None:
        """Run the jobs here, now, each timing itself; each is given to the model's first free
        worker in submission order (as a pool or Dask hands them out), so it finishes at
        max(now, that worker free) + its time on the model's clock. Sending a job and taking
        its result back are the main process's time, as in a pool (pickling the item, then
        unpickling the result in :meth:`_model_wait`); the other halves are the job's."""
        sent = [(tag, pickle.dumps(item, pickle.HIGHEST_PROTOCOL)) for tag, item in tagged]
        now = _model_clock()
        free = _MODEL["free"]
        for tag, item in sent:
            t0 = time.perf_counter()
            out = pickle.dumps(self._fn(pickle.loads(item))[0], pickle.HIGHEST_PROTOCOL)
            job_s = time.perf_counter() - t0
            i = min(range(len(free)), key=free.__getitem__)
            free[i] = max(now, free[i]) + job_s
            self._modelled.append((free[i], _MODEL["order"], tag, (out, job_s)))
            _MODEL["order"] += 1
        _model_resume()

    def _model_wait(self) -> list[tuple[Any, Any]]:
        if not self._modelled:
            raise RuntimeError("JobQueue.wait: nothing submitted")
        now = max(_model_clock(), min(f for f, *_ in self._modelled))
        _MODEL["now"] = now
        done = sorted(m for m in self._modelled if m[0] <= now)
        self._modelled = [m for m in self._modelled if m[0] > now]
        _model_resume()
        return [(tag, self._take(pickle.loads(out), job_s)) for _, _, tag, (out, job_s) in done]


# For the benchmark: jobs and the time spent in them, the main process's time blocked waiting
# for them (the rest of a run's wall time is its serial part), and each submission's size.
STATS: dict[str, Any] = {"submits": [], "job_s": 0.0, "jobs": 0, "wait_s": 0.0}


def reset_stats() -> None:
    """Start counting :data:`STATS` afresh."""
    STATS.update(submits=[], job_s=0.0, jobs=0, wait_s=0.0)


# The model of many workers: its clock (s), each modelled worker's time of being free next,
# and the real time of the main process's last return from the queue.
_MODEL: dict[str, Any] = {}


def model(workers: int | None) -> None:
    """Model ``workers`` workers on this machine (None: stop modelling), for
    ``tools/bench_gap.py --model``: jobs run in this process, when submitted, each timing
    itself; the model's clock advances by the main process's own time between its calls to a
    queue (its serial work) and, when it waits, to the next modelled job's end. Jobs are shaped
    for ``workers`` (:func:`worker_count`); :func:`model_times_s` gives the modelled run's wall
    time. Work handed to a thread beside the main process runs off its clock
    (:class:`ModelThread`). It counts pickling jobs and results (the main process's part of
    sending them) but leaves out what more cores cost each job (memory bandwidth, a shared
    cache) and the pool's pipes: an upper bound on the speed-up."""
    _MODEL.clear()
    while _LIMITS:  # (the BLAS threads this process had before modelling)
        _LIMITS.pop().restore_original_limits()
    if workers:
        prepare_worker()  # (jobs run here: one BLAS thread, as in a worker)
        _MODEL.update(workers=workers, free=[0.0] * workers, now=0.0, serial=0.0, order=0,
                      aside=0.0, mark=time.perf_counter())


def model_times_s() -> tuple[float, float]:
    """The modelled run since :func:`model` was called: its wall time and its serial part
    (the main process's own time), s."""
    return _model_clock(), _MODEL["serial"]


def _model_clock() -> float:
    mine = time.perf_counter() - _MODEL["mark"]
    _MODEL["now"] += mine
    _MODEL["serial"] += mine
    _MODEL["mark"] = time.perf_counter()
    return _MODEL["now"]


def _model_resume() -> None:
    """(the jobs just run here are the model's workers' time, not the main process's)"""
    _MODEL["mark"] = time.perf_counter()


class _AsideDone:
    """A result :class:`ModelThread` computed, ready at a time of the model's clock."""

    def __init__(self, value: Any, ready_s: float) -> None:
        self._value, self._ready_s = value, ready_s

    def result(self) -> Any:
        """The value, once the model's clock has reached its time. Waiting for it counts as
        serial, as in a real run, whose serial rest is all but its waits for jobs."""
        now = _model_clock()
        if self._ready_s > now:
            _MODEL["serial"] += self._ready_s - now
            _MODEL["now"] = self._ready_s
        _model_resume()
        return self._value


class ModelThread:
    """The model of one thread beside the main process (the gap tool judges its located gaps in
    one while the workers run), used in place of a one-thread executor while :func:`model`
    models workers: a thread beside jobs run in this process would share their time."""

    def submit(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> _AsideDone:
        """Run ``fn(*args, **kwargs)`` here, now, off the main process's clock, as if the thread had
        started it when it was handed over, or when its previous call ended; its result is
        ready at that start plus its own run time (what a thread that mostly needs a core
        while the main process waits on the workers would take). Returns an object whose
        ``result()`` advances the model's clock to that time (the wait is serial time)."""
        now = _model_clock()
        t0 = time.perf_counter()
        value = fn(*args, **kwargs)
        ready = max(now, _MODEL["aside"]) + time.perf_counter() - t0
        _MODEL["aside"] = ready
        _model_resume()
        return _AsideDone(value, ready)

    def shutdown(self) -> None:
        """(nothing runs after :meth:`submit` returns)"""


def modelling() -> bool:
    """Whether :func:`model` is modelling workers (the gap tool then judges its located gaps on
    a :class:`ModelThread`)."""
    return bool(_MODEL)
