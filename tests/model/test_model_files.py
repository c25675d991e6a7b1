"""Model folders (``robomorph export``): weights in safetensors, the rest in JSON; read by
every loader, predicting exactly as the checkpoint; refused whole when altered."""

import hashlib
import json
import os

import numpy as np
import pytest
import torch

from robomorph.core.errors import OutputExistsError
from robomorph.inference.calibration import CALIBRATION_KEY
from robomorph.inference.checkpoint import CheckpointError, load_checkpoint_file, load_trained
from robomorph.model.files import CONFIG_FILE, WEIGHTS_FILE, export, read_model
from robomorph.predictor import Predictor
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, tiny_fit_args

C, H = CKPT_CONTEXT, CKPT_HORIZON
OLD = os.path.join(os.path.dirname(os.path.dirname(__file__)), "training", "data")


@pytest.fixture(scope="module")
def trained(linear_store, tmp_path_factory):
    """(store, best.ckpt of a tiny Gaussian-head model on a linear system of 40 robots)."""
    from robomorph.training.fitting import fit

    store = linear_store(n=40, steps=C + H)
    result = fit(tiny_fit_args(store, tmp_path_factory.mktemp("runs"), "gauss",
                               model={"anchor": True, "gaussian": True, "loss": "nll"}))
    return store, result.best_ckpt


def _inputs(n_u=2, n_y=3, batch=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(batch, C, n_u, generator=g), torch.randn(batch, C, n_y, generator=g), \
        torch.randn(batch, 20, n_u, generator=g)


def _copy(src: str, dst) -> str:
    with open(src, "rb") as f, open(dst, "wb") as g:
        g.write(f.read())
    return str(dst)


def test_the_export_holds_the_weights_without_optimizer_state_and_predicts_exactly(trained, tmp_path):
    _, ckpt = trained
    done = export(ckpt, str(tmp_path / "model"))
    assert sorted(os.listdir(tmp_path / "model")) == [CONFIG_FILE, WEIGHTS_FILE]
    from safetensors.torch import load_file

    weights, state = load_file(done["weights"]), load_checkpoint_file(ckpt)["state_dict"]
    assert set(weights) == {k for k in state if k.startswith(("net.", "normalizer."))}
    for k, v in weights.items():
        assert torch.equal(v, state[k]), k
    config = json.load(open(done["config"]))
    assert "optimizer_states" not in config and "lr_schedulers" not in config
    assert done["bytes"]["weights"] < done["bytes"]["source"] / 2
    a, b = Predictor.from_checkpoint(ckpt, "cpu"), Predictor.from_pretrained(str(tmp_path / "model"), "cpu")
    assert b.data_info == a.data_info and b.has_std and (b.n_u, b.n_y, b.patch) == (a.n_u, a.n_y, a.patch)
    for x, y in zip(a.simulate(*_inputs(), return_std=True), b.simulate(*_inputs(), return_std=True)):
        assert torch.equal(x, y)


def test_a_checkpoint_of_an_earlier_version_exports_and_predicts_as_it_did(tmp_path):
    # pre_issue11.ckpt was written by the code of commit 5b37644, with its predictions.
    ref = np.load(os.path.join(OLD, "pre_issue11.npz"))
    export(os.path.join(OLD, "pre_issue11.ckpt"), str(tmp_path / "old"))
    pred = Predictor.from_pretrained(str(tmp_path / "old"), device="cpu")
    np.testing.assert_allclose(pred.simulate(ref["u_ctx"], ref["y_ctx"], ref["u_query"]), ref["y_query"],
                               rtol=0, atol=1e-6)


def test_the_calibration_travels_with_the_export_and_calibrate_writes_into_a_folder(trained, tmp_path):
    from robomorph.evaluation.calibrating import calibrate, remove
    from robomorph.evaluation.requests import CalibrateConfig

    _, best = trained
    ckpt = _copy(best, tmp_path / "model.ckpt")
    calibrate(CalibrateConfig(ckpt=ckpt))
    folder = str(tmp_path / "model")
    export(ckpt, folder)
    assert Predictor.from_pretrained(folder, "cpu").calibration == Predictor.from_checkpoint(ckpt, "cpu").calibration
    # Calibrating the folder itself, in place: the weights stay byte for byte.
    weights = open(os.path.join(folder, WEIGHTS_FILE), "rb").read()
    assert remove(folder) is True
    assert Predictor.from_pretrained(folder, "cpu").calibration is None
    report = calibrate(CalibrateConfig(ckpt=folder, method="quantile"))
    stored = json.load(open(os.path.join(folder, CONFIG_FILE)))[CALIBRATION_KEY]
    assert [stored[k] for k in ("knots", "scale", "method")] == [report["calibration"][k]
                                                                  for k in ("knots", "scale", "method")]
    assert Predictor.from_pretrained(folder, "cpu").calibration.method == "quantile"
    assert open(os.path.join(folder, WEIGHTS_FILE), "rb").read() == weights
    assert _beside(tmp_path) == ["model", "model.ckpt"]  # no temporary left beside it


def test_evaluate_reads_a_folder_as_it_reads_the_checkpoint(trained, tmp_path):
    from robomorph.evaluate import main

    store, ckpt = trained
    export(ckpt, str(tmp_path / "model"))
    scores = []
    for src, out in ((ckpt, tmp_path / "e_ckpt"), (str(tmp_path / "model"), tmp_path / "e_folder")):
        assert main(["--ckpt", src, "--data", store, "--out", str(out), "--baselines", "none", "--n", "4",
                     "--plot-trajectories", "1", "--device", "cpu"]) == 0
        metrics = json.load(open(out / "metrics.json"))
        scores.append([metrics[k] for k in ("approach1", "approach2", "horizons", "calibration")]
                      + [metrics["meta"].get("in_sample")])
    assert scores[0] == scores[1]


def test_a_folder_seeds_a_transfer_with_its_weights_and_statistics(trained, tmp_path):
    from robomorph.training.module import MetaModule
    from robomorph.training.pretrained import load_pretrained

    _, ckpt = trained
    export(ckpt, str(tmp_path / "model"))
    hp = {k: v for k, v in read_model(ckpt)["hyper_parameters"].items() if not k.startswith("_")}
    module = MetaModule(**{**hp, "normalization_from": "source"})
    assert load_pretrained(module, str(tmp_path / "model")) is True
    state = load_checkpoint_file(ckpt)["state_dict"]
    for k, v in module.state_dict().items():
        if k != "stats_ready":
            assert torch.equal(v, state[k]), k


def test_an_altered_or_incomplete_folder_is_refused_with_one_line(trained, tmp_path):
    _, ckpt = trained
    folder = tmp_path / "model"
    export(ckpt, str(folder))
    weights = folder / WEIGHTS_FILE
    data = bytearray(weights.read_bytes())
    data[-1] ^= 0xFF
    weights.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="does not match config.json"):
        load_trained(str(folder))
    config = json.loads((folder / CONFIG_FILE).read_text())
    garbage = b"\x80\x02not safetensors"
    config["weights"]["sha256"] = hashlib.sha256(garbage).hexdigest()  # the digest alone lets it through
    (folder / CONFIG_FILE).write_text(json.dumps(config))
    weights.write_bytes(garbage)
    with pytest.raises(CheckpointError, match="not a readable safetensors file"):
        load_trained(str(folder))
    weights.unlink()
    with pytest.raises(CheckpointError, match="lacks model.safetensors"):
        load_trained(str(folder))
    (folder / CONFIG_FILE).write_text(json.dumps({**config, "format_version": 99}))
    with pytest.raises(CheckpointError, match="format version 99"):
        load_trained(str(folder))
    (folder / CONFIG_FILE).write_text("{not json")
    with pytest.raises(CheckpointError, match="not readable JSON") as err:
        Predictor.from_pretrained(str(folder))
    assert "\n" not in str(err.value)
    with pytest.raises(CheckpointError, match="cannot resume training"):
        load_checkpoint_file(str(folder))


def _beside(folder) -> list[str]:
    """What a folder holds but the writers' lock files (``.<name>.lock``, kept by design)."""
    return sorted(n for n in os.listdir(folder) if not (n.startswith(".") and n.endswith(".lock")))


def test_export_replaces_only_an_export(trained, tmp_path):
    _, ckpt = trained
    other = tmp_path / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="not a model folder"):
        export(ckpt, str(other))
    assert os.listdir(other) == ["keep.txt"]
    with pytest.raises(OutputExistsError):
        export(ckpt, str(other / "keep.txt"))
    folder = str(tmp_path / "model")
    export(ckpt, folder)
    (tmp_path / "model" / WEIGHTS_FILE).write_bytes(b"damaged")
    export(ckpt, folder)  # an earlier export (even a damaged one) is replaced whole
    assert Predictor.from_pretrained(folder, "cpu").n_y == 3
    assert _beside(tmp_path) == ["model", "notes"]
    (tmp_path / "model" / CONFIG_FILE).write_text('{"name": "another tool\'s config"}')
    with pytest.raises(OutputExistsError):
        export(ckpt, folder)  # only config.json and model.safetensors, but not ours


def test_the_command_reports_the_sizes_and_refuses_in_one_line(trained, tmp_path, capsys):
    from robomorph.cli import main

    _, ckpt = trained
    assert main(["export", "--ckpt", ckpt, "--out", str(tmp_path / "m")]) == 0
    out = capsys.readouterr().out
    assert "model.safetensors" in out and "MiB" in out
    assert main(["export", "--ckpt", str(tmp_path / "missing.ckpt"), "--out", str(tmp_path / "n")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: checkpoint not found") and "Traceback" not in err
    assert not os.path.exists(tmp_path / "n")
