"""Configuration of the star-field tracker: frozen dataclasses loaded from TOML by
:func:`wfviz.config.load_config` (sections shared with other trackers live there)."""

from __future__ import annotations

from dataclasses import dataclass, field

from wfviz.config import ConfigError, value_range


@dataclass(frozen=True)
class StarSegmentationConfig:
    """Star-field segmentation: smooth background, matched smoothing, robust k-sigma threshold."""

    background_block: int = field(default=32, metadata=value_range(4, 256))
    background_sigma: float = field(default=4.0, metadata=value_range(0.5, 64.0))
    smooth_sigma: float = field(default=1.0, metadata=value_range(0.0, 5.0))
    k_sigma: float = field(default=4.0, metadata=value_range(0.5, None))
    noise_tile: int = field(default=64, metadata=value_range(0, 1024))
    column_offsets: bool = True
    min_area: int = field(default=2, metadata=value_range(1, None))
    max_area: int = field(default=2000, metadata=value_range(1, None))


@dataclass(frozen=True)
class RegistrationConfig:
    """Frame-to-frame star pairing by distances to two reference stars (mu), robust fallback."""

    mu: float = field(default=1.0, metadata=value_range(0.05, None))
    search_box: int = field(default=64, metadata=value_range(4, 1024))
    reference_separation: float = field(default=200.0, metadata=value_range(1.0, None))
    min_paired_fraction: float = field(default=0.5, metadata=value_range(0.0, 1.0))
    max_rms: float = field(default=0.5, metadata=value_range(0.01, None))
    vote_stars: int = field(default=60, metadata=value_range(3, None))
    fallback: bool = True


@dataclass(frozen=True)
class CandidateConfig:
    """Unpaired points: star-catalogue, sensor-defect and border filters before the chains."""

    star_radius: float = field(default=1.5, metadata=value_range(0.0, None))
    defect_radius: float = field(default=0.75, metadata=value_range(0.0, None))
    defect_frames: int = field(default=3, metadata=value_range(2, None))
    border: float = field(default=3.0, metadata=value_range(0.0, None))


@dataclass(frozen=True)
class ChainConfig:
    """Target chains: three-frame test (v), New/Run/Out lists (N), rejoining (Dis, theta)."""

    v: float = field(default=1.0, metadata=value_range(0.0, None))
    min_speed: float = field(default=0.5, metadata=value_range(0.0, None))
    max_speed: float = field(default=10.0, metadata=value_range(0.1, None))
    max_turn: float = field(default=45.0, metadata=value_range(0.0, 180.0))
    length: int = field(default=4, metadata=value_range(2, None))
    dis: float = field(default=1.0, metadata=value_range(0.0, None))
    theta: float = field(default=30.0, metadata=value_range(0.0, 180.0))
    gate: float = field(default=3.0, metadata=value_range(0.1, None))
    backtrack: int = field(default=4, metadata=value_range(0, 20))


@dataclass(frozen=True)
class ResegmentConfig:
    """Re-segmentation around a Run chain's prediction with a local, lower threshold."""

    enabled: bool = True
    window: int = field(default=15, metadata=value_range(5, 255))
    k_sigma: float = field(default=3.5, metadata=value_range(0.5, None))
    radius: float = field(default=2.0, metadata=value_range(0.1, None))
    references: int = field(default=3, metadata=value_range(0, 10))
    min_offset: float = field(default=4.0, metadata=value_range(0.0, None))
    star_leak: float = field(default=0.005, metadata=value_range(0.0, None))


@dataclass(frozen=True)
class StarKalmanConfig:
    """Constant-velocity Kalman filter of a Run chain (reference-frame px, px/frame)."""

    q: float = field(default=0.01, metadata=value_range(0.0, None))
    r: float = field(default=0.1, metadata=value_range(1e-6, None))
    initial_velocity_std: float = field(default=5.0, metadata=value_range(0.0, None))


@dataclass(frozen=True)
class StarTrackingConfig:
    """Run chains: coasting limit (consecutive predictions) and the trail drawn in the recording."""

    max_misses: int = field(default=10, metadata=value_range(1, None))
    trail_length: int = field(default=60, metadata=value_range(2, None))
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


#: ``wfviz tune``'s default search space (:mod:`wfviz.tune.space`)
SEARCH_SPACE = {
    "segmentation": {"k_sigma": {"low": 3.0, "high": 6.0}},
    "chains": {
        "length": {"low": 3, "high": 8},
        "gate": {"low": 1.5, "high": 6.0},
        "max_turn": {"low": 15.0, "high": 90.0},
    },
    "resegment": {"k_sigma": {"low": 2.5, "high": 5.0}},
    "tracking": {"max_misses": {"low": 3, "high": 20}},
}
