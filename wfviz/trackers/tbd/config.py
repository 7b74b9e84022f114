"""Configuration of the particle-filter track-before-detect tracker: frozen dataclasses loaded from TOML by
:func:`wfviz.config.load_config` (sections shared with other trackers live there)."""

from __future__ import annotations

from dataclasses import dataclass, field

from wfviz.config import CircleConfig, ConfigError, HorizonConfig, value_range


@dataclass(frozen=True)
class TBDModelConfig:
    """Track-before-detect model: constant-velocity targets, truncated Gaussian PSF, amplitude prior.

    ``psf_sigma``: PSF width (px; configured, the likelihood and matched filter use it).
    ``background``: "temporal" (auto) per-pixel running background + per-tile noise
    (:mod:`wfviz.trackers.tbd.background`); "global"/"local" single-frame estimates.
    ``background_memory``: frames of the running background (rate 1/k before).
    ``background_clip``: each background update clipped at this many of its std.
    ``noise_tile``: tile (px) of the noise sigma from frame differences.
    ``noise_memory``: frames over which the tile noise variance is averaged.
    ``hot_pixel_k``: a pixel whose background is this many sigma (or texture spreads) off its
    3 x 3 median is excluded from the likelihood.
    ``background_coherence``: frames over which the background's error counts coherently.
    """

    psf_sigma: float = field(default=0.8, metadata=value_range(0.3, 5.0))
    patch_radius: int = field(default=2, metadata=value_range(1, 8))
    process_noise: float = field(default=0.05, metadata=value_range(0.0, 5.0))
    max_speed: float | None = field(default=None, metadata=value_range(0.0, 20.0))
    amplitude_mean: float = field(default=4.0, metadata=value_range(0.0, None))
    amplitude_std: float = field(default=3.0, metadata=value_range(0.1, None))
    amplitude_min: float = field(default=1.0, metadata=value_range(0.0, None))
    amplitude_walk: float = field(default=0.1, metadata=value_range(0.0, None))
    background: str = field(default="auto", metadata={"choices": ("auto", "temporal", "global", "local")})
    background_window: int = field(default=9, metadata=value_range(3, 255))
    noise_window: int = field(default=31, metadata=value_range(5, 255))
    remove_spikes: bool = True
    background_memory: float = field(default=64.0, metadata=value_range(2.0, 1e6))
    background_clip: float = field(default=2.5, metadata=value_range(0.5, 100.0))
    noise_tile: int = field(default=16, metadata=value_range(4, 256))
    noise_memory: float = field(default=32.0, metadata=value_range(1.0, 1e6))
    hot_pixel_k: float = field(default=8.0, metadata=value_range(2.0, 1e6))
    background_coherence: float = field(default=10.0, metadata=value_range(1.0, 1e6))


@dataclass(frozen=True)
class TBDFilterConfig:
    """Particle filters PF_0..PF_max_targets: birth/continuation/death set sizes, count transition, seed."""

    max_targets: int = field(default=3, metadata=value_range(1, 6))
    birth_particles: int = field(default=500, metadata=value_range(1, None))
    continuation_particles: int = field(default=1000, metadata=value_range(1, None))
    death_particles: int = field(default=250, metadata=value_range(1, None))
    p_birth: float = field(default=0.002, metadata=value_range(0.0, 0.5))
    p_death: float = field(default=0.1, metadata=value_range(0.0, 0.5))
    birth_uniform: float = field(default=0.2, metadata=value_range(0.0, 1.0))
    seed: int = field(default=0, metadata=value_range(0, None))


@dataclass(frozen=True)
class TBDRegionConfig:
    """Where the filters run: the whole frame, fixed tiles, or windows around candidates."""

    mode: str = field(default="auto", metadata={"choices": ("auto", "full", "tiles", "candidates")})
    search: str = field(default="auto", metadata={"choices": ("auto", "all", "sky")})
    full_max_pixels: int = field(default=16384, metadata=value_range(64, None))
    tile: int = field(default=64, metadata=value_range(8, 1024))
    tile_overlap: int = field(default=8, metadata=value_range(0, 512))
    window: int = field(default=32, metadata=value_range(8, 1024))
    max_windows: int = field(default=8, metadata=value_range(1, 256))
    candidate_k: float = field(default=4.5, metadata=value_range(0.0, None))
    candidate_memory: float = field(default=0.3, metadata=value_range(0.01, 1.0))
    clutter_max: float = field(default=1.5, metadata=value_range(1.0, None))
    close_p0: float = field(default=0.9, metadata=value_range(0.0, 1.0))
    close_after: int = field(default=5, metadata=value_range(1, None))


@dataclass(frozen=True)
class TBDTrackingConfig:
    """Track ids from the estimated states, tentative tracks, what the recording shows."""

    id_gate: float = field(default=3.0, metadata=value_range(0.1, None))
    id_memory: int = field(default=5, metadata=value_range(0, None))
    tentative_p: float = field(default=0.2, metadata=value_range(0.0, 1.0))
    merge_distance: float = field(default=2.0, metadata=value_range(0.0, None))
    particles_shown: int = field(default=300, metadata=value_range(0, None))
    trail_length: int = field(default=60, metadata=value_range(2, None))


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


#: ``wfviz tune``'s default search space (:mod:`wfviz.tune.space`)
SEARCH_SPACE = {
    "model": {"amplitude_mean": {"low": 2.0, "high": 8.0}, "process_noise": {"low": 0.005, "high": 0.5, "log": True}},
    "filter": {
        "p_birth": {"low": 1e-4, "high": 0.02, "log": True},
        "p_death": {"low": 0.01, "high": 0.3, "log": True},
    },
    "regions": {"candidate_k": {"low": 3.0, "high": 6.0}},
    "tracking": {"tentative_p": {"low": 0.05, "high": 0.5}},
}
