"""Frame and clip types shared by every input source (files, synthetic scenes)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One frame of a clip.

    ``image`` is 2-D (rows, columns), dtype uint8, uint16 or float32, at the source's full
    range. ``index`` is 0-based in the clip; ``time`` is seconds from the clip's start.
    """

    index: int
    time: float
    image: np.ndarray


@runtime_checkable
class Clip(Protocol):
    """A source of frames, streamed one at a time (never loaded whole)."""

    @property
    def name(self) -> str:
        """Short name used for default output file names (e.g. the file stem)."""
        ...

    @property
    def fps(self) -> float:
        """Frames per second used for timestamps."""
        ...

    @property
    def n_frames(self) -> int | None:
        """Number of frames if known in advance, else None."""
        ...

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of every frame."""
        ...

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop`` in order, one at a time."""
        ...
