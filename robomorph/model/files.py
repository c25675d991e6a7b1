"""Model files: the one reader and writer of everything a trained model is stored in.

Two formats, both read without running anything stored in them:

- a **training checkpoint** (``*.ckpt``, written by ``robomorph fit``): Lightning's torch
  zip with the weights, the optimizer state and the run's settings. It is read with
  ``torch.load(weights_only=True)``, which rebuilds tensors, containers and plain values
  only: a file holding any other object (the way a pickle runs code) is refused with
  :class:`CheckpointError` before that object is built. Checkpoints written by ``fit``
  hold nothing else, so no type is added to torch's allow-list.
- a **model folder** (``robomorph export``): ``model.safetensors`` (the network and its
  normalization buffers, no optimizer state) and ``config.json`` (hyper-parameters, what
  the model was trained on, the std calibration, the weights' SHA-256). Neither format can
  hold code.

:func:`read_model` reads either into the checkpoint's layout (``hyper_parameters``,
``state_dict``, ``datamodule_hyper_parameters`` and the ``robomorph_*`` entries), so every
loader treats both alike; :func:`write_model` writes such a record back in its own format.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import warnings

import torch

from robomorph.core.atomic import atomic_open, write_bytes, write_text
from robomorph.core.errors import FileSystemError, RoboMorphError
from robomorph.core.locks import output_folder

CONFIG_FILE, WEIGHTS_FILE = "config.json", "model.safetensors"
FORMAT, FORMAT_VERSION = "robomorph-model", 1
# Checkpoint entry holding what the model was trained on (channel names, dt, window lengths).
DATA_INFO_KEY = "robomorph_data"
# Top-level checkpoint entries a model folder keeps besides the ``robomorph_*`` ones.
_KEPT = ("hyper_parameters", "datamodule_hyper_parameters", "global_step")
# Weights inference needs: the network and its normalizer (not the training wrapper's flags).
_WEIGHT_PREFIXES = ("net.", "normalizer.")
# Marks a record read from a model folder, so that writing it back writes a folder.
_FOLDER_MARK = "_robomorph_model_folder"
_REFUSED = re.compile(r"[Uu]nsupported (?:global: GLOBAL (\S+)|GLOBAL (\S+)|operand (\S+))")
# How torch opens every refusal of weights_only loading; the rest of its text advises loading
# the file unsafely, which is never relayed.
_WEIGHTS_ONLY = "Weights only load failed"


class CheckpointError(RoboMorphError, RuntimeError):
    """A model file that is missing, corrupt, refused as unsafe, or does not fit the model asked for."""


def is_model_folder(path: str) -> bool:
    """True when ``path`` is a folder written by ``robomorph export`` (it holds ``config.json``)."""
    return os.path.isdir(path) and os.path.isfile(os.path.join(path, CONFIG_FILE))


def load_checkpoint_file(path: str) -> dict:
    """Reads a training checkpoint (a file) without running anything stored in it.

    Raises:
        CheckpointError: the file is missing, a folder, corrupt, not a checkpoint, or holds
            objects other than tensors, containers and plain values (refused unbuilt).
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        what = ("an exported model folder (weights only, no optimizer state)" if is_model_folder(path)
                else "a folder")
        raise CheckpointError(f"{path} is {what}, not a training checkpoint file: it cannot resume training")
    if not os.path.isfile(path):
        raise CheckpointError(f"checkpoint not found: {path}")
    ckpt = _safe_torch_load(path)
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt or "hyper_parameters" not in ckpt:
        raise CheckpointError(f"{path} is not a RoboMorph/Lightning checkpoint (no state_dict/hyper_parameters)")
    return ckpt


def _safe_torch_load(path: str):
    """``torch.load(weights_only=True)`` with one-line errors."""
    try:
        with warnings.catch_warnings():
            # A pickle of another protocol than torch's draws a warning before it is refused.
            warnings.simplefilter("ignore")
            return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001  (any unreadable or refused file)
        text = str(exc)
        refused = _REFUSED.search(text)
        if refused or _WEIGHTS_ONLY in text:
            name = refused and (refused.group(1) or refused.group(2))
            what = name or (f"pickle instruction {refused.group(3)}" if refused else "an object of a type not allowed")
            raise CheckpointError(f"{path} contains objects that are not allowed in a model file ({what}): "
                                  "refused without running anything; load model files only from sources "
                                  "you trust") from None
        reason = text.split("WeightsUnpickler error:")[-1].strip()
        first = (reason.splitlines() or [type(exc).__name__])[0]
        raise CheckpointError(f"{path} is not a readable checkpoint (corrupt or truncated?): {first}") from None


def read_model(path: str) -> dict:
    """A training checkpoint or a model folder, as a checkpoint-layout dict.

    A folder's record has ``state_dict`` (the weights), its ``config.json`` entries
    (``hyper_parameters``, ``datamodule_hyper_parameters``, ``global_step`` and the
    ``robomorph_*`` ones), and a mark that makes :func:`write_model` write a folder again.

    Raises:
        CheckpointError: as :func:`load_checkpoint_file`, or a folder whose files are missing,
            unreadable, of another format, or do not belong together.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        return _read_folder(path)
    return load_checkpoint_file(path)


def _read_config(folder: str) -> dict:
    config_path = os.path.join(folder, CONFIG_FILE)
    if not os.path.isfile(config_path):
        raise CheckpointError(f"{folder} is a folder without {CONFIG_FILE}: not a model exported by robomorph export")
    try:
        with open(config_path, encoding="utf-8") as f:
            config = json.load(f)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise CheckpointError(f"{config_path} is not readable JSON: {exc}") from None
    if not isinstance(config, dict) or config.get("format") != FORMAT:
        raise CheckpointError(f"{config_path} is not a RoboMorph model description (no \"format\": \"{FORMAT}\")")
    version = config.get("format_version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise CheckpointError(f"{config_path} has format version {version!r}; this RoboMorph reads up to "
                              f"{FORMAT_VERSION}: upgrade the package")
    if not isinstance(config.get("hyper_parameters"), dict):
        raise CheckpointError(f"{config_path} lacks its hyper_parameters")
    return config


def _read_folder(folder: str) -> dict:
    from safetensors import SafetensorError  # noqa: PLC0415  (only model folders need it)
    from safetensors.torch import load as load_safetensors  # noqa: PLC0415

    config = _read_config(folder)
    weights_path = os.path.join(folder, WEIGHTS_FILE)
    if not os.path.isfile(weights_path):
        raise CheckpointError(f"{folder} lacks {WEIGHTS_FILE}: copy the whole folder, or export it again")
    with open(weights_path, "rb") as f:
        data = f.read()
    weights = config.get("weights")
    expected = weights.get("sha256") if isinstance(weights, dict) else None
    if not isinstance(expected, str):
        # Without the digest nothing ties the weights to this description: never skip the check.
        raise CheckpointError(f"{os.path.join(folder, CONFIG_FILE)} does not record the SHA-256 of {WEIGHTS_FILE} "
                              "(\"weights\": {\"sha256\": ...}): the folder was altered; export it again")
    if hashlib.sha256(data).hexdigest() != expected:
        raise CheckpointError(f"{weights_path} does not match {CONFIG_FILE} (its SHA-256 differs): the folder "
                              "was altered or mixed with another model's files; export it again")
    try:
        state = load_safetensors(data)
    except (SafetensorError, ValueError, RuntimeError) as exc:
        raise CheckpointError(f"{weights_path} is not a readable safetensors file: {exc}") from None
    record = {k: v for k, v in config.items() if k in _KEPT or k.startswith("robomorph_")}
    return {**record, "state_dict": state, _FOLDER_MARK: True}


def _plain(value, where: str):
    """``value`` as JSON data (tuples become lists); anything else is refused, naming where."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, torch.Tensor) and value.numel() == 1:
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict):
        return {str(k): _plain(v, f"{where}.{k}") for k, v in value.items()}
    raise CheckpointError(f"{where} holds a {type(value).__name__}, which a model folder cannot store as JSON")


def model_weights(record: dict) -> dict[str, torch.Tensor]:
    """The tensors inference needs (network and normalizer), contiguous and unshared."""
    state = record["state_dict"]
    return {k: v.detach().cpu().contiguous().clone() for k, v in state.items() if k.startswith(_WEIGHT_PREFIXES)}


def _folder_files(record: dict, source: str | None) -> tuple[bytes, str]:
    """The bytes of ``model.safetensors`` and the text of ``config.json`` of a record."""
    from safetensors.torch import save as save_safetensors  # noqa: PLC0415

    weights = save_safetensors(model_weights(record), metadata={"format": FORMAT})
    config = {"format": FORMAT, "format_version": FORMAT_VERSION,
              "weights": {"file": WEIGHTS_FILE, "sha256": hashlib.sha256(weights).hexdigest()}}
    for key, value in record.items():
        if (key in _KEPT or key.startswith("robomorph_")) and value is not None:
            config[key] = _plain(value, key)
    if source:
        config["exported_from"] = source
    return weights, json.dumps(config, indent=1, allow_nan=True) + "\n"


def write_folder(record: dict, out: str, source: str | None = None) -> None:
    """Writes a model folder whole, under its lock: a reader sees the old folder or the new
    one, never a mix (:func:`robomorph.core.locks.output_folder`).

    Raises:
        OutputExistsError: ``out`` is a file, in a Zarr store, or a folder that is neither
            empty nor a model folder; LockedError: another process writes it.
    """
    weights, config = _folder_files(record, source)
    with output_folder(out, "model") as tmp:
        write_bytes(os.path.join(tmp, WEIGHTS_FILE), weights)
        write_text(os.path.join(tmp, CONFIG_FILE), config)


def write_model(record: dict, out: str) -> None:
    """Writes a record read by :func:`read_model` back in its own format, whole or not at all:
    a model folder as a folder, a checkpoint as a checkpoint file."""
    if record.get(_FOLDER_MARK):
        write_folder(record, out)
        return
    if os.path.isdir(out):
        raise CheckpointError(f"--out {out} is a folder: give the checkpoint file to write")
    save_torch(record, out)


# How torch's C++ zip writer words a write that failed (a full disk): a RuntimeError, not an OSError.
_WRITE_FAILED = ("PytorchStreamWriter failed", "file write failed", "unexpected pos")


def save_torch(obj, path: str) -> None:
    """``torch.save`` of ``obj`` to ``path``, whole or not at all (the one writer of torch files).

    Raises:
        FileSystemError: the write failed (a full disk, most often): one line, not torch's
            C++ trace; the file at ``path`` is as it was.
    """
    try:
        with atomic_open(path, "wb") as f:
            torch.save(obj, f)
    except RuntimeError as exc:
        if not any(m in str(exc) for m in _WRITE_FAILED):
            raise
        raise FileSystemError(f"writing {path} failed (is the disk full?): {str(exc).splitlines()[0]}; free space "
                              "or write to another disk") from exc


def export(src: str, out: str) -> dict:
    """Writes the inference-only model folder of a checkpoint (or of another model folder).

    Returns:
        ``{"weights": path, "config": path, "bytes": {"source": n, "weights": n, "config": n}}``.

    Raises:
        CheckpointError: ``src`` is unreadable or refused; OutputExistsError: see :func:`write_folder`.
    """
    record = read_model(src)
    hp = record.get("hyper_parameters") or {}
    if hp.get("n_u") is None or hp.get("n_y") is None:
        raise CheckpointError(f"{src} lacks n_u/n_y: it was not written by robomorph fit")
    if not model_weights(record):
        raise CheckpointError(f"{src} holds no network weights (no net.* entries)")
    write_folder(record, out, source=os.path.abspath(src))
    paths = {"weights": os.path.join(out, WEIGHTS_FILE), "config": os.path.join(out, CONFIG_FILE)}
    return {**paths, "bytes": {"source": _size(src), **{k: os.path.getsize(p) for k, p in paths.items()}}}


def _size(path: str) -> int:
    if os.path.isdir(path):
        return sum(os.path.getsize(os.path.join(path, n)) for n in (WEIGHTS_FILE, CONFIG_FILE)
                   if os.path.isfile(os.path.join(path, n)))
    with contextlib.suppress(OSError):
        return os.path.getsize(path)
    return 0
