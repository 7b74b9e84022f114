"""Why a run did what it did: a cause for every truth point and every false track point
(``--explain``), decided from what the stages and the track rules report. Pure: never imports
rerun."""

from wfviz.explain.types import MISSES, Cause, FalseCause, FalseExplanation, FrameExplanation, TruthExplanation

__all__ = ["MISSES", "Cause", "FalseCause", "FalseExplanation", "FrameExplanation", "TruthExplanation"]
