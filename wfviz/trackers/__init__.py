"""Selectable trackers. Each is one module; its Rerun adapter lives in ``wfviz.record``."""

from __future__ import annotations

from wfviz.config import GEWCConfig
from wfviz.trackers.base import FrameResult, Tracker
from wfviz.trackers.gewc import GEWCTracker

TRACKERS = {"gewc": GEWCTracker}


def make_tracker(name: str, config: GEWCConfig | None = None) -> Tracker:
    """Instantiate tracker ``name`` with its config (defaults when None)."""
    try:
        cls = TRACKERS[name]
    except KeyError:
        raise ValueError(f"unknown tracker '{name}' (available: {', '.join(TRACKERS)})") from None
    return cls(config)


__all__ = ["TRACKERS", "FrameResult", "GEWCTracker", "Tracker", "make_tracker"]
