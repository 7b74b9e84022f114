"""Selectable trackers. Each is one module plus its config class; its Rerun adapter lives in
``wfviz.record``. Register a new tracker in ``TRACKERS`` (and its recorder in ``RECORDERS``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from wfviz.config import FusionConfig, GEWCConfig, StarfieldConfig, TBDConfig, load_config
from wfviz.trackers.base import FrameResult, Tracker
from wfviz.trackers.fusion import FusionTracker
from wfviz.trackers.gewc import GEWCTracker
from wfviz.trackers.starfield import StarfieldTracker
from wfviz.trackers.tbd import TBDTracker

# name -> (tracker class, config class)
TRACKERS: dict[str, tuple[type, type]] = {"gewc": (GEWCTracker, GEWCConfig),
                                          "fusion": (FusionTracker, FusionConfig),
                                          "starfield": (StarfieldTracker, StarfieldConfig),
                                          "tbd": (TBDTracker, TBDConfig)}


def _entry(name: str) -> tuple[type, type]:
    try:
        return TRACKERS[name]
    except KeyError:
        raise ValueError(f"unknown tracker '{name}' (available: {', '.join(TRACKERS)})") from None


def config_class(name: str) -> type:
    """The config dataclass of tracker ``name``."""
    return _entry(name)[1]


def make_tracker(name: str, config: Any | None = None) -> Tracker:
    """Instantiate tracker ``name`` with its config (defaults when None)."""
    cls, cfg_cls = _entry(name)
    return cls(config if config is not None else cfg_cls())


def load_tracker(name: str, config_file: str | Path | None) -> Tracker:
    """Tracker ``name`` configured from a TOML file (defaults when None)."""
    return make_tracker(name, load_config(config_file, config_class(name)))


__all__ = ["TRACKERS", "FrameResult", "FusionTracker", "GEWCTracker", "StarfieldTracker", "TBDTracker", "Tracker", "config_class",
           "load_tracker",
           "make_tracker"]
