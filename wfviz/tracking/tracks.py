"""What the trackers report about their tracks: states, predictions with gates, lifecycle events."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


@dataclass(frozen=True)
class TrackState:
    """A live track after the frame's update; (x, y) is the reported position."""

    track_id: int
    x: float
    y: float
    vx: float
    vy: float
    confirmed: bool
    meeting: bool
    hits: int
    misses: int


@dataclass(frozen=True)
class Prediction:
    """A track's prediction for this frame and its rectangular gate (half sizes in px)."""

    track_id: int
    x: float
    y: float
    half_w: float
    half_h: float
    confirmed: bool
    meeting: bool
    cov_trace: float


class EventKind(StrEnum):
    """What can happen to a track; the value is the string recordings and logs show."""

    BORN = "born"                # a tentative track started (a New chain: star field)
    CONFIRMED = "confirmed"      # passed its confirmation test
    DELETED = "deleted"          # ended (dropped, lost, left the image)
    MEETING_ON = "meeting_on"    # GEWC eq. 15: two tracks within the safety distance
    MEETING_OFF = "meeting_off"  # the meeting ended, filter re-initialised
    REACQUIRED = "reacquired"    # a lost track took over a new detection near its path
    WINDOW_LOST = "window_lost"  # fusion: no candidate in its search window, global detection reruns
    RECOVERED = "recovered"      # fusion: found again by that global detection
    COUNT = "count"              # tbd: the most probable number of targets changed (track_id -1)
    REJOINED = "rejoined"        # star field: a new three-frame chain continues a Run chain
    EXITED = "exited"            # star field: the chain's prediction left the field
    REDETECTED = "redetected"    # star field: found by local re-segmentation
    PROMOTED = "promoted"        # star field: New -> Run
    ABSORBED = "absorbed"        # star field: took over the points of a dropped New chain


@dataclass(frozen=True)
class TrackEvent:
    """Something that happened to a track (``kind``: :class:`EventKind`) in ``frame``;
    ``track_id`` -1 for an event of the whole frame."""

    frame: int
    kind: EventKind
    track_id: int
    message: str
