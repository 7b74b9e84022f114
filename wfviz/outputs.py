"""Output files written atomically: to ``NAME.part``, renamed only when complete."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TextIO

from wfviz.tracking import TrackState

TRACKS_HEADER = ["frame", "track_id", "x", "y", "confirmed", "vx", "vy", "meeting"]


class OutputError(OSError):
    """An output path cannot be written (one-line message naming it)."""


def part_path(path: Path) -> Path:
    """The temporary name a file is written under until complete."""
    return path.with_name(path.name + ".part")


def check_writable(path: Path) -> None:
    """Create the parent folder if needed and check a file can be written there."""
    parent = path.parent
    for folder in (parent, *parent.parents):
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"{folder}: is a file, cannot hold the output {path.name}")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{parent}: cannot create output folder ({exc.strerror})") from None
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, expected a file name")
    probe = parent / f".wfviz-probe-{os.getpid()}"
    try:  # a real write: os.access says yes to root even on read-only mounts
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OutputError(f"{parent}: output folder is not writable ({exc.strerror})") from None


def commit(path: Path) -> None:
    """Rename ``path.part`` to ``path`` (replacing an older file)."""
    os.replace(part_path(path), path)


class TracksWriter:
    """Tracks CSV: ``frame,track_id,x,y,confirmed,vx,vy,meeting``, one row per live track."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fh: TextIO = open(part_path(path), "w", newline="", encoding="utf-8")
        self._fh.write(",".join(TRACKS_HEADER) + "\r\n")

    def write(self, frame: int, tracks: tuple[TrackState, ...]) -> None:
        """Append the rows of one frame."""
        self._fh.write("".join(
            f"{frame},{t.track_id},{t.x:.3f},{t.y:.3f},{t.confirmed:d},{t.vx:.3f},{t.vy:.3f},{t.meeting:d}\r\n"
            for t in tracks))  # the csv module's dialect (\r\n), plain numbers need no quoting

    def close(self) -> None:
        """Flush, close and rename into place."""
        self._fh.close()
        commit(self.path)

    def abort(self) -> None:
        """Close and remove the partial file."""
        self._fh.close()
        part_path(self.path).unlink(missing_ok=True)
