"""Frame and clip types shared by every input source (files, synthetic scenes)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
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

    @property
    def path(self) -> Path | None:
        """The file or folder read (None: a generated clip); named in error messages."""
        ...

    @property
    def files(self) -> Sequence[Path]:
        """The image files of a folder clip, one per frame (empty for other clips)."""
        ...

    @property
    def skipped(self) -> Mapping[int, str]:
        """Frames left out so far as unreadable, with the problem (``--skip-bad-frames``)."""
        ...

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop`` in order, one at a time."""
        ...


def read_ahead(frames: Iterator[Frame], depth: int = 2) -> Iterator[Frame]:
    """``frames`` in order, decoded up to ``depth`` frames ahead in a background thread, so
    that decoding (which releases the GIL) overlaps the caller's work on another core.

    Exceptions of the source arrive where the frame would have. Closing the returned generator
    (or leaving a ``for`` loop over it) stops the reader and closes ``frames`` in its thread.
    """
    import queue
    import threading

    items: queue.Queue = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()
    end = object()

    def put(item: object) -> bool:
        while not stop.is_set():
            try:
                items.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def read() -> None:
        try:
            for frame in frames:
                if not put(frame):
                    return
            put(end)
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            put(exc)
        finally:
            getattr(frames, "close", lambda: None)()

    reader = threading.Thread(target=read, name="wfviz-read-ahead", daemon=True)
    reader.start()
    try:
        while True:
            item = items.get()
            if item is end:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        reader.join()
