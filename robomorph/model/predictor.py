"""Inference API: a trained meta-model as a simulator of an unseen robot.

    from robomorph import Predictor
    pred = Predictor.from_checkpoint("results/runs/ms/checkpoints/best.ckpt")
    y_query = pred.simulate(u_ctx, y_ctx, u_query)   # physical units in and out

This is what a model predictive controller calls: given a window of measured torques and
outputs of the robot at hand (the context) and candidate future torques, it returns the
predicted outputs. Normalization is handled inside (statistics stored in the checkpoint).
Only ``robomorph.model`` and ``robomorph.core`` are needed: no training code, no Lightning.

A model trained with ``data.normalization: paper_window`` (the paper's protocol) rescales
each window with the mean and std of the very outputs it predicts; ``simulate`` refuses it
unless the caller passes those statistics explicitly (``y_query_stats``), which only an
evaluation against recorded outputs can do.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
import torch

from robomorph.core.errors import RoboMorphError
from robomorph.core.inputs import check_model_inputs
from robomorph.core.normalizations import NormalizationError, leaks_query_statistics
from robomorph.model.checkpoint import CheckpointError, TrainedModel, load_trained


class PredictionError(RoboMorphError, ValueError):
    """Inputs the model cannot predict from (wrong shape, non-finite, or overflowing)."""


class Predictor:
    """Wraps a :class:`TrainedModel` for inference on numpy or torch arrays.

    Attributes:
        model: the network with its normalization, in eval mode.
        n_u, n_y: channel counts the model expects.
        patch: steps per token; context lengths must be multiples of it.
        normalization: the protocol it was trained with (``train_stats`` or ``paper_window``).
        inputs: the input formulation it was trained on: ``total`` (total joint torque)
            or ``command`` (the command without the arm's gravity compensation).
        data_info: channel names, dt and the training window (None for checkpoints that predate it).
        has_std: the model has a Gaussian head (``simulate(..., return_std=True)`` works).
        calibration: the per-horizon scale of that std stored in the checkpoint by
            ``python -m robomorph.calibrate`` (a :class:`StdCalibration`), or None; ``simulate``
            applies it.
        device: where it runs.
    """

    def __init__(self, model: TrainedModel, device: str | torch.device | None = None, data_info: dict | None = None):
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        self.model = model.to(self.device).eval()
        self.n_u, self.n_y, self.patch = model.config.n_u, model.config.n_y, model.config.patch
        self.normalization: str = model.normalizer.normalization
        self.data_info = data_info
        self.has_std = bool(getattr(model, "gaussian", False))
        # Checkpoints written before the command formulation were all trained on total torque.
        self.inputs: str = (data_info or {}).get("inputs", "total")

    def check_inputs(self, inputs: str | None) -> None:
        """Refuses inputs of the other formulation than the one the model was trained on."""
        check_model_inputs(self.inputs, inputs)

    @property
    def calibration(self):
        return self.model.calibration

    @contextlib.contextmanager
    def raw_std(self) -> Iterator["Predictor"]:
        """Within the block, ``simulate`` returns the Gaussian head's own standard deviation,
        without the stored calibration (what calibrating is fitted on)."""
        kept = self.model.calibration
        self.model.calibration = None
        try:
            yield self
        finally:
            self.model.calibration = kept

    @property
    def leaks_query_statistics(self) -> bool:
        """True when this model's predictions need the query outputs' statistics (``paper_window``)."""
        return leaks_query_statistics(self.normalization)

    @classmethod
    def from_checkpoint(cls, path: str, device: str | torch.device | None = None) -> "Predictor":
        """Loads a checkpoint written by ``robomorph fit`` (clear errors for bad files)."""
        model, info = load_trained(path)
        return cls(model, device, info)

    def _check(self, name: str, x: torch.Tensor, width: int) -> None:
        if x.shape[-1] != width:
            raise PredictionError(f"{name} has {x.shape[-1]} channels, the model expects {width}")
        if not torch.isfinite(x).all():
            raise PredictionError(f"{name} holds NaN or inf values")

    def _check_output(self, y: torch.Tensor, inputs: list[torch.Tensor]) -> None:
        """Refuses non-finite predictions instead of handing them on without a word."""
        bad = (~torch.isfinite(y)).flatten(1).any(1)
        if not bad.any():
            return
        rows = torch.nonzero(bad).flatten().tolist()
        stats = self.model.normalizer
        scale = max(float((inputs[0].abs() / stats.u_std).max()), float((inputs[2].abs() / stats.u_std).max()))
        raise PredictionError(
            f"the model's predictions are non-finite (NaN or inf) for batch rows {rows[:10]}: the inputs reach "
            f"{scale:.3g} training standard deviations, far outside what the model was trained on; check their "
            "units and scale (the checkpoint expects the training data's)")

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
                "(robomorph.core.normalizations.query_output_stats(y_query)) to score it as the paper did, or train "
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
                ``gaussian: true`` only), recalibrated by horizon when the checkpoint
                carries a calibration (:attr:`calibration`).

        Returns:
            y_query (Th, n_y) or (B, Th, n_y), the same kind (numpy/torch) as ``u_query``;
            with ``return_std``, ``(mean, std)``, both in the outputs' physical units.

        Raises:
            NormalizationError: ``y_query_stats`` missing for a ``paper_window`` model, given
                for another, or of the wrong shape.
            InputsError: ``inputs`` names the other formulation.
            PredictionError: arrays of the wrong shape, non-finite inputs, or non-finite predictions.
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
            raise PredictionError("give all three arrays unbatched (T, C) or all batched (B, T, C)")
        if single:
            tensors = [t.unsqueeze(0) for t in tensors]
        for name, t, w in zip(("u_ctx", "y_ctx", "u_query"), tensors, (self.n_u, self.n_y, self.n_u)):
            self._check(name, t, w)
        mean, std = self.model.forward_dist(*tensors, self._query_stats(y_query_stats, len(tensors[0])))
        self._check_output(mean, tensors)
        out = [t[0] if single else t for t in (mean, std) if t is not None]
        if as_numpy:
            kind = dtype if dtype is not None and np.issubdtype(dtype, np.floating) else np.float32
            out = [t.cpu().numpy().astype(kind) for t in out]
        else:
            out = [t.to(u_query.device, u_query.dtype) for t in out]
        return tuple(out) if return_std else out[0]
