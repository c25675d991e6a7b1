import pytest

from robomorph.core.overrides import merge, unflatten


def test_merge_is_deep_and_leaves_both_arguments_alone():
    base = {"model": {"d_model": 16, "lr": 1e-3}, "trainer": {"max_steps": 5}, "run": "a"}
    over = {"model": {"lr": 3e-4, "init_ckpt": "x"}, "run": "b"}
    merged = merge(base, over)
    assert merged == {"model": {"d_model": 16, "lr": 3e-4, "init_ckpt": "x"}, "trainer": {"max_steps": 5}, "run": "b"}
    assert base["model"] == {"d_model": 16, "lr": 1e-3} and over["model"] == {"lr": 3e-4, "init_ckpt": "x"}
    assert merge(base, None) == base and merge(None, over) == over
    merged["trainer"]["max_steps"] = 99  # a deep copy: the base is not shared
    assert base["trainer"]["max_steps"] == 5


@pytest.mark.parametrize("base, over, expected", [
    ({"a": {"b": 1}}, {"a": 2}, {"a": 2}),                      # a value replaces a mapping
    ({"a": 2}, {"a": {"b": 1}}, {"a": {"b": 1}}),               # and a mapping a value
    ({"a": [1, 2]}, {"a": [3]}, {"a": [3]}),                    # lists are replaced, not merged
    ({"a": {"b": {"c": 1, "d": 2}}}, {"a": {"b": {"d": None}}}, {"a": {"b": {"c": 1, "d": None}}}),
])
def test_merge_replaces_everything_but_mappings(base, over, expected):
    assert merge(base, over) == expected


def test_unflatten_nests_dotted_keys():
    flat = {"model.lr": 1e-3, "model.d_model": 32, "data.stores": ["a.zarr"], "run": "x", "a.b.c": 1}
    assert unflatten(flat) == {"model": {"lr": 1e-3, "d_model": 32}, "data": {"stores": ["a.zarr"]},
                               "run": "x", "a": {"b": {"c": 1}}}
