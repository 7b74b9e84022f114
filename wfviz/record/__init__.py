"""The only package that imports rerun: maps each tracker's stage results to entities."""

from __future__ import annotations

from pathlib import Path

from wfviz.record.fusion import FusionRecorder
from wfviz.record.gewc import GEWCRecorder
from wfviz.record.recorder import Recorder, track_color
from wfviz.record.starfield import StarfieldRecorder
from wfviz.record.tbd import TBDRecorder

RECORDERS: dict[str, type[Recorder]] = {"gewc": GEWCRecorder, "fusion": FusionRecorder,
                                         "starfield": StarfieldRecorder, "tbd": TBDRecorder}


def open_recorder(tracker: str, path: Path, **kwargs: object) -> Recorder:
    """The logging adapter for ``tracker``, writing to ``path``."""
    return RECORDERS[tracker](path, tracker=tracker, **kwargs)  # type: ignore[arg-type]


__all__ = ["RECORDERS", "Recorder", "open_recorder", "track_color"]
