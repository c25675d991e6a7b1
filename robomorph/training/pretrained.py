"""Starting a run from a pretrained model (``--model.init_ckpt``): its weights, optionally its
normalization, and the parts of the network kept frozen (``--model.freeze``).

:class:`robomorph.training.module.MetaModule` calls :func:`start_from` once, when training
begins (not on a resume: the run's own checkpoint then supplies the weights).
"""

from __future__ import annotations

import torch

from robomorph.inference.checkpoint import CheckpointError
from robomorph.model.files import DATA_INFO_KEY, read_model

# Parameters of these layers depend on n_u / n_y; ``reinit_io`` re-initializes them.
IO_LAYERS = ("encoder.embed", "decoder.embed", "decoder.init_embed", "head")


def apply_freeze(net: torch.nn.Module, mode: str) -> None:
    """Leaves trainable only what ``freeze`` mode ``mode`` trains."""
    for name, p in net.named_parameters():
        if mode == "encoder":
            p.requires_grad = not name.startswith("enc")
        elif mode == "all_but_head":
            p.requires_grad = name.startswith("head")


def inherited_channels(init_ckpt: str | None, reinit_io: bool, stores: list[str], inputs: str
                       ) -> dict[str, list[str]] | None:
    """The channel set to fine-tune ``init_ckpt`` with, when it is a model of several arms.

    A multi-arm model (``channel_mask``) carries the union of its arms' channels; a run that
    starts from it on stores whose channels are all among them (an arm with fewer joints, or
    one of its arms) trains in that set, so nothing is re-initialized. ``None`` otherwise:
    no checkpoint, ``reinit_io`` (new channels asked for), a single-arm model, or stores
    with channels the model does not carry (the usual messages then say what to do).
    """
    from robomorph.data.sources import Source  # noqa: PLC0415

    if not init_ckpt or reinit_io:
        return None
    try:
        info = read_model(init_ckpt).get(DATA_INFO_KEY) or {}
    except CheckpointError:
        return None  # start_from reports an unreadable checkpoint in its own words
    if not info.get("channel_mask"):
        return None
    u_set, y_set = list(info["u_names"]), list(info["y_names"])
    for path in stores:
        try:
            src = Source(path, inputs)
        except Exception:  # noqa: BLE001  (a missing or foreign store: the pre-flight checks say so)
            return None
        if not (set(src.u_names) <= set(u_set) and set(src.y_names) <= set(y_set)):
            return None
    return {"u": u_set, "y": y_set}


def start_from(module: torch.nn.Module, path: str) -> None:
    """Loads ``path``'s weights into a built ``MetaModule`` and freezes what its ``freeze`` says.

    Its normalization counts as ready only when it came along (``normalization_from=source``);
    otherwise the module's ``setup`` computes it from this run's training data.
    """
    from_source = load_pretrained(module, path)
    module.stats_ready.fill_(from_source)
    apply_freeze(module.net, module.hparams.freeze)


def load_pretrained(module: torch.nn.Module, path: str) -> bool:
    """Loads a pretrained checkpoint's weights into ``module``; True when its normalization came too.

    The statistics (and their "ready" flag) come along only with ``normalization_from=source``;
    otherwise ``setup`` computes them from this run's data. Refuses another protocol, other
    channels without ``reinit_io``, ``source`` statistics for other channels and another
    architecture.
    """
    ckpt = read_model(path)  # a training checkpoint or an exported model folder
    src = ckpt["hyper_parameters"]
    same_io = (src.get("n_u"), src.get("n_y")) == (module.hparams.n_u, module.hparams.n_y)
    theirs, ours = src.get("normalization", "train_stats"), module.hparams.get("normalization", "train_stats")
    if theirs != ours:
        raise CheckpointError(f"{path} was trained with normalization {theirs!r}, this run uses {ours!r}: "
                              "transfer between the same protocol only (set data.normalization to match)")
    if not same_io and not module.hparams.reinit_io:
        raise CheckpointError(
            f"{path} was trained with n_u={src.get('n_u')}, n_y={src.get('n_y')}; this model has "
            f"n_u={module.hparams.n_u}, n_y={module.hparams.n_y}. Set reinit_io=true to re-initialize the "
            "input embeddings and the head (the rest transfers)."
        )
    from_source = module.hparams.get("normalization_from", "target") == "source"
    if from_source and not same_io:
        raise CheckpointError(
            f"normalization_from=source needs the checkpoint's channels, but {path} has n_u={src.get('n_u')}, "
            f"n_y={src.get('n_y')} and this data n_u={module.hparams.n_u}, n_y={module.hparams.n_y}: "
            "use --model.normalization_from target (statistics of the new training data)")
    state = {k: v for k, v in ckpt["state_dict"].items()
             if (from_source or not _is_stats(k)) and (same_io or not _is_io(k))}
    ours = module.state_dict()
    # Checked first: torch refuses other shapes with a page-long RuntimeError, after loading the rest.
    reshaped = sorted(k for k, v in state.items() if k in ours and tuple(v.shape) != tuple(ours[k].shape))
    if reshaped:
        raise CheckpointError(f"{path} does not match this architecture (other shapes of {reshaped[:5]}): "
                              "use the same d_model, n_head, layers and patch")
    missing, unexpected = module.load_state_dict(state, strict=False)
    allowed_missing = [k for k in missing if (not from_source and _is_stats(k)) or (not same_io and _is_io(k))]
    if unexpected and all(".absent." in k for k in unexpected) and not set(missing) - set(allowed_missing) - {"stats_ready"}:
        raise CheckpointError(f"{path} is a model of several arms (it reads absent channels): give its channel "
                              "set (the u_names and y_names it was trained on) with --data.channels to fine-tune it")
    if set(missing) - set(allowed_missing) - {"stats_ready"} or unexpected:
        raise CheckpointError(
            f"{path} does not match this architecture (missing {sorted(set(missing) - set(allowed_missing))[:5]}, "
            f"unexpected {sorted(unexpected)[:5]}): use the same d_model, n_head, layers and patch"
        )
    return from_source


def _is_stats(key: str) -> bool:
    return key.startswith("normalizer.") or key == "stats_ready"


def _is_io(key: str) -> bool:
    return any(key.startswith(f"net.{layer}.") for layer in IO_LAYERS)
