"""Where campaign runs execute: a local process pool (default) or a Ray cluster.

Both hand the same :func:`~slamfront.campaign.task.run_one` a :class:`RunTask` and yield
:class:`RunOutcome` objects as runs finish. A worker that dies (a crash in native code)
fails only the run it was executing: the runs in flight with it are retried one at a time
to find which one it was.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import socket
from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Protocol

from slamfront.campaign.task import RunOutcome, RunTask, run_one, thread_environment
from slamfront.errors import SlamfrontError


class Backend(Protocol):
    """Executes run tasks; a context manager that owns its workers."""

    shared_dir: bool
    """Workers write straight into the campaign folder (else they return the files)."""
    threads_per_run: int

    def __enter__(self) -> Backend: ...

    def __exit__(self, *exc: object) -> None: ...

    def run(self, tasks: Sequence[RunTask]) -> Iterator[RunOutcome]:
        """Execute ``tasks``; yield each outcome as soon as it is known."""
        ...


def died(task: RunTask, why: str) -> RunOutcome:
    return RunOutcome(key=task.key, status="failed", error=why)


def _ignore_sigint() -> None:
    # Ctrl-C reaches every process of the terminal's group; the campaign decides, then
    # stops the workers with SIGTERM, which a running run turns into a finalised log.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _child_environment(extra: dict[str, str]) -> Iterator[None]:
    """Variables set while the pool may start workers (BLAS reads its thread count at import).

    Spawned workers inherit them; the campaign process itself has its libraries loaded already.
    """
    saved = {name: os.environ.get(name) for name in extra}
    os.environ.update(extra)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


class LocalBackend:
    """A pool of ``workers`` fresh processes on this machine (spawned, not forked:
    forking a process that already runs OpenMP or Open3D threads can deadlock)."""

    shared_dir = True

    def __init__(self, workers: int | None = None) -> None:
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.threads_per_run = max(1, (os.cpu_count() or 1) // self.workers)
        self._pool: ProcessPoolExecutor | None = None

    def __enter__(self) -> LocalBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop(kill=False)

    def _start(self) -> ProcessPoolExecutor:
        self._pool = ProcessPoolExecutor(
            self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=_ignore_sigint
        )
        return self._pool

    def _stop(self, kill: bool) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if kill:
            # Python < 3.14 has no public way to stop running workers; SIGTERM lets a run finalise its log
            processes = list((getattr(pool, "_processes", None) or {}).values())
            for process in processes:
                if process.is_alive():
                    process.terminate()
            for process in processes:
                process.join(timeout=10)
        pool.shutdown(wait=True, cancel_futures=True)

    def run(self, tasks: Sequence[RunTask]) -> Iterator[RunOutcome]:
        queue = deque(tasks)
        suspects: deque[RunTask] = deque()  # in flight when a worker died: rerun alone
        in_flight: dict[Future[RunOutcome], RunTask] = {}
        pool = self._pool or self._start()
        with _child_environment(thread_environment(self.threads_per_run)):
            try:
                while queue or suspects or in_flight:
                    if suspects and not in_flight:
                        task = suspects.popleft()
                        in_flight[_submit(pool, task)] = task
                    while not suspects and queue and len(in_flight) < self.workers:
                        task = queue.popleft()
                        in_flight[_submit(pool, task)] = task
                    done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                    lost: list[RunTask] = []
                    for future in done:
                        task = in_flight.pop(future)
                        error = future.exception()  # the worker's, never this process's own Ctrl-C
                        if error is None:
                            yield future.result()
                        elif isinstance(error, BrokenProcessPool):
                            lost.append(task)
                        else:  # e.g. an outcome that could not be sent back: that run failed
                            yield died(task, f"{type(error).__name__}: {error}")
                    if lost:  # every run still in flight went down with the pool
                        lost += in_flight.values()
                        in_flight.clear()
                        # the pool has already sent SIGTERM to its other workers: a second one
                        # would cut short the log a stopped run is finalising
                        self._stop(kill=False)
                        pool = self._start()
                        if len(lost) == 1:
                            yield died(lost[0], "the worker process died while running it (a crash in native "
                                                "code, os._exit or the out-of-memory killer)")
                        else:
                            suspects.extend(lost)
            finally:
                if in_flight:
                    self._stop(kill=True)


def _submit(pool: ProcessPoolExecutor, task: RunTask) -> Future[RunOutcome]:
    """``pool.submit``, except that a pool a worker broke since the last ``wait`` gives a
    future that has failed with ``BrokenProcessPool``: the run loop then restarts the pool
    and reruns the task, exactly as for a task that was in flight when the worker died."""
    try:
        return pool.submit(run_one, task)
    except BrokenProcessPool as exc:
        failed: Future[RunOutcome] = Future()
        failed.set_exception(exc)
        return failed


class RayBackend:
    """Runs as Ray tasks: ``address`` is ``local`` (start Ray here), ``auto`` (the cluster
    this machine belongs to) or a cluster address (``ray://head:10001``, ``head:6379``).

    If Ray is already initialised in this process, that instance is used as it is.
    """

    def __init__(
        self, address: str, workers: int | None = None, cpus_per_run: float = 1.0, shared_dir: bool | None = None
    ) -> None:
        check_address(address)
        self.address = address
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.cpus_per_run = cpus_per_run
        self.threads_per_run = max(1, int(cpus_per_run))
        self.shared_dir = address == "local" if shared_dir is None else shared_dir
        self._started = False

    def __enter__(self) -> RayBackend:
        if not import_ray().is_initialized():
            start_ray(self.address, self.workers)
            self._started = True
        return self

    def __exit__(self, *exc: object) -> None:
        if self._started:
            import_ray().shutdown()
            self._started = False

    def run(self, tasks: Sequence[RunTask]) -> Iterator[RunOutcome]:
        ray = import_ray()
        # one retry: a node lost mid-run is worth it; a run's own errors come back in its outcome
        remote = ray.remote(num_cpus=self.cpus_per_run, max_retries=1)(run_one)
        pending = {remote.remote(task): task for task in tasks}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    task = pending.pop(ref)
                    try:
                        yield ray.get(ref)
                    except ray.exceptions.RayError as exc:
                        yield died(task, f"{type(exc).__name__}: {str(exc).strip().splitlines()[0]}")
        finally:
            for ref in pending:  # interrupted: a running task gets KeyboardInterrupt and finalises its log
                ray.cancel(ref)


def import_ray() -> Any:
    """The ``ray`` module, or a clear error when the optional dependency is missing."""
    try:
        import ray
        import ray.exceptions  # noqa: F401  (RayError, for failed tasks)
    except ImportError:
        raise SlamfrontError("--ray needs Ray, an optional dependency: pip install 'slamfront[ray]'") from None
    return ray


def start_ray(address: str, cpus: int) -> None:
    """``ray.init`` for ``local`` (a private Ray instance with ``cpus`` CPUs), ``auto`` or an address."""
    ray = import_ray()
    if address == "local":
        # address="local": always a new instance, never a cluster `ray start` left running here
        ray.init(address="local", num_cpus=cpus, include_dashboard=False, log_to_driver=False)
    else:
        _check_reachable(address)
        try:
            ray.init(address=address, log_to_driver=False)
        except ConnectionError as exc:
            raise SlamfrontError(f"--ray {address}: cannot connect to a Ray cluster: {exc}") from exc


def check_address(address: str) -> None:
    """``local``, ``auto``, ``ray://HOST:PORT`` or ``HOST:PORT``, else a clear error."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if address not in ("local", "auto") and not (host and port.isdigit()):
        raise SlamfrontError(f"--ray {address}: expected local, auto, ray://HOST:PORT or HOST:PORT")


def _check_reachable(address: str, timeout_s: float = 10.0) -> None:
    """Fail fast on a ``HOST:PORT`` nobody answers at (Ray itself retries for minutes)."""
    if address == "auto" or "://" in address:
        return
    host, _, port = address.rpartition(":")
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise SlamfrontError(f"--ray {address}: no Ray cluster answers there: {exc.strerror or exc}") from exc
