"""The GEWC wide-field tracker (Wang Xiaoyu et al.): the shared front end (:mod:`wfviz.stages`),
GEWC centroids in each prediction window and the track manager (:mod:`wfviz.tracking`)."""

from wfviz.trackers.gewc.config import CentroidConfig, GEWCConfig
from wfviz.trackers.gewc.tracker import GEWCResult, GEWCTracker

__all__ = ["CentroidConfig", "GEWCConfig", "GEWCResult", "GEWCTracker"]
