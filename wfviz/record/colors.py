"""Colours of the recording's overlays that several modules share."""

from __future__ import annotations

import colorsys
import functools
from collections.abc import Iterable

#: a track's colour: golden-ratio hue steps (saturation, value); a truth target's colour has
#: the same; the colour of a track matching no target in ``wfviz compare`` a pale one, far from both
TRACK_SV = (0.85, 1.0)
UNMATCHED_SV = (0.3, 0.75)


def _hue_color(n: int, sv: tuple[float, float], turn: float = 0.0) -> tuple[int, int, int]:
    r, g, b = colorsys.hsv_to_rgb((n * 0.618033988749895 + turn) % 1.0, *sv)
    return int(r * 255), int(g * 255), int(b * 255)


@functools.lru_cache(maxsize=8192)
def track_color(track_id: int) -> tuple[int, int, int]:
    """A stable, well-separated colour for a track id (golden-ratio hue steps)."""
    return _hue_color(track_id, TRACK_SV)


def target_color(target_id: int) -> tuple[int, int, int]:
    """A truth target's colour: golden-ratio hue steps from target to target (the first few
    targets far apart), half a turn from the track of the same number."""
    return _hue_color(target_id, TRACK_SV, 0.5)


@functools.lru_cache(maxsize=8192)
def unmatched_color(track_id: int) -> tuple[int, int, int]:
    """The colour of a track that has matched no truth target (``wfviz compare`` with truth):
    the track's hue, pale and darker, so that it is never taken for a target's colour."""
    return _hue_color(track_id, UNMATCHED_SV)


class TargetPalette:
    """One run's track colours by the truth target they match, so that a target keeps one
    colour in every run: a track has the colour of the target it matched last
    (:func:`target_color`), a track that has matched none its pale own (:func:`unmatched_color`)."""

    def __init__(self) -> None:
        self.target_of: dict[int, int] = {}  # track id -> the target it matched last

    def update(self, matches: Iterable[tuple[int, int]]) -> None:
        """This frame's (track id, target id) matches."""
        self.target_of.update(matches)

    def color(self, track_id: int) -> tuple[int, int, int]:
        """The track's colour (see the class docstring)."""
        target = self.target_of.get(track_id)
        return unmatched_color(track_id) if target is None else target_color(target)
