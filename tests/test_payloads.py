"""A model file with a planted payload runs nothing, through every loader.

The payload is a pickle whose ``__reduce__`` would create a marker file when unpickled (as
``torch.load(weights_only=False)`` did). Each loader gets it through its real door; the
marker must not exist afterwards, and a command exits 2 with one ``error:`` line naming
the file.
"""

import builtins
import hashlib
import json
import os
import pickle

import pytest
import torch

from robomorph.inference.checkpoint import CheckpointError
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, tiny_fit_args


class Payload:
    """Unpickled, it would open (create) ``marker`` for writing."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return builtins.open, (self.marker, "w")


def plant(path, marker, kind: str = "checkpoint") -> str:
    """A file at ``path`` whose loading would create ``marker``: a checkpoint-shaped torch
    zip with the payload among its hyper-parameters, or a bare pickle."""
    os.makedirs(os.path.dirname(str(path)), exist_ok=True)
    if kind == "checkpoint":
        torch.save({"state_dict": {}, "global_step": 3, "hyper_parameters": {"n_u": 2, "n_y": 3, "x": Payload(marker)}},
                   path)
    else:
        with open(path, "wb") as f:
            pickle.dump({"state_dict": Payload(marker)}, f, protocol=2)
    return str(path)


@pytest.fixture(scope="module")
def trained(linear_store, tmp_path_factory):
    """(store, best.ckpt of a tiny model trained on it): the honest side of each command."""
    from robomorph.training.fitting import fit

    store = linear_store(n=32, steps=CKPT_CONTEXT + CKPT_HORIZON)
    return store, fit(tiny_fit_args(store, tmp_path_factory.mktemp("runs"), "honest")).best_ckpt


def _flags(args: dict) -> list[str]:
    """``fit()``'s nested dict as command-line flags."""
    out = []
    for key, value in args.items():
        items = value.items() if isinstance(value, dict) else [(None, value)]
        for sub, v in items:
            flag = f"--{key}" if sub is None else f"--{key}.{sub}"
            out += [flag, str(v).lower() if isinstance(v, bool) else str(v)]
    return out


def _fit_argv(store, runs, run="victim", **extra) -> list[str]:
    return ["fit", *_flags(tiny_fit_args(store, runs, run, steps=2)), *extra.get("flags", [])]


def _doors(payload: str, store: str, honest: str, tmp) -> dict[str, list[str]]:
    """Each loader's command line with the payload where a model file goes."""
    return {
        "evaluate --ckpt": ["evaluate", "--ckpt", payload, "--data", store, "--out", str(tmp / "ev")],
        "evaluate --compare": ["evaluate", "--ckpt", honest, "--data", store, "--out", str(tmp / "ev"),
                               "--baselines", "none", "--compare", f"other={payload}"],
        "calibrate": ["calibrate", "--ckpt", payload],
        "export": ["export", "--ckpt", payload, "--out", str(tmp / "model")],
        "fit --model.init_ckpt": _fit_argv(store, tmp / "runs", flags=["--model.init_ckpt", payload]),
        "fit --ckpt_path": _fit_argv(store, tmp / "runs", flags=["--ckpt_path", payload]),
    }


def _one_error_line(capfd, payload: str) -> str:
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert payload in lines[0] and "not allowed" in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("kind", ["checkpoint", "pickle"])
@pytest.mark.parametrize("door", ["evaluate --ckpt", "evaluate --compare", "calibrate", "export",
                                  "fit --model.init_ckpt", "fit --ckpt_path"])
def test_a_command_refuses_the_payload_and_runs_nothing(door, kind, trained, tmp_path, capfd):
    from robomorph.cli import main

    store, honest = trained
    marker = tmp_path / "PWNED"
    payload = plant(tmp_path / "shared" / "model.ckpt", str(marker), kind)
    capfd.readouterr()
    assert main(_doors(payload, store, honest, tmp_path)[door]) == 2
    _one_error_line(capfd, payload)
    assert not marker.exists()


def test_the_automatic_resume_refuses_a_planted_last_ckpt(trained, tmp_path, capfd):
    from robomorph.cli import main

    store, _ = trained
    marker = tmp_path / "PWNED"
    payload = plant(tmp_path / "runs" / "shared" / "checkpoints" / "last.ckpt", str(marker))
    capfd.readouterr()
    assert main(_fit_argv(store, tmp_path / "runs", run="shared")) == 2
    assert "cannot resume" in _one_error_line(capfd, payload)
    assert not marker.exists()
    assert sorted(os.listdir(tmp_path / "runs" / "shared" / "checkpoints")) == ["last.ckpt"]  # nothing written


@pytest.mark.parametrize("kind", ["checkpoint", "pickle"])
def test_the_python_loaders_refuse_the_payload(kind, tmp_path):
    from robomorph.predictor import Predictor
    from robomorph.training.checkpoints import AtomicCheckpointIO

    marker = tmp_path / "PWNED"
    payload = plant(tmp_path / "model.ckpt", str(marker), kind)
    with pytest.raises(CheckpointError, match="not allowed") as err:
        Predictor.from_checkpoint(payload)
    assert "\n" not in str(err.value) and payload in str(err.value)
    # Lightning's own read of a resume point (trainer.fit(ckpt_path=...)) goes through the same reader.
    with pytest.raises(CheckpointError, match="not allowed"):
        AtomicCheckpointIO().load_checkpoint(payload, weights_only=False)
    assert not marker.exists()


def test_a_pickle_posing_as_safetensors_weights_is_refused(trained, tmp_path):
    from robomorph.model.files import CONFIG_FILE, WEIGHTS_FILE, export
    from robomorph.predictor import Predictor

    _, honest = trained
    folder = tmp_path / "model"
    export(honest, str(folder))
    marker = tmp_path / "PWNED"
    plant(folder / WEIGHTS_FILE, str(marker), "pickle")
    with pytest.raises(CheckpointError, match="does not match config.json"):
        Predictor.from_pretrained(str(folder))
    # With the planted file's own digest recorded, the integrity check passes and the reader refuses it.
    config = json.loads((folder / CONFIG_FILE).read_text())
    config["weights"]["sha256"] = hashlib.sha256((folder / WEIGHTS_FILE).read_bytes()).hexdigest()
    (folder / CONFIG_FILE).write_text(json.dumps(config))
    with pytest.raises(CheckpointError, match="not a readable safetensors file"):
        Predictor.from_pretrained(str(folder))
    assert not marker.exists()
