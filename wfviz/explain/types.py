"""What an explanation of a run is made of: a cause for every truth point of every frame and
for every confirmed track point that matches no truth (docs/debugging.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum


class Cause(StrEnum):
    """Why a truth point was, or was not, matched, in the order of the pipeline
    (:data:`FUNNEL`): the first stage that lost it names it."""

    MATCHED = "matched"                # a confirmed track within the gate (the scorer's match)
    HIDDEN = "hidden"                  # truth marked not visible (don't care)
    OUTSIDE_CIRCLE = "outside_circle"  # outside the imaging circle (or the frame)
    OUTSIDE_REGION = "outside_region"  # outside the searched region (horizon, its margin, windows)
    NOT_DETECTED = "not_detected"      # no detection within the gate
    NOT_ASSOCIATED = "not_associated"  # a detection within the gate that no track on it took
    LATENCY = "latency"                # on a tentative track too young to have been confirmed
    NOT_CONFIRMED = "not_confirmed"    # on a tentative track old enough, held back by a test
    LOST = "lost"                      # its confirmed track is off it or deleted


#: the causes of a missed visible point, in the order they are decided: a point takes the first
#: stage it does not pass (visible -> searched -> detected -> its confirmed track kept -> on a
#: track -> old enough -> confirmed and matched)
MISSES = (Cause.OUTSIDE_CIRCLE, Cause.OUTSIDE_REGION, Cause.NOT_DETECTED, Cause.LOST, Cause.NOT_ASSOCIATED,
          Cause.LATENCY, Cause.NOT_CONFIRMED)


class FalseCause(StrEnum):
    """Why a confirmed track point matches no truth (rules in :mod:`wfviz.explain.false_tracks`)."""

    STATIC_IN_SCENE = "static_in_scene"  # fixed in scene coordinates (a star, a lamp, a roof corner)
    CAMERA_MOTION = "camera_motion"      # moves only because the camera's motion was not compensated
    HOPPING = "hopping"                  # hops across its misses from one static spot to the next
    STRUCTURE = "structure"              # on an edge, line or extended object, or sliding along a line
    DEFECT = "defect"                    # on a pixel flagged as a sensor defect
    DUPLICATE = "duplicate"              # a second track on a target another track matches
    OFF_TARGET = "off_target"            # a track that matched a target and drifted off it
    UNKNOWN = "unknown"                  # none of the above


@dataclass(frozen=True)
class TruthExplanation:
    """One truth point in one frame: its ``cause`` and a short ``detail``; ``significance``: the
    point's own significance in σ of the local noise (the larger of the residual's and the
    change's, as a detection's; NaN: the tracker has no noise stage), ``residual`` and ``change``
    the two parts, ``threshold`` the level (σ) a detection needed there; ``det_dist``: distance to
    the nearest detection of the frame (NaN: none); ``track_id``: the track the cause refers to
    (None: none); ``pred_dist``: how far that track's prediction of this frame lies from the
    point (px) and ``pred_gate`` that offset against the gate's half sizes (the larger of
    |dx| / half width and |dy| / half height: above 1 the point lies outside the gate; NaN: no
    track, or it predicted nothing this frame). A manoeuvre shows as ``pred_gate`` growing over
    the matched frames before a loss."""

    frame: int
    target_id: int
    x: float
    y: float
    cause: Cause
    detail: str = ""
    significance: float = math.nan
    residual: float = math.nan
    change: float = math.nan
    threshold: float = math.nan
    det_dist: float = math.nan
    track_id: int | None = None
    test: str = ""
    statistic: float = math.nan
    level: float = math.nan
    pred_dist: float = math.nan
    pred_gate: float = math.nan


@dataclass(frozen=True)
class FalseExplanation:
    """One confirmed track point of one frame that matches no truth: its ``cause`` and ``detail``."""

    frame: int
    track_id: int
    x: float
    y: float
    cause: FalseCause
    detail: str = ""


@dataclass(frozen=True)
class FrameExplanation:
    """One frame's explanation: every truth point's (visible and hidden) and every false
    confirmed track point's."""

    frame: int
    truth: tuple[TruthExplanation, ...]
    false: tuple[FalseExplanation, ...]
