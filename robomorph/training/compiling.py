"""A faster training step on a GPU: the step compiled, with CUDA graphs, and a fused optimizer.

On a GPU the paper's model (12 + 12 layers, d_model 192) is not bound by arithmetic but by
the host: an eager step launches about 2,300 small kernels, one at a time, and bf16 then
gains nothing (REFERENCE.md, issue 24). ``torch.compile`` fuses the element-wise work of
normalization, attention glue, MLP and loss into fewer kernels, and ``mode="reduce-overhead"``
replays the forward and backward as CUDA graphs: one launch each, whatever their kernel count.
The optimizer is AdamW's fused CUDA kernel (:mod:`robomorph.training.optim`). Together they
make the host's share of a step small enough for bf16 to pay.

``--model.compile`` chooses:

- ``auto`` (default): ``reduce-overhead`` when training on a CUDA device and Triton is
  there, otherwise ``off``. The CPU path stays eager, as it was (on a CPU the compiled step
  needs a C++ compiler, and its speed there has not been measured). Where the training
  windows vary in length (``--data.context_min``, ``--data.horizon_min``, as in
  ``train_cpu.yaml``), ``auto`` stays eager too: CUDA graphs would be recorded again for
  every length (hundreds of them, each holding memory), and the compiled step for symbolic
  lengths (what ``default`` then compiles) has not yet been timed on a GPU.
- ``off``: eager, as before.
- ``default``, ``reduce-overhead``, ``max-autotune``: ``torch.compile``'s modes, on any device;
  for windows of varying length, compiled once for symbolic lengths.

Only the training step is compiled. Validation, test and prediction stay eager: their
batch shapes differ from training's, and each new shape would be another compilation.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from robomorph.core.names import COMPILE_MODES
from robomorph.training.losses import ModelOptionError

# The modes whose compiled step replays CUDA graphs (reduce-overhead's and max-autotune's).
_GRAPHED = ("reduce-overhead", "max-autotune")


def check_compile(mode: str) -> None:
    """Raises ModelOptionError naming ``--model.compile`` for an unknown mode."""
    if mode not in COMPILE_MODES:
        raise ModelOptionError(f"--model.compile must be one of {', '.join(COMPILE_MODES)}, got {mode!r}")


def has_triton() -> bool:
    """Whether torch's GPU compiler backend (Triton) can be used here."""
    try:
        from torch.utils._triton import has_triton as _has_triton
    except ImportError:  # an older torch: no such helper, so no promise either
        return False
    return bool(_has_triton())


def resolve_compile(mode: str, device_type: str, varying: bool = False) -> str | None:
    """The ``torch.compile`` mode a training step on ``device_type`` uses, or None for eager;
    ``varying``: the training windows' lengths vary from batch to batch."""
    check_compile(mode)
    if mode == "auto":
        return "reduce-overhead" if device_type == "cuda" and not varying and has_triton() else None
    return None if mode == "off" else mode


class CompiledStep:
    """``fn`` compiled in ``mode`` (for symbolic shapes where ``dynamic``), called as ``fn`` is.

    With CUDA graphs, every call is marked as a new step (the graphs' memory of the last
    call may then be reused), and the outputs are cloned out of that memory: the loss
    Lightning keeps for logging would otherwise be overwritten by the next replay.
    """

    def __init__(self, fn: Callable, mode: str, backend: str | Callable = "inductor", dynamic: bool = False) -> None:
        self.mode = mode
        self.graphed = mode in _GRAPHED and backend == "inductor"
        # dynamic: one compilation for symbolic window lengths rather than one per length.
        self._fn = torch.compile(fn, mode=None if mode == "default" else mode, backend=backend, dynamic=dynamic)

    def __call__(self, *args, **kwargs):
        if self.graphed:
            torch.compiler.cudagraph_mark_step_begin()
        out = self._fn(*args, **kwargs)
        if not self.graphed:
            return out
        return tuple(o.clone() if isinstance(o, torch.Tensor) else o for o in out)
