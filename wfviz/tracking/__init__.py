"""Track management shared by the trackers, as small parts: the constant-velocity Kalman filter
(:mod:`.kalman`), the track types and lifecycle events (:mod:`.tracks`), association
(:mod:`.association`), the confirmation rules (:mod:`.rules`) with their sequential tests
(:mod:`.confirmation`), and the track manager (:mod:`.manager`) that runs them per frame."""

from wfviz.tracking.association import Association, Measurements, assign_confirmed_first, gate_boxes
from wfviz.tracking.manager import TrackManager, extrapolate
from wfviz.tracking.rules import CONFIRMATION_RULES, Evidence, HitsRule, SequentialRule
from wfviz.tracking.tracks import EventKind, Prediction, TrackEvent, TrackState

__all__ = ["CONFIRMATION_RULES", "Association", "EventKind", "Evidence", "HitsRule", "Measurements", "Prediction",
           "SequentialRule", "TrackEvent", "TrackManager", "TrackState", "assign_confirmed_first", "extrapolate",
           "gate_boxes"]
