"""Selectable trackers. Each is one module plus its config class; its Rerun adapter lives in
``wfviz.record`` (the only package that imports rerun). A new tracker is one line in
``TRACKERS``: its tracker class, config class and recorder (named, imported only to record)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

from wfviz.config import load_config
from wfviz.trackers.base import FrameResult, Tracker
from wfviz.trackers.fusion import FusionTracker
from wfviz.trackers.fusion.config import SEARCH_SPACE as FUSION_SPACE, FusionConfig
from wfviz.trackers.gewc import GEWCTracker
from wfviz.trackers.gewc.config import SEARCH_SPACE as GEWC_SPACE, GEWCConfig
from wfviz.trackers.starfield import StarfieldTracker
from wfviz.trackers.starfield.config import SEARCH_SPACE as STARFIELD_SPACE, StarfieldConfig
from wfviz.trackers.tbd import TBDTracker
from wfviz.trackers.tbd.config import SEARCH_SPACE as TBD_SPACE, TBDConfig

class TrackerEntry(NamedTuple):
    """One registered tracker: its class, its config class, its recorder adapter
    (``module:Class`` under ``wfviz.record``) and ``wfviz tune``'s default search space (the
    TOML form of :mod:`wfviz.tune.space`; None: the tracker has none)."""

    tracker: type
    config: type
    recorder: str
    space: dict | None = None


TRACKERS: dict[str, TrackerEntry] = {
    "gewc": TrackerEntry(GEWCTracker, GEWCConfig, "wfviz.record.gewc:GEWCRecorder", GEWC_SPACE),
    "fusion": TrackerEntry(FusionTracker, FusionConfig, "wfviz.record.fusion:FusionRecorder", FUSION_SPACE),
    "starfield": TrackerEntry(StarfieldTracker, StarfieldConfig, "wfviz.record.starfield:StarfieldRecorder", STARFIELD_SPACE),
    "tbd": TrackerEntry(TBDTracker, TBDConfig, "wfviz.record.tbd:TBDRecorder", TBD_SPACE),
}


def _entry(name: str) -> TrackerEntry:
    try:
        return TRACKERS[name]
    except KeyError:
        raise ValueError(f"unknown tracker '{name}' (available: {', '.join(TRACKERS)})") from None


def config_class(name: str) -> type:
    """The config dataclass of tracker ``name``."""
    return _entry(name).config


def default_space(name: str) -> dict | None:
    """``wfviz tune``'s default search space of tracker ``name`` (TOML form; None: none)."""
    return _entry(name).space


def make_tracker(name: str, config: Any | None = None) -> Tracker:
    """Instantiate tracker ``name`` with its config (defaults when None)."""
    e = _entry(name)
    return e.tracker(config if config is not None else e.config())


def load_tracker(name: str, config_file: str | Path | None) -> Tracker:
    """Tracker ``name`` configured from a TOML file (defaults when None)."""
    return make_tracker(name, load_config(config_file, config_class(name)))


__all__ = ["TRACKERS", "TrackerEntry", "FrameResult", "FusionTracker", "GEWCTracker", "StarfieldTracker", "TBDTracker", "Tracker", "config_class", "default_space",
           "load_tracker",
           "make_tracker"]
