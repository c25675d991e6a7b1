"""Shipped recipes and sweep spaces: found by name or by path from any directory."""

import os
from pathlib import Path

import pytest

from robomorph.core import recipes
from robomorph.core.errors import MissingInputError, RoboMorphError
from robomorph.core.recipes import available, locate, locate_config_args, shipped_dir

ROOT = Path(__file__).resolve().parents[2]


def _stems(folder: str) -> list[str]:
    return sorted(p.stem for p in (ROOT / folder).glob("*.yaml"))


@pytest.fixture
def elsewhere(tmp_path, monkeypatch):
    """An empty working directory outside the repository."""
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    return cwd


@pytest.mark.parametrize("kind", recipes.KINDS)
def test_every_top_level_file_is_shipped_by_name(kind, elsewhere):
    assert available(kind) == _stems(kind) and available(kind)
    for name in available(kind):
        for ref in (name, f"{name}.yaml", f"{kind}/{name}.yaml", f"./{kind}/{name}.yaml"):
            path = locate(ref, kind)
            assert os.path.isabs(path) and Path(path).read_bytes() == (ROOT / kind / f"{name}.yaml").read_bytes()
    assert not os.listdir(elsewhere)


def test_an_existing_path_wins_over_a_shipped_name(elsewhere):
    from robomorph.sim.recipe import load_recipe

    (elsewhere / "datamodules").mkdir()
    (elsewhere / "datamodules" / "multisine.yaml").write_text("task: chirp\nrobots: 3\n")
    (elsewhere / "mine.yaml").write_text("robots: 5\n")
    assert locate("datamodules/multisine.yaml") == "datamodules/multisine.yaml"
    assert load_recipe("datamodules/multisine.yaml").robots == 3
    assert load_recipe("mine.yaml").robots == 5
    shipped = load_recipe("multisine")  # a bare name is the shipped recipe
    assert shipped.task == "multisine" and shipped.robots == 256
    # Flags still override a recipe found by name.
    assert load_recipe("multisine", {"robots": 7, "steps": None}).robots == 7


def test_an_unknown_name_is_one_line_listing_the_shipped_names(elsewhere):
    with pytest.raises(MissingInputError) as exc:
        locate("multisin")
    msg = str(exc.value)
    assert "\n" not in msg and "multisin is neither a file" in msg
    assert "(shipped datamodules: arms, chirp, circle, mixture, multisine, realistic, residual, spiral, train_cpu)" in msg
    with pytest.raises(RoboMorphError, match="shipped sweeps: architecture, architecture_cpu, ci,"):
        locate("sweeps/nope.yaml", "sweeps")


def test_a_path_elsewhere_or_a_folder_is_not_taken_for_a_name(elsewhere):
    # other/multisine.yaml names a file in other/, not the shipped recipe.
    with pytest.raises(MissingInputError, match="other/multisine.yaml is neither a file"):
        locate("other/multisine.yaml")
    (elsewhere / "multisine").mkdir()
    with pytest.raises(MissingInputError, match="multisine is a folder, not a recipe file"):
        locate("multisine")
    with pytest.raises(ValueError, match="unknown recipe kind"):
        locate("multisine", "recipes")


def test_an_installed_package_reads_its_own_copy(tmp_path, monkeypatch):
    # The wheel's layout: robomorph/_recipes/<kind>/ inside site-packages, no folders beside it.
    package = tmp_path / "site-packages" / "robomorph"
    (package / "_recipes" / "datamodules").mkdir(parents=True)
    (package / "_recipes" / "datamodules" / "only.yaml").write_text("robots: 2\n")
    monkeypatch.setattr(recipes.resources, "files", lambda name: package)
    assert shipped_dir("datamodules") == package / "_recipes" / "datamodules"
    assert available("datamodules") == ["only"]
    assert locate("only") == str(package / "_recipes" / "datamodules" / "only.yaml")
    assert shipped_dir("sweeps") is None and available("sweeps") == []
    with pytest.raises(MissingInputError, match=r"\(shipped sweeps: none\)"):
        locate("ci", "sweeps")


def test_config_arguments_are_located_and_inline_yaml_is_left_alone(elsewhere):
    (elsewhere / "own.yaml").write_text("trainer: {max_steps: 3}\n")
    argv = ["--config", "train_cpu", "--config=own.yaml", "--config", "{trainer: {max_steps: 3}}", "--data.stores",
            "x.zarr"]
    assert locate_config_args(argv) == ["--config", str(ROOT / "datamodules" / "train_cpu.yaml"), "--config=own.yaml",
                                        "--config", "{trainer: {max_steps: 3}}", "--data.stores", "x.zarr"]
    with pytest.raises(MissingInputError, match="train_gpu is neither a file"):
        locate_config_args(["--config=train_gpu"])


def test_generate_takes_a_recipe_name_from_an_empty_folder(elsewhere, capsys):
    from robomorph import generate
    from robomorph.data.store import open_store

    code = generate.main(["--config", "multisine", "--robots", "2", "--steps", "12", "--out", "ms.zarr",
                          "--workers", "1", "--quiet"])
    assert code == 0
    ds = open_store(str(elsewhere / "ms.zarr"))
    assert ds.n == 2 and ds.attrs["task"] == "multisine"
    assert generate.main(["--config", "multisin", "--out", "bad.zarr", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: config file not found: multisin is neither") and err.count("\n") == 1
    assert not (elsewhere / "bad.zarr").exists()


def test_fit_takes_the_training_recipe_by_name(elsewhere, capsys):
    from robomorph import fit

    with pytest.raises(SystemExit) as exc:
        fit.main(["--config", "train_cpu", "--print_config"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "patch: 10" in out and "recenter: true" in out


def test_sweep_spaces_and_their_base_recipe_are_found_by_name(elsewhere):
    from robomorph.reproduction.pipeline import recipe_path
    from robomorph.tuning.space import load_space

    assert load_space("ci").name == load_space(str(ROOT / "sweeps" / "ci.yaml")).name
    # architecture_cpu's base names datamodules/train_cpu.yaml, which this folder lacks.
    args = load_space("sweeps/architecture_cpu.yaml").fit_args({}, run="r", runs_dir="runs")
    assert args["model"]["patch"] == 10 and args["data"]["stores"] == "data/ms.zarr"
    assert recipe_path("train_cpu") == str(ROOT / "datamodules" / "train_cpu.yaml")
