"""``wfviz tune``'s front-end cache: a clip's frames through the stages before detection
(:meth:`wfviz.stages.front_end.FrontEnd.prepare`), computed once per worker process and
replayed in every trial whose configuration prepares them the same
(:meth:`~wfviz.stages.front_end.FrontEnd.prepare_key`). A replayed trial runs the very same
detection and tracking code on the very same arrays, so its tracks are those of a full run
(the tests check it); only the decoding and the stages before detection are skipped.

Only trackers whose front end does not depend on the tracks take it: GEWC in "cfar" mode
(fusion searches windows that follow its tracks, and the noise statistics follow the windows)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from wfviz.io.frames import Frame
from wfviz.stages.front_end import FrontEnd, PreparedFrame, Preparer
from wfviz.stages.imaging_circle import ImagingCircle
from wfviz.synth.clip import MemoryClip

CACHE_MB = 3072  # per worker process; clips that no longer fit are prepared afresh each trial

_CACHE: dict[tuple, tuple[list[Frame], list[PreparedFrame], int]] = {}
STATS = {"hits": 0, "misses": 0}


def _noop(_stage: str) -> None:
    pass


class Replay:
    """A :class:`~wfviz.stages.front_end.PreparedSource` that hands out prepared frames in
    order (the raw frame it is given is not looked at): a tracker's front end given it runs
    only the detection (:meth:`~wfviz.stages.front_end.FrontEnd.finish`)."""

    def __init__(self, frames: list[PreparedFrame]) -> None:
        self._frames, self._next = frames, 0

    @property
    def circle(self) -> ImagingCircle | None:
        """The imaging circle of the last frame handed out."""
        return self._frames[self._next - 1].circle if self._next else None

    def prepare(self, raw: Any, lap: Callable[[str], None], whole: bool = True,
                update_horizon: bool = True) -> PreparedFrame:
        """The next prepared frame."""
        p = self._frames[self._next]
        self._next += 1
        return p


def cacheable(tracker: str, config: Any) -> bool:
    """Whether trials of ``tracker`` with ``config`` can replay a prepared clip: the tracker
    takes a front end and searches whole frames, and the front end is independent of the
    tracks with ``config``."""
    from wfviz.trackers import TRACKERS

    cls = TRACKERS[tracker].tracker
    return getattr(cls, "searches_whole_frames", False) and FrontEnd.independent_of_tracks(config)


def _nbytes(frames: list[PreparedFrame]) -> int:
    seen: set[int] = set()
    total = 0
    for p in frames:
        for v in (p.image, p.raw, p.mask, p.valid, p.region, p.suppressed, p.change,
                  None if p.noise is None else p.noise.level, None if p.noise is None else p.noise.sigma):
            if v is not None and id(v) not in seen:
                seen.add(id(v))
                total += v.nbytes
    return total


def replay(spec: str, stop: int | None, config: Any) -> tuple[MemoryClip, Replay]:
    """The clip ``spec`` (frames before ``stop``) and a source of its frames prepared for
    ``config`` (a tracker's ``source``), prepared now or taken from the cache."""
    from wfviz.io.clip import open_clip

    key = (spec, stop, FrontEnd.prepare_key(config))
    hit = _CACHE.get(key)
    clip = open_clip(spec)
    if hit is None:
        STATS["misses"] += 1
        stages = Preparer(config)
        frames, prepared = [], []
        for f in clip.frames(0, stop):
            frames.append(f)
            prepared.append(stages.prepare(f.image, _noop))
        hit = (frames, prepared, _nbytes(prepared))
        # a study visits its clips in the same order every trial: dropping the oldest to make
        # room would drop each clip just before it is needed again, so what is cached stays
        if sum(v[2] for v in _CACHE.values()) + hit[2] <= CACHE_MB * 2**20:
            _CACHE[key] = hit
    else:
        STATS["hits"] += 1
    frames, prepared, _ = hit
    return MemoryClip(clip.name, frames, clip.fps), Replay(prepared)
