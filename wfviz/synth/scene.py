"""Scene physics for the scenarios: 3-D flights, spot rendering, static background, noise.

World frame: x east, y north, z up, metres from the camera. Image coordinates: x = column,
y = row, origin at the centre of the top-left pixel. All DN values are float32 before the
final rounding to uint16.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np
from scipy.special import erf

from wfviz.synth.camera import FisheyeCamera

_SUB = (np.arange(4) + 0.5) / 4.0 - 0.5  # 4x4 sub-samples per pixel


@dataclass(frozen=True)
class Flight:
    """A 3-D path: at time 0 at ``p0`` (m), then piecewise constant-rate turns.

    Horizontal speed ``speed`` (m/s) along ``heading`` (deg clockwise from north);
    ``turns`` are ``(t_start s, rate deg/s)`` in increasing time (t_start >= 0), the rate
    holding until the next entry (0 before the first). Height: z0 + climb*t + accel*t^2/2.
    Closed form at any time (negative times extrapolate the initial straight leg).
    """

    p0: tuple[float, float, float]
    speed: float = 0.0
    heading: float = 0.0
    climb: float = 0.0
    accel: float = 0.0
    turns: tuple[tuple[float, float], ...] = ()

    @cached_property
    def _segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(start times, turn rates rad/s, start states (e, n, psi)) of every segment."""
        starts, rates = [0.0], [0.0]
        for t, r in self.turns:
            starts.append(float(t))
            rates.append(math.radians(r))
        states = [np.array([self.p0[0], self.p0[1], math.radians(self.heading)])]
        for k in range(1, len(starts)):
            states.append(self._advance(states[-1], rates[k - 1], starts[k] - starts[k - 1]))
        return np.array(starts), np.array(rates), np.array(states)

    def _advance(self, state: np.ndarray, rate: float, dt: np.ndarray | float) -> np.ndarray:
        """State(s) (e, n, psi) after ``dt`` seconds of turning at ``rate`` rad/s."""
        e, n, psi = state[..., 0], state[..., 1], state[..., 2]
        rate = np.asarray(rate, dtype=np.float64)
        psi1 = psi + rate * dt
        safe = np.where(np.abs(rate) < 1e-12, 1.0, rate)
        straight = np.abs(rate) < 1e-12
        de = np.where(straight, self.speed * dt * np.sin(psi),
                      self.speed / safe * (np.cos(psi) - np.cos(psi1)))
        dn = np.where(straight, self.speed * dt * np.cos(psi),
                      self.speed / safe * (np.sin(psi1) - np.sin(psi)))
        return np.stack([e + de, n + dn, psi1], axis=-1)

    def position(self, t: np.ndarray) -> np.ndarray:
        """Positions (N, 3) in metres at times ``t`` (s)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        starts, rates, states = self._segments
        k = np.searchsorted(starts[1:], t, side="right")
        s = self._advance(states[k], rates[k], t - starts[k])
        z = self.p0[2] + self.climb * t + 0.5 * self.accel * t * t
        return np.column_stack([s[:, 0], s[:, 1], z])


@dataclass(frozen=True)
class Target:
    """A target flying ``flight`` (flight time 0 at frame ``t0_frame``).

    It exists in frames ``first..last`` (inclusive; ``last`` None = to the clip's end) and
    renders nothing in the ``hidden`` frame ranges. ``snr`` is its peak SNR (continuous
    peak / local noise sigma); ``sigma0`` the on-axis PSF width (px); ``kind`` "point" or
    "aircraft" (an ~8 px cross of two elongated Gaussians along the image motion).
    """

    target_id: int
    flight: Flight
    snr: float
    sigma0: float = 0.9
    first: int = 0
    last: int | None = None
    t0_frame: float = 0.0
    kind: str = "point"
    hidden: tuple[tuple[int, int], ...] = ()

    def state(self, frames: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (N, 3) m, exists (N,), brightness factor (N,)) at ``frames``."""
        frames = np.asarray(frames)
        pos = self.flight.position((frames - self.t0_frame) / fps)
        exists = (frames >= self.first) & ((frames <= self.last) if self.last is not None else True)
        bright = np.ones(len(frames))
        for a, b in self.hidden:
            bright[(frames >= a) & (frames <= b)] = 0.0
        return pos, np.broadcast_to(exists, frames.shape).copy(), bright


def add_spot(image: np.ndarray, x: float, y: float, peak: float, s_major: float,
             s_minor: float, angle: float) -> None:
    """Add in place a pixel-integrated elliptical Gaussian (4x4 sub-samples per pixel).

    ``peak`` is the continuous profile's peak; ``s_major`` is the width along ``angle``
    (radians from +x towards +y), ``s_minor`` across it. Clipped at the image border.
    """
    rows, cols = image.shape
    h = math.ceil(4.5 * max(s_major, s_minor)) + 1
    c0, c1 = max(round(x) - h, 0), min(round(x) + h + 1, cols)
    r0, r1 = max(round(y) - h, 0), min(round(y) + h + 1, rows)
    if c0 >= c1 or r0 >= r1:
        return
    u = (np.arange(c0, c1)[:, None] + _SUB).ravel() - x
    v = (np.arange(r0, r1)[:, None] + _SUB).ravel() - y
    ca, sa = math.cos(angle), math.sin(angle)
    along = ca * u[None, :] + sa * v[:, None]
    across = -sa * u[None, :] + ca * v[:, None]
    g = np.exp(-0.5 * ((along / s_major) ** 2 + (across / s_minor) ** 2))
    patch = g.reshape(r1 - r0, 4, c1 - c0, 4).mean(axis=(1, 3))
    image[r0:r1, c0:c1] += (peak * patch).astype(image.dtype, copy=False)


def add_spots(image: np.ndarray, x: np.ndarray, y: np.ndarray, peak: np.ndarray,
              sigma: float) -> None:
    """Add in place many circular pixel-integrated Gaussians (vectorised, for stars)."""
    rows, cols = image.shape
    h = math.ceil(4.5 * sigma)
    off = np.arange(-h, h + 1)
    cx, cy = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
    px_idx, py_idx = cx[:, None] + off, cy[:, None] + off
    s2 = math.sqrt(2.0) * sigma

    def frac(idx: np.ndarray, c: np.ndarray) -> np.ndarray:
        edges = np.concatenate([idx - 0.5, idx[:, -1:] + 0.5], axis=1) - c[:, None]
        return 0.5 * np.diff(erf(edges / s2), axis=1)

    flux = peak * 2.0 * math.pi * sigma * sigma
    w = flux[:, None, None] * frac(py_idx, y)[:, :, None] * frac(px_idx, x)[:, None, :]
    rr = np.broadcast_to(py_idx[:, :, None], w.shape)
    cc = np.broadcast_to(px_idx[:, None, :], w.shape)
    ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
    np.add.at(image.reshape(-1), rr[ok] * cols + cc[ok], w[ok].astype(image.dtype))


@dataclass(frozen=True)
class SceneSpec:
    """Static scene parameters (DN levels, ground kind, clutter, sensor defects, noise)."""

    dark: float = 800.0
    sky_zenith: float = 5000.0
    sky_horizon: float = 7000.0
    clouds: float = 0.0
    cloud_scale: float = 40.0
    ground: str = "none"  # "none" | "city" | "field"
    city_tops: tuple[float, float] = (0.8, 3.5)  # building top elevations (deg)
    ground_level: float = 9600.0
    flare: tuple[float, float, float, float, float] | None = None  # x, y, DN, ring r, width
    n_stars: int = 0
    star_snr: tuple[float, float] = (4.0, 60.0)
    star_sigma: float = 0.9
    fpn: float = 5.0
    n_hot: int = 6
    n_dead: int = 4
    read_noise: float = 25.0
    shot_gain: float = 0.04
    plain: bool = False  # constant level + Gaussian read noise only


@dataclass
class Background:
    """Noise-free static background and what the renderer needs alongside it."""

    image: np.ndarray  # float32 DN
    sigma: np.ndarray  # float32 temporal noise std per pixel
    buildings: np.ndarray  # (K, 3): azimuth centre, half width, top elevation (deg)
    hot: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    dead: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    stars: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # x, y, peak SNR

    def skyline(self, az: np.ndarray) -> np.ndarray:
        """Elevation (deg) of the top of the ground/buildings at azimuths ``az``."""
        az = np.asarray(az, dtype=np.float64)
        top = np.zeros_like(az)
        for c, half, h in self.buildings:
            inside = np.abs((az - c + 180.0) % 360.0 - 180.0) <= half
            top = np.where(inside, np.maximum(top, h), top)
        return top


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Zero-mean unit-std blurred white noise of feature size ~``sigma`` px (float32)."""
    rows, cols = shape
    f = max(1, int(sigma // 4))
    small = rng.standard_normal((rows // f + 2, cols // f + 2)).astype(np.float32)
    small = cv2.GaussianBlur(small, (0, 0), sigma / f, borderType=cv2.BORDER_REFLECT)
    out = cv2.resize(small, (cols, rows), interpolation=cv2.INTER_CUBIC)
    return (out - out.mean()) / out.std()


def fractal(rng: np.random.Generator, shape: tuple[int, int],
            sigmas: tuple[float, ...]) -> np.ndarray:
    """Unit-std sum of smooth noise at several scales (float32)."""
    out = sum(smooth_noise(rng, shape, s) for s in sigmas)
    return (out - out.mean()) / out.std()


def _city(rng: np.random.Generator, az0: float, tops: tuple[float, float]) -> np.ndarray:
    """Random blocks along the horizon within +-80 deg of ``az0``: (az, half width, top)."""
    centres = az0 + np.cumsum(rng.uniform(5.0, 14.0, 40)) - 80.0
    centres = centres[centres < az0 + 80.0]
    return np.column_stack([centres % 360.0, rng.uniform(0.8, 3.0, len(centres)),
                            rng.uniform(*tops, len(centres))])


def render_background(cam: FisheyeCamera, spec: SceneSpec, seed: int) -> Background:
    """Render the static scene once: sky, clouds, ground, skyline, flare, stars, defects."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
    shape = (cam.height, cam.width)
    if spec.plain:
        image = np.full(shape, spec.sky_zenith, np.float32)
        return Background(image, np.full(shape, spec.read_noise, np.float32), np.zeros((0, 3)))
    az, el = cam.direction_maps()
    sin_el = np.sin(np.radians(np.clip(el, 0.0, None)))
    scene = spec.sky_zenith + (spec.sky_horizon - spec.sky_zenith) * (1.0 - sin_el) ** 2
    if spec.clouds:
        c = smooth_noise(rng, shape, spec.cloud_scale)
        scene += spec.clouds * np.clip((c - 0.2) / 1.2, 0.0, 1.0) ** 1.5
    scene += 15.0 * fractal(rng, shape, (20.0, 60.0))
    buildings = np.zeros((0, 3))
    if spec.ground != "none":
        grad = np.maximum(np.hypot(*np.gradient(el)), 1e-9)
        ground = spec.ground_level + 1600.0 * np.clip(-el / 60.0, 0.0, 1.0)
        ground += 450.0 * fractal(rng, shape, (1.0, 3.0, 8.0, 20.0, 50.0))
        if spec.ground == "field":
            dist = 20.0 / np.tan(np.radians(np.clip(-el, 0.05, 90.0)))
            a = np.radians(az + 17.0)
            stripes = np.sin(2 * np.pi * dist * np.cos(a) / 14.0) * np.exp(-dist / 300.0)
            ground += 350.0 * stripes
        sky_cover = np.clip(0.5 + el / grad, 0.0, 1.0)
        scene = scene * sky_cover + ground * (1.0 - sky_cover)
        if spec.ground == "city":
            buildings = _city(rng, cam.az, spec.city_tops)
            level = 11600.0 + 250.0 * fractal(rng, shape, (1.0, 4.0))
            for c, half, h in buildings:
                d = np.abs((az - c + 180.0) % 360.0 - 180.0)
                cover = np.clip(0.5 + (h - el) / grad, 0.0, 1.0) * np.clip(half + 0.5 - d, 0, 1)
                cover *= el > -0.8
                scene = scene * (1.0 - cover) + (level + 40.0 * h) * cover
    if spec.flare is not None:
        fx, fy, amp, ring, width = spec.flare
        ys, xs = np.mgrid[0:cam.height, 0:cam.width]
        r = np.hypot(xs - fx, ys - fy)
        scene += amp * (np.exp(-0.5 * (r / (0.35 * ring)) ** 2)
                        + 0.45 * np.exp(-0.5 * ((r - ring) / width) ** 2))
    image = (spec.dark + cam.coverage() * (scene - spec.dark)).astype(np.float32)
    stars = np.zeros((0, 3))
    base_sigma = np.sqrt(spec.read_noise ** 2 + spec.shot_gain
                         * np.clip(image - spec.dark, 0.0, None)).astype(np.float32)
    if spec.n_stars:
        stars = _static_stars(rng, cam, spec, base_sigma)
        peaks = stars[:, 2] * base_sigma[stars[:, 1].astype(int), stars[:, 0].astype(int)]
        add_spots(image, stars[:, 0], stars[:, 1], peaks, spec.star_sigma)
    image += spec.fpn * (rng.standard_normal(shape) + 0.5 * rng.standard_normal((1, shape[1])))
    inside = np.argwhere(cam.coverage() > 0.999)[:, ::-1]
    pick = inside[rng.choice(len(inside), spec.n_hot + spec.n_dead, replace=False)]
    hot, dead = pick[:spec.n_hot], pick[spec.n_hot:]
    image[hot[:, 1], hot[:, 0]] += rng.uniform(1500.0, 4000.0, len(hot)).astype(np.float32)
    image[dead[:, 1], dead[:, 0]] = 0.5 * spec.dark
    sigma = np.sqrt(spec.read_noise ** 2 + spec.shot_gain
                    * np.clip(image - spec.dark, 0.0, None)).astype(np.float32)
    sigma[dead[:, 1], dead[:, 0]] = 0.0
    return Background(image, sigma, buildings, hot, dead, stars)


def _static_stars(rng: np.random.Generator, cam: FisheyeCamera, spec: SceneSpec,
                  sigma: np.ndarray) -> np.ndarray:
    """Stars (x, y, peak SNR) at random sky directions above 10 deg inside the field."""
    x = rng.uniform(8, cam.width - 9, 8 * spec.n_stars)
    y = rng.uniform(8, cam.height - 9, 8 * spec.n_stars)
    _, el = _az_el_at(cam, x, y)
    theta, _ = cam.off_axis(x, y)
    ok = (el > 10.0) & (theta < cam.theta_max - 8.0 / cam.f_px)
    x, y = x[ok][:spec.n_stars], y[ok][:spec.n_stars]
    lo, hi = spec.star_snr
    snr = lo * (hi / lo) ** rng.uniform(0.0, 1.0, len(x))
    return np.column_stack([x, y, snr])


def _az_el_at(cam: FisheyeCamera, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(azimuth, elevation) in degrees of pixel positions."""
    d = cam.pixel_to_dir(x, y)
    return (np.degrees(np.arctan2(d[..., 0], d[..., 1])) % 360.0,
            np.degrees(np.arcsin(np.clip(d[..., 2], -1.0, 1.0))))


def add_noise(image: np.ndarray, sigma: np.ndarray, seed: int, index: int) -> None:
    """Add in place temporal noise for frame ``index``: N(0, sigma) per pixel.

    ``sigma`` combines read noise and shot noise (variance proportional to the
    background signal), i.e. Poisson noise in its Gaussian limit.
    """
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0, index)))
    image += rng.standard_normal(image.shape, dtype=np.float32) * sigma


def to_uint16(image: np.ndarray) -> np.ndarray:
    """Round a float32 DN image to uint16 (clipped to the 16-bit range)."""
    np.clip(image, 0.0, 65535.0, out=image)
    image += 0.5
    return image.astype(np.uint16)
