"""Scenario library with exact truth: clips modelled on the four methods' test sequences.

``list_scenarios()`` describes them, ``make_scenario(name)`` builds a lazily rendered
``ScenarioClip`` (a ``wfviz.io.frames.Clip``), ``write_scenario`` saves 16-bit PNGs, truth.csv
and meta.json (optionally an 8-bit AVI). Coordinates: x = column, y = row, origin at the
centre of the top-left pixel. Truth = projection of each target's 3-D position at the
frame's time, exactly where its spot is rendered.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from wfviz.io.clip import ClipError, opencv_name, register_source, write_image
from wfviz.io.frames import Frame
from wfviz.synth.clip import GeneratedClip, TruthRow
from wfviz.synth.camera import FisheyeCamera, az_el_to_dirs, dirs_to_az_el
from wfviz.synth.folder import write_folder
from wfviz.synth.scene import (Flight, SceneSpec, Target, add_noise, add_spot, add_spots,
                               render_background, to_uint16)

K_RADIAL, K_TANGENTIAL = 0.35, 0.10  # PSF growth: sigma = sigma0 * (1 + k * theta^2)
EDGE_MARGIN_PX = 3.0  # visible only this far inside the imaging circle / frame
HORIZON_MARGIN_DEG = 0.3  # visible only this far above the ground/skyline
PRECOMPUTE_MAX = 20_000  # longer clips evaluate their targets frame by frame


@dataclass(frozen=True)
class ScenarioInfo:
    """One-line description and key numbers of a scenario (defaults, before overrides)."""

    name: str
    description: str
    width: int
    height: int
    fov_deg: float
    fps: float
    n_frames: int
    n_targets: int


@dataclass(frozen=True)
class Respawning:
    """A target slot that re-spawns every ``period`` frames on a new random flight.

    Life L starts at frame ``offset + L*period`` and lasts ``life`` frames; its target id is
    ``slot + 1 + n_slots*L`` and its flight is drawn from (seed, slot, L), so any frame's state
    costs O(1).
    """

    slot: int
    n_slots: int
    period: int
    offset: int
    life: int
    snr: float
    sigma0: float = 0.8
    kind: str = "point"
    seed: int = 0
    f_px: float = 300.0
    az0: float = 0.0

    def flight(self, life: int, fps: float) -> Flight:
        """The random flight of life ``life`` (time 0 at the life's first frame)."""
        rng = np.random.default_rng([self.seed, self.slot, life])
        az, el = self.az0 + rng.uniform(-60.0, 60.0), rng.uniform(20.0, 55.0)
        rng_m = rng.uniform(1200.0, 3000.0)
        speed = rng.uniform(0.8, 1.8) * fps * rng_m / self.f_px  # ~0.8-1.8 px/frame
        p0 = tuple(float(v) for v in rng_m * az_el_to_dirs(az, el))
        turn = ((rng.uniform(2.0, self.life / fps - 2.0), rng.uniform(-10.0, 10.0)),)
        return Flight(p0, speed, rng.uniform(0.0, 360.0), rng.uniform(-3.0, 3.0), 0.0, turn)

    def state(self, frames: np.ndarray, fps: float) -> tuple[np.ndarray, ...]:
        """(ids, positions (N, 3), exists, brightness) at ``frames``."""
        rel = np.asarray(frames) - self.offset
        life, phase = np.divmod(rel, self.period)
        exists = (rel >= 0) & (phase < self.life)
        pos = np.tile([0.0, 1.0, 0.0], (len(rel), 1))
        for lf in np.unique(life[exists]):
            m = exists & (life == lf)
            pos[m] = self.flight(int(lf), fps).position(phase[m] / fps)
        return self.slot + 1 + self.n_slots * life, pos, exists, np.ones(len(rel))


@dataclass(frozen=True)
class _Design:
    """Everything that defines a scenario apart from the seed and overrides."""

    info: ScenarioInfo
    camera: FisheyeCamera
    spec: SceneSpec
    targets: tuple[Target | Respawning, ...]
    jitter_px: float = 0.0  # star field: uniform frame shifts in [-j, j] px
    n_field_stars: int = 0  # stars re-rendered every frame (moving with the jitter)
    lazy: bool = False  # evaluate targets per frame instead of precomputing the clip


class ScenarioClip(GeneratedClip):
    """A scenario rendered lazily frame by frame (implements ``wfviz.io.frames.Clip``).

    Frame ``i`` is the static background (+ jittered field stars) + target spots + noise
    seeded by (seed, i), so any frame renders alone and identically on every pass.
    """

    def __init__(self, design: _Design, seed: int, n_frames: int | None, snr: float | None) -> None:
        self._d, self._seed, self._snr = design, seed, snr
        self._n = design.info.n_frames if n_frames is None else n_frames
        self._cam = cam = design.camera
        self._targets = tuple(replace(t, snr=snr) if snr is not None else t
                              for t in design.targets)
        self._targets = tuple(replace(t, seed=seed) if isinstance(t, Respawning) else t
                              for t in self._targets)
        self._bg = render_background(cam, design.spec, seed)
        self._bg.image.flags.writeable = False
        self._sigma_ref = float(np.median(self._bg.sigma[self._bg.sigma > 0]))
        j = design.jitter_px
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2,)))
        self._jitter = rng.uniform(-j, j, (self._n, 2)) if j else None  # prefix-stable in n
        self._stars = np.zeros((0, 3))
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(3,)))
        if design.n_field_stars:
            k, pad = design.n_field_stars, 12.0
            self._stars = np.column_stack([rng.uniform(-pad, cam.width - 1 + pad, k),
                                           rng.uniform(-pad, cam.height - 1 + pad, k),
                                           4.0 * (75.0 ** rng.uniform(0.0, 1.0, k))])
        lazy = design.lazy or self._n > PRECOMPUTE_MAX
        self._table = None if lazy else self._evaluate(np.arange(self._n))

    @property
    def name(self) -> str:
        """Scenario name."""
        return self._d.info.name

    @property
    def fps(self) -> float:
        """Frames per second."""
        return self._d.info.fps

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return self._n

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns)."""
        return (self._cam.height, self._cam.width)

    @property
    def info(self) -> ScenarioInfo:
        """Scenario description with this clip's frame count."""
        return replace(self._d.info, n_frames=self._n)

    @property
    def camera(self) -> FisheyeCamera:
        """The camera model."""
        return self._cam

    def _evaluate(self, frames: np.ndarray) -> list[dict[str, np.ndarray]]:
        """Per target: ids, x, y, peak_snr, visible, exists and PSF parameters at ``frames``."""
        cam, fps, out = self._cam, self.fps, []
        for t in self._targets:
            if isinstance(t, Respawning):
                ids, pos, exists, bright = t.state(frames, fps)
                pos2 = t.state(frames + 0.25, fps)[1]
            else:
                pos, exists, bright = t.state(frames, fps)
                ids, pos2 = np.full(len(frames), t.target_id), t.flight.position(
                    (frames + 0.25 - t.t0_frame) / fps)
            x, y, in_view = cam.project(pos)
            x2, y2, _ = cam.project(pos2)
            theta, radial = cam.off_axis(x, y)
            inside = theta <= cam.theta_max - EDGE_MARGIN_PX / cam.f_px
            ok = exists & in_view & (bright > 0) & inside
            if self._d.spec.ground != "none":
                az, el = dirs_to_az_el(pos)
                ok &= el > self._bg.skyline(az) + HORIZON_MARGIN_DEG
            if self._jitter is not None:
                x, y = x + self._jitter[frames, 0], y + self._jitter[frames, 1]
            m = EDGE_MARGIN_PX - 0.5
            ok &= (x >= m) & (x <= cam.width - 1 - m) & (y >= m) & (y <= cam.height - 1 - m)
            snr = np.where(ok, t.snr * bright, 0.0)
            iy = np.clip(np.rint(y), 0, cam.height - 1).astype(int)
            ix = np.clip(np.rint(x), 0, cam.width - 1).astype(int)
            sig = self._bg.sigma[iy, ix]
            sig = np.where(sig > 0, sig, self._d.spec.read_noise)
            out.append({"id": ids, "x": x, "y": y, "snr": snr, "visible": ok, "exists": exists,
                        "peak": snr * sig, "s_r": t.sigma0 * (1 + K_RADIAL * theta ** 2),
                        "s_t": t.sigma0 * (1 + K_TANGENTIAL * theta ** 2), "radial": radial,
                        "motion": np.arctan2(y2 - y, x2 - x), "kind": t.kind})
        return out

    def _rows(self, frames: np.ndarray) -> list[dict[str, np.ndarray]]:
        if self._table is not None:
            return [{k: (v[frames] if isinstance(v, np.ndarray) else v) for k, v in tab.items()}
                    for tab in self._table]
        return self._evaluate(frames)

    def truth_at(self, index: int) -> list[TruthRow]:
        """Truth rows of frame ``index`` by target id."""
        return self._truth(np.array([index]))

    def truth(self) -> list[TruthRow]:
        """A row for every frame each target exists, by frame then target id."""
        return [r for a in range(0, self._n, 4096)
                for r in self._truth(np.arange(a, min(a + 4096, self._n)))]

    def _truth(self, frames: np.ndarray) -> list[TruthRow]:
        """Truth rows of ``frames``, by frame then target id."""
        if len(frames) and not 0 <= frames[0] <= frames[-1] < self._n:
            raise IndexError(f"frames outside 0..{self._n - 1}")
        cols = [(t["exists"], t["id"], t["x"], t["y"], t["snr"], t["visible"])
                for t in self._rows(frames)]
        rows: list[TruthRow] = []
        for i, f in enumerate(frames):
            rows.extend(sorted(TruthRow(int(f), int(ids[i]), float(x[i]), float(y[i]),
                                        float(s[i]), int(v[i]))
                               for ex, ids, x, y, s, v in cols if ex[i]))
        return rows

    @property
    def static_background(self) -> np.ndarray:
        """Read-only noise-free float32 scene fixed to the sensor (no targets, no field stars)."""
        return self._bg.image

    def background(self, index: int) -> np.ndarray:
        """Noise-free float32 frame ``index`` without targets (read-only when static)."""
        if not len(self._stars):
            return self._bg.image
        image = self._bg.image.copy()
        jx, jy = self._jitter[index] if self._jitter is not None else (0.0, 0.0)
        add_spots(image, self._stars[:, 0] + jx, self._stars[:, 1] + jy,
                  self._stars[:, 2] * self._sigma_ref, self._d.spec.star_sigma)
        return image

    def render(self, index: int, noise: bool = True) -> np.ndarray:
        """Frame ``index`` as uint16 (deterministic per (seed, index))."""
        if not 0 <= index < self._n:
            raise IndexError(f"frame {index} outside 0..{self._n - 1}")
        image = self.background(index)
        image = image.copy() if image is self._bg.image else image
        for t in self._rows(np.array([index])):
            if not t["visible"][0]:
                continue
            x, y, p = float(t["x"][0]), float(t["y"][0]), float(t["peak"][0])
            if t["kind"] == "aircraft":
                s, a = float(t["s_r"][0]), float(t["motion"][0])
                add_spot(image, x, y, 0.6 * p, 3.0 * s, 0.9 * s, a)
                add_spot(image, x, y, 0.4 * p, 0.9 * s, 2.6 * s, a)
            else:
                add_spot(image, x, y, p, float(t["s_r"][0]), float(t["s_t"][0]),
                         float(t["radial"][0]))
        if noise:
            add_noise(image, self._bg.sigma, self._seed, index)
        dead = self._bg.dead
        image[dead[:, 1], dead[:, 0]] = self._bg.image[dead[:, 1], dead[:, 0]]
        return to_uint16(image)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop`` in order, one at a time."""
        stop = self._n if stop is None else min(stop, self._n)
        for index in range(max(start, 0), stop):
            yield Frame(index, index / self.fps, self.render(index))

    def meta(self) -> dict:
        """Everything but the pixels and truth: camera, geometry, noise, stars, jitter, seed."""
        cam, spec, bg = self._cam, self._d.spec, self._bg
        circle = cam.circle
        horizon = cam.horizon(721) if spec.ground != "none" else None
        stars = np.vstack([bg.stars, self._stars]) if len(bg.stars) + len(self._stars) else None
        return {
            "name": self.name, "description": self._d.info.description, "seed": self._seed,
            "fps": self.fps, "n_frames": self._n, "width": cam.width, "height": cam.height,
            "snr_override": self._snr, "camera": cam.to_meta(),
            "imaging_circle": None if circle is None else dict(zip(("cx", "cy", "radius"), circle)),
            "horizon": None if horizon is None else np.round(horizon, 3).tolist(),
            "skyline_blocks_az_halfwidth_top_deg": np.round(bg.buildings, 3).tolist(),
            "stars": None if stars is None else np.round(stars, 4).tolist(),
            "stars_columns": "x, y, peak_snr (x, y before jitter)",
            "jitter": None if self._jitter is None else self._jitter.tolist(),
            "noise_sigma": spec.read_noise,
            "noise": {"read_sigma": spec.read_noise,
                      "shot_gain": 0.0 if spec.plain else spec.shot_gain,
                      "dark_level": spec.dark, "fpn_sigma": 0.0 if spec.plain else spec.fpn,
                      "model": "N(0, read^2 + shot_gain*(background - dark)) per pixel and frame; "
                               "peak_snr = continuous peak / that sigma at the target"},
            "psf": {"model": "pixel-integrated elliptical Gaussian, sigma = sigma0*(1 + k*theta^2)",
                    "k_radial": K_RADIAL, "k_tangential": K_TANGENTIAL},
            "targets": [_target_meta(t) for t in self._targets],
            "hot_pixels": bg.hot.tolist(), "dead_pixels": bg.dead.tolist(),
        }


def _target_meta(t: Target | Respawning) -> dict:
    """A target's (or re-spawning slot's) description for meta.json."""
    common = {"kind": t.kind, "sigma0": t.sigma0, "snr": t.snr}
    if isinstance(t, Respawning):
        return {"slot": t.slot, **common, "first_frame": t.offset, "period": t.period,
                "life_frames": t.life, "ids": f"{t.slot + 1} + {t.n_slots} * life"}
    return {"target_id": t.target_id, **common, "first": t.first, "last": t.last,
            "hidden": [list(h) for h in t.hidden]}


def _fly(cam: FisheyeCamera, xy: tuple[float, float], v_px: tuple[float, float], r: float,
         fps: float, turns: tuple[tuple[float, float], ...] = (), accel: float = 0.0) -> Flight:
    """A flight at range ``r`` (m) imaged at pixel ``xy`` at time 0, starting to move
    ``v_px`` px/frame in the image (3-D velocity from the back-projected displacement)."""
    d0 = cam.pixel_to_dir(xy[0], xy[1])
    d1 = cam.pixel_to_dir(xy[0] + v_px[0], xy[1] + v_px[1])
    p0, vel = r * d0, r * (d1 - d0) * fps
    return Flight(tuple(float(v) for v in p0), float(np.hypot(vel[0], vel[1])),
                  float(np.degrees(np.arctan2(vel[0], vel[1]))), float(vel[2]), accel, turns)


def _orbit(r_h: float, alt: float, az: float, speed: float, climb: float = 0.0) -> Flight:
    """A clockwise circle of horizontal radius ``r_h`` around the camera from azimuth ``az``."""
    a = np.radians(az)
    p0 = (float(r_h * np.sin(a)), float(r_h * np.cos(a)), alt)
    return Flight(p0, speed, az + 90.0, climb, 0.0, ((0.0, float(np.degrees(speed / r_h))),))


def _info(name: str, desc: str, cam: FisheyeCamera, fps: float, n: int, k: int) -> ScenarioInfo:
    return ScenarioInfo(name, desc, cam.width, cam.height, cam.fov_deg, fps, n, k)


def _designs() -> dict[str, _Design]:
    """The scenario table (positions and velocities chosen in the image, flown in 3-D)."""
    d: dict[str, _Design] = {}
    cam70 = FisheyeCamera.filling(640, 512, 70.0, 0.0, 14.0)
    turns = ((2.2, -100.0), (3.1, 0.0), (4.4, 120.0), (5.4, 0.0), (6.6, -110.0), (7.6, 0.0))
    man = Target(1, _fly(cam70, (110.0, 170.0), (2.1, 0.3), 500.0, 25.0, turns), snr=9.0)
    d["fov70-maneuver"] = _Design(
        _info("fov70-maneuver", "70° fisheye over fields and clouds; one target making three "
              "sharp turns (GEWC paper, 70° sequence)", cam70, 25.0, 220, 1),
        cam70, SceneSpec(clouds=260.0, ground="field", sky_zenith=5200.0), (man,))
    four = (
        Target(1, _fly(cam70, (330.0, 200.0), (1.9, -0.4), 900.0, 25.0), snr=10.0,
               t0_frame=76.5),
        Target(2, _fly(cam70, (331.2, 201.0), (-1.6, -0.9), 1100.0, 25.0), snr=8.0,
               t0_frame=76.5),
        Target(3, _fly(cam70, (500.0, 120.0), (-0.8, 0.9), 700.0, 25.0, ((3.0, 12.0),)),
               snr=12.0, first=17, t0_frame=17.0),
        Target(4, _fly(cam70, (80.0, 330.0), (1.2, -0.3), 1400.0, 25.0), snr=8.0, first=46,
               t0_frame=46.0),
    )
    d["fov70-four-targets"] = _Design(
        _info("fov70-four-targets", "70° fisheye over fields; four targets appearing at frames "
              "0, 0, 17, 46; targets 1 and 2 meet (< 20 px) around frames 71-82 and cross",
              cam70, 25.0, 200, 4), cam70,
        SceneSpec(clouds=200.0, ground="field", sky_zenith=5100.0), four)
    cam180 = FisheyeCamera.circular(640, 512, 0.0, 25.0, offset=(0.3, -0.4))
    plane = Target(1, _orbit(433.0, 250.0, -93.5, 236.0, 3.0), snr=15.0, sigma0=1.0,
                   kind="aircraft")
    d["fov180-city-aircraft"] = _Design(
        _info("fov180-city-aircraft", "180° fisheye over a city skyline; one ~8 px aircraft "
              "circling the camera at ~3 px/frame", cam180, 25.0, 150, 1),
        cam180, SceneSpec(clouds=150.0, ground="city"), (plane,))
    launches = (
        Target(1, Flight((600.0 * np.sin(np.radians(-40.0)), 600.0 * np.cos(np.radians(-40.0)),
                          0.0), 30.0, 60.0, 30.0, 120.0), snr=12.0),
        Target(2, Flight((700.0 * np.sin(np.radians(35.0)), 700.0 * np.cos(np.radians(35.0)),
                          0.0), 25.0, 300.0, 20.0, 110.0), snr=10.0, first=70, t0_frame=70.0),
    )
    d["fov180-launches"] = _Design(
        _info("fov180-launches", "180° fisheye over fields with a lens-flare halo; two launches "
              "rising fast, the second appearing at frame 70", cam180, 25.0, 160, 2),
        cam180, SceneSpec(ground="field", flare=(470.0, 160.0, 900.0, 38.0, 6.0)), launches)
    camstar = FisheyeCamera.filling(1024, 1024, 1.0, 135.0, 50.0)
    stars = (
        Target(1, _fly(camstar, (200.0, 300.0), (2.1, 0.8), 80_000.0, 10.0), snr=7.0,
               sigma0=1.0),
        Target(2, _fly(camstar, (800.0, 700.0), (-1.5, 1.7), 60_000.0, 10.0), snr=6.0,
               sigma0=1.0, hidden=((20, 24),)),
    )
    d["starfield"] = _Design(
        _info("starfield", "1024x1024 telescope star field (500 stars) with frame jitter; two "
              "dim moving targets, target 2 hidden in frames 20-24", camstar, 10.0, 44, 2),
        camstar, SceneSpec(sky_zenith=1500.0, sky_horizon=1600.0, read_noise=20.0, n_hot=8,
                           n_dead=6), stars, jitter_px=3.0, n_field_stars=500)
    camtbd = FisheyeCamera.filling(64, 64, 0.3, 200.0, 40.0)
    tbd = (
        Target(1, _fly(camtbd, (12.0, 20.0), (0.6, 0.3), 40_000.0, 10.0), snr=3.0,
               sigma0=0.8, first=3, last=27, t0_frame=3.0),
        Target(2, _fly(camtbd, (48.0, 12.0), (-0.5, 0.7), 50_000.0, 10.0), snr=3.0,
               sigma0=0.8, first=8, last=17, t0_frame=8.0),
        Target(3, _fly(camtbd, (30.0, 50.0), (0.4, -0.5), 45_000.0, 10.0), snr=3.0,
               sigma0=0.8, first=13, last=22, t0_frame=13.0),
    )
    d["lowsnr-tbd"] = _Design(
        _info("lowsnr-tbd", "64x64 low-SNR crops (Gaussian noise only); three targets at "
              "sub-pixel speeds present in frames 3-27, 8-17, 13-22 (TBD paper)",
              camtbd, 10.0, 30, 3),
        camtbd, SceneSpec(plain=True, sky_zenith=1000.0, read_noise=20.0), tbd)
    cam50 = FisheyeCamera.filling(480, 320, 30.0, 90.0, 32.0)
    uni = (
        Target(1, _fly(cam50, (60.0, 90.0), (1.6, 0.15), 2000.0, 50.0), snr=12.0, sigma0=0.7,
               kind="aircraft"),
        Target(2, _fly(cam50, (420.0, 240.0), (-1.4, -0.35), 2500.0, 50.0), snr=10.0,
               sigma0=0.7, kind="aircraft"),
    )
    d["uniform-50hz"] = _Design(
        _info("uniform-50hz", "480x320 at 50 Hz over clouds; two aircraft in near-uniform "
              "motion (feature-fusion paper)", cam50, 50.0, 200, 2),
        cam50, SceneSpec(clouds=300.0, sky_zenith=5200.0), uni)
    cam1k = FisheyeCamera.circular(1024, 1024, 0.0, 30.0, offset=(0.4, 0.2))
    slots = tuple(Respawning(s, 4, 360 + 40 * s, 60 * s, 320 + 40 * s - 40, snr=9.0,
                             f_px=cam1k.f_px) for s in range(4))
    d["long-1024"] = _Design(
        _info("long-1024", "long 1024x1024 180° clip over fields with 30 static stars; four "
              "target slots re-spawning on random flights every 360-480 frames",
              cam1k, 25.0, 20_000, 4),
        cam1k, SceneSpec(ground="field", n_stars=30, star_snr=(5.0, 40.0)), slots, lazy=True)
    return d


_DESIGNS = _designs()


def list_scenarios() -> list[ScenarioInfo]:
    """Every scenario's name, one-line description and default numbers."""
    return [d.info for d in _DESIGNS.values()]


def make_scenario(name: str, seed: int = 0, n_frames: int | None = None,
                  snr: float | None = None) -> ScenarioClip:
    """Build scenario ``name``; ``snr`` sets every target's peak SNR, ``n_frames`` its length."""
    if name not in _DESIGNS:
        raise ValueError(f"unknown scenario '{name}' (available: {', '.join(_DESIGNS)})")
    if seed < 0 or (n_frames is not None and n_frames < 1) or (snr is not None and snr <= 0):
        raise ValueError("seed must be >= 0, n_frames >= 1 and snr > 0")
    return ScenarioClip(_DESIGNS[name], seed, n_frames, snr)


def _avi_scale(clip: ScenarioClip) -> tuple[float, float]:
    """Fixed linear 16->8-bit map (offset, gain) from the static background's range."""
    bg = clip.background(0)
    lo, hi = np.percentile(bg, [0.5, 99.9])
    span = max(hi - lo, 1.0)
    return float(lo - 0.05 * span), float(255.0 / (1.3 * span))


def _open_avi(path: Path, fps: float, shape: tuple[int, int]) -> tuple[cv2.VideoWriter, str]:
    """An 8-bit grey AVI writer: lossless FFV1 if available, else MJPG."""
    for codec in ("FFV1", "MJPG"):
        with opencv_name(path) as name:  # the writer has the file open when the link goes
            writer = cv2.VideoWriter(name, cv2.VideoWriter_fourcc(*codec), fps,
                                     (shape[1], shape[0]), isColor=False)
        if writer.isOpened():
            return writer, codec
        writer.release()
    raise OSError(f"OpenCV cannot write an AVI here ({path})")


def write_scenario(clip: ScenarioClip, out_dir: Path, avi: bool = False, *,
                   progress: Callable[[int], None] | None = None) -> Path:
    """Write 16-bit ``frame_NNNNNN.png``, ``truth.csv``, ``meta.json`` (+ ``<name>.avi``).

    ``out_dir`` must be new, empty or written by wfviz before (else :class:`OutputError`,
    nothing touched): everything is written into a temporary sibling folder first and moved
    into ``out_dir`` when complete; of an earlier run's files only those it listed are
    replaced or removed (:mod:`wfviz.synth.folder`). ``progress`` is called with the frames
    written so far. Returns ``out_dir``.
    """

    def fill(tmp: Path) -> None:
        meta, writer = clip.meta(), None
        if avi:
            offset, gain = _avi_scale(clip)
            avi_path = tmp / f"{clip.name}.avi"
            writer, codec = _open_avi(avi_path, clip.fps, clip.shape)
            meta["avi"] = {"file": avi_path.name, "codec": codec, "offset": offset, "gain": gain,
                           "map": "u8 = clip(round((u16 - offset) * gain), 0, 255)"}
        for frame in clip.frames():
            if not write_image(tmp / f"frame_{frame.index:06d}.png", frame.image):
                raise OSError(f"could not write frame {frame.index} to {tmp}")
            if writer is not None:
                u8 = np.clip(np.rint((frame.image - offset) * gain), 0, 255).astype(np.uint8)
                writer.write(u8)
            if progress is not None:
                progress(frame.index + 1)
        if writer is not None:
            writer.release()
            with opencv_name(avi_path) as name:
                cap = cv2.VideoCapture(name)
                count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
                cap.release()
            if count != clip.n_frames:
                raise OSError(f"{avi_path.name}: reads back {count} frames, not {clip.n_frames}")
        with (tmp / "truth.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(TruthRow._fields)
            for r in clip.truth():
                w.writerow([r.frame, r.target_id, f"{r.x:.4f}", f"{r.y:.4f}",
                            f"{r.peak_snr:.4f}", r.visible])
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")

    return write_folder(Path(out_dir), fill, by="wfviz synth", what="the scenario")


#: ``synth:NAME[:SEED]``: a built-in scenario as a clip spec (:func:`wfviz.io.clip.open_clip`)
SYNTH_PREFIX = "synth:"


def synthetic_clip(spec: str, fps: float | None = None) -> ScenarioClip:
    """``synth:NAME`` or ``synth:NAME:SEED``: a built-in scenario rendered lazily, frame by
    frame (nothing written; ``--stop`` shortens it)."""
    name, _, seed = spec[len(SYNTH_PREFIX):].partition(":")
    names = [i.name for i in list_scenarios()]
    if name not in names:
        raise ClipError(f"{spec}: unknown scenario '{name}' (available: {', '.join(names)})")
    if seed and not seed.isdigit():
        raise ClipError(f"{spec}: the seed must be a whole number >= 0, got '{seed}'")
    if fps is not None:
        raise ClipError(f"{spec}: --fps does not apply to a synthetic scenario (its rate is fixed)")
    return make_scenario(name, seed=int(seed or 0))


register_source(SYNTH_PREFIX, synthetic_clip)  # open_clip("synth:...") once wfviz.synth is imported
