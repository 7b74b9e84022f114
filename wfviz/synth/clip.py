"""What every generated clip shares: its truth rows (one type for the demo and the scenarios)
and the :class:`wfviz.io.frames.Clip` properties of a clip that reads no file (and
:class:`MemoryClip`, frames already in memory)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import NamedTuple

from wfviz.evaluate import Points
from wfviz.io.frames import Frame


class TruthRow(NamedTuple):
    """Target ``target_id`` in ``frame``: exact centre (pixels), rendered peak SNR, visibility
    (0: present but hidden, scored as don't-care)."""

    frame: int
    target_id: int
    x: float
    y: float
    peak_snr: float
    visible: int


def truth_points(rows: Iterable[TruthRow]) -> tuple[Points, Points]:
    """Truth rows as (visible, hidden) points ``{frame: [(target_id, x, y)]}``, the form
    :func:`wfviz.evaluate.read_truth` reads from a truth CSV."""
    shown: Points = {}
    hidden: Points = {}
    for r in rows:
        (shown if r.visible else hidden).setdefault(r.frame, []).append((r.target_id, r.x, r.y))
    return shown, hidden


class GeneratedClip:
    """Base of the clips rendered in memory: no file behind them, nothing skipped, truth known
    (a subclass provides :meth:`truth`)."""

    path: Path | None = None
    files: Sequence[Path] = ()
    skipped: Mapping[int, str] = MappingProxyType({})

    def truth(self) -> list[TruthRow]:
        """Every row, by frame then target id."""
        raise NotImplementedError

    def truth_points(self) -> tuple[Points, Points]:
        """The whole clip's truth as (visible, hidden) points, ready to score against."""
        return truth_points(self.truth())


class MemoryClip(GeneratedClip):
    """Frames already in memory (a :class:`wfviz.io.frames.Clip` that decodes nothing: the
    benchmarks' rendered frames, ``wfviz tune``'s cached ones); frames by their index. No
    truth of its own."""

    def __init__(self, name: str, frames: list[Frame], fps: float) -> None:
        self.name, self._frames, self.fps = name, frames, fps
        self.n_frames = len(frames)
        self.shape = frames[0].image.shape if frames else (0, 0)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        for f in self._frames:
            if f.index >= start and (stop is None or f.index < stop):
                yield f
