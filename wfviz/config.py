"""Tracker configuration: frozen dataclasses whose defaults are the GEWC paper's values.

Loaded from TOML (``[section] key = value``) and printed back as TOML by ``wfviz config``.
Unknown keys, wrong types and out-of-range values raise :class:`ConfigError` naming the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import stat
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, get_type_hints


class ConfigError(ValueError):
    """A configuration file or value is invalid (one-line message naming the key)."""


def value_range(lo: float | None = None, hi: float | None = None) -> dict[str, Any]:
    """Field metadata: the inclusive bounds (None: open) a loaded value is checked against."""
    return {"range": (lo, hi)}


@dataclass(frozen=True)
class CircleConfig:
    """Imaging circle / non-imaging mask (eq. 1). ``center``/``radius`` None = estimate."""

    center: tuple[float, float] | None = None
    radius: float | None = field(default=None, metadata=value_range(1.0, None))
    margin: float = field(default=6.0, metadata=value_range(0.0, None))
    enabled: bool = True
    # px at the frame's edge left out of the search (not in the paper): the 5x5 suppression has
    # no neighbours there, and video codecs disturb the outermost rows and columns
    border: int = field(default=2, metadata=value_range(0, 64))


@dataclass(frozen=True)
class HorizonConfig:
    """Sky-ground line by multi-direction maximum gradient (eqs. 2-3)."""

    enabled: bool = True
    step: int = field(default=2, metadata=value_range(1, 10))
    smooth: int = field(default=3, metadata=value_range(1, 15))
    variance_window: int = field(default=9, metadata=value_range(3, 51))
    ground_std_min: float = field(default=4.0, metadata=value_range(0.0, None))
    position_std_max: float = field(default=4.0, metadata=value_range(0.1, None))
    min_coverage: float = field(default=0.3, metadata=value_range(0.0, 1.0))
    degree: int = field(default=4, metadata=value_range(1, 8))
    max_rise: float = field(default=40.0, metadata=value_range(0.0, None))
    every: int = field(default=10, metadata=value_range(1, None))
    smoothing: float = field(default=0.5, metadata=value_range(0.0, 1.0))
    margin: float = field(default=4.0, metadata=value_range(0.0, None))
    exclude_ground: str = field(default="always", metadata={"choices": ("always", "auto", "never")})


@dataclass(frozen=True)
class DefectsConfig:
    """Hot and dead pixels: one-pixel outliers that stay at the same sensor position over many
    frames (their time-averaged deviation from the 3x3 median), replaced by their 3x3 median."""

    enabled: bool = True
    # weight of this frame in the time averages (1 / rate: about the frames remembered)
    rate: float = field(default=0.3, metadata=value_range(0.01, 1.0))
    # the average deviation is at least this many times its spread over time
    steady: float = field(default=3.0, metadata=value_range(0.0, None))
    # ... and at least this fraction of its height above the darkest pixel of its 5x5
    # neighbourhood (below the brightest: dead) in the frames' time average
    sharp: float = field(default=0.5, metadata=value_range(0.0, 1.0))
    # ... and at least this many times the mean step between adjacent pixels of the 7x7
    # neighbourhood (the pixel itself left out) in the frames' time average
    contrast: float = field(default=6.0, metadata=value_range(0.0, None))
    # ... and above level + k_sigma local noise σ (the "cfar" detection's typical threshold at
    # this k); global/local detection: the detection's own threshold
    k_sigma: float = field(default=4.0, metadata=value_range(0.0, None))


@dataclass(frozen=True)
class SuppressionConfig:
    """Background suppression: 5x5 minimum background prediction, positive residual."""

    size: int = field(default=5, metadata=value_range(3, 31))
    method: str = field(default="opening", metadata={"choices": ("opening", "erosion")})


@dataclass(frozen=True)
class DetectionConfig:
    """Track start points: adaptive threshold (mean + k*std) and connected components."""

    mode: str = field(default="cfar", metadata={"choices": ("cfar", "global", "local")})
    k_sigma: float = field(default=4.0, metadata=value_range(0.0, None))
    local_window: int = field(default=31, metadata=value_range(5, 255))
    significance: bool = False
    blob_sigma: float = field(default=1.0, metadata=value_range(0.3, 10.0))
    merge_gap: int = field(default=1, metadata=value_range(0, 10))
    min_area: int = field(default=1, metadata=value_range(1, None))
    max_area: int = field(default=400, metadata=value_range(1, None))
    max_detections: int = field(default=200, metadata=value_range(1, None))
    # a detection whose linearity (wfviz.stages.detection.linearity: the share of its contrast
    # that carries on along a line or an edge) exceeds this is line-like: it starts no track and
    # its hits count as static clutter (not in the paper); 1: off
    max_linearity: float = field(default=0.45, metadata=value_range(0.0, 1.0))
    # multi-frame detection (not in the paper; wfviz.stages.multiframe): the change significance
    # integrated along every path moving up to 1 px a frame, with this memory λ per frame (an
    # effective 1 / (1 - λ) frames; 0: off), each frame's value clipped to ±multi_clip σ; path
    # heads above k_sigma are detected, their hits keep tracks on their targets without evidence
    multi_memory: float = field(default=0.85, metadata=value_range(0.0, 0.99))
    multi_clip: float = field(default=3.0, metadata=value_range(0.5, 20.0))
    # confirmed tracks' gates are searched beyond the search region too, below the horizon
    # (false: inside the search region only, the rule before; an ablation, docs/accuracy.md)
    gates_cross_horizon: bool = True


@dataclass(frozen=True)
class NoiseConfig:
    """Local noise estimate of the residual (wfviz.stages.noise): tile size (px), the weight of the
    previous estimate's tile statistics, and how often (frames) the statistics and tail
    calibrations are re-estimated (every frame after a camera shift of a quarter tile).

    ``residual_floor_overall`` (off) and ``change_floor_overall`` (on): the tail calibration of
    the residual's significance, and of the change's, holds everywhere at least the tail ratio
    that three quarters of the tiles reach (``overall`` of
    :meth:`wfviz.stages.noise.TailCalibration.update`); switches for ablations.
    """

    tile: int = field(default=32, metadata=value_range(8, 256))
    smoothing: float = field(default=0.5, metadata=value_range(0.0, 0.99))
    every: int = field(default=4, metadata=value_range(1, None))
    residual_floor_overall: bool = False
    change_floor_overall: bool = True


@dataclass(frozen=True)
class KalmanConfig:
    """Constant-velocity Kalman filter (eqs. 8-14); units px and frames."""

    q: float = field(default=0.2, metadata=value_range(0.0, None))
    r: float = field(default=0.4, metadata=value_range(1e-6, None))
    initial_velocity_std: float = field(default=3.0, metadata=value_range(0.0, None))
    gate_sigma: float = field(default=3.0, metadata=value_range(0.5, None))
    gate_min: float = field(default=3.0, metadata=value_range(0.5, None))
    gate_max: float = field(default=15.0, metadata=value_range(1.0, None))
    # px: a coasting track whose position uncertainty (gate_sigma std) grows past this is deleted
    coast_limit: float = field(default=45.0, metadata=value_range(1.0, None))

    def check(self) -> None:
        """Cross-field checks of the section (raise ConfigError)."""
        if self.gate_min > self.gate_max:
            raise ConfigError(f"kalman.gate_min ({self.gate_min}) must not exceed kalman.gate_max ({self.gate_max})")


@dataclass(frozen=True)
class TrackingConfig:
    """Track management: confirmation, deletion, meeting mode (eq. 15).

    ``confirm``: "sprt" (sequential test, :mod:`wfviz.tracking.confirmation`; not in the paper) or "hits"
    (the paper: ``confirm_hits`` hits, deleted after ``max_misses`` misses).
    """

    confirm: str = field(default="sprt", metadata={"choices": ("sprt", "hits")})
    false_tracks_per_1000: float = field(default=1.0, metadata=value_range(1e-6, 1000.0))
    p_detect: float = field(default=0.9, metadata=value_range(0.05, 0.999))
    beta: float = field(default=0.01, metadata=value_range(1e-6, 0.5))
    p_lost: float = field(default=0.001, metadata=value_range(1e-9, 0.5))
    position_noise: float = field(default=0.3, metadata=value_range(0.001, 10.0))
    require_motion: bool = True
    # confirm = "sprt": the tests against static clutter (motion, not clutter) need less evidence
    # where the scene's clutter map (wfviz.tracking.clutter_map) has seen no persistent
    # unexplained detections; false: every track proves it moves, everywhere
    clutter_map: bool = True
    clutter_memory: float = field(default=200.0, metadata=value_range(1.0, None))  # frames
    clutter_cell: int = field(default=16, metadata=value_range(2, None))  # px, in the scene
    min_motion: float = field(default=1.5, metadata=value_range(0.0, None))  # px, net (tracking.confirmation)
    # a track with missed frames must make this share of its velocity's progress between hits of
    # consecutive frames (tracking.confirmation.consecutive_progress): not only in the jumps
    # between separate spots across its misses; 0: off (chosen on real half A)
    consecutive_share: float = field(default=0.5, metadata=value_range(0.0, 1.0))
    # a track whose hits' components are, in the median, this many times longer along its way in
    # the scene than across it slides along a line (a road, an edge: the detected piece moves
    # along it) and is not confirmed (tracking.confirmation.slide); 0: off (chosen on real half A)
    max_slide: float = field(default=1.75, metadata=value_range(0.0, None))
    # confirm = "sprt": a miss reads the change significance at the track's prediction and scores
    # it (tracking.subthreshold): a dim target below the threshold is evidence, noise against
    read_misses: bool = True
    static_change_rate: float = field(default=0.05, metadata=value_range(1e-6, 0.5))
    target_change_rate: float = field(default=0.7, metadata=value_range(0.01, 0.999))
    confirm_hits: int = field(default=6, metadata=value_range(1, None))
    confirm_significance: float = field(default=0.0, metadata=value_range(0.0, None))
    confirm_blobness: float = field(default=0.0, metadata=value_range(0.0, 1.0))
    # px; 0: off (not in the paper): a gapless, straight mover needs only confirm_moving_significance
    confirm_moving: float = field(default=0.0, metadata=value_range(0.0, None))
    confirm_moving_significance: float = field(default=1.0, metadata=value_range(0.0, None))
    confirm_straightness: float = field(default=0.8, metadata=value_range(0.0, 1.0))
    reacquire: float = field(default=15.0, metadata=value_range(0.0, None))  # px; 0: off (not in the paper)
    # a confirmed track's gate is searched at a lower threshold, such that noise alone crosses
    # it somewhere in the gate with this probability (tracking.confirmation.gate_threshold); 0: off
    gate_false_alarm: float = field(default=0.0, metadata=value_range(0.0, 0.5))
    min_displacement: float = field(default=0.0, metadata=value_range(0.0, None))
    max_misses: int = field(default=3, metadata=value_range(1, None))
    # confirm = "sprt": a confirmed track whose hits have stopped being new at their place in the
    # scene is deleted (false: the rule before it, for ablations; docs/accuracy.md)
    delete_when_static: bool = True
    safety_distance: float = field(default=20.0, metadata=value_range(0.0, None))
    max_meeting_frames: int = field(default=40, metadata=value_range(1, None))
    meeting_velocity: str = field(default="kalman", metadata={"choices": ("kalman", "eq15")})
    meeting_overlap: bool = False   # meet only when the two gates overlap (not in the paper)
    meeting_misses: bool = False    # meeting mode: no detection near the extrapolation = a miss
    trail_length: int = field(default=60, metadata=value_range(2, None))
    # camera motion (wfviz.stages.registration): "auto" measures it every frame and moves the tracks
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
    lag: int = field(default=10, metadata=value_range(2, 100))
    min_lag: int = field(default=3, metadata=value_range(0, 100))
    min_shift: float = field(default=3.0, metadata=value_range(0.0, None))
    persist: float = field(default=0.35, metadata=value_range(0.0, None))
    neighbourhood: float = field(default=0.0, metadata=value_range(0.0, None))
    min_neighbours: int = field(default=10, metadata=value_range(1, None))
    bright: float = field(default=4.0, metadata=value_range(0.0, None))
    max_static: float = field(default=0.5, metadata=value_range(0.0, 1.0))
    delete_static: float = field(default=0.8, metadata=value_range(0.0, 1.0))
    min_known: int = field(default=2, metadata=value_range(1, None))
    memory: float = field(default=0.1, metadata=value_range(0.01, 1.0))
    wait: bool = True


@dataclass(frozen=True)
class FrontEndSections:
    """The sections of the shared front end (:mod:`wfviz.stages.front_end`), first in the
    configuration of every tracker built on it (GEWC, fusion)."""

    defects: DefectsConfig = DefectsConfig()
    circle: CircleConfig = CircleConfig()
    horizon: HorizonConfig = HorizonConfig()
    suppression: SuppressionConfig = SuppressionConfig()
    noise: NoiseConfig = NoiseConfig()
    detection: DetectionConfig = DetectionConfig()


#: ``wfviz tune``'s default search space of the sections GEWC and fusion share (the TOML form
#: of :mod:`wfviz.tune.space`): the detection threshold and the sequential test's trade-off
SHARED_SEARCH_SPACE = {
    "detection": {"k_sigma": {"low": 3.0, "high": 6.0}},
    "tracking": {
        "false_tracks_per_1000": {"low": 0.05, "high": 20.0, "log": True},
        "p_detect": {"low": 0.6, "high": 0.98},
        "min_motion": {"low": 0.5, "high": 4.0},
    },
}


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


def config_from_dict(data: dict[str, Any], cls: type) -> Any:
    """Build a ``cls`` config (a tracker's, :func:`wfviz.trackers.config_class`) from nested
    dicts as parsed from TOML, validating every key; a ``validate()`` method on the config class
    checks cross-field rules."""
    config = _build(cls, data, "")
    check = getattr(config, "validate", None)
    if check is not None:
        check()
    return config


#: Largest config or search-space file read (bytes); the defaults print as about 3 KB.
MAX_TOML_BYTES = 1 << 20


def read_toml(path: Path, what: str) -> dict[str, Any]:
    """The TOML file ``path`` (a ``what``: "config file", ...) parsed; ConfigError naming the
    file when it is missing, a folder, not a regular file (a device, a pipe), larger than
    :data:`MAX_TOML_BYTES`, nested too deeply or not valid TOML. A byte-order mark is accepted."""
    try:
        mode = os.stat(path).st_mode  # before opening: opening a pipe waits for a writer
        if stat.S_ISDIR(mode):
            raise IsADirectoryError
        if not stat.S_ISREG(mode):
            raise ConfigError(f"{path}: not a regular file (a device or pipe?), not a {what}")
        with open(path, "rb") as fh:
            data = fh.read(MAX_TOML_BYTES + 1)  # never more: the file may grow while read
        if len(data) > MAX_TOML_BYTES:
            raise ConfigError(f"{path}: larger than {MAX_TOML_BYTES // (1 << 20)} MiB, too large "
                              f"for a {what}")
        return tomllib.loads(data.decode("utf-8-sig"))  # a BOM, as some editors save
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such {what}") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a {what}") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply to be a {what}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None


def load_config(path: str | Path | None, cls: type) -> Any:
    """Load a TOML config file for ``cls``; None gives the defaults."""
    if path is None:
        return cls()
    path = Path(path)
    data = read_toml(path, "config file")
    try:
        return config_from_dict(data, cls)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def toml_value(value: Any) -> str:
    """``value`` as TOML text (None, a value chosen at run time: ``"auto"``)."""
    if value is None:
        return '"auto"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
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
            lines.append(f"{f.name} = {toml_value(value)}")
        lines.append("")
    return "\n".join(lines)
