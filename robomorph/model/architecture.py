"""The meta-model's architecture: :class:`ModelConfig`, validated, and the head's bounds.

Read by every part of the network (:mod:`robomorph.model.transformer`,
:mod:`robomorph.model.blocks`, :mod:`robomorph.model.parameter_head`);
``from robomorph.model.transformer import ModelConfig`` keeps working.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from robomorph.core.config import ConfigError

# Range of the Gaussian head's log-variance (normalized units): std from 4.5e-5 to 150.
LOGVAR_MIN, LOGVAR_MAX = -20.0, 10.0


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of the meta-model.

    Attributes:
        n_u: Input channels per step (joint torques).
        n_y: Output channels per step (pose and joint positions).
        d_model: Width of the residual stream.
        n_head: Attention heads; must divide ``d_model``.
        n_layer: Encoder blocks.
        n_layer_dec: Decoder blocks; ``None`` means the same as ``n_layer``.
        dropout: Dropout on embeddings, attention weights and residual branches.
        bias: Biases in the linear layers and LayerNorms.
        max_context: Longest context, in steps, the encoder's positional table covers.
        max_horizon: Longest query horizon, in steps, the decoder's table covers.
        patch: Steps per token (1 = one token per step, the paper's model). The default
            10 is the CPU-sized model's: about 13x faster per training step than 1 on two
            cores (README, "Training on a CPU"); the training module takes its defaults here.
        n_init: Last context steps given to the decoder as initial-condition tokens (0 = off);
            a multiple of ``patch``, at most ``max_context``; contexts must be at least this long.
        gaussian: The head also emits a log-variance per step and channel.
        n_params: Physical parameters the parameter head predicts from the encoder's memory
            (0 = no parameter head; the hybrid model's amortized identification,
            :meth:`MetaModel.forward_params`).
        channel_mask: Inputs may lack channels (an arm with fewer joints than the model's
            channel set): NaN marks an absent channel; it enters as 0 and a learned
            embedding of which channels are absent is added to every token. False: the
            original model (its checkpoints load unchanged).
        residual: The decoder also reads a prior prediction of the query outputs (``n_y`` more
            channels per query step, e.g. the physics hybrid's), and the network's output is a
            correction added to it (:mod:`robomorph.inference.residual`). False: the original model.
    """

    n_u: int = 7
    n_y: int = 14
    d_model: int = 128
    n_head: int = 4
    n_layer: int = 4
    n_layer_dec: int | None = None
    dropout: float = 0.0
    bias: bool = True
    max_context: int = 1024
    max_horizon: int = 1024
    patch: int = 10
    n_init: int = 0
    gaussian: bool = False
    n_params: int = 0
    channel_mask: bool = False
    residual: bool = False

    def __post_init__(self) -> None:
        for name in ("n_u", "n_y", "d_model", "n_head", "n_layer", "max_context", "max_horizon", "patch"):
            _require_positive_int(name, getattr(self, name))
        if self.n_layer_dec is not None:
            _require_positive_int("n_layer_dec", self.n_layer_dec)
        if self.d_model % self.n_head != 0:
            raise ConfigError(f"ModelConfig.d_model ({self.d_model}) must be divisible by n_head ({self.n_head})")
        if isinstance(self.dropout, bool) or not isinstance(self.dropout, (int, float)) or not 0 <= self.dropout < 1:
            raise ConfigError(f"ModelConfig.dropout must be a number in [0, 1), got {self.dropout!r}")
        for name in ("bias", "gaussian", "channel_mask", "residual"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"ModelConfig.{name} must be true or false, got {getattr(self, name)!r}")
        if isinstance(self.n_params, bool) or not isinstance(self.n_params, int) or self.n_params < 0:
            raise ConfigError(f"ModelConfig.n_params must be a non-negative integer, got {self.n_params!r}")
        if self.channel_mask and self.n_params:
            raise ConfigError("ModelConfig.channel_mask (stores of several arms) and a parameter head (n_params, "
                              "the Panda's physics) do not go together: train the hybrid on Panda stores")
        if self.residual and (self.channel_mask or self.n_params or self.gaussian):
            raise ConfigError("ModelConfig.residual (a correction of a physics prior) goes with neither channel_mask, "
                              "a parameter head (n_params) nor a Gaussian head (gaussian)")
        if isinstance(self.n_init, bool) or not isinstance(self.n_init, int) or self.n_init < 0:
            raise ConfigError(f"ModelConfig.n_init must be a non-negative integer, got {self.n_init!r}")
        if self.n_init % self.patch or self.n_init > self.max_context:
            raise ConfigError(f"ModelConfig.n_init ({self.n_init}) must be a multiple of patch ({self.patch}) "
                              f"and at most max_context ({self.max_context})")
        for name in ("max_context", "max_horizon"):
            if getattr(self, name) < self.patch:
                raise ConfigError(f"ModelConfig.{name} ({getattr(self, name)}) must be at least patch ({self.patch})")

    @property
    def decoder_layers(self) -> int:
        """Number of decoder blocks."""
        return self.n_layer if self.n_layer_dec is None else self.n_layer_dec

    @property
    def n_prior(self) -> int:
        """Prior channels per query step the decoder reads (``n_y`` with ``residual``, else 0)."""
        return self.n_y if self.residual else 0

    @property
    def context_tokens(self) -> int:
        """Rows of the encoder's positional table."""
        return math.ceil(self.max_context / self.patch)

    @property
    def horizon_tokens(self) -> int:
        """Rows of the decoder's positional table."""
        return math.ceil(self.max_horizon / self.patch)

    @property
    def init_tokens(self) -> int:
        """Initial-condition tokens ahead of the query tokens."""
        return self.n_init // self.patch


# Upper bounds of the sizes, far above any model this package trains: a model file declaring
# more (d_model 10^9, n_layer 10^6) would exhaust memory building the network before its
# weights could be checked against it.
MAX_SIZES = {"n_u": 4096, "n_y": 4096, "d_model": 65536, "n_head": 1024, "n_layer": 1024, "n_layer_dec": 1024,
             "max_context": 10**7, "max_horizon": 10**7, "patch": 10**5}


def _require_positive_int(name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"ModelConfig.{name} must be a positive integer, got {value!r}")
    if value > MAX_SIZES.get(name, value):
        raise ConfigError(f"ModelConfig.{name} must be at most {MAX_SIZES[name]}, got {value!r}")
