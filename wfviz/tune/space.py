"""Search spaces of ``wfviz tune``: which configuration values a study varies, over what range.

A space reads like a tracker's configuration, one table per section, each searched key an
inline table (a fixed value is a plain value, applied to every trial)::

    [detection]
    k_sigma = { low = 3.0, high = 6.0 }
    [tracking]
    false_tracks_per_1000 = { low = 0.05, high = 20.0, log = true }
    confirm = { choices = ["sprt", "hits"] }
    min_motion = 2.0

Integer fields are searched as integers (``step`` optional). Every key, range and choice is
checked against the tracker's configuration class before a trial runs. Each tracker ships a
default space (``SEARCH_SPACE`` beside its configuration; ``wfviz tune --print-space``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, get_type_hints

from wfviz.config import ConfigError, _closest, _coerce, config_from_dict, config_to_toml, read_toml, toml_value


@dataclass(frozen=True)
class Param:
    """One searched value: ``name`` is ``section.key``; numbers in ``[low, high]`` (``log``:
    sampled uniformly in log, ``step``: grid of integers), or one of ``choices``."""

    name: str
    kind: str  # "float", "int" or "choice"
    low: float | None = None
    high: float | None = None
    log: bool = False
    step: int | None = None
    choices: tuple[Any, ...] = ()


@dataclass(frozen=True)
class SearchSpace:
    """The searched ``params`` and the ``fixed`` values ({section.key: value}) of a study."""

    params: tuple[Param, ...]
    fixed: dict[str, Any]

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.params]


def _field(cls: type, section: str, key: str, where: str) -> tuple[dataclasses.Field, Any]:
    """The config field ``section.key`` of ``cls`` and its type hint (ConfigError naming the
    closest key when unknown)."""
    sections = {f.name: f for f in fields(cls)}
    if section not in sections:
        raise ConfigError(f"{where}unknown section '[{section}]'{_closest(section, list(sections))}")
    sub = get_type_hints(cls)[section]
    keys = {f.name: f for f in fields(sub)}
    if key not in keys:
        raise ConfigError(f"{where}unknown key '{section}.{key}'{_closest(key, list(keys))}")
    return keys[key], get_type_hints(sub)[key]


def parse_space(data: dict[str, Any], cls: type, where: str = "") -> SearchSpace:
    """A :class:`SearchSpace` for config class ``cls`` from TOML-shaped ``data`` ({section:
    {key: value or {low, high, log, step} or {choices}}}); ``where`` prefixes errors (a file)."""
    params: list[Param] = []
    fixed: dict[str, Any] = {}
    for section, table in data.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{where}'{section}' must be a [{section}] table of keys")
        for key, spec in table.items():
            name = f"{section}.{key}"
            f, hint = _field(cls, section, key, where)
            meta = dict(f.metadata)
            if not isinstance(spec, dict):
                fixed[name] = _coerce(f"{where}{name}", spec, hint, meta)
                continue
            params.append(_param(name, spec, hint, meta, where))
    if not params:
        raise ConfigError(f"{where}no parameter to search (give at least one key a "
                          "{ low = ..., high = ... } or { choices = [...] } range)")
    space = SearchSpace(tuple(params), fixed)
    check_space(space, cls, where)
    return space


def _param(name: str, spec: dict[str, Any], hint: Any, meta: dict[str, Any], where: str) -> Param:
    known = {"low", "high", "log", "step", "choices"}
    for k in spec:
        if k not in known:
            raise ConfigError(f"{where}{name}: unknown range key '{k}'{_closest(k, sorted(known))}")
    if "choices" in spec:
        if set(spec) - {"choices"}:
            raise ConfigError(f"{where}{name}: give either choices or low/high, not both")
        choices = spec["choices"]
        if not isinstance(choices, list) or not choices:
            raise ConfigError(f"{where}{name}: choices must be a non-empty list")
        values = tuple(_coerce(f"{where}{name}", c, hint, meta) for c in choices)
        if len(set(values)) != len(values):
            raise ConfigError(f"{where}{name}: choices repeat a value")
        return Param(name, "choice", choices=values)
    if "low" not in spec or "high" not in spec:
        raise ConfigError(f"{where}{name}: a range needs both low and high (or choices = [...])")
    if hint not in (int, float):
        raise ConfigError(f"{where}{name}: not a number; give choices = [...] instead of a range")
    low = _coerce(f"{where}{name}.low", spec["low"], hint, meta)
    high = _coerce(f"{where}{name}.high", spec["high"], hint, meta)
    if not low < high:
        raise ConfigError(f"{where}{name}: low ({low!r}) must be below high ({high!r})")
    log = spec.get("log", False)
    if not isinstance(log, bool):
        raise ConfigError(f"{where}{name}: log must be true or false")
    if log and low <= 0:
        raise ConfigError(f"{where}{name}: a log range needs low > 0 (got {low!r})")
    step = spec.get("step")
    if step is not None:
        if hint is not int or isinstance(step, bool) or not isinstance(step, int) or step < 1:
            raise ConfigError(f"{where}{name}: step must be a positive integer, for integer keys only")
        if log and step != 1:
            raise ConfigError(f"{where}{name}: a log range takes no step")
    return Param(name, "int" if hint is int else "float", float(low), float(high), log,
                 step if hint is int else None)


def check_space(space: SearchSpace, cls: type, where: str = "") -> None:
    """Raise ConfigError unless the lows, highs and choices of ``space`` each make a valid
    configuration (cross-field rules included) with the fixed values."""
    for p in space.params:
        for value in (p.choices if p.kind == "choice" else _ends(p)):
            try:
                make_config(cls, {p.name: value}, space.fixed)
            except ConfigError as exc:
                raise ConfigError(f"{where}{p.name} = {value!r}: {exc}") from None


def _ends(p: Param) -> tuple[Any, ...]:
    return (int(p.low), int(p.high)) if p.kind == "int" else (p.low, p.high)


def make_config(cls: type, params: dict[str, Any], fixed: dict[str, Any] | None = None,
                base: Any | None = None) -> Any:
    """The ``cls`` configuration of ``base`` (defaults when None) with ``fixed`` and then
    ``params`` ({section.key: value}) applied, validated."""
    data = config_dict(base) if base is not None else {}
    for name, value in {**(fixed or {}), **params}.items():
        section, key = name.split(".", 1)
        data.setdefault(section, {})[key] = value
    return config_from_dict(data, cls)


def config_dict(config: Any) -> dict[str, dict[str, Any]]:
    """A configuration as {section: {key: value}} (tuples as lists, None as "auto"), the form
    :func:`wfviz.config.config_from_dict` reads back."""
    def plain(v: Any) -> Any:
        if v is None:
            return "auto"
        return list(v) if isinstance(v, tuple) else v
    return {s.name: {f.name: plain(getattr(getattr(config, s.name), f.name))
                     for f in fields(getattr(config, s.name))} for s in fields(config)}


def load_space(path: str | Path, cls: type) -> SearchSpace:
    """The search space in TOML file ``path`` for config class ``cls`` (ConfigError naming
    the file and the problem)."""
    path = Path(path)
    return parse_space(read_toml(path, "search-space file"), cls, f"{path}: ")


def space_to_toml(space: SearchSpace, tracker: str) -> str:
    """``space`` as the TOML :func:`load_space` reads (what ``--print-space`` prints)."""
    lines = [f"# wfviz tune search space of tracker '{tracker}': edit and pass with --space FILE.",
             "# key = { low = L, high = H [, log = true] [, step = N] }, key = { choices = [...] },",
             "# or key = value (fixed in every trial)."]
    sections: dict[str, list[str]] = {}
    for p in space.params:
        section, key = p.name.split(".", 1)
        if p.kind == "choice":
            spec = "{ choices = [" + ", ".join(toml_value(v) for v in p.choices) + "] }"
        else:
            lo, hi = _ends(p)
            spec = f"{{ low = {toml_value(lo)}, high = {toml_value(hi)}"
            spec += ", log = true" if p.log else ""
            spec += f", step = {p.step}" if p.step not in (None, 1) else ""
            spec += " }"
        sections.setdefault(section, []).append(f"{key} = {spec}")
    for name, value in space.fixed.items():
        section, key = name.split(".", 1)
        sections.setdefault(section, []).append(f"{key} = {toml_value(value)}")
    for section, body in sections.items():
        lines += ["", f"[{section}]", *body]
    return "\n".join(lines) + "\n"


def best_toml(config: Any, header: str) -> str:
    """A full configuration file (``--config``) headed by comment lines ``header``."""
    comments = "".join(f"# {line}\n" for line in header.splitlines())
    return comments + config_to_toml(config)
