"""Run independent tasks (captures, chunks) on a local process pool or on a Ray cluster.

``make_executor("local", workers=4)`` forks a pool of processes on this machine;
``make_executor("ray", address="head:6379")`` sends the same tasks to a Ray cluster (the
``[distributed]`` extra; docs/scaling.md). Both are context managers with one method,
:meth:`Executor.map`, which returns the results in the order of the items.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import os
import signal
import sys
import threading
import time
from typing import Callable

from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

EXECUTORS = ("local", "ray")


class TaskError(MocapgraphError):
    """One or more tasks of :meth:`Executor.map` raised.

    Attributes:
        results: one entry per item, the task's result or None where it failed.
        failures: ``{task index: message}`` of the failed tasks, in index order.
    """

    def __init__(self, message: str, results: list, failures: dict[int, str]):
        super().__init__(message)
        self.results = results
        self.failures = failures

    def __reduce__(self):
        return TaskError, (str(self), self.results, self.failures)


def describe_exception(exc: BaseException) -> str:
    """The message for the user: a MocapgraphError's own words, anything else with its type."""
    if isinstance(exc, MocapgraphError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


class Executor:
    """Runs ``fn(item)`` for every item, as separate tasks; use it as a context manager."""


    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the workers (idempotent)."""

    def map(self, fn: Callable, items: list, progress: str = "", context=None) -> list:
        """``[fn(item) for item in items]`` (``fn(context, item)`` with a ``context``), computed as
        one task per item.

        ``fn`` must be picklable: a module-level function (pickled by reference, so the workers
        must be able to import its module), a builtin, or a ``functools.partial`` of those; the
        items and results must be picklable too. ``context`` is what every task shares (a
        problem, a model): it reaches the workers once, not with every item (forked workers
        inherit it; Ray stores it once). Every task runs to the end even when some fail; then,
        if any failed, a :class:`TaskError` names the first failed task's index and message and
        carries every result. ``progress`` labels a progress bar of the tasks as they end.
        """
        items = list(items)
        results: list = [None] * len(items)
        failures: dict[int, str] = {}
        causes: dict[int, BaseException] = {}
        with progress_bar(total=len(items), desc=progress, unit="task") as bar:
            for i, ok, value in self._run(fn, items, context):
                if ok:
                    results[i] = value
                else:
                    failures[i], causes[i] = describe_exception(value), value
                bar.update()
        if failures:
            first = min(failures)
            more = f" ({len(failures) - 1} more failed: tasks {', '.join(map(str, sorted(failures)[1:]))})" if len(failures) > 1 else ""
            raise TaskError(
                f"task {first} of {len(items)} failed: {failures[first]}{more}", results, dict(sorted(failures.items()))
            ) from causes[first]
        return results

    def _run(self, fn: Callable, items: list, context):
        """Yields ``(index, ok, result or exception)`` once per item, in completion order."""
        raise NotImplementedError


_CONTEXT = None
"""The context of the local pool's current map, inherited by its forked workers."""


def _with_context(fn: Callable, item):
    return fn(_CONTEXT, item)


_PR_SET_PDEATHSIG = 1


def worker_threads(workers: int) -> int:
    """Threads each of ``workers`` processes may use so that together they fill, not
    oversubscribe, the cores this process may run on."""
    return max(1, len(os.sched_getaffinity(0)) // workers) if hasattr(os, "sched_getaffinity") else 1


def _init_worker(parent: int, threads: int) -> None:
    """A pool worker's start: die with ``parent``; torch and OpenMP on ``threads`` threads."""
    die_with_parent(parent)
    os.environ["OMP_NUM_THREADS"] = str(threads)
    if "torch" in sys.modules:  # forked from a parent that loaded it: set it here, not only for later imports
        sys.modules["torch"].set_num_threads(threads)


def die_with_parent(parent: int) -> None:
    """Make this process (a pool worker) die when process ``parent`` does.

    A worker left behind after its parent was killed goes on computing for minutes and keeps the
    parent's stdout and stderr open, so whoever waits on those pipes hangs. Linux delivers SIGKILL
    at the parent's death (``prctl(PR_SET_PDEATHSIG)``); elsewhere a daemon thread watches for
    the worker's adoption by another process. A parent already gone before this ran is caught by
    the pid check.
    """
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    else:
        def watch() -> None:
            while os.getppid() == parent:
                time.sleep(0.5)
            os._exit(1)

        threading.Thread(target=watch, name="die-with-parent", daemon=True).start()
    if os.getppid() != parent:
        os._exit(1)


class LocalExecutor(Executor):
    """``workers`` forked processes on this machine; ``workers == 1`` runs every task in this process.

    Fork (as ``aircap``'s per-frame pass does) lets the workers inherit loaded modules and
    module-level state (body tables, gtsam objects) instead of importing and pickling them again.
    """


    def __init__(self, workers: int):
        self.workers = workers
        self._pool = None
        self._pool_context = None

    def _run(self, fn, items, context):
        call = fn if context is None else functools.partial(fn, context)
        if self.workers == 1:
            for i, item in enumerate(items):
                try:
                    yield i, True, call(item)
                except Exception as exc:  # reported per task, as from the pool
                    yield i, False, exc
            return
        from concurrent.futures import as_completed

        pool = self._get_pool(context)
        task = fn if context is None else functools.partial(_with_context, fn)
        futures = {pool.submit(task, item): i for i, item in enumerate(items)}
        for future in as_completed(futures):
            exc = future.exception()
            yield futures[future], exc is None, future.result() if exc is None else exc

    def _get_pool(self, context):
        """The pool, forked afresh when the context changed (its workers hold the old one)."""
        global _CONTEXT
        if self._pool is not None and self._pool_context is not context:
            self.close()
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            # A fork pool starts all its workers at the first submit, which follows at once: they
            # inherit this context.
            _CONTEXT, self._pool_context = context, context
            self._pool = ProcessPoolExecutor(
                self.workers, mp_context=multiprocessing.get_context("fork"), initializer=_init_worker,
                initargs=(os.getpid(), worker_threads(self.workers)),
            )  # fmt: skip
        return self._pool

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
            self._pool_context = None


def _apply(fn: Callable, item):
    return fn(item)


class RayExecutor(Executor):
    """Tasks on Ray: a cluster at ``address``, the instance this process already joined, or a
    local instance of ``workers`` CPUs started here (and shut down by :meth:`close`)."""


    def __init__(self, workers: int, address: str | None):
        try:
            import ray
        except ImportError:
            raise MocapgraphError("the ray executor needs the [distributed] extra: pip install 'mocapgraph[distributed]'") from None
        self._ray = ray
        self._started = False
        if ray.is_initialized():
            return
        # No internet in many labs and clusters: Ray would otherwise try to report usage.
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        quiet = dict(log_to_driver=False, logging_level=logging.WARNING, configure_logging=True)
        try:
            if address is None:
                ray.init(num_cpus=workers, include_dashboard=False, **quiet)
                self._started = True
            else:
                ray.init(address=address, **quiet)
        except Exception as exc:
            where = f"the Ray cluster at {address}" if address else "a local Ray instance"
            raise MocapgraphError(f"could not start or join {where}: {describe_exception(exc)}") from exc

    def _run(self, fn, items, context):
        ray = self._ray
        # One trampoline rather than ray.remote(fn): it also takes builtins and functools.partial,
        # and the function and the context are shipped to the object store once, not with every task.
        apply = ray.remote(_apply)
        fn_ref = ray.put(fn if context is None else functools.partial(fn, context))
        pending = {apply.remote(fn_ref, item): i for i, item in enumerate(items)}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                i = pending.pop(ref)
                try:
                    yield i, True, ray.get(ref)
                except ray.exceptions.RayTaskError as exc:
                    yield i, False, exc.cause if exc.cause is not None else exc
                except ray.exceptions.RayError as exc:  # a worker died or a node was lost
                    yield i, False, exc

    def close(self) -> None:
        if self._started:
            self._ray.shutdown()
            self._started = False


def make_executor(kind: str = "local", workers: int = 2, address: str | None = None) -> Executor:
    """An executor of ``kind`` ("local" or "ray").

    ``workers``: processes of the local pool, or CPUs of a local Ray instance (ignored when
    joining a cluster, whose size is its own). ``address``: a Ray cluster to join (``"auto"``
    or ``"host:6379"``); only with ``kind="ray"``.
    """
    if kind not in EXECUTORS:
        raise MocapgraphError(f"executor {kind!r}: choose one of {', '.join(EXECUTORS)}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise MocapgraphError(f"workers: a whole number of processes >= 1, got {workers!r}")
    if kind == "local":
        if address is not None:
            raise MocapgraphError(f"address {address!r}: only the ray executor joins a cluster")
        return LocalExecutor(workers)
    return RayExecutor(workers, address)
