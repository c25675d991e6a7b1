"""The multi-arm meta-model as a free-running simulator, to fine-tune on free-run simulation error.

:class:`MetaSim` wraps a trained encoder-decoder meta-model (a shipped one such as
``realistic-arms-60hz``, or any model folder or checkpoint) in the interface of
:class:`robomorph.training.free_run.FreeRunModel`, so :func:`robomorph.training.free_run.fit`
fine-tunes it exactly as it trains the ARX, NARX and GRU: windows growing to whole trajectories,
free-run from a short warm-up, normalisation from the training split, early stopping on validation
trajectories.

How a robot's channels reach the model (:class:`ChannelMap`): its ``n_u`` inputs fill the model's
first input channels, its ``n_y`` outputs the model's output channels named by ``y_channels``
(for a 6-joint arm's joint angles, ``q0..q5``); every other channel (the seventh joint, the
end-effector pose a joint log lacks) is absent, NaN, which a ``channel_mask`` model reads as
missing rather than zero. The data arrive z-scored by the training split
(:class:`robomorph.training.free_run.Normalizer`), so the model's own normalizer is set to the
identity: the network sees the new robot's training statistics, not the simulated arms'.

How the rate is mapped: one model step is one sample of the data, whatever its rate (the
industrial robot's 0.1 s against the 1/60 s the model was trained at). Nothing is resampled: the
query positions, the context and initial-condition tokens keep their meaning as steps, and the
fine-tuning relearns the time scale (a 10 Hz step moves six times as far).

The free run (:meth:`MetaSim.run`): the context is the last ``context`` samples before the query
(a warm-up shorter than that is padded with its first sample, the robot at rest before it moved,
as :func:`robomorph.training.free_run._history` pads); the query is predicted in chunks of at most
``chunk`` steps (the model's horizon tables are finite), each next context being the inputs and the
model's *own* predicted outputs, so no true output is read after the warm-up.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from robomorph.inference.checkpoint import TrainedModel, load_trained
from robomorph.model.channels import pad, select
from robomorph.model.pretrained import resolve
from robomorph.training.free_run import FreeRunError, FreeRunModel


@dataclass(frozen=True)
class ChannelMap:
    """Where a robot's channels sit among the model's.

    Attributes:
        u_channels: the model input index of each of the robot's inputs.
        y_channels: the model output index of each of the robot's outputs.
    """

    u_channels: tuple[int, ...]
    y_channels: tuple[int, ...]

    @classmethod
    def joints(cls, model: TrainedModel, y_names: list[str], n_u: int, n_y: int) -> ChannelMap:
        """The first ``n_u`` torques onto ``tau0..``, the ``n_y`` joint angles onto ``q0..`` of ``y_names``
        (the model's output names)."""
        if n_u > model.config.n_u:
            raise FreeRunError(f"the robot has {n_u} inputs, the model {model.config.n_u}")
        wanted = [f"q{j}" for j in range(n_y)]
        missing = [q for q in wanted if q not in y_names]
        if missing:
            raise FreeRunError(f"the model has no output channel {', '.join(missing)} (its outputs: "
                               f"{', '.join(y_names)})")
        return cls(tuple(range(n_u)), tuple(y_names.index(q) for q in wanted))


class MetaSim(FreeRunModel):
    """A meta-model (:class:`TrainedModel`) stepping as a free-run simulator of one robot.

    Args:
        model: the trained meta-model; its weights are the starting point (and are trained).
        channels: where the robot's channels sit (:class:`ChannelMap`).
        context: context samples per prediction, a multiple of the model's patch and at least its
            initial-condition tokens.
        chunk: query steps predicted per pass, at most the model's horizon table.
    """

    def __init__(self, model: TrainedModel, channels: ChannelMap, context: int = 20, chunk: int = 600):
        super().__init__()
        cfg = model.config
        if context % cfg.patch or context < max(cfg.n_init, cfg.patch) or context > cfg.max_context:
            raise FreeRunError(f"MetaSim context {context} must be a multiple of the patch ({cfg.patch}), at least "
                               f"{max(cfg.n_init, cfg.patch)} and at most {cfg.max_context}")
        if not 1 <= chunk <= cfg.max_horizon:
            raise FreeRunError(f"MetaSim chunk {chunk} must be in [1, {cfg.max_horizon}]")
        if not cfg.channel_mask and (len(channels.u_channels) < cfg.n_u or len(channels.y_channels) < cfg.n_y):
            raise FreeRunError("the model has no channel mask, so it cannot read a robot with fewer channels")
        self.model, self.channels, self.lag, self.chunk = model, channels, context, chunk
        self.n_u, self.n_y = cfg.n_u, cfg.n_y
        self.columns = (list(channels.u_channels), list(channels.y_channels))  # model.channels.Columns: pad and select
        with torch.no_grad():  # the data arrive z-scored by the robot's own training split
            for name in ("u_mean", "y_mean"):
                getattr(model.normalizer, name).zero_()
            for name in ("u_std", "y_std"):
                getattr(model.normalizer, name).fill_(1.0)

    @classmethod
    def from_pretrained(cls, path: str, n_u: int, n_y: int, context: int = 20, chunk: int = 600,
                        scratch: bool = False) -> MetaSim:
        """The meta-model at ``path`` (a shipped model's name, a model folder or a checkpoint) for a robot of
        ``n_u`` torques and ``n_y`` joint angles; ``scratch``: its architecture and output form alone, the
        weights drawn afresh from torch's current seed (what the pre-training is worth, measured)."""
        model, info = load_trained(resolve(path))
        if scratch:
            model = TrainedModel(model.config, recenter=model.normalizer.recenter, anchor=model.anchor,
                                 integrate=model.integrate, extrapolate=model.extrapolate,
                                 velocity_points=model.velocity_points)
        y_names = (info or {}).get("y_names") or []
        return cls(model, ChannelMap.joints(model, y_names, n_u, n_y), context, chunk)

    def start(self, y_hist, u_hist):  # (B, context, n_y), (B, context, n_u): the robot's channels
        return y_hist, u_hist

    def run(self, state, u):  # u (B, L, n_u) -> (state, y (B, L, n_y))
        y_ctx, u_ctx = state
        outs = []
        for c0 in range(0, u.shape[1], self.chunk):
            uq = u[:, c0:c0 + self.chunk]
            # The robot's channels spread over the model's, NaN (absent) where it has none, and its outputs read back.
            mean, _ = self.model.forward_dist_raw(*pad([u_ctx, y_ctx, uq], self.columns, self.n_u, self.n_y))
            y = select(mean, self.columns)  # (B, Lc, n_y)
            outs.append(y)
            # the next context: the inputs and the model's own outputs, never a true output
            u_ctx = torch.cat([u_ctx, uq], 1)[:, -self.lag:]
            y_ctx = torch.cat([y_ctx, y], 1)[:, -self.lag:]
        return (y_ctx, u_ctx), torch.cat(outs, 1)

    def step(self, state, u_t):
        state, y = self.run(state, u_t[:, None])
        return state, y[:, 0]
