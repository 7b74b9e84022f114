"""Configuration of the GEWC wide-field tracker: frozen dataclasses loaded from TOML by
:func:`wfviz.config.load_config` (sections shared with other trackers live there)."""

from __future__ import annotations

from dataclasses import dataclass, field

from wfviz.config import (SHARED_SEARCH_SPACE, ClutterConfig, ConfigError, FrontEndSections, KalmanConfig,
                          TrackingConfig, value_range)


@dataclass(frozen=True)
class CentroidConfig:
    """Measurement in each prediction window: GEWC (eqs. 4-7) or intensity centroid."""

    method: str = field(default="gewc", metadata={"choices": ("gewc", "intensity", "gewc-weighted",
                                                               "gaussian")})
    window: int = field(default=9, metadata=value_range(3, 63))
    gradient_bins: int = field(default=32, metadata=value_range(2, 256))
    iterations: int = field(default=2, metadata=value_range(1, 10))


@dataclass(frozen=True)
class GEWCConfig(FrontEndSections):
    """All stages of the GEWC wide-field tracker."""

    centroid: CentroidConfig = CentroidConfig()
    kalman: KalmanConfig = KalmanConfig()
    tracking: TrackingConfig = TrackingConfig()
    clutter: ClutterConfig = ClutterConfig()

    def validate(self) -> None:
        """Cross-field checks (raise ConfigError)."""
        self.kalman.check()
        c = self.clutter
        if c.min_lag > c.lag:
            raise ConfigError(f"clutter.min_lag ({c.min_lag}) must not exceed clutter.lag ({c.lag})")
        if c.delete_static < c.max_static:
            raise ConfigError(f"clutter.delete_static ({c.delete_static}) must not be below "
                              f"clutter.max_static ({c.max_static})")


#: ``wfviz tune``'s default search space (the TOML form, :mod:`wfviz.tune.space`): the values
#: that move the detection/false-track trade-off most; the rest are the papers' or measured
SEARCH_SPACE = {
    **SHARED_SEARCH_SPACE,
    "tracking": {
        **SHARED_SEARCH_SPACE["tracking"],
        "static_change_rate": {"low": 0.01, "high": 0.3, "log": True},
        "target_change_rate": {"low": 0.2, "high": 0.9},
    },
    "kalman": {
        "q": {"low": 0.02, "high": 2.0, "log": True},
        "r": {"low": 0.05, "high": 2.0, "log": True},
        "gate_max": {"low": 8.0, "high": 30.0},
    },
}
