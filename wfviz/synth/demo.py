"""Built-in demo clip: a staring 180-degree IR fisheye over sky and ground, 4 dim targets.

Coordinates: x = column, y = row, origin at the centre of the top-left pixel. Frames are
rendered lazily from a precomputed static background plus targets and per-frame noise;
the truth positions are exactly where the target spots are rendered.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from wfviz.io.clip import write_image
from wfviz.io.frames import Frame
from wfviz.synth.clip import GeneratedClip, TruthRow
from wfviz.synth.folder import write_folder
from wfviz.synth.psf import add_gaussian_spot

WIDTH, HEIGHT = 640, 512
FPS = 20.0
CX, CY, RADIUS = 319.3, 255.6, 236.4
FOCAL = RADIUS / (math.pi / 2)  # equidistant fisheye: r = FOCAL * theta
ELEVATION = math.radians(25.0)  # optical axis elevation, azimuth 0 (north)
DARK_LEVEL = 800.0  # DN outside the imaging circle
READ_NOISE = 25.0  # DN, temporal
SHOT_GAIN = 0.04  # DN^2 per DN above dark: shot-noise variance scale
FPN_SIGMA = 5.0  # DN, static fixed-pattern offset
PATH_FRAMES = 160  # targets exist only within the first PATH_FRAMES frames

_AXIS = np.array([0.0, math.cos(ELEVATION), math.sin(ELEVATION)])
_RIGHT = np.array([1.0, 0.0, 0.0])
_UP = np.array([0.0, -math.sin(ELEVATION), math.cos(ELEVATION)])


@dataclass(frozen=True)
class TargetPath:
    """A target moving with speed ``s(t)`` and heading ``psi(t)`` through ``(x0, y0)``.

    At frame ``anchor`` the target is at (x0, y0) with heading ``heading_deg`` (image
    coordinates: 0 = +x, 90 = +y, i.e. down). With tau = t - anchor, the heading rate is
    ``sum(turn[i] * tau**i)`` rad/frame and the speed is
    ``speed[0] + (speed[1] - speed[0]) * exp(-(tau/40)**2)`` px/frame. The target is
    present in frames ``first..last``; ``peak`` is its continuous peak (DN above the
    background) and ``sigma`` its (x, y) Gaussian widths in pixels.
    """

    target_id: int
    first: int
    last: int
    anchor: int
    x0: float
    y0: float
    heading_deg: float
    turn: tuple[float, ...]
    speed: tuple[float, float]
    peak: float
    sigma: tuple[float, float]

    def positions(self, substeps: int = 32) -> np.ndarray:
        """(last - first + 1, 2) array of (x, y) at frames first..last."""
        tau = np.arange((self.first - self.anchor) * substeps,
                        (self.last - self.anchor) * substeps + 1) / substeps
        turned = np.polynomial.polynomial.polyval(tau, np.polynomial.polynomial.polyint(self.turn))
        psi = math.radians(self.heading_deg) + turned
        s0, s1 = self.speed
        speed = s0 + (s1 - s0) * np.exp(-((tau / 40.0) ** 2))
        vel = np.stack([speed * np.cos(psi), speed * np.sin(psi)], axis=1)
        steps = 0.5 * (vel[1:] + vel[:-1]) / substeps
        pos = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
        pos -= pos[(self.anchor - self.first) * substeps]
        return pos[::substeps] + (self.x0, self.y0)


# 1 and 2: gentle S-curves crossing at ~102 degrees near frame 78 (closest 1.28 px);
# 3: a 330-degree circular arc near the top; 4: appears at frame 30, low along the horizon.
TARGETS: tuple[TargetPath, ...] = (
    TargetPath(1, 0, 159, 78, 320.0, 182.0, 40.0, (0.0015, -2.2e-4), (1.6, 2.5), 260.0,
               (0.9, 1.0)),
    TargetPath(2, 0, 159, 78, 319.2, 183.0, 142.0, (-0.001, 2.3e-4), (1.7, 2.4), 240.0,
               (1.0, 0.9)),
    TargetPath(3, 0, 159, 80, 322.0, 128.0, 180.0, (0.036,), (1.55, 1.55), 280.0, (0.9, 0.9)),
    TargetPath(4, 30, 159, 95, 320.0, 285.0, 180.0, (0.004,), (1.6, 1.6), 220.0, (0.95, 0.9)),
)


def _project(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel (x, y) of unit world directions ``d`` (..., 3) through the fisheye."""
    theta = np.arccos(np.clip(d @ _AXIS, -1.0, 1.0))
    phi = np.arctan2(d @ _UP, d @ _RIGHT)
    return CX + FOCAL * theta * np.cos(phi), CY - FOCAL * theta * np.sin(phi)


def _horizon_curve(n: int = 20001) -> tuple[np.ndarray, np.ndarray]:
    """Densely sampled horizon (x increasing, y) for azimuths in [-90, 90] degrees."""
    az = np.linspace(-math.pi / 2, math.pi / 2, n)
    d = np.stack([np.sin(az), np.cos(az), np.zeros_like(az)], axis=1)
    return _project(d)


_HORIZON_X, _HORIZON_Y = _horizon_curve()


def horizon_row(x: np.ndarray) -> np.ndarray:
    """Exact horizon row at columns ``x`` (NaN where no horizon lies inside the circle)."""
    return np.interp(np.asarray(x, dtype=np.float64), _HORIZON_X, _HORIZON_Y,
                     left=np.nan, right=np.nan)


def _elevation_map() -> np.ndarray:
    """World elevation (rad) of the direction imaged at every pixel centre."""
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    dx, dy = xs - CX, CY - ys
    theta, phi = np.hypot(dx, dy) / FOCAL, np.arctan2(dy, dx)
    z = np.sin(theta) * np.sin(phi) * _UP[2] + np.cos(theta) * _AXIS[2]
    return np.arcsin(np.clip(z, -1.0, 1.0))


def _disc_coverage() -> np.ndarray:
    """Anti-aliased fraction of each pixel inside the imaging circle."""
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    return np.clip(RADIUS + 0.5 - np.hypot(xs - CX, ys - CY), 0.0, 1.0)


def _smooth_noise(rng: np.random.Generator, sigma: float) -> np.ndarray:
    """Zero-mean, unit-std Gaussian-blurred white noise of feature size ~``sigma`` px."""
    f = max(1, int(sigma // 4))
    small = rng.standard_normal((HEIGHT // f + 2, WIDTH // f + 2)).astype(np.float32)
    small = cv2.GaussianBlur(small, (0, 0), sigma / f, borderType=cv2.BORDER_REFLECT)
    out = cv2.resize(small, (WIDTH, HEIGHT), interpolation=cv2.INTER_CUBIC).astype(np.float64)
    return (out - out.mean()) / out.std()


def _fractal(rng: np.random.Generator, sigmas: tuple[float, ...]) -> np.ndarray:
    """Unit-std equal-weight sum of smooth noise at several scales."""
    out = sum(_smooth_noise(rng, s) for s in sigmas)
    return (out - out.mean()) / out.std()


# Blocks standing on the horizon: (centre column, half width, height above horizon px, DN).
_BUILDINGS = ((196.0, 12, 7, 12400.0), (258.0, 6, 11, 12800.0), (300.0, 18, 5, 11900.0),
              (384.0, 9, 9, 12600.0), (432.0, 15, 6, 12200.0))


def _building_cover() -> tuple[np.ndarray, np.ndarray]:
    """(coverage, level) of the blocks on the horizon; top edges anti-aliased."""
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
    hr = horizon_row(np.arange(WIDTH, dtype=np.float64))
    cover, level = np.zeros((HEIGHT, WIDTH)), np.zeros((HEIGHT, WIDTH))
    for x0, half, h, dn in _BUILDINGS:
        cols = np.abs(xs - x0) <= half
        top = np.where(cols, hr[None, :] - h, np.inf)
        c = np.clip(ys - top + 0.5, 0.0, 1.0) * (ys <= hr[None, :] + 3)
        cover, level = np.maximum(cover, c), np.where(c > 0, dn, level)
    return cover, level


def _render_background(seed: int) -> np.ndarray:
    """Noise-free static scene in DN (float32): sky, ground, blocks, rim, fixed pattern."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
    el = _elevation_map()
    sky = 5000.0 + 2000.0 * (1.0 - np.sin(np.clip(el, 0.0, None))) ** 2
    sky += 20.0 * _fractal(rng, (25.0, 60.0))
    ground = 9600.0 + 1600.0 * np.clip(-el / math.radians(60.0), 0.0, 1.0)
    ground += 500.0 * _fractal(rng, (1.0, 3.0, 8.0, 20.0, 50.0))
    grad = np.hypot(*np.gradient(el))
    sky_cover = np.clip(0.5 + el / np.maximum(grad, 1e-9), 0.0, 1.0)
    scene = sky * sky_cover + ground * (1.0 - sky_cover)
    b_cover, b_level = _building_cover()
    b_level = b_level + 150.0 * _fractal(rng, (1.0, 4.0))
    scene = scene * (1.0 - b_cover) + b_level * b_cover
    image = DARK_LEVEL + _disc_coverage() * (scene - DARK_LEVEL)
    image += FPN_SIGMA * rng.standard_normal(image.shape)
    return image.astype(np.float32)


def _noise_sigma(background: np.ndarray) -> np.ndarray:
    """Per-pixel temporal noise std (DN): read noise plus scaled shot noise."""
    signal = np.clip(background - DARK_LEVEL, 0.0, None)
    return np.sqrt(READ_NOISE**2 + SHOT_GAIN * signal).astype(np.float32)


class DemoClip(GeneratedClip):
    """The demo clip (implements ``wfviz.io.frames.Clip``), rendered lazily frame by frame."""

    def __init__(self, seed: int = 0, n_frames: int = PATH_FRAMES) -> None:
        if seed < 0 or n_frames < 1:
            raise ValueError("seed must be >= 0 and n_frames >= 1")
        self._seed, self._n_frames = seed, n_frames
        self._background = _render_background(seed)
        self._background.flags.writeable = False
        self._sigma = _noise_sigma(self._background)
        self._spots: dict[int, list[tuple[TargetPath, float, float]]] = {}
        for t in TARGETS:
            last = min(t.last, n_frames - 1, PATH_FRAMES - 1)
            for f, (x, y) in zip(range(t.first, last + 1), t.positions()):
                self._spots.setdefault(f, []).append((t, float(x), float(y)))

    @property
    def name(self) -> str:
        """Clip name: ``"demo"``."""
        return "demo"

    @property
    def fps(self) -> float:
        """Frames per second (20)."""
        return FPS

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return self._n_frames

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) = (512, 640)."""
        return (HEIGHT, WIDTH)

    @property
    def circle(self) -> tuple[float, float, float]:
        """Imaging circle (cx, cy, R) in pixels."""
        return (CX, CY, RADIUS)

    @property
    def background(self) -> np.ndarray:
        """Read-only noise-free float32 scene without targets (fixed pattern included)."""
        return self._background

    @staticmethod
    def horizon_row(x: np.ndarray) -> np.ndarray:
        """Exact horizon row at columns ``x`` (NaN outside the circle's horizon span)."""
        return horizon_row(x)

    def truth_at(self, index: int) -> list[TruthRow]:
        """Targets present in frame ``index``, by target id (all visible; peak SNR against the
        noise σ at the rounded centre)."""
        h, w = self._sigma.shape
        return [TruthRow(index, t.target_id, x, y,
                         float(t.peak / self._sigma[min(max(round(y), 0), h - 1), min(max(round(x), 0), w - 1)]), 1)
                for t, x, y in self._spots.get(index, [])]

    def truth(self) -> list[TruthRow]:
        """Every (frame, target_id, x, y) where a target is present, by frame then id."""
        return [p for f in range(self._n_frames) for p in self.truth_at(f)]

    def render(self, index: int) -> np.ndarray:
        """Frame ``index`` as uint16 (deterministic per (seed, index))."""
        if not 0 <= index < self._n_frames:
            raise IndexError(f"frame {index} outside 0..{self._n_frames - 1}")
        image = self._background.copy()
        for t, x, y in self._spots.get(index, []):
            add_gaussian_spot(image, x, y, t.peak, t.sigma[0], t.sigma[1])
        rng = np.random.default_rng(np.random.SeedSequence(self._seed, spawn_key=(0, index)))
        image += rng.standard_normal(image.shape, dtype=np.float32) * self._sigma
        np.clip(np.rint(image, out=image), 0, 65535, out=image)
        return image.astype(np.uint16)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop`` in order, one at a time."""
        stop = self._n_frames if stop is None else min(stop, self._n_frames)
        for index in range(max(start, 0), stop):
            yield Frame(index, index / FPS, self.render(index))

    def write_truth_csv(self, path: str | Path, start: int = 0, stop: int | None = None) -> Path:
        """Write ``frame,target_id,x,y,peak`` rows (4 decimals) for frames in [start, stop)."""
        path = Path(path)
        stop = self._n_frames if stop is None else stop
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(["frame", "target_id", "x", "y", "peak"])
            for f in range(max(start, 0), min(stop, self._n_frames)):
                for t, x, y in self._spots.get(f, []):
                    writer.writerow([f, t.target_id, f"{x:.4f}", f"{y:.4f}", f"{t.peak:.4f}"])
        return path

    def save(self, folder: str | Path, start: int = 0, stop: int | None = None) -> Path:
        """Write frames as 16-bit ``frame_NNNNNN.png`` plus ``truth.csv`` into ``folder``: a new
        or empty folder, or one wfviz wrote before (else :class:`OutputError`, nothing
        touched; see :mod:`wfviz.synth.folder`)."""

        def fill(tmp: Path) -> None:
            for frame in self.frames(start, stop):
                if not write_image(tmp / f"frame_{frame.index:06d}.png", frame.image):
                    raise OSError(f"could not write frame {frame.index} to {tmp}")
            self.write_truth_csv(tmp / "truth.csv", start, stop)

        return write_folder(Path(folder), fill, by="wfviz demo --save-clip")


def demo_clip(seed: int = 0, n_frames: int = PATH_FRAMES) -> DemoClip:
    """The built-in demo clip: 640x512 uint16 at 20 fps, 4 targets with exact truth."""
    return DemoClip(seed, n_frames)
