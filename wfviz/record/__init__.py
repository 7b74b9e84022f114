"""The only package that imports rerun: maps each tracker's stage results to entities. Which
adapter records which tracker is named in ``wfviz.trackers.TRACKERS``."""

from __future__ import annotations

import importlib
from pathlib import Path

from wfviz.record.recorder import Recorder, track_color
from wfviz.record_options import RecorderOptions
from wfviz.trackers import TRACKERS


def recorder_class(tracker: str) -> type[Recorder]:
    """The logging adapter class registered for ``tracker``."""
    module, _, name = TRACKERS[tracker].recorder.partition(":")
    return getattr(importlib.import_module(module), name)


def open_recorder(tracker: str, path: Path, options: RecorderOptions) -> Recorder:
    """The logging adapter for ``tracker``, writing to ``path``."""
    return recorder_class(tracker)(path, tracker, options)


__all__ = ["Recorder", "RecorderOptions", "open_recorder", "recorder_class", "track_color"]
