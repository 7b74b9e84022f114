"""Evidence gathered over frames before anything is thresholded: dynamic-programming
track-before-detect on the change significance (not in the GEWC paper).

A dim target's single-frame significance hovers about the threshold: it is detected on some
frames and the track dies between them. Integrating along its path first gains up to √K over K
frames for a mover and nothing for noise. Dynamic programming does it for every path at once
(Y. Barniv, "Dynamic programming solution for detecting dim moving targets", IEEE TAES 21(1),
1985; S. M. Tonissen and R. J. Evans, "Performance of dynamic programming techniques for
track-before-detect", IEEE TAES 32(4), 1996): each pixel's score is its own value plus the
best score among the pixels it could have come from on the previous frame,

    A_t(p) = c_t(p) + λ · max_{|q − p|∞ ≤ 1} A_{t−1}(q − s_t),

with ``s_t`` the camera's shift (the past is registered to this frame), so a path may move up
to 1 px a frame along each axis in the scene and bend anywhere; λ forgets the past (an
effective memory of 1 / (1 − λ) frames). The input ``c`` is the change significance (what is
new at its place in the scene, :class:`wfviz.stages.background.TemporalBackground`), clipped
to ±``clip``: static structure has no change and gains nothing, and a bright target, already
detected on its own, cannot lend its score to every path that crosses its trail. The score's
null distribution (the max over neighbours makes noise drift upward) is not Gaussian; the caller
standardises it like any other significance (local level and σ, tail calibration), so that
its threshold is a false-alarm rate like the single frame's.
"""

from __future__ import annotations

import cv2
import numpy as np

_NEIGHBOURS = np.ones((3, 3), np.uint8)
_NEIGHBOURS[1, 1] = 0  # a path moves every frame: a fixed place gains nothing


class MotionIntegrator:
    """The DP track-before-detect score of every pixel (module docstring): :meth:`update` with
    each frame's change significance and camera shift; :meth:`forget` when the camera's motion
    is lost."""

    def __init__(self, memory: float = 0.85, clip: float = 3.0) -> None:
        self.memory, self.clip = float(memory), float(clip)
        self.score: np.ndarray | None = None
        self.frames = 0  # frames integrated since the start or :meth:`forget`

    def forget(self) -> None:
        """Start again (the past cannot be registered to the frames to come)."""
        self.score = None
        self.frames = 0

    def update(self, change: np.ndarray, shift: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """This frame's score (float32, ``change``'s shape; the integrator's own array: read it,
        do not modify it): ``change`` (NaN: unknown, no evidence) clipped to ±clip, plus λ × the
        best score among the 8 neighbours on the previous frame, moved by the camera's
        ``shift`` (px)."""
        c = np.clip(np.asarray(change, dtype=np.float32), -self.clip, self.clip)
        cv2.patchNaNs(c, 0.0)
        past = self.score
        self.frames += 1
        if past is None or past.shape != c.shape:
            self.frames = 1
            self.score = c
            return c
        dx, dy = float(shift[0]), float(shift[1])
        if abs(dx) > 1e-3 or abs(dy) > 1e-3:
            m = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]], dtype=np.float32)  # p held the scene point at p - shift
            past = cv2.warpAffine(past, m, (c.shape[1], c.shape[0]), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        best = cv2.dilate(past, _NEIGHBOURS, borderType=cv2.BORDER_REPLICATE)
        self.score = cv2.scaleAdd(best, self.memory, c)
        return self.score
