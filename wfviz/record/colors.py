"""Colours of the recording's overlays that several modules share."""

from __future__ import annotations

import colorsys
import functools


@functools.lru_cache(maxsize=8192)
def track_color(track_id: int) -> tuple[int, int, int]:
    """A stable, well-separated colour for a track id (golden-ratio hue steps)."""
    h = (track_id * 0.618033988749895) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, 0.85, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)
