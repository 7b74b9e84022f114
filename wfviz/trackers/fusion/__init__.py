"""The feature-fusion Kalman tracker (Zheng Jia, Li Jiangyong and Chen Gang): the shared front end
(:mod:`wfviz.stages`), the features and fused cost (:mod:`.features`) and the tracker (:mod:`.tracker`)."""

from wfviz.trackers.fusion.config import FusionConfig
from wfviz.trackers.fusion.features import Features, fused_cost, min_area_rect, scalar_phi
from wfviz.trackers.fusion.tracker import FusionResult, FusionTracker

__all__ = ["Features", "FusionConfig", "FusionResult", "FusionTracker", "fused_cost", "min_area_rect", "scalar_phi"]
