"""Properties: random configs load or fail with a one-line ConfigError (and the ones that load
run); random frames never crash the pipeline (too small ones get the clear error); the same
input and config always give the same tracks CSV."""

from __future__ import annotations

import dataclasses
import tomllib
import warnings
from pathlib import Path
from typing import get_type_hints

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from wfviz.cli import app
from wfviz.config import ConfigError, config_from_dict, load_config
from wfviz.io.clip import MIN_SIDE, ClipError, ClipWarning, open_clip
from wfviz.io.frames import Frame
from wfviz.run import run
from wfviz.trackers import TRACKERS, make_tracker
from wfviz.trackers.gewc.config import GEWCConfig

SETTINGS = settings(max_examples=60, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# --- configs -----------------------------------------------------------------------------

SCHEMA = {s.name: [f.name for f in dataclasses.fields(s.type if isinstance(s.type, type) else
                                                      type(getattr(GEWCConfig(), s.name)))]
          for s in dataclasses.fields(GEWCConfig)}
scalars = st.one_of(
    st.integers(-(10**6), 10**6), st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.integers(0, 10**400 + 1).filter(lambda v: v > 10**20),  # TOML parsers keep big ints
    st.floats(allow_nan=True, allow_infinity=True), st.floats(-100, 300),
    st.booleans(), st.sampled_from(["auto", "opening", "erosion", "global", "local", "gewc",
                                    "intensity", "kalman", "eq15", ""]),
    st.text(max_size=8))
values = st.one_of(scalars, st.lists(scalars, max_size=3), st.dictionaries(st.text(max_size=5), scalars, max_size=2))


@st.composite
def config_dicts(draw: st.DrawFn) -> dict:
    """Mostly-valid structure (real sections and keys) with random values and stray keys."""
    data: dict = {}
    for section in draw(st.lists(st.sampled_from(sorted(SCHEMA)), max_size=4, unique=True)):
        keys = draw(st.lists(st.sampled_from(SCHEMA[section]), max_size=4, unique=True))
        data[section] = {k: draw(values) for k in keys}
        if draw(st.integers(0, 9)) == 0:
            data[section][draw(st.text(min_size=1, max_size=8))] = draw(scalars)
    if draw(st.integers(0, 9)) == 0:
        data[draw(st.text(min_size=1, max_size=8))] = draw(values)
    if draw(st.integers(0, 9)) == 0 and data:
        data[draw(st.sampled_from(sorted(data)))] = draw(scalars)
    return data


def _valid_value(hint: object, meta: dict) -> st.SearchStrategy:
    """Values a field accepts: its choices, or numbers in its range (edges included)."""
    if "choices" in meta:
        return st.sampled_from(meta["choices"])
    if hint is bool:
        return st.booleans()
    if "tuple" in str(hint):
        return st.just("auto") | st.lists(st.floats(-20, 80), min_size=2, max_size=2)
    lo, hi = meta.get("range", (None, None))
    lo = 0 if lo is None else lo
    hi = lo + 100 if hi is None else hi
    if hint is int:
        return st.sampled_from([lo, hi]) | st.integers(lo, hi)
    base = st.sampled_from([float(lo), float(hi)]) | st.floats(lo, hi)
    return st.just("auto") | base if "None" in str(hint) else base


@st.composite
def valid_config_dicts(draw: st.DrawFn) -> dict:
    """Configs that pass validation, with extreme in-range values (edges of every range)."""
    data: dict = {}
    for section in dataclasses.fields(GEWCConfig):
        cls = type(getattr(GEWCConfig(), section.name))
        hints = get_type_hints(cls)
        keys = draw(st.lists(st.sampled_from([f.name for f in dataclasses.fields(cls)]), max_size=6, unique=True))
        fields = {f.name: f for f in dataclasses.fields(cls)}
        data[section.name] = {k: draw(_valid_value(hints[k], dict(fields[k].metadata))) for k in keys}
    kalman = data["kalman"]
    if kalman.get("gate_min", 3.0) > kalman.get("gate_max", 15.0):
        kalman["gate_min"], kalman["gate_max"] = kalman.get("gate_max", 15.0), kalman.get("gate_min", 3.0)
    return data


def assert_clear(exc: Exception) -> None:
    text = str(exc)
    assert text and "\n" not in text and "Traceback" not in text


def frames_of(shape: tuple[int, int], n: int = 4, dtype: type = np.uint16) -> list[Frame]:
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        image = rng.normal(500, 5, shape)
        image[shape[0] // 2, (3 * i) % shape[1]] += 200
        out.append(Frame(i, i / 20, image.astype(dtype)))
    return out


@SETTINGS
@given(config_dicts() | valid_config_dicts())
def test_random_configs_load_or_fail_clearly_and_loaded_ones_run(data: dict) -> None:
    try:
        config = config_from_dict(data, GEWCConfig)
    except ConfigError as exc:
        assert_clear(exc)
        return
    side = make_tracker("gewc", config).min_frame_side()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # odd thresholds may divide by zero
        for shape in ((side, side), (max(side, 40), max(side, 56))):  # the smallest frame accepted
            tracker = make_tracker("gewc", config)
            for frame in frames_of(shape):
                tracker.step(frame)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.binary(max_size=200) | st.text(max_size=200).map(lambda t: t.encode()))
def test_random_config_files_load_or_fail_clearly(tmp_path_factory: pytest.TempPathFactory, raw: bytes) -> None:
    path = tmp_path_factory.mktemp("cfg") / "c.toml"
    path.write_bytes(raw)
    try:
        load_config(path, GEWCConfig)
    except ConfigError as exc:
        assert_clear(exc)
        assert str(exc).startswith(f"{path}: ")


@settings(max_examples=8, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(config_dicts())
def test_random_configs_through_the_cli_never_show_a_traceback(tmp_path: Path, data: dict) -> None:
    text = "\n".join(f"[{section}]\n" + "\n".join(f"{k} = {_toml(v)}" for k, v in table.items())
                     for section, table in data.items() if isinstance(table, dict))
    try:
        tomllib.loads(text)
    except (tomllib.TOMLDecodeError, ValueError):
        return  # keys that TOML cannot spell bare
    (tmp_path / "c.toml").write_text(text)
    np.save(tmp_path / "c.npy", np.stack([f.image for f in frames_of((40, 48), 2)]))
    r = CliRunner().invoke(app, ["track", str(tmp_path / "c.npy"), "--tracks", str(tmp_path / "t.csv"),
                                 "--config", str(tmp_path / "c.toml")])
    assert r.exit_code in (0, 2), (r.exit_code, r.stderr, r.exception)
    if r.exit_code == 2:
        assert r.stderr.startswith(f"wfviz: error: {tmp_path / 'c.toml'}: ") and r.stderr.count("\n") == 1


def _toml(v: object) -> str:
    """A TOML value for ``v`` (non-finite floats and nested tables as TOML spells them)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if v != v else ("inf" if v == float("inf") else "-inf" if v == float("-inf") else repr(v))
    if isinstance(v, str):
        return '"' + v.encode("unicode_escape").decode().replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f'"{k}" = {_toml(x)}' for k, x in v.items()) + "}"
    return str(v)


# --- frames ------------------------------------------------------------------------------

DTYPES = [np.uint8, np.uint16, np.float32, np.float64, np.int16, np.int32, np.bool_]


@st.composite
def stacks(draw: st.DrawFn) -> np.ndarray:
    """(T, H, W) stacks: constant, saturated, zero, noise, spots, NaN-laced; any dtype."""
    t = draw(st.integers(1, 4))
    h, w = draw(st.integers(1, 72)), draw(st.integers(1, 72))
    dtype = np.dtype(draw(st.sampled_from(DTYPES)))
    kind = draw(st.sampled_from(["constant", "saturated", "zeros", "noise", "spots", "extreme", "nan"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    if dtype.kind == "f":
        lo, hi = (-1e6, 1e6) if kind != "extreme" else (-np.finfo(dtype).max / 4, np.finfo(dtype).max / 4)
    elif dtype == np.bool_:
        lo, hi = 0, 1
    else:
        lo, hi = np.iinfo(dtype).min, np.iinfo(dtype).max
    if kind == "constant":
        stack = np.full((t, h, w), draw(st.floats(lo, hi) if dtype.kind == "f" else st.integers(lo, hi)))
    elif kind == "saturated":
        stack = np.full((t, h, w), hi)
    elif kind == "zeros":
        stack = np.zeros((t, h, w))
    elif kind in ("noise", "extreme", "nan"):
        stack = rng.uniform(lo, hi, (t, h, w)) if dtype.kind == "f" else rng.integers(lo, hi, (t, h, w), endpoint=True)
    else:
        stack = np.full((t, h, w), lo + (hi - lo) // 8 if dtype.kind != "f" else 100.0)
        for i in range(t):
            stack[i, rng.integers(h, size=3), rng.integers(w, size=3)] = hi
    stack = stack.astype(dtype)
    if kind == "nan" and dtype.kind == "f":
        stack[rng.random(stack.shape) < 0.05] = rng.choice([np.nan, np.inf, -np.inf])
    return stack


@pytest.mark.parametrize("tracker", sorted(TRACKERS))
@settings(SETTINGS, max_examples=25)
@given(stack=stacks(), nan_as_zero=st.booleans())
def test_random_frames_never_crash_the_pipeline(tmp_path_factory: pytest.TempPathFactory, tracker: str,
                                                stack: np.ndarray, nan_as_zero: bool) -> None:
    folder = tmp_path_factory.mktemp("frames")
    np.save(folder / "s.npy", stack)
    clip = open_clip(folder / "s.npy", nan_as_zero=nan_as_zero)
    too_small = min(stack.shape[1:]) < MIN_SIDE
    has_nan = stack.dtype.kind == "f" and not np.isfinite(stack).all()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ClipWarning)
            warnings.simplefilter("ignore", RuntimeWarning)  # |values| ~1e38 overflow float32 sums
            summary = run(clip, make_tracker(tracker), tracks_csv=folder / "t.csv")
    except ClipError as exc:
        assert_clear(exc)
        if too_small:
            assert "smaller than the processing windows" in str(exc)
        else:
            assert has_nan and not nan_as_zero and "NaN or infinite pixels" in str(exc)
        assert not (folder / "t.csv").exists() and not list(folder.glob(".t.csv.*"))
        return
    assert not too_small and not (has_nan and not nan_as_zero)
    assert summary.frames == stack.shape[0]
    text = (folder / "t.csv").read_text()
    assert "nan" not in text and "inf" not in text


# --- determinism -------------------------------------------------------------------------


def test_same_input_and_config_give_identical_tracks(tmp_path: Path) -> None:
    runner = CliRunner()
    r = runner.invoke(app, ["synth", "uniform-50hz", str(tmp_path / "scene"), "--frames", "40"])
    assert r.exit_code == 0, r.stderr
    outputs = []
    for name in ("a.csv", "b.csv"):
        r = runner.invoke(app, ["track", str(tmp_path / "scene"), "--tracks", str(tmp_path / name)])
        assert r.exit_code == 0, r.stderr
        outputs.append((tmp_path / name).read_bytes())
    assert outputs[0] == outputs[1] and outputs[0].count(b"\n") > 40
