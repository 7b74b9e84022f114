"""Where trials run: in this process, in local worker processes, or as Ray tasks. Every kind
runs the same :func:`wfviz.tune.trial.run_trial` on a batch of tasks and returns the outcomes
in the batch's order, so a study gives the same trials whichever runs it."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections.abc import Callable
from typing import Any

from wfviz.tune.trial import TrialOutcome, TrialTask, run_trial

POLL_S = 0.05


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the study's to handle


class Inline:
    """Trials one after another in this process (``--workers 1``)."""

    workers = 1

    def run(self, tasks: list[TrialTask], stop: Callable[[], bool]) -> list[TrialOutcome | None]:
        out: list[TrialOutcome | None] = []
        for task in tasks:
            out.append(None if stop() else run_trial(task))
        return out

    def close(self) -> None:
        pass


class LocalPool:
    """``workers`` local processes (spawned: no state shared with this one), each serving one
    trial at a time over a pipe. Ctrl-C kills them (a trial's own stop handling would let it
    finish its clip first); a worker that dies fails its trial and is replaced."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self._ctx = multiprocessing.get_context("spawn")
        self._procs = [self._start() for _ in range(workers)]

    def _start(self) -> tuple[Any, Any]:
        parent, child = self._ctx.Pipe()
        p = self._ctx.Process(target=_serve, args=(child,), daemon=True, name="wfviz-tune-worker")
        p.start()
        child.close()
        return p, parent

    def run(self, tasks: list[TrialTask], stop: Callable[[], bool]) -> list[TrialOutcome | None]:
        results: list[TrialOutcome | None] = [None] * len(tasks)
        queue = list(range(len(tasks)))
        busy: dict[int, int] = {}  # worker -> task index
        while queue or busy:
            for w in range(len(self._procs)):
                if w not in busy and queue:
                    busy[w] = queue.pop(0)
                    self._procs[w][1].send(tasks[busy[w]])
            if stop():
                self._kill()
                return results
            for w in list(busy):
                p, conn = self._procs[w]
                if conn.poll():
                    try:
                        results[busy.pop(w)] = conn.recv()
                        continue
                    except EOFError:
                        pass
                if not p.is_alive():
                    j = busy.pop(w)
                    results[j] = TrialOutcome(tasks[j].number, None, f"the worker process died (exit code "
                                              f"{p.exitcode})", 0.0)
                    conn.close()
                    self._procs[w] = self._start()
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


def _serve(conn: Any) -> None:
    """A worker: run each task received until None arrives (Ctrl-C is the study's to handle)."""
    _ignore_sigint()
    while True:
        try:
            task = conn.recv()
        except EOFError:
            return
        if task is None:
            return
        conn.send(run_trial(task))


def require_ray() -> Any:
    """The ``ray`` module, or a one-line refusal when it is not installed."""
    try:
        import ray
    except ImportError:
        raise ValueError("--ray needs Ray: pip install \"wfviz[ray]\"") from None
    return ray


class RayPool:
    """Trials as Ray tasks (``ray.init(address)``; a local Ray when ``address`` is None), at
    most ``workers`` at a time."""

    def __init__(self, workers: int, address: str | None) -> None:
        ray = require_ray()
        self._ray = ray
        if not ray.is_initialized():
            ray.init(address=address, include_dashboard=False, log_to_driver=False,
                     configure_logging=False)
        self.workers = workers
        self._remote: Any = ray.remote(num_cpus=1, max_retries=0)(run_trial)

    def run(self, tasks: list[TrialTask], stop: Callable[[], bool]) -> list[TrialOutcome | None]:
        ray = self._ray
        refs = [self._remote.remote(t) for t in tasks]
        done: dict[int, TrialOutcome] = {}
        waiting = list(refs)
        while waiting:
            ready, waiting = ray.wait(waiting, num_returns=len(waiting), timeout=POLL_S)
            for r in ready:
                done[refs.index(r)] = ray.get(r)
            if waiting and stop():
                for r in waiting:
                    ray.cancel(r, force=True)
                break
        return [done.get(i) for i in range(len(refs))]

    def close(self) -> None:
        pass


def worker_count(asked: int | None, trials: int, use_ray: bool) -> tuple[int, str | None]:
    """Trials run at a time for ``--workers`` ``asked`` (None: this machine's cores): at most
    ``trials``, and locally at most the cores (more processes only share them, and cost memory).
    Returns the count and a note when it is less than asked."""
    cores = os.cpu_count() or 1
    n = min(asked or cores, trials) if use_ray else min(asked or cores, trials, cores)
    note = None
    if asked is not None and n < asked:
        why = "--trials" if n == trials else "this machine's cores"
        note = f"--workers {asked}: {n} at a time (at most {why}: {n})"
    return n, note


def make_pool(workers: int, ray_address: str | None, use_ray: bool) -> Inline | LocalPool | RayPool:
    """The runner for ``--workers`` and ``--ray``."""
    if use_ray:
        return RayPool(workers, ray_address)
    return Inline() if workers == 1 else LocalPool(workers)
