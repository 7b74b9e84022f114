"""Selectable trackers. Each is one module plus its config class; its Rerun adapter lives in
``wfviz.record`` (the only package that imports rerun). A new tracker is one line in
``TRACKERS``: its tracker class, config class and recorder (named, imported only to record)."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:  # imported on use: `wfviz --help` and a tracker's start need none of the others
    from wfviz.trackers.base import FrameResult, Tracker


class TrackerEntry(NamedTuple):
    """One registered tracker: its class, its config class, its recorder adapter
    (``module:Class`` under ``wfviz.record``) and ``wfviz tune``'s default search space (the
    TOML form of :mod:`wfviz.tune.space`; None: the tracker has none)."""

    tracker: type
    config: type
    recorder: str
    space: dict | None = None


def _load(package: str, tracker: str, config: str, recorder: str) -> TrackerEntry:
    """The entry of the tracker in ``wfviz.trackers.<package>`` (imported now)."""
    mod = importlib.import_module(f"wfviz.trackers.{package}")
    conf = importlib.import_module(f"wfviz.trackers.{package}.config")
    return TrackerEntry(getattr(mod, tracker), getattr(conf, config), recorder, getattr(conf, "SEARCH_SPACE", None))


class _Registry(dict):
    """Tracker name -> :class:`TrackerEntry`. A value may be a zero-argument loader, called (and
    replaced by its entry) the first time the name is looked up, so listing the names imports no
    tracker (``wfviz --help`` starts without numpy, OpenCV or SciPy)."""

    def __getitem__(self, name: str) -> TrackerEntry:
        value = super().__getitem__(name)
        if callable(value) and not isinstance(value, tuple):
            value = value()
            super().__setitem__(name, value)
        return value

    def get(self, name: str, default: Any = None) -> Any:
        return self[name] if name in self else default

    def values(self) -> Any:  # type: ignore[override]
        return [self[k] for k in self]

    def items(self) -> Any:  # type: ignore[override]
        return [(k, self[k]) for k in self]


TRACKERS: dict[str, TrackerEntry] = _Registry({
    "gewc": lambda: _load("gewc", "GEWCTracker", "GEWCConfig", "wfviz.record.gewc:GEWCRecorder"),
    "fusion": lambda: _load("fusion", "FusionTracker", "FusionConfig", "wfviz.record.fusion:FusionRecorder"),
    "starfield": lambda: _load("starfield", "StarfieldTracker", "StarfieldConfig",
                               "wfviz.record.starfield:StarfieldRecorder"),
    "tbd": lambda: _load("tbd", "TBDTracker", "TBDConfig", "wfviz.record.tbd:TBDRecorder"),
})

_CLASSES = {"GEWCTracker": "gewc", "FusionTracker": "fusion", "StarfieldTracker": "starfield", "TBDTracker": "tbd"}


def __getattr__(name: str) -> Any:
    """The tracker classes and ``FrameResult``/``Tracker``, imported on first use."""
    if name in _CLASSES:
        return TRACKERS[_CLASSES[name]].tracker
    if name in ("FrameResult", "Tracker"):
        return getattr(importlib.import_module("wfviz.trackers.base"), name)
    raise AttributeError(f"module 'wfviz.trackers' has no attribute '{name}'")


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
    from wfviz.config import load_config

    return make_tracker(name, load_config(config_file, config_class(name)))


__all__ = ["TRACKERS", "TrackerEntry", "FrameResult", "FusionTracker", "GEWCTracker", "StarfieldTracker", "TBDTracker", "Tracker", "config_class", "default_space",
           "load_tracker",
           "make_tracker"]
