"""A ``wfviz run``: the dataset's clips, which of them an earlier run already did, the rest run on
a pool (:mod:`wfviz.pools`: this process, local workers or Ray, as ``wfviz tune``'s trials), each
row written to ``results.csv`` as it arrives, ``summary.md`` at the end.

Resume: a clip is skipped when ``results.csv`` holds an ``ok`` row of it (same clip and truth)
made with the same tracker, configuration and gate (its ``config_hash``), its tracks CSV is there,
and so is its recording when one is asked for. Any change of the configuration (or tracker, or
gate) reruns every clip. A signal (Ctrl-C, SIGTERM) stops the clips running (their rows are not
written) and keeps every row finished."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wfviz.dataset.discover import DatasetClip, discover
from wfviz.dataset.goals import Goal
from wfviz.dataset.job import ClipTask, failed, outputs, run_clip
from wfviz.dataset.results import (OWN_TRUTH, Row, Totals, config_hash, read_results, summary_markdown, totals,
                                   write_results)
from wfviz.io.outputs import OutputError, check_writable, remove_stale, write_atomically

RESULTS = "results.csv"
SUMMARY = "summary.md"
SUBFOLDERS = ("tracks", "explain", "recordings")


@dataclass(frozen=True)
class RunSettings:
    """What ``wfviz run`` was asked: ``goal`` (what a clip should meet: the summary's "goals
    met"), ``record`` (record every clip), ``record_if`` (record the clips whose scores meet it)."""

    dataset: Path
    out: Path
    tracker: str
    config: Any
    gate: float = 3.0
    goal: Goal | None = None
    record: bool = False
    record_if: Goal | None = None

    @property
    def config_dict(self) -> dict[str, dict[str, Any]]:
        from wfviz.tune.space import config_dict

        return config_dict(self.config)

    @property
    def config_hash(self) -> str:
        return config_hash(self.tracker, self.config_dict, self.gate)


@dataclass
class Plan:
    """The dataset's ``clips``, the ``kept`` rows of an earlier run ({label: row}), the clips
    ``todo``, how many of them an earlier run did with another configuration (``changed``) and
    how many rows of clips no longer in the dataset are dropped."""

    clips: list[DatasetClip]
    kept: dict[str, Row]
    todo: list[DatasetClip]
    changed: int = 0
    dropped: int = 0


@dataclass
class Outcome:
    """The run's rows (dataset order), totals, clips run now, wall time and the signal that stopped it."""

    rows: list[Row]
    totals: Totals
    ran: int
    wall: float
    signal: int | None = None
    files: list[Path] = field(default_factory=list)


def _truth_column(c: DatasetClip) -> str:
    return c.truth or (OWN_TRUTH if c.synthetic else "")


def _same_path(a: str, b: str) -> bool:
    if a == b:
        return True
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


def _wants_recording(row: Row, settings: RunSettings) -> bool:
    return settings.record or (settings.record_if is not None and row.scored
                               and settings.record_if.holds(row.scores))


def check_out(settings: RunSettings) -> None:
    """Refuse an output folder that is a file, the dataset folder, or inside a clip folder (before
    anything is written)."""
    out = settings.out
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out}: is a file, expected the run's folder")
    for folder in (out, *out.parents):
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"--out {out}: {folder} is a file")
    if settings.dataset.is_dir() and out.resolve() == settings.dataset.resolve():
        raise OutputError(f"--out {out}: is the dataset folder; choose a folder for the results")


def plan(settings: RunSettings) -> Plan:
    """Find the clips and decide which need running (nothing written)."""
    check_out(settings)
    clips = discover(settings.dataset, exclude=settings.out)
    target = settings.out.resolve()
    for c in clips:
        if not c.synthetic and Path(c.spec).is_dir() and (target == Path(c.spec).resolve()
                                                          or Path(c.spec).resolve() in target.parents):
            raise OutputError(f"--out {settings.out}: inside the clip folder {c.spec}; choose a folder "
                              f"outside the clips")
    old = read_results(settings.out / RESULTS)
    labels = {c.label for c in clips}
    h = settings.config_hash
    kept: dict[str, Row] = {}
    todo: list[DatasetClip] = []
    changed = 0
    for c in clips:
        r = old.get(c.label)
        if r is not None and r.ok and r.config_hash != h:
            changed += 1
        if (r is not None and r.ok and r.config_hash == h and _same_path(r.clip, c.spec)
                and _same_path(r.truth, _truth_column(c)) and outputs(settings.out, c.label)["tracks"].is_file()
                and (not _wants_recording(r, settings) or outputs(settings.out, c.label)["recording"].is_file())):
            kept[c.label] = r
        else:
            todo.append(c)
    return Plan(clips, kept, todo, changed, sum(1 for k in old if k not in labels))


def execute(settings: RunSettings, *, workers: int = 1, use_ray: bool = False, ray_address: str | None = None,
            on_row: Callable[[Row, Totals], None] | None = None) -> Outcome:
    """Run the clips :func:`plan` finds to do (planned again once the output folder is held) on
    ``workers`` at a time (Ray with ``use_ray``); ``on_row`` gets each new row and the totals so
    far. ``results.csv`` is rewritten (atomically) after every row."""
    out = settings.out
    check_writable(out / RESULTS)  # the subfolders are made by the first clip that writes there
    with _hold(out):
        the_plan = plan(settings)  # again, under the lock: what a run that just ended left
        return _execute(settings, the_plan, workers, use_ray, ray_address, on_row)


@contextmanager
def _hold(out: Path) -> Iterator[None]:
    """Hold the output folder for this process: a second ``wfviz run`` on it is refused."""
    import fcntl

    fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OutputError(f"{out}: in use by another wfviz run; wait for it to end or choose another --out") \
                from None
        yield
    finally:
        os.close(fd)


def _execute(settings: RunSettings, the_plan: Plan, workers: int, use_ray: bool, ray_address: str | None,
             on_row: Callable[[Row, Totals], None] | None) -> Outcome:
    from wfviz.pools import make_pool
    from wfviz.run import StopSignals

    out = settings.out
    for sub in ("", *SUBFOLDERS):
        remove_stale(out / sub)  # temporaries of a killed run
    rows: dict[str, Row] = dict(the_plan.kept)
    order = [c.label for c in the_plan.clips]

    def current() -> list[Row]:
        return [rows[label] for label in order if label in rows]

    def save() -> None:
        write_results(out / RESULTS, current(), settings.goal)

    tasks = [ClipTask(c, settings.tracker, settings.config_dict, settings.gate, str(out), settings.config_hash,
                      record=settings.record, record_if=None if settings.record else settings.record_if)
             for c in the_plan.todo]
    caught: list[int] = []
    ran = 0
    t0 = time.perf_counter()
    save()  # rows of clips no longer in the dataset are dropped now
    with StopSignals() as signals:
        def stop() -> bool:
            return bool(caught) or signals.signum is not None

        def arrived(_i: int, row: Row) -> None:
            nonlocal ran
            if row.signal is not None or row.status == "interrupted":
                caught.append(row.signal or signal.SIGINT)
                return
            rows[row.label] = row
            ran += 1
            save()
            if on_row is not None:
                on_row(row, totals(current(), len(order), settings.goal))

        if tasks:
            pool = make_pool(workers, ray_address, use_ray, run_clip, failed, name="wfviz-run-worker")
            try:
                pool.run(tasks, stop, on_result=arrived)
            finally:
                pool.close()
        stopped = signals.signum if signals.signum is not None else (caught[0] if caught else None)
    for sub in SUBFOLDERS:  # the temporaries of the clips a stop cut short
        remove_stale(out / sub)
    wall = time.perf_counter() - t0
    final = current()
    t = totals(final, len(order), settings.goal)
    write_atomically(out / SUMMARY, summary_markdown(final, t, settings.goal, dataset=str(settings.dataset),
                                                     tracker=settings.tracker, gate=settings.gate,
                                                     config_hash=settings.config_hash, wall=wall, ran=ran))
    return Outcome(final, t, ran, wall, stopped, [out / RESULTS, out / SUMMARY])
