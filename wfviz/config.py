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


@dataclass(frozen=True)
class DefectsConfig:
    """Hot pixels: persistent one-pixel spikes, flagged and replaced by their 3x3 median."""

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

    mode: str = field(default="global", metadata={"choices": ("global", "local")})
    k_sigma: float = field(default=4.0, metadata=_range(0.0, None))
    local_window: int = field(default=31, metadata=_range(5, 255))
    merge_gap: int = field(default=1, metadata=_range(0, 10))
    min_area: int = field(default=1, metadata=_range(1, None))
    max_area: int = field(default=400, metadata=_range(1, None))
    max_detections: int = field(default=200, metadata=_range(1, None))


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


@dataclass(frozen=True)
class TrackingConfig:
    """Track management: confirmation, deletion, meeting mode (eq. 15)."""

    confirm_hits: int = field(default=6, metadata=_range(1, None))
    max_misses: int = field(default=3, metadata=_range(1, None))
    safety_distance: float = field(default=20.0, metadata=_range(0.0, None))
    max_meeting_frames: int = field(default=40, metadata=_range(1, None))
    meeting_velocity: str = field(default="kalman", metadata={"choices": ("kalman", "eq15")})
    trail_length: int = field(default=60, metadata=_range(2, None))


@dataclass(frozen=True)
class GEWCConfig:
    """All stages of the GEWC wide-field tracker."""

    defects: DefectsConfig = DefectsConfig()
    circle: CircleConfig = CircleConfig()
    horizon: HorizonConfig = HorizonConfig()
    suppression: SuppressionConfig = SuppressionConfig()
    detection: DetectionConfig = DetectionConfig()
    centroid: CentroidConfig = CentroidConfig()
    kalman: KalmanConfig = KalmanConfig()
    tracking: TrackingConfig = TrackingConfig()

    def validate(self) -> None:
        """Cross-field checks (raise ConfigError)."""
        k = self.kalman
        if k.gate_min > k.gate_max:
            raise ConfigError(f"kalman.gate_min ({k.gate_min}) must not exceed kalman.gate_max ({k.gate_max})")


def _closest(name: str, options: list[str]) -> str:
    match = difflib.get_close_matches(name, options, n=1)
    return f" (did you mean '{match[0]}'?)" if match else f" (known: {', '.join(options)})"


def _coerce(key: str, value: Any, hint: Any, meta: dict[str, Any]) -> Any:
    """Check ``value`` against the field's type hint and metadata; return the typed value."""
    text = str(hint)
    if "tuple" in text:
        if value is None or (isinstance(value, str) and value == "auto"):
            return None
        if not (isinstance(value, list) and len(value) == 2
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
            raise ConfigError(f"{key}: expected [x, y] (two numbers) or \"auto\", got {value!r}")
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
    if want_int and not float(value).is_integer():
        raise ConfigError(f"{key}: expected an integer, got {value!r}")
    if not math.isfinite(float(value)):
        raise ConfigError(f"{key}: expected a finite number, got {value!r}")
    lo, hi = meta.get("range", (None, None))
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        accepted = f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
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
        data = tomllib.loads(path.read_text(encoding="utf-8"))
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
