"""Typed configs from plain dicts (YAML recipes): unknown keys and wrong types are errors.

Configs are frozen dataclasses validated in ``__post_init__``; this module only turns
nested dicts into them, naming the offending key path in every error.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, TypeVar

import yaml

from robomorph.core.errors import RoboMorphError

T = TypeVar("T")


class ConfigError(RoboMorphError, ValueError):
    """A recipe or override is malformed; the message names the key."""


def _coerce(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        return from_dict(hint, value, where)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{where}: invalid value {value!r}")
    if origin is typing.Literal:
        if value not in typing.get_args(hint):
            raise ConfigError(f"{where}: {value!r} is not one of {list(typing.get_args(hint))}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(hint)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(f"{where}: expected {len(args)} values, got {list(value)}")
            return tuple(_coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
        item = args[0] if args else Any
        return tuple(_coerce(v, item, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        _, vt = typing.get_args(hint) or (Any, Any)
        return {str(k): _coerce(v, vt, f"{where}.{k}") for k, v in value.items()}
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    return value


def from_dict(cls: type[T], data: dict[str, Any], where: str = "") -> T:
    """Builds dataclass ``cls`` from ``data``, recursing into nested dataclasses."""
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise ConfigError(
            f"{where or cls.__name__}: unknown key(s) {unknown}; valid keys are {sorted(fields)}"
        )
    kwargs = {k: _coerce(v, hints[k], f"{where + '.' if where else ''}{k}") for k, v in data.items()}
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{where or cls.__name__}: {exc}") from exc


def to_dict(cfg: Any) -> dict[str, Any]:
    """A JSON/YAML-ready dict of a config (tuples become lists)."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(cfg)


def load_yaml(path: str) -> dict[str, Any]:
    """Reads a recipe file into a dict with clear errors for missing or malformed files."""
    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except FileNotFoundError as exc:
        raise ConfigError(f"config file not found: {path}") from exc
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path} is not valid YAML: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path} must hold a mapping of keys to values, got {type(data).__name__}")
    return data


def check_range(name: str, rng: tuple[float, float], low: float | None = 0.0, high: float | None = None) -> None:
    """Validates a (lo, hi) range: finite, ordered and, when ``low`` / ``high`` are given,
    within them.

    Finite always: a range is drawn from (``uniform(lo, hi)``), and a NaN or an infinity
    there would pass every comparison below or overflow the draw. ``high`` bounds what the
    physics or the memory can take (a latency of 10^9 physics steps is a 7 GiB buffer).
    """
    lo, hi = rng
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"{name}: range ({lo}, {hi}) must hold finite numbers")
    if lo > hi:
        raise ValueError(f"{name}: inverted range ({lo}, {hi}); write it as (low, high)")
    if low is not None and lo < low:
        raise ValueError(f"{name}: range ({lo}, {hi}) goes below {low}")
    if high is not None and hi > high:
        raise ValueError(f"{name}: range ({lo}, {hi}) goes above {high:g}, the most it may be")


def check_number(name: str, value: float, low: float | None = None, high: float | None = None,
                 low_open: bool = False, high_open: bool = False) -> None:
    """Validates one number: finite and within ``low`` / ``high`` (open ends excluded), the
    scalar counterpart of :func:`check_range`. A NaN fails every comparison, so a check written
    ``if x < 0: raise`` lets it through; this one does not."""
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value}")
    if low is not None and (value <= low if low_open else value < low):
        raise ValueError(f"{name} must be {'>' if low_open else '>='} {low:g}, got {value}")
    if high is not None and (value >= high if high_open else value > high):
        raise ValueError(f"{name} must be {'<' if high_open else '<='} {high:g}, got {value}")


def yaml_value(text: str, where: str) -> Any:
    """The value of a ``NAME=VALUE`` option read as plain YAML (``16``, ``[1, 2]``, ``true``).

    Raises:
        ConfigError: one line naming the option for text that is not YAML (``[1,``) or that
            asks for a constructor (``!!python/object/apply:...``): safe_load builds plain data
            only, and its own message spans several lines of markers.
    """
    try:
        return yaml.safe_load(text)
    except yaml.constructor.ConstructorError as exc:
        tag = getattr(exc, "problem", "") or ""
        raise ConfigError(f"{where}: {text!r} uses a YAML tag that builds objects ({tag.strip()}); give a plain "
                          "value (a number, a string, true/false or a [list])") from None
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{where}: {text!r} is not a YAML value ({problem}); quote a string, close a [list]") from None
