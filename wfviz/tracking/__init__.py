"""Track management shared by the trackers: the constant-velocity Kalman filter (:mod:`.kalman`),
the sequential confirmation and deletion tests (:mod:`.confirmation`) and the track manager
(:mod:`.manager`) with its track state, predictions and lifecycle events."""

from wfviz.tracking.manager import (CONFIRMATION_RULES, Association, EventKind, Evidence, HitsRule, Measurements,
                                    Prediction, SequentialRule, TrackEvent, TrackManager, TrackState,
                                    assign_confirmed_first, extrapolate)

__all__ = ["CONFIRMATION_RULES", "Association", "EventKind", "Evidence", "HitsRule", "Measurements", "Prediction",
           "SequentialRule", "TrackEvent", "TrackManager", "TrackState", "assign_confirmed_first", "extrapolate"]
