"""Where static clutter lives: a map of the scene (camera motion removed) that counts how often
detections no track explains appear there and persist (not in the GEWC paper).

Spatial clutter maps are standard in radar tracking (D. Musicki, S. Suvorova, M. Morelande and
B. Moran, "Clutter map and target tracking", FUSION 2005; T. L. Song and D. Musicki, "Adaptive
clutter measurement density estimation for improved target tracking", IEEE TAES 47(2), 2011).
Here the map answers one question for the sequential confirmation test
(:class:`wfviz.tracking.rules.SequentialRule`): how likely is a persistent point at this place
to be a fixed object of the scene rather than a target? On a clear sky nothing but noise
appears, and noise does not persist; on textured ground, spots of the terrain keep appearing at
the same places.

Per scene cell of ``cell`` px the map keeps, with exponential forgetting over ``memory``
frames, the number of *persistent unexplained* detections ``K`` (below) and the number of
frames the cell was searched ``E``. The rate of such detections per frame about a point
(:func:`static_rate`) is the posterior mean over its 3 × 3 cells, ``9 (ΣK + k0) / (ΣE + e0)``,
of a Gamma prior of mean 1 a frame per cell (a cell never watched is taken for clutter) and
weight ``e0`` frames; cells never searched (below the horizon) weigh nothing.

A detection is *persistent* (:meth:`ClutterMap.persistent`) when one of the previous frame lay
within 1.5 px of the same scene point (noise rarely strikes one place twice), and as *unexplained*
when it lies in no confirmed track's gate; those in a tentative track's gate are counted for it
too, and the rule takes them out again for that track
(:attr:`~wfviz.tracking.rules.SequentialStats.own_static`), so a hovering target and its other
parts do not teach the map that its own place is clutter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wfviz.tracking.confirmation import box3

PERSIST_RADIUS = 1.5  # px: a detection this close to one of the previous frame (in the scene) persists
PRIOR_FRAMES = 0.05  # e0: weight of the prior rate (1 a frame), in frames of observation


class ClutterMap:
    """Rates of persistent unexplained detections per scene cell (see the module docstring)."""

    def __init__(self, cell: int = 16, memory: float = 200.0) -> None:
        self.cell, self.memory = int(cell), float(memory)
        self.counts: np.ndarray | None = None    # K per cell
        self.exposure: np.ndarray | None = None  # E per cell
        self.origin = np.zeros(2, dtype=np.int64)  # scene cell (col, row) of counts[0, 0]
        self._sums: tuple[np.ndarray, np.ndarray] | None = None  # 3 x 3 sums of counts, exposures
        self._last_scene: np.ndarray | None = None  # the previous frame's detections, in the scene

    # -- grid ---------------------------------------------------------------------------
    def _cover(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Grow the grid (keeping its contents) so that scene cells ``lo``..``hi`` (col, row)
        inclusive, with one cell of margin, lie inside it."""
        lo, hi = lo - 1, hi + 1
        if self.counts is None:
            shape = (int(hi[1] - lo[1] + 1), int(hi[0] - lo[0] + 1))
            self.counts, self.exposure = np.zeros(shape), np.zeros(shape)
            self.origin = lo.astype(np.int64)
            return
        assert self.exposure is not None
        end = self.origin + np.array(self.counts.shape[::-1]) - 1
        if (lo >= self.origin).all() and (hi <= end).all():
            return
        new_lo, new_hi = np.minimum(lo, self.origin), np.maximum(hi, end)
        shape = (int(new_hi[1] - new_lo[1] + 1), int(new_hi[0] - new_lo[0] + 1))
        r0, c0 = int(self.origin[1] - new_lo[1]), int(self.origin[0] - new_lo[0])
        h, w = self.counts.shape
        for name in ("counts", "exposure"):
            grown = np.zeros(shape)
            grown[r0:r0 + h, c0:c0 + w] = getattr(self, name)
            setattr(self, name, grown)
        self.origin = new_lo.astype(np.int64)

    def _cells(self, xy: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Scene cell (col, row) of image points ``xy`` (N, 2) under camera ``offset``."""
        return np.floor((np.asarray(xy, dtype=np.float64).reshape(-1, 2) - offset) / self.cell).astype(np.int64)

    # -- persistence ----------------------------------------------------------------------
    def persistent(self, xy: np.ndarray, offset: np.ndarray | tuple[float, float]) -> np.ndarray:
        """Detections ``xy`` (N, 2) with one of the previous frame within ``PERSIST_RADIUS`` px of
        the same scene point (camera ``offset`` removed): noise rarely strikes one place twice, a
        fixed object of the scene does; then remembers this frame's."""
        scene = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - np.asarray(offset, dtype=np.float64)
        last, self._last_scene = self._last_scene, scene
        if not len(scene) or last is None or not len(last):
            return np.zeros(len(scene), dtype=bool)
        d2 = ((scene[:, None, :] - last[None, :, :]) ** 2).sum(axis=2)  # N x M: N, M <= max_detections
        return (d2 < PERSIST_RADIUS ** 2).any(axis=1)

    def forget_last(self) -> None:
        """The camera's motion is lost this frame: the next frame's detections cannot be compared
        with any earlier ones."""
        self._last_scene = None

    # -- update and query -----------------------------------------------------------------
    def update(self, xy: np.ndarray, searched: np.ndarray, offset: np.ndarray | tuple[float, float]) -> None:
        """Add this frame: ``xy`` (N, 2) its persistent unexplained detections, ``searched`` the
        pixels detection looked at (bool image), ``offset`` the camera's (scene point s at
        s + offset in the image)."""
        off = np.asarray(offset, dtype=np.float64)
        h, w = searched.shape[:2]
        c = self.cell
        lo = np.floor((np.array([0.0, 0.0]) - off) / c).astype(np.int64)
        hi = np.floor((np.array([w - 1.0, h - 1.0]) - off) / c).astype(np.int64)
        self._cover(lo, hi)
        assert self.counts is not None and self.exposure is not None
        keep = 1.0 - 1.0 / self.memory
        self.counts *= keep
        self.exposure *= keep
        # a cell was searched when the image pixel at its centre was
        cols = np.arange(lo[0], hi[0] + 1)
        rows = np.arange(lo[1], hi[1] + 1)
        px = np.rint((cols + 0.5) * c + off[0]).astype(np.int64)
        py = np.rint((rows + 0.5) * c + off[1]).astype(np.int64)
        inside_x, inside_y = (px >= 0) & (px < w), (py >= 0) & (py < h)
        seen = np.zeros((len(rows), len(cols)))
        seen[np.ix_(inside_y, inside_x)] = searched[np.ix_(py[inside_y], px[inside_x])]
        r0, c0 = int(lo[1] - self.origin[1]), int(lo[0] - self.origin[0])
        self.exposure[r0:r0 + len(rows), c0:c0 + len(cols)] += seen
        if len(xy):
            cell = self._cells(xy, off) - self.origin
            ok = ((cell >= 0) & (cell < np.array(self.counts.shape[::-1]))).all(axis=1)
            np.add.at(self.counts, (cell[ok, 1], cell[ok, 0]), 1.0)
        self._sums = (box3(self.counts), box3(self.exposure))

    def at(self, xy: np.ndarray, offset: np.ndarray | tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """The counts and the exposures summed over the 3 × 3 cells about each image point
        ``xy`` (N, 2) (0 where the map has not been): :func:`static_rate`'s arguments."""
        return self.snapshot().at(xy, offset)

    def snapshot(self) -> ClutterView:
        """The map as it is now (its 3 × 3 sums, shared, not copied: :meth:`update` makes new ones)."""
        return ClutterView(self._sums, self.origin.copy(), self.cell)


@dataclass(frozen=True)
class ClutterView:
    """A :class:`ClutterMap` at one frame: the 3 × 3 sums of its counts and exposures (None:
    empty), the scene cell of their [0, 0] and the cell size (px)."""

    sums: tuple[np.ndarray, np.ndarray] | None
    origin: np.ndarray
    cell: int

    def at(self, xy: np.ndarray, offset: np.ndarray | tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """See :meth:`ClutterMap.at`."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        k, e = np.zeros(len(xy)), np.zeros(len(xy))
        if self.sums is None or not len(xy):
            return k, e
        off = np.asarray(offset, dtype=np.float64)
        cell = np.floor((xy - off) / self.cell).astype(np.int64) - self.origin
        ok = ((cell >= 0) & (cell < np.array(self.sums[0].shape[::-1]))).all(axis=1)
        k[ok] = self.sums[0][cell[ok, 1], cell[ok, 0]]
        e[ok] = self.sums[1][cell[ok, 1], cell[ok, 0]]
        return k, e

    def prior(self, shape: tuple[int, int], offset: np.ndarray | tuple[float, float]) -> np.ndarray:
        """The static-clutter prior ``1 - exp(-r)`` (:func:`static_rate`) of the cells in view, one
        value per ``cell`` × ``cell`` block of an image of ``shape`` (its rows and columns divided
        by ``cell``, rounded up), for the recording."""
        h, w = shape[:2]
        c = self.cell
        ys = (np.arange(-(-h // c)) + 0.5) * c
        xs = (np.arange(-(-w // c)) + 0.5) * c
        gx, gy = np.meshgrid(xs, ys)
        k, e = self.at(np.column_stack([gx.ravel(), gy.ravel()]), offset)
        return -np.expm1(-static_rate(k, e)).reshape(gy.shape)


def static_rate(count: np.ndarray, exposure: np.ndarray) -> np.ndarray:
    """Persistent unexplained detections per frame in a 3 × 3-cell neighbourhood, from its summed
    ``count`` and ``exposure`` (:meth:`ClutterMap.at`): ``9 (K + k0) / (E + e0)``, the posterior mean of the rate per cell (Gamma
    prior of mean 1 a frame, weight ``e0 =`` :data:`PRIOR_FRAMES` frames) over the neighbourhood's
    searched cells, times its 9 cells. Cells never searched (below the horizon) weigh nothing."""
    k = np.asarray(count, dtype=np.float64)
    return 9.0 * (k + PRIOR_FRAMES) / (np.asarray(exposure, dtype=np.float64) + PRIOR_FRAMES)
