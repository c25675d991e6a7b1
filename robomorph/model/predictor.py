"""Inference API: a trained meta-model as a simulator of an unseen robot.

    from robomorph import Predictor
    pred = Predictor.from_checkpoint("results/runs/ms/checkpoints/best.ckpt")
    y_query = pred.simulate(u_ctx, y_ctx, u_query)   # physical units in and out

This is what a model predictive controller calls: given a window of measured torques and
outputs of the robot at hand (the context) and candidate future torques, it returns the
predicted outputs. Normalization is handled inside (statistics stored in the checkpoint).
Only ``robomorph.model`` and ``robomorph.core`` are needed: no training code, no Lightning.
"""

from __future__ import annotations

import numpy as np
import torch

from robomorph.model.checkpoint import TrainedModel, load_trained


class Predictor:
    """Wraps a :class:`TrainedModel` for inference on numpy or torch arrays.

    Attributes:
        model: the network with its normalization, in eval mode.
        n_u, n_y: channel counts the model expects.
        patch: steps per token; context lengths must be multiples of it.
        data_info: channel names, dt and the training window (None for checkpoints that predate it).
        device: where it runs.
    """

    def __init__(self, model: TrainedModel, device: str | torch.device | None = None, data_info: dict | None = None):
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        self.model = model.to(self.device).eval()
        self.n_u, self.n_y, self.patch = model.config.n_u, model.config.n_y, model.config.patch
        self.data_info = data_info

    @classmethod
    def from_checkpoint(cls, path: str, device: str | torch.device | None = None) -> "Predictor":
        """Loads a checkpoint written by ``robomorph fit`` (clear errors for bad files)."""
        model, info = load_trained(path)
        return cls(model, device, info)

    def _check(self, name: str, x: torch.Tensor, width: int) -> None:
        if x.shape[-1] != width:
            raise ValueError(f"{name} has {x.shape[-1]} channels, the model expects {width}")
        if not torch.isfinite(x).all():
            raise ValueError(f"{name} holds NaN or inf values")

    @torch.no_grad()
    def simulate(self, u_ctx, y_ctx, u_query):
        """Predicts the outputs over the query horizon.

        Args:
            u_ctx: (Tc, n_u) or (B, Tc, n_u) context inputs, numpy or torch.
            y_ctx: (Tc, n_y) or (B, Tc, n_y) context outputs.
            u_query: (Th, n_u) or (B, Th, n_u) future inputs.

        Returns:
            y_query (Th, n_y) or (B, Th, n_y), the same kind (numpy/torch) as ``u_query``.
        """
        as_numpy = not isinstance(u_query, torch.Tensor)
        dtype = getattr(u_query, "dtype", None)
        tensors = [torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x,
                                   dtype=torch.float32, device=self.device) for x in (u_ctx, y_ctx, u_query)]
        single = tensors[0].dim() == 2
        if any(t.dim() != (2 if single else 3) for t in tensors):
            raise ValueError("give all three arrays unbatched (T, C) or all batched (B, T, C)")
        if single:
            tensors = [t.unsqueeze(0) for t in tensors]
        for name, t, w in zip(("u_ctx", "y_ctx", "u_query"), tensors, (self.n_u, self.n_y, self.n_u)):
            self._check(name, t, w)
        y = self.model(*tensors)
        y = y[0] if single else y
        if as_numpy:
            return y.cpu().numpy().astype(dtype if dtype is not None and np.issubdtype(dtype, np.floating) else np.float32)
        return y.to(u_query.device, u_query.dtype)
