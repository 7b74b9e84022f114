"""Tracker configuration: frozen dataclasses whose defaults are the GEWC paper's values.

Loaded from TOML (``[section] key = value``) and printed back as TOML by ``wfviz config``.
Unknown keys, wrong types and out-of-range values raise :class:`ConfigError` naming the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, get_type_hints


class ConfigError(ValueError):
    """A configuration file or value is invalid (one-line message naming the key)."""


def _range(lo: float | None = None, hi: float | None = None) -> dict[str, Any]:
    return {"range": (lo, hi)}


@dataclass(frozen=True)
class CircleConfig:
    """Imaging circle / non-imaging mask (eq. 1). ``center``/``radius`` None = estimate."""

    center: tuple[float, float] | None = None
    radius: float | None = field(default=None, metadata=_range(1.0, None))
    margin: float = field(default=6.0, metadata=_range(0.0, None))
    enabled: bool = True
    # px at the frame's edge left out of the search (not in the paper): the 5x5 suppression has
    # no neighbours there, and video codecs disturb the outermost rows and columns
    border: int = field(default=2, metadata=_range(0, 64))


@dataclass(frozen=True)
class HorizonConfig:
    """Sky-ground line by multi-direction maximum gradient (eqs. 2-3)."""

    enabled: bool = True
    step: int = field(default=2, metadata=_range(1, 10))
    smooth: int = field(default=3, metadata=_range(1, 15))
    variance_window: int = field(default=9, metadata=_range(3, 51))
    ground_std_min: float = field(default=4.0, metadata=_range(0.0, None))
    position_std_max: float = field(default=4.0, metadata=_range(0.1, None))
    min_coverage: float = field(default=0.3, metadata=_range(0.0, 1.0))
    degree: int = field(default=4, metadata=_range(1, 8))
    max_rise: float = field(default=40.0, metadata=_range(0.0, None))
    every: int = field(default=10, metadata=_range(1, None))
    smoothing: float = field(default=0.5, metadata=_range(0.0, 1.0))
    margin: float = field(default=4.0, metadata=_range(0.0, None))
    exclude_ground: str = field(default="always", metadata={"choices": ("always", "auto", "never")})


@dataclass(frozen=True)
class DefectsConfig:
    """Hot and dead pixels: persistent one-pixel outliers, flagged and replaced by their 3x3 median."""

    enabled: bool = True
    spike_ratio: float = field(default=0.8, metadata=_range(0.0, 1.0))
    rate: float = field(default=0.3, metadata=_range(0.01, 1.0))
    flag_level: float = field(default=0.75, metadata=_range(0.01, 1.0))


@dataclass(frozen=True)
class SuppressionConfig:
    """Background suppression: 5x5 minimum background prediction, positive residual."""

    size: int = field(default=5, metadata=_range(3, 31))
    method: str = field(default="opening", metadata={"choices": ("opening", "erosion")})


@dataclass(frozen=True)
class DetectionConfig:
    """Track start points: adaptive threshold (mean + k*std) and connected components."""

    mode: str = field(default="cfar", metadata={"choices": ("cfar", "global", "local")})
    k_sigma: float = field(default=4.0, metadata=_range(0.0, None))
    local_window: int = field(default=31, metadata=_range(5, 255))
    significance: bool = False
    blob_sigma: float = field(default=1.0, metadata=_range(0.3, 10.0))
    merge_gap: int = field(default=1, metadata=_range(0, 10))
    min_area: int = field(default=1, metadata=_range(1, None))
    max_area: int = field(default=400, metadata=_range(1, None))
    max_detections: int = field(default=200, metadata=_range(1, None))


@dataclass(frozen=True)
class NoiseConfig:
    """Local noise estimate of the residual (wfviz.noise): tile size (px), the weight of the
    previous estimate's tile statistics, and how often (frames) the statistics and tail
    calibrations are re-estimated (every frame after a camera shift of a quarter tile)."""

    tile: int = field(default=32, metadata=_range(8, 256))
    smoothing: float = field(default=0.5, metadata=_range(0.0, 0.99))
    every: int = field(default=4, metadata=_range(1, None))


@dataclass(frozen=True)
class CentroidConfig:
    """Measurement in each prediction window: GEWC (eqs. 4-7) or intensity centroid."""

    method: str = field(default="gewc", metadata={"choices": ("gewc", "intensity", "gewc-weighted",
                                                               "gaussian")})
    window: int = field(default=9, metadata=_range(3, 63))
    gradient_bins: int = field(default=32, metadata=_range(2, 256))
    iterations: int = field(default=2, metadata=_range(1, 10))


@dataclass(frozen=True)
class KalmanConfig:
    """Constant-velocity Kalman filter (eqs. 8-14); units px and frames."""

    q: float = field(default=0.2, metadata=_range(0.0, None))
    r: float = field(default=0.4, metadata=_range(1e-6, None))
    initial_velocity_std: float = field(default=3.0, metadata=_range(0.0, None))
    gate_sigma: float = field(default=3.0, metadata=_range(0.5, None))
    gate_min: float = field(default=3.0, metadata=_range(0.5, None))
    gate_max: float = field(default=15.0, metadata=_range(1.0, None))
    # px: a coasting track whose position uncertainty (gate_sigma std) grows past this is deleted
    coast_limit: float = field(default=45.0, metadata=_range(1.0, None))


@dataclass(frozen=True)
class TrackingConfig:
    """Track management: confirmation, deletion, meeting mode (eq. 15).

    ``confirm``: "sprt" (sequential test, :mod:`wfviz.track_score`; not in the paper) or "hits"
    (the paper: ``confirm_hits`` hits, deleted after ``max_misses`` misses).
    """

    confirm: str = field(default="sprt", metadata={"choices": ("sprt", "hits")})
    false_tracks_per_1000: float = field(default=1.0, metadata=_range(1e-6, 1000.0))
    p_detect: float = field(default=0.9, metadata=_range(0.05, 0.999))
    beta: float = field(default=0.01, metadata=_range(1e-6, 0.5))
    p_lost: float = field(default=0.001, metadata=_range(1e-9, 0.5))
    position_noise: float = field(default=0.3, metadata=_range(0.001, 10.0))
    require_motion: bool = True
    min_motion: float = field(default=2.0, metadata=_range(0.0, None))  # px, net (track_score)
    static_change_rate: float = field(default=0.05, metadata=_range(1e-6, 0.5))
    target_change_rate: float = field(default=0.5, metadata=_range(0.01, 0.999))
    confirm_hits: int = field(default=6, metadata=_range(1, None))
    confirm_significance: float = field(default=0.0, metadata=_range(0.0, None))
    confirm_blobness: float = field(default=0.0, metadata=_range(0.0, 1.0))
    # px; 0: off (not in the paper): a gapless, straight mover needs only confirm_moving_significance
    confirm_moving: float = field(default=0.0, metadata=_range(0.0, None))
    confirm_moving_significance: float = field(default=1.0, metadata=_range(0.0, None))
    confirm_straightness: float = field(default=0.8, metadata=_range(0.0, 1.0))
    reacquire: float = field(default=15.0, metadata=_range(0.0, None))  # px; 0: off (not in the paper)
    # a confirmed track's gate is searched at a lower threshold, such that noise alone crosses
    # it somewhere in the gate with this probability (track_score.gate_threshold); 0: off
    gate_false_alarm: float = field(default=0.0, metadata=_range(0.0, 0.5))
    min_displacement: float = field(default=0.0, metadata=_range(0.0, None))
    max_misses: int = field(default=3, metadata=_range(1, None))
    safety_distance: float = field(default=20.0, metadata=_range(0.0, None))
    max_meeting_frames: int = field(default=40, metadata=_range(1, None))
    meeting_velocity: str = field(default="kalman", metadata={"choices": ("kalman", "eq15")})
    meeting_overlap: bool = False   # meet only when the two gates overlap (not in the paper)
    meeting_misses: bool = False    # meeting mode: no detection near the extrapolation = a miss
    trail_length: int = field(default=60, metadata=_range(2, None))
    # camera motion (wfviz.registration): "auto" measures it every frame and moves the tracks
    # with the scene; "off" assumes a still camera
    compensate_motion: str = field(default="auto", metadata={"choices": ("auto", "off")})


@dataclass(frozen=True)
class ClutterConfig:
    """Static clutter: points fixed in the scene amid many detections (textured ground).

    Not in the paper (docs/pipeline.md §9). A detection is *static* when, in scene coordinates
    (camera motion removed), the background-suppressed image of ``lag`` (±2) frames earlier
    held at least ``persist`` times what this frame's image holds there; where that is not
    decidable (clip start, point outside the frame then), shorter lags k down to ``min_lag``
    (0: none; ±k//5 frames) are tried: across a camera move of ``min_shift`` px they decide
    either way, under a smaller one only "not static". It is *crowded* when at least ``min_neighbours`` other
    detections lie within ``neighbourhood`` px (0: anywhere in the frame). Detections ``bright``
    times above the threshold or more are never clutter. A track whose crowded hits are mostly
    static (mean above ``max_static`` after ``min_known`` decided hits: a plain mean while that
    weighs more than ``memory``, then a running one with weight ``memory``) is not confirmed, and a confirmed one is deleted when its
    mean exceeds ``delete_static``.
    ``wait``: hold confirmation until decided.
    """

    enabled: bool = False
    lag: int = field(default=10, metadata=_range(2, 100))
    min_lag: int = field(default=3, metadata=_range(0, 100))
    min_shift: float = field(default=3.0, metadata=_range(0.0, None))
    persist: float = field(default=0.35, metadata=_range(0.0, None))
    neighbourhood: float = field(default=0.0, metadata=_range(0.0, None))
    min_neighbours: int = field(default=10, metadata=_range(1, None))
    bright: float = field(default=4.0, metadata=_range(0.0, None))
    max_static: float = field(default=0.5, metadata=_range(0.0, 1.0))
    delete_static: float = field(default=0.8, metadata=_range(0.0, 1.0))
    min_known: int = field(default=2, metadata=_range(1, None))
    memory: float = field(default=0.1, metadata=_range(0.01, 1.0))
    wait: bool = True


@dataclass(frozen=True)
class GEWCConfig:
    """All stages of the GEWC wide-field tracker."""

    defects: DefectsConfig = DefectsConfig()
    circle: CircleConfig = CircleConfig()
    horizon: HorizonConfig = HorizonConfig()
    suppression: SuppressionConfig = SuppressionConfig()
    noise: NoiseConfig = NoiseConfig()
    detection: DetectionConfig = DetectionConfig()
    centroid: CentroidConfig = CentroidConfig()
    kalman: KalmanConfig = KalmanConfig()
    tracking: TrackingConfig = TrackingConfig()
    clutter: ClutterConfig = ClutterConfig()

    def validate(self) -> None:
        """Cross-field checks (raise ConfigError)."""
        k = self.kalman
        if k.gate_min > k.gate_max:
            raise ConfigError(f"kalman.gate_min ({k.gate_min}) must not exceed kalman.gate_max ({k.gate_max})")
        c = self.clutter
        if c.min_lag > c.lag:
            raise ConfigError(f"clutter.min_lag ({c.min_lag}) must not exceed clutter.lag ({c.lag})")
        if c.delete_static < c.max_static:
            raise ConfigError(f"clutter.delete_static ({c.delete_static}) must not be below "
                              f"clutter.max_static ({c.max_static})")


@dataclass(frozen=True)
class FusionFeaturesConfig:
    """Fusion tracker features: centre of the bounding rectangle, area, grey sum."""

    centre: str = field(default="bbox", metadata={"choices": ("bbox", "min_area_rect", "centroid")})
    grey: str = field(default="residual", metadata={"choices": ("residual", "raw")})


@dataclass(frozen=True)
class FusionMatchConfig:
    """Fused feature matching (alpha centre + beta area + gamma grey), windows, re-detection."""

    alpha: float = field(default=0.4, metadata=_range(0.0, None))
    beta: float = field(default=0.3, metadata=_range(0.0, None))
    gamma: float = field(default=0.3, metadata=_range(0.0, None))
    cost: str = field(default="sum", metadata={"choices": ("sum", "scalar")})
    max_cost: float = field(default=1.0, metadata=_range(0.0, None))
    pad: int = field(default=6, metadata=_range(0, 64))
    recover_radius: float = field(default=40.0, metadata=_range(1.0, None))
    recover_max_cost: float = field(default=0.5, metadata=_range(0.0, None))
    detect_every: int = field(default=10, metadata=_range(0, None))


@dataclass(frozen=True)
class FusionConfig:
    """All stages of the feature-fusion Kalman tracker (Zheng Jia, Li Jiangyong and Chen Gang)."""

    defects: DefectsConfig = DefectsConfig()
    circle: CircleConfig = CircleConfig()
    horizon: HorizonConfig = HorizonConfig()
    suppression: SuppressionConfig = SuppressionConfig()
    noise: NoiseConfig = NoiseConfig()
    detection: DetectionConfig = DetectionConfig()
    features: FusionFeaturesConfig = FusionFeaturesConfig()
    fusion: FusionMatchConfig = FusionMatchConfig()
    kalman: KalmanConfig = KalmanConfig()
    tracking: TrackingConfig = TrackingConfig()

    def validate(self) -> None:
        """Cross-field checks (raise ConfigError)."""
        k, f = self.kalman, self.fusion
        if k.gate_min > k.gate_max:
            raise ConfigError(f"kalman.gate_min ({k.gate_min}) must not exceed kalman.gate_max ({k.gate_max})")
        if f.alpha + f.beta + f.gamma <= 0:
            raise ConfigError("fusion.alpha + fusion.beta + fusion.gamma must be positive")
        t = self.tracking  # GEWC-only options of the shared section
        if getattr(t, "confirm_moving", 0.0) > 0:
            raise ConfigError("tracking.confirm_moving is not supported by the fusion tracker (the "
                              "paper's rule with the GEWC real-footage options); keep 0")
        if getattr(t, "meeting_misses", False):
            raise ConfigError("tracking.meeting_misses is not supported by the fusion tracker "
                              "(it associates in its own search windows)")


@dataclass(frozen=True)
class StarSegmentationConfig:
    """Star-field segmentation: smooth background, matched smoothing, robust k-sigma threshold."""

    background_block: int = field(default=32, metadata=_range(4, 256))
    background_sigma: float = field(default=4.0, metadata=_range(0.5, 64.0))
    smooth_sigma: float = field(default=1.0, metadata=_range(0.0, 5.0))
    k_sigma: float = field(default=4.0, metadata=_range(0.5, None))
    noise_tile: int = field(default=64, metadata=_range(0, 1024))
    column_offsets: bool = True
    min_area: int = field(default=2, metadata=_range(1, None))
    max_area: int = field(default=2000, metadata=_range(1, None))


@dataclass(frozen=True)
class RegistrationConfig:
    """Frame-to-frame star pairing by distances to two reference stars (mu), robust fallback."""

    mu: float = field(default=1.0, metadata=_range(0.05, None))
    search_box: int = field(default=64, metadata=_range(4, 1024))
    reference_separation: float = field(default=200.0, metadata=_range(1.0, None))
    min_paired_fraction: float = field(default=0.5, metadata=_range(0.0, 1.0))
    max_rms: float = field(default=0.5, metadata=_range(0.01, None))
    vote_stars: int = field(default=60, metadata=_range(3, None))
    fallback: bool = True


@dataclass(frozen=True)
class CandidateConfig:
    """Unpaired points: star-catalogue, sensor-defect and border filters before the chains."""

    star_radius: float = field(default=1.5, metadata=_range(0.0, None))
    defect_radius: float = field(default=0.75, metadata=_range(0.0, None))
    defect_frames: int = field(default=3, metadata=_range(2, None))
    border: float = field(default=3.0, metadata=_range(0.0, None))


@dataclass(frozen=True)
class ChainConfig:
    """Target chains: three-frame test (v), New/Run/Out lists (N), rejoining (Dis, theta)."""

    v: float = field(default=1.0, metadata=_range(0.0, None))
    min_speed: float = field(default=0.5, metadata=_range(0.0, None))
    max_speed: float = field(default=10.0, metadata=_range(0.1, None))
    max_turn: float = field(default=45.0, metadata=_range(0.0, 180.0))
    length: int = field(default=4, metadata=_range(2, None))
    dis: float = field(default=1.0, metadata=_range(0.0, None))
    theta: float = field(default=30.0, metadata=_range(0.0, 180.0))
    gate: float = field(default=3.0, metadata=_range(0.1, None))
    backtrack: int = field(default=4, metadata=_range(0, 20))


@dataclass(frozen=True)
class ResegmentConfig:
    """Re-segmentation around a Run chain's prediction with a local, lower threshold."""

    enabled: bool = True
    window: int = field(default=15, metadata=_range(5, 255))
    k_sigma: float = field(default=3.5, metadata=_range(0.5, None))
    radius: float = field(default=2.0, metadata=_range(0.1, None))
    references: int = field(default=3, metadata=_range(0, 10))
    min_offset: float = field(default=4.0, metadata=_range(0.0, None))
    star_leak: float = field(default=0.005, metadata=_range(0.0, None))


@dataclass(frozen=True)
class StarKalmanConfig:
    """Constant-velocity Kalman filter of a Run chain (reference-frame px, px/frame)."""

    q: float = field(default=0.01, metadata=_range(0.0, None))
    r: float = field(default=0.1, metadata=_range(1e-6, None))
    initial_velocity_std: float = field(default=5.0, metadata=_range(0.0, None))


@dataclass(frozen=True)
class StarTrackingConfig:
    """Run chains: coasting limit (consecutive predictions) and the trail drawn in the recording."""

    max_misses: int = field(default=10, metadata=_range(1, None))
    trail_length: int = field(default=60, metadata=_range(2, None))
    compensate_motion: bool = False


@dataclass(frozen=True)
class StarfieldConfig:
    """All stages of the star-field tracker (Gao Jianwei et al. 2012)."""

    segmentation: StarSegmentationConfig = StarSegmentationConfig()
    registration: RegistrationConfig = RegistrationConfig()
    candidates: CandidateConfig = CandidateConfig()
    chains: ChainConfig = ChainConfig()
    resegment: ResegmentConfig = ResegmentConfig()
    kalman: StarKalmanConfig = StarKalmanConfig()
    tracking: StarTrackingConfig = StarTrackingConfig()

    def validate(self) -> None:
        """Cross-field checks (raise ConfigError)."""
        c, s = self.chains, self.segmentation
        if c.min_speed > c.max_speed:
            raise ConfigError(f"chains.min_speed ({c.min_speed}) must not exceed chains.max_speed ({c.max_speed})")
        if s.min_area > s.max_area:
            raise ConfigError(f"segmentation.min_area ({s.min_area}) must not exceed segmentation.max_area ({s.max_area})")



@dataclass(frozen=True)
class TBDModelConfig:
    """Track-before-detect model: constant-velocity targets, truncated Gaussian PSF, amplitude prior.

    ``psf_sigma``: PSF width (px; configured, the likelihood and matched filter use it).
    ``background``: "temporal" (auto) per-pixel running background + per-tile noise
    (:mod:`wfviz.tbd.background`); "global"/"local" single-frame estimates.
    ``background_memory``: frames of the running background (rate 1/k before).
    ``background_clip``: each background update clipped at this many of its std.
    ``noise_tile``: tile (px) of the noise sigma from frame differences.
    ``noise_memory``: frames over which the tile noise variance is averaged.
    ``hot_pixel_k``: a pixel whose background is this many sigma (or texture spreads) off its
    3 x 3 median is excluded from the likelihood.
    ``background_coherence``: frames over which the background's error counts coherently.
    """

    psf_sigma: float = field(default=0.8, metadata=_range(0.3, 5.0))
    patch_radius: int = field(default=2, metadata=_range(1, 8))
    process_noise: float = field(default=0.05, metadata=_range(0.0, 5.0))
    max_speed: float | None = field(default=None, metadata=_range(0.0, 20.0))
    amplitude_mean: float = field(default=4.0, metadata=_range(0.0, None))
    amplitude_std: float = field(default=3.0, metadata=_range(0.1, None))
    amplitude_min: float = field(default=1.0, metadata=_range(0.0, None))
    amplitude_walk: float = field(default=0.1, metadata=_range(0.0, None))
    background: str = field(default="auto", metadata={"choices": ("auto", "temporal", "global", "local")})
    background_window: int = field(default=9, metadata=_range(3, 255))
    noise_window: int = field(default=31, metadata=_range(5, 255))
    remove_spikes: bool = True
    background_memory: float = field(default=64.0, metadata=_range(2.0, 1e6))
    background_clip: float = field(default=2.5, metadata=_range(0.5, 100.0))
    noise_tile: int = field(default=16, metadata=_range(4, 256))
    noise_memory: float = field(default=32.0, metadata=_range(1.0, 1e6))
    hot_pixel_k: float = field(default=8.0, metadata=_range(2.0, 1e6))
    background_coherence: float = field(default=10.0, metadata=_range(1.0, 1e6))


@dataclass(frozen=True)
class TBDFilterConfig:
    """Particle filters PF_0..PF_max_targets: birth/continuation/death set sizes, count transition, seed."""

    max_targets: int = field(default=3, metadata=_range(1, 6))
    birth_particles: int = field(default=500, metadata=_range(1, None))
    continuation_particles: int = field(default=1000, metadata=_range(1, None))
    death_particles: int = field(default=250, metadata=_range(1, None))
    p_birth: float = field(default=0.002, metadata=_range(0.0, 0.5))
    p_death: float = field(default=0.1, metadata=_range(0.0, 0.5))
    birth_uniform: float = field(default=0.2, metadata=_range(0.0, 1.0))
    seed: int = field(default=0, metadata=_range(0, None))


@dataclass(frozen=True)
class TBDRegionConfig:
    """Where the filters run: the whole frame, fixed tiles, or windows around candidates."""

    mode: str = field(default="auto", metadata={"choices": ("auto", "full", "tiles", "candidates")})
    search: str = field(default="auto", metadata={"choices": ("auto", "all", "sky")})
    full_max_pixels: int = field(default=16384, metadata=_range(64, None))
    tile: int = field(default=64, metadata=_range(8, 1024))
    tile_overlap: int = field(default=8, metadata=_range(0, 512))
    window: int = field(default=32, metadata=_range(8, 1024))
    max_windows: int = field(default=8, metadata=_range(1, 256))
    candidate_k: float = field(default=4.5, metadata=_range(0.0, None))
    candidate_memory: float = field(default=0.3, metadata=_range(0.01, 1.0))
    clutter_max: float = field(default=1.5, metadata=_range(1.0, None))
    close_p0: float = field(default=0.9, metadata=_range(0.0, 1.0))
    close_after: int = field(default=5, metadata=_range(1, None))


@dataclass(frozen=True)
class TBDTrackingConfig:
    """Track ids from the estimated states, tentative tracks, what the recording shows."""

    id_gate: float = field(default=3.0, metadata=_range(0.1, None))
    id_memory: int = field(default=5, metadata=_range(0, None))
    tentative_p: float = field(default=0.2, metadata=_range(0.0, 1.0))
    merge_distance: float = field(default=2.0, metadata=_range(0.0, None))
    particles_shown: int = field(default=300, metadata=_range(0, None))
    trail_length: int = field(default=60, metadata=_range(2, None))


@dataclass(frozen=True)
class TBDConfig:
    """All stages of the multi-target particle-filter track-before-detect tracker (Wang Hongbo and
    Wang Zhongwei)."""

    model: TBDModelConfig = TBDModelConfig()
    filter: TBDFilterConfig = TBDFilterConfig()
    regions: TBDRegionConfig = TBDRegionConfig()
    tracking: TBDTrackingConfig = TBDTrackingConfig()
    circle: CircleConfig = CircleConfig()
    horizon: HorizonConfig = HorizonConfig()

    def validate(self) -> None:
        """Cross-field checks (raise ConfigError)."""
        r, f, m = self.regions, self.filter, self.model
        if r.tile_overlap >= r.tile:
            raise ConfigError(f"regions.tile_overlap ({r.tile_overlap}) must be smaller than regions.tile ({r.tile})")
        if f.p_birth + f.p_death > 1.0:
            raise ConfigError("filter.p_birth + filter.p_death must not exceed 1")
        side = 2 * m.patch_radius + 1
        if min(r.tile, r.window) < side:
            raise ConfigError(f"regions.tile and regions.window must be at least the PSF patch "
                              f"(2 * model.patch_radius + 1 = {side} px)")


def _closest(name: str, options: list[str]) -> str:
    match = difflib.get_close_matches(name, options, n=1)
    return f" (did you mean '{match[0]}'?)" if match else f" (known: {', '.join(options)})"


SANE_LIMIT = 1e9  # bound of every parameter whose range is open: larger values overflow stages


def _finite(value: int | float) -> bool:
    """Whether ``value`` is a finite float (huge integers overflow: not finite)."""
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _coerce(key: str, value: Any, hint: Any, meta: dict[str, Any]) -> Any:
    """Check ``value`` against the field's type hint and metadata; return the typed value."""
    text = str(hint)
    if "tuple" in text:
        if value is None or (isinstance(value, str) and value == "auto"):
            return None
        if not (isinstance(value, list) and len(value) == 2
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) and _finite(v)
                        for v in value)):
            raise ConfigError(f"{key}: expected [x, y] (two finite numbers) or \"auto\", got {value!r}")
        return (float(value[0]), float(value[1]))
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise ConfigError(f"{key}: '{value}' is not one of {', '.join(choices)}")
        return value
    optional = "None" in text
    if optional and (value is None or value == "auto"):
        return None
    want_int = hint is int
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{key}: expected {'an integer' if want_int else 'a number'}, got {value!r}")
    lo, hi = meta.get("range", (None, None))
    accepted = f"[{lo if lo is not None else '-1e9'}, {hi if hi is not None else '1e9'}]"
    lo = -SANE_LIMIT if lo is None else lo  # open ends: no parameter is sane beyond 1e9
    hi = SANE_LIMIT if hi is None else hi
    if not _finite(value):
        if isinstance(value, int):  # too large for a float
            raise ConfigError(f"{key}: {str(value)[:8]}... ({len(str(value))} digits) is out of "
                              f"range {accepted}")
        raise ConfigError(f"{key}: expected a finite number, got {value!r}")
    if want_int and not float(value).is_integer():
        raise ConfigError(f"{key}: expected an integer, got {value!r}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ConfigError(f"{key}: {value!r} is out of range {accepted}")
    return int(value) if want_int else float(value)


def _build(cls: type, data: dict[str, Any], prefix: str) -> Any:
    hints = get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        where = f"{prefix}{key}"
        if key not in names:
            raise ConfigError(f"unknown key '{where}'{_closest(key, names)}")
        f = next(f for f in fields(cls) if f.name == key)
        hint = hints[key]
        if dataclasses.is_dataclass(hint):
            if not isinstance(value, dict):
                raise ConfigError(f"{where}: expected a [{where}] table, got {value!r}")
            kwargs[key] = _build(hint, value, f"{where}.")
        else:
            kwargs[key] = _coerce(where, value, hint, dict(f.metadata))
    return cls(**kwargs)


def config_from_dict(data: dict[str, Any], cls: type = GEWCConfig) -> Any:
    """Build a ``cls`` config (default GEWC) from nested dicts as parsed from TOML, validating
    every key; a ``validate()`` method on the config class checks cross-field rules."""
    config = _build(cls, data, "")
    check = getattr(config, "validate", None)
    if check is not None:
        check()
    return config


def load_config(path: str | Path | None, cls: type = GEWCConfig) -> Any:
    """Load a TOML config file for ``cls``; None gives the defaults."""
    if path is None:
        return cls()
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a BOM, as some editors save
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a config file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    try:
        return config_from_dict(data, cls)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def config_to_toml(config: Any) -> str:
    """Render a config as TOML; None values are written as ``"auto"``."""
    lines: list[str] = []
    for section in fields(config):
        sub = getattr(config, section.name)
        lines.append(f"[{section.name}]")
        doc = (type(sub).__doc__ or "").strip().splitlines()[0]
        lines.insert(len(lines) - 1, f"# {doc}")
        for f in fields(sub):
            value = getattr(sub, f.name)
            text = _toml_value(value) if value is not None else '"auto"'
            lines.append(f"{f.name} = {text}")
        lines.append("")
    return "\n".join(lines)
