"""Where independent jobs run: in this process, in local worker processes, or as Ray tasks.
Every kind runs the same picklable top-level function on each task of a list and returns the
results in the list's order (and, to ``on_result``, each as it finishes), so a job gives the same
result whichever pool runs it. ``wfviz tune`` runs its trials here (:mod:`wfviz.tune.workers`),
``wfviz run`` its clips (:mod:`wfviz.dataset.session`)."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections.abc import Callable
from typing import Any, Generic, TypeVar

POLL_S = 0.05

T = TypeVar("T")
R = TypeVar("R")

#: called with each result as it arrives: (its task's index in the list, the result)
OnResult = Callable[[int, Any], None]
#: the result standing for a task whose worker died or whose Ray task failed: (task, why)
Failed = Callable[[Any, str], Any]


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's to handle


class Inline(Generic[T, R]):
    """Tasks one after another in this process (one worker)."""

    workers = 1

    def __init__(self, fn: Callable[[T], R]) -> None:
        self._fn = fn

    def run(self, tasks: list[T], stop: Callable[[], bool], on_result: OnResult | None = None) -> list[R | None]:
        """Each task's result (None: not run, ``stop()`` was true before it)."""
        out: list[R | None] = []
        for i, task in enumerate(tasks):
            if stop():
                out.append(None)
                continue
            out.append(self._fn(task))
            if on_result is not None:
                on_result(i, out[-1])
        return out

    def close(self) -> None:
        pass


class LocalPool(Generic[T, R]):
    """``workers`` local processes (spawned: no state shared with this one), each serving one
    task at a time over a pipe. ``stop()`` true (Ctrl-C) kills them (a job's own stop handling
    would let it finish its clip first); a worker that dies fails its task (``failed(task, why)``
    is its result) and is replaced."""

    def __init__(self, workers: int, fn: Callable[[T], R], failed: Failed, name: str = "wfviz-worker") -> None:
        self.workers = workers
        self._fn = fn
        self._failed = failed
        self._name = name
        self._ctx = multiprocessing.get_context("spawn")
        self._procs = [self._start() for _ in range(workers)]

    def _start(self) -> tuple[Any, Any]:
        parent, child = self._ctx.Pipe()
        p = self._ctx.Process(target=_serve, args=(child, self._fn), daemon=True, name=self._name)
        p.start()
        child.close()
        return p, parent

    def run(self, tasks: list[T], stop: Callable[[], bool], on_result: OnResult | None = None) -> list[R | None]:
        """Each task's result (None: not finished when ``stop()`` became true)."""
        results: list[R | None] = [None] * len(tasks)
        queue = list(range(len(tasks)))
        busy: dict[int, int] = {}  # worker -> task index

        def done(j: int, result: R) -> None:
            results[j] = result
            if on_result is not None:
                on_result(j, result)

        while queue or busy:
            for w in range(len(self._procs)):
                if w not in busy and queue and not stop():
                    busy[w] = queue.pop(0)
                    self._procs[w][1].send(tasks[busy[w]])
            if stop():
                self._kill()
                return results
            for w in list(busy):
                p, conn = self._procs[w]
                if conn.poll():
                    try:
                        result = conn.recv()
                        done(busy.pop(w), result)
                        continue
                    except EOFError:
                        pass
                if not p.is_alive():
                    j = busy.pop(w)
                    conn.close()
                    self._procs[w] = self._start()
                    done(j, self._failed(tasks[j], f"the worker process died (exit code {p.exitcode})"))
            time.sleep(POLL_S)
        return results

    def _kill(self) -> None:
        for p, conn in self._procs:
            p.kill()
            p.join()
            conn.close()
        self._procs = []

    def close(self) -> None:
        for p, conn in self._procs:
            try:
                conn.send(None)
            except OSError:
                pass
        for p, conn in self._procs:
            p.join(timeout=5)
            if p.is_alive():
                p.kill()
                p.join()
            conn.close()
        self._procs = []


def _serve(conn: Any, fn: Callable[[Any], Any]) -> None:
    """A worker: run ``fn`` on each task received until None arrives (Ctrl-C is the caller's)."""
    _ignore_sigint()
    while True:
        try:
            task = conn.recv()
        except EOFError:
            return
        if task is None:
            return
        conn.send(fn(task))


def require_ray() -> Any:
    """The ``ray`` module, or a one-line refusal when it is not installed."""
    try:
        import ray
    except ImportError:
        raise ValueError("--ray needs Ray: pip install \"wfviz[ray]\"") from None
    return ray


class RayPool(Generic[T, R]):
    """Tasks as Ray tasks (``ray.init(address)``; a local Ray when ``address`` is None), at
    most ``workers`` at a time; a Ray task that fails (its worker died) has ``failed(task, why)``
    as its result."""

    def __init__(self, workers: int, address: str | None, fn: Callable[[T], R], failed: Failed) -> None:
        ray = require_ray()
        self._ray = ray
        if not ray.is_initialized():
            ray.init(address=address, include_dashboard=False, log_to_driver=False,
                     configure_logging=False)
        self.workers = workers
        self._failed = failed
        self._remote: Any = ray.remote(num_cpus=1, max_retries=0)(fn)

    def run(self, tasks: list[T], stop: Callable[[], bool], on_result: OnResult | None = None) -> list[R | None]:
        """Each task's result (None: not finished when ``stop()`` became true)."""
        ray = self._ray
        results: list[R | None] = [None] * len(tasks)
        queue = list(range(len(tasks)))
        running: dict[Any, int] = {}  # ref -> task index
        while queue or running:
            while queue and len(running) < self.workers and not stop():
                j = queue.pop(0)
                running[self._remote.remote(tasks[j])] = j
            if stop():
                for r in running:
                    ray.cancel(r, force=True)
                break
            ready, _ = ray.wait(list(running), num_returns=len(running), timeout=POLL_S)
            for r in ready:
                j = running.pop(r)
                try:
                    results[j] = ray.get(r)
                except Exception as exc:  # noqa: BLE001 - a crashed Ray worker fails its task only
                    results[j] = self._failed(tasks[j], f"the Ray task failed ({type(exc).__name__})")
                if on_result is not None:
                    on_result(j, results[j])
        return results

    def close(self) -> None:
        pass


Pool = Inline[Any, Any] | LocalPool[Any, Any] | RayPool[Any, Any]


def worker_count(asked: int | None, items: int, use_ray: bool, *, flag: str = "--workers",
                 items_are: str = "--trials") -> tuple[int, str | None]:
    """Jobs run at a time for ``flag`` ``asked`` (None: this machine's cores): at most ``items``
    (the jobs there are, ``items_are`` in the note), and locally at most the cores (more processes
    only share them, and cost memory). Returns the count and a note when it is less than asked."""
    cores = os.cpu_count() or 1
    items = max(items, 1)
    n = min(asked or cores, items) if use_ray else min(asked or cores, items, cores)
    note = None
    if asked is not None and n < asked:
        why = items_are if n == items else "this machine's cores"
        note = f"{flag} {asked}: {n} at a time (at most {why}: {n})"
    return n, note


def make_pool(workers: int, ray_address: str | None, use_ray: bool, fn: Callable[[Any], Any], failed: Failed,
              name: str = "wfviz-worker") -> Pool:
    """The pool for ``workers`` at a time (1: this process) or Ray (``use_ray``) running ``fn``."""
    if use_ray:
        return RayPool(workers, ray_address, fn, failed)
    return Inline(fn) if workers == 1 else LocalPool(workers, fn, failed, name)
