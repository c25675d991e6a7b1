"""Inference API: a trained meta-model as a simulator of an unseen robot.

    from robomorph import Predictor
    pred = Predictor.from_checkpoint("results/runs/ms/checkpoints/best.ckpt")
    y_query = pred.simulate(u_ctx, y_ctx, u_query)   # physical units in and out

This is what a model predictive controller calls: given a window of measured torques and
outputs of the robot at hand (the context) and candidate future torques, it returns the
predicted outputs. Normalization is handled inside (statistics stored in the checkpoint).

A model trained with ``data.normalization: paper_window`` (the paper's protocol) rescales
each window with the mean and std of the very outputs it predicts; ``simulate`` refuses it
unless the caller passes those statistics explicitly (``y_query_stats``), which only an
evaluation against recorded outputs can do.
"""

from __future__ import annotations

import inspect

import numpy as np
import torch

from robomorph.data.statistics import NormalizationError, leaks_query_statistics
from robomorph.data.store import InputsError, check_inputs
from robomorph.training.module import CheckpointError, MetaModule, load_checkpoint_file


_MEANING = {"total": "total joint torque, gravity compensation included",
            "command": "the command, without the gravity compensation the arm adds"}


class Predictor:
    """Wraps a trained :class:`MetaModule` for inference.

    Attributes:
        module: the LightningModule in eval mode.
        n_u, n_y: channel counts the model expects.
        inputs: the input formulation it was trained on: ``total`` (total joint torque)
            or ``command`` (the command without the arm's gravity compensation).
        device: where it runs.
    """

    def __init__(self, module: MetaModule, device: str | torch.device | None = None):
        if module.net is None:
            raise CheckpointError("the module has no network (it was never built or trained)")
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        self.module = module.to(self.device).eval()
        self.n_u, self.n_y = int(module.hparams.n_u), int(module.hparams.n_y)
        # Channel names, dt and the training window (None for checkpoints that predate it).
        self.data_info: dict | None = module.data_info
        # Whether the model has a Gaussian head (simulate(..., return_std=True) works).
        self.has_std = bool(module.hparams.get("gaussian", False))
        # Checkpoints written before the command formulation were all trained on total torque.
        self.inputs: str = (self.data_info or {}).get("inputs", "total")
        self.normalization: str = module.hparams.get("normalization", "train_stats")

    def check_inputs(self, inputs: str | None) -> None:
        """Refuses inputs of the other formulation than the one the model was trained on."""
        if inputs is not None and check_inputs(inputs) != self.inputs:
            raise InputsError(
                f"the model was trained on inputs={self.inputs} ({_MEANING[self.inputs]}) but was given "
                f"inputs={inputs} ({_MEANING[inputs]}): feed it the {self.inputs} array "
                f"({'u' if self.inputs == 'total' else 'u_cmd'}) or use a checkpoint trained with "
                f"data.inputs={inputs}")

    @property
    def leaks_query_statistics(self) -> bool:
        """True when this model's predictions need the query outputs' statistics (``paper_window``)."""
        return leaks_query_statistics(self.normalization)

    @classmethod
    def from_checkpoint(cls, path: str, device: str | torch.device | None = None) -> "Predictor":
        """Loads a checkpoint written by ``robomorph.fit`` (clear errors for bad files)."""
        ckpt = load_checkpoint_file(path)
        hp = ckpt["hyper_parameters"]
        if hp.get("n_u") is None or hp.get("n_y") is None:
            raise CheckpointError(f"{path} lacks n_u/n_y: it was not written by robomorph.fit")
        accepted = inspect.signature(MetaModule.__init__).parameters
        module = MetaModule(**{k: v for k, v in hp.items() if k in accepted and k != "init_ckpt"})
        module.on_load_checkpoint(ckpt)
        try:
            module.load_state_dict(ckpt["state_dict"])
        except RuntimeError as exc:
            raise CheckpointError(f"{path} does not match its own hyper-parameters: {exc}") from exc
        return cls(module, device)

    def _check(self, name: str, x: torch.Tensor, width: int) -> None:
        if x.shape[-1] != width:
            raise ValueError(f"{name} has {x.shape[-1]} channels, the model expects {width}")
        if not torch.isfinite(x).all():
            raise ValueError(f"{name} holds NaN or inf values")

    def _query_stats(self, y_query_stats, batch: int):
        """Checks ``y_query_stats`` against the normalization; (mean, std) tensors (B, n_y) or None."""
        if not self.leaks_query_statistics:
            if y_query_stats is not None:
                raise NormalizationError(f"this model was trained with normalization {self.normalization!r}, which "
                                         "uses no query statistics: drop y_query_stats")
            return None
        if y_query_stats is None:
            raise NormalizationError(
                "this model was trained with normalization 'paper_window' (the paper's protocol): it rescales each "
                "window with the mean and std of the outputs it is asked to predict, which a deployed model cannot "
                "know. Pass y_query_stats=(mean, std) of the query outputs "
                "(robomorph.data.statistics.query_output_stats(y_query)) to score it as the paper did, or train "
                "with data.normalization=train_stats for a model you can deploy")
        if len(y_query_stats) != 2:
            raise NormalizationError("y_query_stats must be a pair (mean, std) of the query outputs")
        out = []
        for name, v in zip(("mean", "std"), y_query_stats):
            t = torch.as_tensor(np.asarray(v) if not isinstance(v, torch.Tensor) else v, dtype=torch.float32,
                                device=self.device)
            t = t.unsqueeze(0) if t.dim() == 1 else t
            if t.shape not in ((1, self.n_y), (batch, self.n_y)) or not torch.isfinite(t).all():
                raise NormalizationError(f"y_query_stats {name} must be finite, ({self.n_y},) or ({batch}, {self.n_y}); "
                                         f"got {tuple(t.shape)}")
            out.append(t.expand(batch, self.n_y))
        return tuple(out)

    @torch.no_grad()
    def simulate(self, u_ctx, y_ctx, u_query, y_query_stats=None, inputs: str | None = None,
                 return_std: bool = False):
        """Predicts the outputs over the query horizon.

        Args:
            u_ctx: (Tc, n_u) or (B, Tc, n_u) context inputs, numpy or torch.
            y_ctx: (Tc, n_y) or (B, Tc, n_y) context outputs.
            u_query: (Th, n_u) or (B, Th, n_u) future inputs.
            y_query_stats: only for a ``paper_window`` model, and required there: ``(mean, std)``
                over time of the query outputs, (n_y,) or (B, n_y) each. This is information
                about the answer: scores obtained with it are not those of a deployable model.
            inputs: which formulation the torques are (``total`` or ``command``); when
                given, a mismatch with the training formulation is refused.
            return_std: also return the predicted standard deviation (models trained with
                ``gaussian: true`` only).

        Returns:
            y_query (Th, n_y) or (B, Th, n_y), the same kind (numpy/torch) as ``u_query``;
            with ``return_std``, ``(mean, std)``, both in the outputs' physical units.

        Raises:
            NormalizationError: ``y_query_stats`` missing for a ``paper_window`` model, given
                for another, or of the wrong shape.
            CheckpointError: ``return_std`` for a model without a Gaussian head.
        """
        self.check_inputs(inputs)
        if return_std and not self.has_std:
            raise CheckpointError("this model has no Gaussian head, so it predicts no standard deviation; "
                                  "train one with --model.gaussian true --model.loss nll, or drop return_std")
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
        mean, std = self.module.forward_dist(*tensors, self._query_stats(y_query_stats, len(tensors[0])))
        out = [t[0] if single and t is not None else t for t in (mean, std)]
        if as_numpy:
            kind = dtype if dtype is not None and np.issubdtype(dtype, np.floating) else np.float32
            out = [t.cpu().numpy().astype(kind) for t in out if t is not None]
        else:
            out = [t.to(u_query.device, u_query.dtype) for t in out if t is not None]
        return tuple(out) if return_std else out[0]
