"""Configuration of the feature-fusion Kalman tracker: frozen dataclasses loaded from TOML by
:func:`wfviz.config.load_config` (sections shared with other trackers live there)."""

from __future__ import annotations

from dataclasses import dataclass, field

from wfviz.config import (SHARED_SEARCH_SPACE, ConfigError, DetectionConfig, FrontEndSections, KalmanConfig,
                          TrackingConfig, value_range)


@dataclass(frozen=True)
class FusionFeaturesConfig:
    """Fusion tracker features: centre of the bounding rectangle, area, grey sum."""

    centre: str = field(default="bbox", metadata={"choices": ("bbox", "min_area_rect", "centroid")})
    grey: str = field(default="residual", metadata={"choices": ("residual", "raw")})


@dataclass(frozen=True)
class FusionMatchConfig:
    """Fused feature matching (alpha centre + beta area + gamma grey), windows, re-detection."""

    alpha: float = field(default=0.4, metadata=value_range(0.0, None))
    beta: float = field(default=0.3, metadata=value_range(0.0, None))
    gamma: float = field(default=0.3, metadata=value_range(0.0, None))
    cost: str = field(default="sum", metadata={"choices": ("sum", "scalar")})
    max_cost: float = field(default=1.0, metadata=value_range(0.0, None))
    pad: int = field(default=6, metadata=value_range(0, 64))
    recover_radius: float = field(default=40.0, metadata=value_range(1.0, None))
    recover_max_cost: float = field(default=0.5, metadata=value_range(0.0, None))
    detect_every: int = field(default=10, metadata=value_range(0, None))


@dataclass(frozen=True)
class FusionConfig(FrontEndSections):
    """All stages of the feature-fusion Kalman tracker (Zheng Jia, Li Jiangyong and Chen Gang).
    Its detection has no multi-frame stage by default (``detection.multi_memory`` 0): its fused
    features (a component's box, area and grey sum) are not those of a one-pixel path head, and
    with it real false tracks doubled (docs/accuracy.md, issue 36)."""

    detection: DetectionConfig = DetectionConfig(multi_memory=0.0)
    features: FusionFeaturesConfig = FusionFeaturesConfig()
    fusion: FusionMatchConfig = FusionMatchConfig()
    kalman: KalmanConfig = KalmanConfig()
    tracking: TrackingConfig = TrackingConfig()

    def validate(self) -> None:
        """Cross-field checks (raise ConfigError)."""
        f = self.fusion
        self.kalman.check()
        if f.alpha + f.beta + f.gamma <= 0:
            raise ConfigError("fusion.alpha + fusion.beta + fusion.gamma must be positive")
        t = self.tracking  # GEWC-only options of the shared section
        if getattr(t, "confirm_moving", 0.0) > 0:
            raise ConfigError("tracking.confirm_moving is not supported by the fusion tracker (the "
                              "paper's rule with the GEWC real-footage options); keep 0")
        if getattr(t, "meeting_misses", False):
            raise ConfigError("tracking.meeting_misses is not supported by the fusion tracker "
                              "(it associates in its own search windows)")


#: ``wfviz tune``'s default search space (:mod:`wfviz.tune.space`): detection and the
#: sequential test as for GEWC, and the paper's feature weights (eq. 10)
SEARCH_SPACE = {
    **SHARED_SEARCH_SPACE,
    "fusion": {
        "alpha": {"low": 0.0, "high": 1.0},
        "beta": {"low": 0.0, "high": 1.0},
        "gamma": {"low": 0.0, "high": 1.0},
        "max_cost": {"low": 0.3, "high": 2.0},
    },
    "kalman": {"q": {"low": 0.02, "high": 2.0, "log": True}},
}
