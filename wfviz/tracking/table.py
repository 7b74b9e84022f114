"""Per-track columns: the track table of :class:`wfviz.tracking.manager.TrackManager` and the
statistics a confirmation rule keeps of its own (:mod:`wfviz.tracking.rules`).

A table is a dataclass of numpy arrays of one row per track (a struct of arrays): a frame costs a
few numpy calls whatever the number of tracks, which matters with tens of tentative tracks
started by noise every frame. Rows follow the manager's track order; :meth:`Columns.keep` and
:meth:`Columns.append` keep every column of a table in step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Self

import numpy as np

HISTORY = 3  # reported positions kept per track: eq. 15 reads s(k-1) and s(k-3)
MOTION_HISTORY = 32  # measured scene positions kept per track for the motion test (confirmation)


@dataclass(eq=False)
class Columns:
    """Columns of equal length, one row per track; a subclass declares them as fields and gives
    their empty rows in :meth:`blank`."""

    @classmethod
    def blank(cls, n: int) -> Self:
        """``n`` new rows (a column with no field: none)."""
        return cls()

    def __len__(self) -> int:
        names = self.__dataclass_fields__
        return len(getattr(self, next(iter(names)))) if names else 0

    def keep(self, rows: np.ndarray) -> None:
        """Keep the rows ``rows`` (a mask or indices) of every column."""
        for name in self.__dataclass_fields__:
            setattr(self, name, getattr(self, name)[rows])

    def append(self, new: Self) -> None:
        """Append the rows of ``new`` (the same columns) below the present ones."""
        for name in self.__dataclass_fields__:
            setattr(self, name, np.concatenate([getattr(self, name), getattr(new, name)]))


@dataclass(eq=False)
class TrackTable(Columns):
    """The live tracks of a :class:`~wfviz.tracking.manager.TrackManager`: the filter's state,
    the hit and miss counts, meeting mode (GEWC eq. 15) and what the confirmation rules read.
    Positions are (x = column, y = row) in image pixels unless said "scene" (camera motion
    removed: image position minus the manager's accumulated offset)."""

    ids: np.ndarray             #: (N,) int64 track ids
    x: np.ndarray               #: (N, 4) Kalman state (x, y, vx, vy)
    P: np.ndarray               #: (N, 4, 4) its covariance
    hits: np.ndarray            #: (N,) int64 measurements so far (the birth counts)
    misses: np.ndarray          #: (N,) int64 consecutive misses
    confirmed: np.ndarray       #: (N,) bool
    meeting: np.ndarray         #: (N,) bool: in meeting mode (eq. 15)
    meeting_frames: np.ndarray  #: (N,) int64 frames in the present meeting
    meet_again: np.ndarray      #: (N,) bool: False after a meeting until the next hit
    score_sum: np.ndarray       #: (N,) sum of the significance of the hits
    shape_sum: np.ndarray       #: (N,) sum of the blobness of the hits
    origin: np.ndarray          #: (N, 2) birth position, moved with the camera
    birth_image: np.ndarray     #: (N, 2) birth position in the image (not moved)
    path: np.ndarray            #: (N,) length of the reported path (scene) since birth
    gapless: np.ndarray         #: (N,) bool: updated in every frame since birth
    history: np.ndarray         #: (N, HISTORY, 2) last reported (x, y), oldest first
    history_len: np.ndarray     #: (N,) int64 valid rows of ``history``
    velocities: np.ndarray      #: (N, 3, 2) filtered (vx, vy) of the last updates, oldest first
    velocities_len: np.ndarray  #: (N,) int64 valid rows of ``velocities``
    innovation: np.ndarray      #: (N, 2) this frame's innovation (NaN: not updated)
    clutter: np.ndarray         #: (N,) mean of the hits' static-clutter labels (TrackManager._add_clutter)
    clutter_known: np.ndarray   #: (N,) int64 hits with a decided label
    motion_t: np.ndarray        #: (N, MOTION_HISTORY) frames of the measured scene positions
    motion_xy: np.ndarray       #: (N, MOTION_HISTORY, 2) measured positions (scene), oldest first
    motion_ok: np.ndarray       #: (N, MOTION_HISTORY) bool: that slot holds a position
    motion_reg: np.ndarray      #: (N, MOTION_HISTORY) the camera registration's standard error then (px)
    motion_wh: np.ndarray       #: (N, MOTION_HISTORY, 2) the hit's component's width and height (px; NaN: unknown)

    @classmethod
    def blank(cls, n: int) -> TrackTable:
        """``n`` empty rows (no position, no hits, not confirmed)."""
        return cls(
            ids=np.zeros(n, dtype=np.int64), x=np.zeros((n, 4)), P=np.zeros((n, 4, 4)),
            hits=np.zeros(n, dtype=np.int64), misses=np.zeros(n, dtype=np.int64),
            confirmed=np.zeros(n, dtype=bool), meeting=np.zeros(n, dtype=bool),
            meeting_frames=np.zeros(n, dtype=np.int64), meet_again=np.ones(n, dtype=bool),
            score_sum=np.zeros(n), shape_sum=np.zeros(n), origin=np.zeros((n, 2)),
            birth_image=np.zeros((n, 2)), path=np.zeros(n), gapless=np.ones(n, dtype=bool),
            history=np.zeros((n, HISTORY, 2)), history_len=np.zeros(n, dtype=np.int64),
            velocities=np.zeros((n, 3, 2)), velocities_len=np.zeros(n, dtype=np.int64),
            innovation=np.full((n, 2), np.nan), clutter=np.zeros(n),
            clutter_known=np.zeros(n, dtype=np.int64), motion_t=np.zeros((n, MOTION_HISTORY)),
            motion_xy=np.zeros((n, MOTION_HISTORY, 2)), motion_ok=np.zeros((n, MOTION_HISTORY), dtype=bool),
            motion_reg=np.zeros((n, MOTION_HISTORY)), motion_wh=np.full((n, MOTION_HISTORY, 2), np.nan))

    @property
    def confirmed_ids(self) -> list[int]:
        """Ids of the confirmed tracks, in row order."""
        return self.ids[self.confirmed].tolist()

    def shift(self, d: np.ndarray) -> None:
        """Move the image positions (state, birth point, history) by the camera's motion ``d``."""
        self.x[:, :2] += d
        self.origin += d
        self.history += d

    def push_history(self, rows: np.ndarray, xy: np.ndarray) -> None:
        """Append reported positions ``xy`` to the history of ``rows`` (the oldest drops out)."""
        self.history[rows, :-1] = self.history[rows, 1:]
        self.history[rows, -1] = xy
        self.history_len[rows] = np.minimum(self.history_len[rows] + 1, HISTORY)

    def push_motion(self, rows: np.ndarray, frame: int, scene_xy: np.ndarray, registration: float = 0.0,
                    size: np.ndarray | None = None) -> None:
        """Append measured scene positions ``scene_xy`` of ``rows`` in ``frame``, the camera's
        registration then known to ``registration`` px (standard error), and the hits'
        components' width and height ``size`` (None: unknown)."""
        if not rows.size:
            return
        for a in (self.motion_t, self.motion_xy, self.motion_ok, self.motion_reg, self.motion_wh):
            a[rows, :-1] = a[rows, 1:]
        self.motion_t[rows, -1] = frame
        self.motion_xy[rows, -1] = scene_xy
        self.motion_ok[rows, -1] = True
        self.motion_reg[rows, -1] = registration
        self.motion_wh[rows, -1] = np.nan if size is None else size
