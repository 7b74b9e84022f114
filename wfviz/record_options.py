"""What a recording is asked for (:class:`RecorderOptions`) and the defaults of its images
(:mod:`wfviz.record.images`), importable without rerun (the command line's option defaults)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from wfviz.record.live import Live

EXACT_EVERY = 10  # frames per exact (lossless, source dtype) image
PREVIEW_QUALITY = 85  # JPEG quality of the previews between


@dataclass(frozen=True)
class RecorderOptions:
    """Options of one recording (:class:`wfviz.record.Recorder`), from the command line or
    ``wfviz tune`` to the recorder.

    ``source`` and ``config_text`` are shown in the recording's ``config`` document;
    ``image_every`` logs the raw and stage images every N frames (0: never), exact (lossless) on
    the first image frame of every ``exact_every`` frames and JPEG previews at ``jpeg_quality``
    between; ``trail_length``: frames of a track's trail; ``live``: stream to a viewer or serve
    the run as well as writing the file (:mod:`wfviz.record.live`)."""

    source: str = ""
    config_text: str = ""
    image_every: int = 1
    exact_every: int = EXACT_EVERY
    jpeg_quality: int = PREVIEW_QUALITY
    trail_length: int = 60
    live: Live | None = None
