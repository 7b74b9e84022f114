"""The runs ``wfviz compare`` puts side by side: parsed from ``--run`` specs or taken from a
``wfviz tune`` study, each a tracker with its configuration and a label; trackers whose
stages before detection are the same share one front end (:class:`SharedPrepare`)."""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from wfviz.config import config_to_toml, load_config
from wfviz.io.clip import check_frame_size
from wfviz.io.frames import Frame
from wfviz.stages.front_end import FrontEnd, PreparedFrame, Preparer
from wfviz.stages.imaging_circle import ImagingCircle
from wfviz.trackers import TRACKERS, config_class

LABEL = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]*")


@dataclass(frozen=True)
class RunSpec:
    """One run: its label (the entity root ``runs/<label>``), tracker, configuration and
    where the configuration came from (a file, a study's trial, or the defaults)."""

    label: str
    tracker: str
    config: Any
    source: str

    @property
    def config_text(self) -> str:
        return config_to_toml(self.config)


def parse_run(spec: str) -> RunSpec:
    """``NAME``, ``NAME:CONFIG.toml`` or ``LABEL=NAME:CONFIG.toml`` (``LABEL=NAME`` too).
    The label defaults to the tracker's name, or to ``NAME-<config stem>``."""
    label, sep, rest = spec.partition("=")
    if not sep:
        label, rest = "", spec
    name, sep, config = rest.partition(":")
    if not name:
        raise ValueError(f"--run '{spec}': expected NAME, NAME:CONFIG.toml or LABEL=NAME:CONFIG.toml")
    if name not in TRACKERS:
        raise ValueError(f"--run '{spec}': unknown tracker '{name}' (available: {', '.join(TRACKERS)})")
    if sep and not config:
        raise ValueError(f"--run '{spec}': no config file after ':'")
    path = Path(config) if config else None
    if path is not None and not path.is_file():
        raise ValueError(f"--run '{spec}': {path}: no such config file")
    label = label or (f"{name}-{path.stem}" if path is not None else name)
    if not LABEL.fullmatch(label):
        raise ValueError(f"--run '{spec}': label '{label}' must be letters, digits, '_', '-' or '.'")
    return RunSpec(label, name, load_config(path, config_class(name)), str(path) if path else "defaults")


def study_runs(folder: Path, top: int) -> list[RunSpec]:
    """The ``top`` best trials of the ``wfviz tune`` study in ``folder`` (labels ``trial-N``,
    ranked as its report ranks them) and the tracker's defaults (``defaults``)."""
    from wfviz.config import ConfigError, config_from_dict
    from wfviz.tune.outputs import ranked
    from wfviz.tune.space import make_config
    from wfviz.tune.study import JOURNAL, load_journal

    journal = folder / JOURNAL
    if not journal.is_file():
        raise ValueError(f"--study {folder}: no {JOURNAL} (not a wfviz tune study folder)")
    study = load_journal(journal)
    try:
        settings = study.user_attrs.get("settings") or {}
        tracker = settings.get("tracker")
        if tracker not in TRACKERS:
            raise ValueError(f"{journal}: the study's tracker '{tracker}' is not available")
        cls = config_class(tracker)
        base = config_from_dict(settings["base"], cls)
        trials = [t for t in study.get_trials(deepcopy=False) if t.state.name == "COMPLETE"]
        best = ranked(trials, settings.get("objective", "mota"))[:top]
        runs = [RunSpec(f"trial-{t.number}", tracker, make_config(cls, dict(t.params), settings.get("fixed"), base),
                        f"{folder} trial {t.number}") for t in best]
    except (KeyError, TypeError, AttributeError, ConfigError) as exc:  # a journal edited by hand
        raise ValueError(f"{journal}: not a study wfviz can read ({type(exc).__name__}: {exc})") from None
    if not best:
        raise ValueError(f"--study {folder}: no finished trial yet")
    return runs + [RunSpec("defaults", tracker, cls(), "defaults")]


def check_labels(runs: list[RunSpec]) -> None:
    """At least two runs, every label once."""
    if len(runs) < 2:
        raise ValueError("compare: give at least two runs (--run SPEC --run SPEC, or --study DIR)")
    seen: set[str] = set()
    for r in runs:
        if r.label in seen:
            raise ValueError(f"--run: label '{r.label}' given twice (name runs with LABEL=NAME:CONFIG.toml)")
        seen.add(r.label)


class SharedPrepare:
    """One preparation per frame (:class:`~wfviz.stages.front_end.Preparer`) for every tracker
    of a group: the first tracker to ask for a frame computes it (its ``lap`` times the
    stages), the others get the same :class:`PreparedFrame`. ``cost_ms`` is what the frame's
    preparation cost and ``payer`` the tracker's source that paid it."""

    def __init__(self, config: Any) -> None:
        self.stages = Preparer(config)
        self._raw: np.ndarray | None = None
        self._prepared: PreparedFrame | None = None
        self.cost_ms = 0.0
        self.payer: object | None = None

    def get(self, asker: object, raw: np.ndarray, lap: Callable[[str], None], whole: bool,
            update_horizon: bool) -> PreparedFrame:
        if raw is not self._raw or self._prepared is None:
            t0 = time.perf_counter()
            self._prepared = self.stages.prepare(raw, lap, whole, update_horizon)
            self.cost_ms = (time.perf_counter() - t0) * 1e3
            self._raw, self.payer = raw, asker
        return self._prepared


class SharedSource:
    """One tracker's :class:`~wfviz.stages.front_end.PreparedSource` in a group: its prepared
    frames come from the group's :class:`SharedPrepare`."""

    def __init__(self, shared: SharedPrepare) -> None:
        self.shared = shared

    @property
    def circle(self) -> ImagingCircle | None:
        """The group's imaging circle."""
        return self.shared.stages.circle

    def prepare(self, raw: np.ndarray, lap: Callable[[str], None], whole: bool = True,
                update_horizon: bool = True) -> PreparedFrame:
        """This frame prepared once for the group."""
        return self.shared.get(self, raw, lap, whole, update_horizon)

    def shared_ms(self) -> float:
        """This frame's preparation cost when another tracker paid it (else 0)."""
        return self.shared.cost_ms if self.shared.payer is not self else 0.0


class RunGroup:
    """The trackers of a comparison as one stepper of the drive loop (:class:`wfviz.run.Stepper`):
    every tracker steps on a frame, in run order, each timed as it would cost alone (its own
    time plus the shared front end's when another run paid it). (Stepping the front-end groups
    in threads gained nothing on 2 cores: the frame reader and Rerun's writer threads already
    use the second core; docs/performance.md.)"""

    def __init__(self, trackers: list[Any]) -> None:
        self.trackers = trackers

    def min_frame_side(self) -> int:
        return max(t.min_frame_side() for t in self.trackers)

    def advance(self, frame: Frame) -> tuple[tuple[Any, ...], tuple[float, ...]]:
        results, ms = [], []
        for trk in self.trackers:
            t0 = time.perf_counter()
            results.append(trk.step(frame))
            own = (time.perf_counter() - t0) * 1e3
            source = getattr(getattr(trk, "front", None), "source", None)
            ms.append(own + (source.shared_ms() if isinstance(source, SharedSource) else 0.0))
        return tuple(results), tuple(ms)


def make_trackers(runs: list[RunSpec]) -> tuple[list[Any], list[int]]:
    """A tracker per run, and per run its front-end group: the index of the group's first run
    (runs of one group share one :class:`SharedPrepare`; a run that cannot share is a group of
    its own)."""
    from wfviz.tune.cache import cacheable

    groups: dict[tuple, tuple[int, SharedPrepare]] = {}
    trackers, group_of = [], []
    for i, r in enumerate(runs):
        cls = TRACKERS[r.tracker].tracker
        if cacheable(r.tracker, r.config):
            key = (r.tracker, FrontEnd.prepare_key(r.config))
            g, shared = groups.setdefault(key, (i, SharedPrepare(r.config)))
            trackers.append(cls(r.config, source=SharedSource(shared)))
        else:
            g = i  # a group of its own
            trackers.append(cls(r.config))
        group_of.append(g)
    return trackers, group_of


def check_fit(shape: tuple[int, int], source: str, runs: list[RunSpec]) -> None:
    """Refuse (one line, naming ``source`` and the smallest side needed) frames of ``shape``
    that a run's configured windows do not fit in; nothing is written, so the command can check
    this before it touches an output folder."""
    for r in runs:  # the first run whose windows do not fit names its minimum
        check_frame_size(shape, source, TRACKERS[r.tracker].tracker(r.config).min_frame_side())
