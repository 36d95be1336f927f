"""Ensemble jobs run alike in this process, on local worker processes and on a Dask cluster
(a real one: scheduler and two workers started here as processes on 127.0.0.1)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from virtualgps.gap import jobs
from virtualgps.gap.ensemble import EnsembleJob, RunSetup, setup_digest, simulate_job
from virtualgps.receiver.definition import Georef
from virtualgps.receiver.profiles import load_profile

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def stop_workers():
    yield
    jobs.shutdown()


def _setup() -> RunSetup:
    t = 1489257600.0 + np.arange(300.0)
    ant = np.zeros((t.size, 3))
    valid = np.ones(t.size, bool)
    g = Georef(44.98, -93.24, 250.0)
    tle = str(REPO / "ephemeris" / "gps-ops-2017-03-26.tle")
    return RunSetup("still", t, ant, ant.copy(), valid, float(t[0]), g, None, tle, 0.0,
                    setup_digest(t, ant, valid, g, None, tle, 0.0))


def _items() -> list[EnsembleJob]:
    prof = load_profile("holux-m1000")
    return [EnsembleJob(_setup(), prof, (s, s + 1)) for s in (0, 2, 4)]


def _same(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.lat_deg, y.lat_deg)
        np.testing.assert_array_equal(x.cn0_dbhz, y.cn0_dbhz)
        np.testing.assert_array_equal(x.used, y.used)


def test_local_workers_equal_this_process():
    items = _items()
    _same(jobs.map_jobs(simulate_job, items, jobs=1), jobs.map_jobs(simulate_job, items, jobs=2))


def _boom(x: int) -> int:
    if x == 3:
        raise ValueError("job 3 failed")
    return x


def test_a_workers_exception_reaches_the_caller():
    with pytest.raises(ValueError, match="job 3 failed"):
        jobs.map_jobs(_boom, list(range(6)), jobs=2)


def test_pool_workers_end_with_a_killed_parent(tmp_path):
    """A parent killed outright (e.g. for memory) leaves no pool worker waiting for jobs
    forever; without it, such workers also held the terminal's pipe of ``virtualgps gap``."""
    pids = tmp_path / "pids"
    code = ("import os\n"
            "from virtualgps.gap import jobs\n"
            "import test_jobs\n"
            f"open({str(pids)!r}, 'w').write(' '.join(map(str, set("
            "jobs.map_jobs(test_jobs._pid, list(range(8)), jobs=2)))))\n"
            "os.kill(os.getpid(), 9)\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).parent,
                          timeout=120)
    assert proc.returncode == -signal.SIGKILL
    workers = [int(p) for p in pids.read_text().split()]
    assert workers
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and any(_alive(p) for p in workers):
        time.sleep(0.1)
    assert not [p for p in workers if _alive(p)]


def _pid(_: int) -> int:
    return os.getpid()


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"  # (a zombie has ended)
    except FileNotFoundError:
        return False


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def dask_cluster():
    """A scheduler and two single-threaded workers, as separate processes on 127.0.0.1."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        if os.environ.get("CI"):
            pytest.fail("dask.distributed is missing (the test extra installs it)")
        pytest.skip("dask.distributed not installed")
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), str(REPO / "tests")]))
    procs = [subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", str(port), "--dashboard-address", ":0"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    for _ in range(2):
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", addr, "--nthreads", "1",
             "--nworkers", "1", "--dashboard-address", ":0", "--host", "127.0.0.1"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True))
    try:
        from distributed import Client

        deadline = time.monotonic() + 60.0
        while True:
            try:
                with Client(addr, timeout=5) as c:
                    if len(c.scheduler_info()["workers"]) >= 2:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                pytest.fail("the local Dask cluster did not come up with 2 workers in 60 s")
            time.sleep(0.5)
        yield addr
    finally:
        jobs.shutdown()
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def test_dask_cluster_gives_the_same_ensembles(dask_cluster):
    # (batches are shaped to the cluster's size: two single-threaded workers)
    assert jobs.worker_count(dask_address=dask_cluster) == 2
    assert jobs.worker_count(jobs=3) == 3
    items = _items()
    _same(jobs.map_jobs(simulate_job, items, jobs=1),
          jobs.map_jobs(simulate_job, items, dask_address=dask_cluster))
    with pytest.raises(ValueError, match="job 3 failed"):
        jobs.map_jobs(_boom, list(range(6)), dask_address=dask_cluster)



def _read_shared(key: str) -> tuple[float, int, int, str | None]:
    """A job that reads a shared object; the BLAS threads its worker runs with; the page faults
    of a numpy job's temporaries there (ten rounds of twenty 2 MB blocks alive at once, then
    freed); the worker's MALLOC_TRIM_THRESHOLD_."""
    import resource

    from threadpoolctl import threadpool_info

    blas = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(10):
        blocks = [np.ones(262144) for _ in range(20)]
        del blocks
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
    return (float(np.sum(jobs.shared(key))), max(blas) if blas else 1, faults,
            os.environ.get("MALLOC_TRIM_THRESHOLD_"))


def test_every_worker_is_set_up_once(dask_cluster):
    """A run's epochs go to the workers once (not with each job): forked into local workers,
    installed on every Dask worker. Each worker keeps one BLAS thread, and reuses freed memory
    although Dask's nanny starts it with MALLOC_TRIM_THRESHOLD_=65536 (which made every
    temporary a fresh mmap: ~10,000 page faults a round, 1.7x the time of a job)."""
    jobs.share({"test:a": np.arange(10.0)})
    try:
        for kw in ({"jobs": 1}, {"jobs": 2}, {"dask_address": dask_cluster}):
            got = jobs.map_jobs(_read_shared, ["test:a"] * 4, **kw)
            assert [g[0] for g in got] == [45.0] * 4
            if "jobs" not in kw or kw["jobs"] > 1:
                assert all(g[1] == 1 for g in got), (kw, got)
                # kept for reuse, only the first round of a worker faults (~10,000)
                assert all(g[2] < 25_000 for g in got), (kw, got)
            if "dask_address" in kw:
                assert all(g[3] == "65536" for g in got), got  # (the case this guards)
        jobs.share({"test:a": np.arange(5.0)})  # changed: the workers see the new one
        for kw in ({"jobs": 2}, {"dask_address": dask_cluster}):
            assert jobs.map_jobs(_read_shared, ["test:a"] * 2, **kw)[0][0] == 10.0
    finally:
        jobs.unshare(["test:a"])


def _nap(s: float) -> float:
    time.sleep(s)
    return s


def test_a_queue_hands_back_each_job_as_it_finishes():
    q = jobs.JobQueue(_nap, jobs=2)
    q.submit([("slow", 1.0), ("quick", 0.05)])
    first = q.wait()
    assert first == [("quick", 0.05)] and q.pending() == 1
    q.submit([("later", 0.0)])  # submitted while the slow job still runs
    got = []
    while q.pending():
        got += q.wait()
    assert sorted(got) == [("later", 0.0), ("slow", 1.0)]


def test_a_failing_job_in_a_queue_reaches_the_caller():
    q = jobs.JobQueue(_boom, jobs=2)
    q.submit([(i, i) for i in range(6)])
    with pytest.raises(ValueError, match="job 3 failed"):
        while q.pending():
            q.wait()


def test_the_model_of_many_workers_plays_their_clock():
    """Jobs of known length on two modelled workers: each to the first free one in submission
    order, the main process's own time on the same clock."""
    jobs.model(2)
    try:
        assert jobs.worker_count(jobs=1) == 2
        q = jobs.JobQueue(_nap, jobs=1)
        q.submit([("a", 0.3), ("b", 0.1), ("c", 0.1), ("d", 0.1)])
        assert q.busy() == 4  # (run already, but not done by the model's clock)
        assert [t for t, _ in q.wait()] == ["b"]  # at 0.1 s
        time.sleep(0.15)  # the main process's own work, to 0.25 s: "c" is done meanwhile
        assert [t for t, _ in q.wait()] == ["c"]
        rest = []
        while q.pending():  # "a" and "d" at 0.3 s
            rest += [t for t, _ in q.wait()]
        assert sorted(rest) == ["a", "d"]
        wall_s, serial_s = jobs.model_times_s()
    finally:
        jobs.model(None)
    assert wall_s == pytest.approx(0.3, abs=0.03)
    assert serial_s == pytest.approx(0.15, abs=0.03)


def test_the_model_plays_a_thread_beside_the_main_process():
    """Work handed to the judging thread where workers are modelled runs off the main
    process's clock: its result is ready at its start (when handed over, or when the thread's
    previous work ended) plus its own time. The main process's wait for it is serial (not a
    wait for jobs), as a real run counts it."""
    jobs.model(2)
    thread = jobs.ModelThread()
    try:
        first = thread.submit(_nap, 0.2)  # ready at 0.2 s
        # queued behind it: ready at 0.3 s (keywords pass as to a ThreadPoolExecutor: the gap
        # tool hands the final where-table over with one)
        second = thread.submit(_nap, s=0.1)
        time.sleep(0.05)  # the main process's own work meanwhile
        assert first.result() == 0.2
        assert jobs.model_times_s()[0] == pytest.approx(0.2, abs=0.03)
        assert second.result() == 0.1
        wall_s, serial_s = jobs.model_times_s()
    finally:
        jobs.model(None)
    assert wall_s == pytest.approx(0.3, abs=0.03)
    assert serial_s == pytest.approx(0.3, abs=0.03)  # (0.05 of its own work, 0.25 waiting)
    # a result the thread had ready while the workers ran costs no serial time
    jobs.model(2)
    try:
        q = jobs.JobQueue(_nap, jobs=1)
        done = jobs.ModelThread().submit(_nap, 0.1)
        q.submit([("a", 0.3)])
        q.wait()
        assert done.result() == 0.1
        wall_s, serial_s = jobs.model_times_s()
    finally:
        jobs.model(None)
    assert wall_s == pytest.approx(0.3, abs=0.03)
    assert serial_s == pytest.approx(0.0, abs=0.03)
