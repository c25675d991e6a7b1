"""Typed config parsing: nested dataclasses, coercion, errors that name the key."""

from dataclasses import dataclass, field
from typing import Literal

import pytest

from robomorph.core.config import ConfigError, check_range, from_dict, load_yaml, to_dict


@dataclass(frozen=True)
class Inner:
    gain: float = 1.0
    span: tuple[float, float] = (0.0, 1.0)


@dataclass(frozen=True)
class Outer:
    name: str = "a"
    count: int = 1
    mode: Literal["x", "y"] = "x"
    weights: dict[str, float] = field(default_factory=dict)
    inner: Inner = field(default_factory=Inner)
    limit: int | None = None

    def __post_init__(self):
        if self.count < 0:
            raise ValueError("count must be >= 0")


def test_nested_values_are_coerced_and_round_trip():
    cfg = from_dict(Outer, {"count": 3, "inner": {"gain": 2, "span": [0.5, 2]}, "weights": {"a": 1}, "limit": None})
    assert cfg.inner == Inner(gain=2.0, span=(0.5, 2.0)) and isinstance(cfg.inner.gain, float)
    assert cfg.weights == {"a": 1.0} and cfg.limit is None
    assert from_dict(Outer, to_dict(cfg)) == cfg
    assert to_dict(cfg)["inner"]["span"] == [0.5, 2.0]  # YAML-ready: tuples become lists


@pytest.mark.parametrize("data, message", [
    ({"colour": 1}, r"unknown key\(s\) \['colour'\]"),
    ({"count": "3"}, "count: expected an integer"),
    ({"count": True}, "count: expected an integer"),
    ({"mode": "z"}, "mode: 'z' is not one of"),
    ({"inner": {"span": [1.0]}}, r"inner.span: expected 2 values"),
    ({"inner": {"gain": "big"}}, "inner.gain: expected a number"),
    ({"count": -1}, "Outer: count must be >= 0"),
])
def test_errors_name_the_key(data, message):
    with pytest.raises(ConfigError, match=message):
        from_dict(Outer, data)


def test_yaml_files_missing_malformed_or_not_a_mapping(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_yaml(str(tmp_path / "none.yaml"))
    (tmp_path / "bad.yaml").write_text("a: [1\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_yaml(str(tmp_path / "bad.yaml"))
    (tmp_path / "list.yaml").write_text("- 1\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_yaml(str(tmp_path / "list.yaml"))
    (tmp_path / "empty.yaml").write_text("")
    assert load_yaml(str(tmp_path / "empty.yaml")) == {}


def test_ranges_are_ordered_and_bounded():
    check_range("r", (0.0, 1.0))
    with pytest.raises(ValueError, match="inverted"):
        check_range("r", (2.0, 1.0))
    with pytest.raises(ValueError, match="below 0.0"):
        check_range("r", (-1.0, 1.0))
    check_range("r", (-1.0, 1.0), low=None)
