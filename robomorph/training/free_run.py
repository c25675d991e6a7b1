"""Small sequence models trained on free-run simulation error (the industrial robot benchmark's way).

The published models of the industrial robot benchmark learn to *simulate*: from a state set by a
few true samples, the measured inputs alone drive them over long sequences, and the loss is the
error of that free run. Three such models live here, one interface (:class:`FreeRunModel`):

- :class:`ARX`: linear, ``y_t = sum_i A_i y_{t-i} + sum_k B_k u_{t-k} + c`` (``u_t`` included),
  started from its least-squares (one-step) fit and refined on simulation error;
- :class:`NARX`: that ARX plus a small MLP of the same regressors (its last layer zero at the
  start, so it starts as the ARX);
- :class:`GRUSim`: a GRU over the inputs and its own fed-back outputs, integrating a predicted
  increment (``y_t = y_{t-1} + head(h_t)``), its state set from the warm-up's last outputs.

:func:`fit` trains one: windows cut at random from the training trajectories (a share from the
trajectory's start, at rest), growing to whole trajectories; truncated back-propagation through
time every ``tbptt`` steps; inputs and outputs normalised with the training split's statistics
(:class:`Normalizer`); early stopping on the free-run error of whole validation trajectories
(a split cut by trajectory), the best state kept; a wall-clock budget. Optionally the training
inputs are perturbed (``input_offset``, ``input_noise``): a robot's torques for one motion change
with its temperature, measured on the benchmark's repeated test motions.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from robomorph.core.errors import RoboMorphError


class FreeRunError(RoboMorphError, ValueError):
    """A free-run training setting or data set that cannot be used."""


@dataclass(frozen=True)
class Normalizer:
    """Per-channel mean and std of inputs and outputs, from the training split alone."""

    u_mean: np.ndarray
    u_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray

    @classmethod
    def of(cls, trajectories: list) -> Normalizer:
        u = np.concatenate([u for u, _ in trajectories])
        y = np.concatenate([y for _, y in trajectories])
        floor = 1e-8  # a constant channel keeps its scale instead of dividing by zero
        return cls(u.mean(0), np.maximum(u.std(0), floor), y.mean(0), np.maximum(y.std(0), floor))

    def u(self, u):
        return (u - self.u_mean) / self.u_std

    def y(self, y):
        return (y - self.y_mean) / self.y_std

    def y_back(self, y):
        return y * self.y_std + self.y_mean


class FreeRunModel(nn.Module):
    """A model that simulates: ``start`` from the warm-up's last ``lag`` samples, then ``step``
    on one input at a time, never reading a true output again."""

    lag = 1

    def start(self, y_hist: torch.Tensor, u_hist: torch.Tensor):  # (B, lag, n_y), (B, lag, n_u)
        raise NotImplementedError

    def step(self, state, u_t: torch.Tensor):  # u_t (B, n_u) -> (state, y_t (B, n_y))
        raise NotImplementedError

    def run(self, state, u: torch.Tensor):  # u (B, L, n_u) -> (state, y (B, L, n_y))
        """Steps over a chunk of inputs; a model with a faster whole-chunk path overrides it."""
        outs = []
        for t in range(u.shape[1]):
            state, y_t = self.step(state, u[:, t])
            outs.append(y_t)
        return state, torch.stack(outs, 1)

    @staticmethod
    def detach(state):
        return tuple(s.detach() for s in state)


class ARX(FreeRunModel):
    """Linear ARX(na, nb) in normalised units; ``u_t`` is among its ``nb`` inputs."""

    def __init__(self, n_u: int, n_y: int, na: int = 2, nb: int = 2):
        super().__init__()
        self.na, self.nb, self.lag = na, nb, max(na, nb)
        self.lin = nn.Linear(na * n_y + nb * n_u, n_y)

    def regressors(self, y_hist, u_hist, u_t):  # y_hist (B, na, n_y) oldest first; u_hist (B, nb-1, n_u)
        ys = y_hist.flip(1).flatten(1)  # y_{t-1}, y_{t-2}, ...
        us = torch.cat([u_t[:, None], u_hist.flip(1)], 1).flatten(1)  # u_t, u_{t-1}, ...
        return torch.cat([ys, us], 1)

    def start(self, y_hist, u_hist):
        return y_hist[:, -self.na:], u_hist[:, u_hist.shape[1] - (self.nb - 1):]

    def predict_step(self, y_hist, u_hist, u_t):
        return self.lin(self.regressors(y_hist, u_hist, u_t))

    def step(self, state, u_t):
        y_hist, u_hist = state
        y_t = self.predict_step(y_hist, u_hist, u_t)
        y_hist = torch.cat([y_hist[:, 1:], y_t[:, None]], 1)
        u_hist = torch.cat([u_hist[:, 1:], u_t[:, None]], 1) if self.nb > 1 else u_hist
        return (y_hist, u_hist), y_t

    def fit_least_squares(self, trajectories: list) -> ARX:
        """The one-step least-squares fit (normalised trajectories ``[(u, y)]``), written into the
        linear layer; ridge 1e-6 keeps it defined on collinear torques."""
        rows, targets = [], []
        for u, y in trajectories:
            for t in range(self.lag, len(u)):
                rows.append(np.concatenate([y[t - self.na:t][::-1].ravel(), u[t - self.nb + 1:t + 1][::-1].ravel(), [1.0]]))
                targets.append(y[t])
        a, b = np.asarray(rows), np.asarray(targets)
        theta = np.linalg.solve(a.T @ a + 1e-6 * np.eye(a.shape[1]), a.T @ b)
        with torch.no_grad():
            self.lin.weight.copy_(torch.as_tensor(theta[:-1].T, dtype=self.lin.weight.dtype))
            self.lin.bias.copy_(torch.as_tensor(theta[-1], dtype=self.lin.bias.dtype))
        return self


class NARX(ARX):
    """The ARX plus an MLP of the same regressors, which starts at zero."""

    def __init__(self, n_u: int, n_y: int, na: int = 2, nb: int = 2, hidden: int = 64):
        super().__init__(n_u, n_y, na, nb)
        self.mlp = nn.Sequential(nn.Linear(na * n_y + nb * n_u, hidden), nn.Tanh(), nn.Linear(hidden, hidden),
                                 nn.Tanh(), nn.Linear(hidden, n_y))
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    def predict_step(self, y_hist, u_hist, u_t):
        x = self.regressors(y_hist, u_hist, u_t)
        return self.lin(x) + self.mlp(x)


class GRUSim(FreeRunModel):
    """A GRU over ``[u_t, y_{t-1}, y_{t-1} - y_{t-2}]`` (its own outputs fed back) that integrates
    ``y_t = y_{t-1} + head(h_t)``; ``h_0`` from the warm-up's last two outputs."""

    lag = 2

    def __init__(self, n_u: int, n_y: int, hidden: int = 96):
        super().__init__()
        self.cell = nn.GRUCell(n_u + 2 * n_y, hidden)
        self.init = nn.Linear(2 * n_y, hidden)
        self.head = nn.Linear(hidden, n_y)
        with torch.no_grad():  # small first increments: the free run starts near hold
            self.head.weight.mul_(0.1)
            self.head.bias.zero_()

    def start(self, y_hist, u_hist):
        y1, y0 = y_hist[:, -1], y_hist[:, -2]
        return torch.tanh(self.init(torch.cat([y1, y1 - y0], 1))), y1, y0

    def step(self, state, u_t):
        h, y1, y0 = state
        h = self.cell(torch.cat([u_t, y1, y1 - y0], 1), h)
        y_t = y1 + self.head(h)
        return (h, y_t, y1), y_t


def _history(x: torch.Tensor, w: int, lag: int) -> torch.Tensor:
    """The last ``lag`` of the first ``w`` samples (B, lag, n), the first repeated where ``w < lag``
    (a run from rest: the robot stood there before)."""
    h = x[:, max(0, w - lag):w]
    if h.shape[1] < lag:
        h = torch.cat([h[:, :1].expand(-1, lag - h.shape[1], -1), h], 1)
    return h


def simulate(model: FreeRunModel, u: torch.Tensor, y_init: torch.Tensor) -> torch.Tensor:
    """The free run (B, T, n_y): ``y_init`` (B, w, n_y) copied, then ``model`` stepped on ``u[:, w:]``."""
    w = y_init.shape[1]
    state = model.start(_history(y_init, w, model.lag), _history(u, w, model.lag))
    _, y = model.run(state, u[:, w:])
    return torch.cat([y_init, y], 1)


def predictor(model: FreeRunModel, norm: Normalizer):
    """``predict(u, y_init) -> y_hat`` in the data's units (readings' contract), no gradients."""

    def predict(u: np.ndarray, y_init: np.ndarray) -> np.ndarray:
        model.eval()
        with torch.no_grad():
            un = torch.as_tensor(norm.u(u), dtype=torch.float32)[None]
            yn = torch.as_tensor(norm.y(y_init), dtype=torch.float32)[None]
            out = norm.y_back(simulate(model, un, yn)[0].double().numpy())
        out[:len(y_init)] = y_init
        return out

    return predict


@dataclass(frozen=True)
class FreeRunConfig:
    """How :func:`fit` trains (see the module's docstring); validated on construction."""

    warmup: int = 3
    window_min: int = 100
    tbptt: int = 200
    batch: int = 32
    lr: float = 3e-3
    weight_decay: float = 0.0
    iterations: int = 600
    val_every: int = 10
    patience: int = 12
    from_rest: float = 0.5
    input_offset: float = 0.0
    input_noise: float = 0.0
    grad_clip: float = 1.0
    time_budget_s: float = 900.0
    seed: int = 0

    def __post_init__(self):
        for name in ("warmup", "window_min", "tbptt", "batch", "iterations", "val_every", "patience"):
            if getattr(self, name) < 1:
                raise FreeRunError(f"FreeRunConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.input_offset < 0 or self.input_noise < 0:
            raise FreeRunError("FreeRunConfig.input_offset and input_noise must be >= 0")
        if not 0 <= self.from_rest <= 1:
            raise FreeRunError(f"FreeRunConfig.from_rest must be in [0, 1], got {self.from_rest}")
        if self.lr <= 0 or self.time_budget_s <= 0 or self.weight_decay < 0:
            raise FreeRunError("FreeRunConfig.lr and time_budget_s must be > 0, weight_decay >= 0")


def _tensors(trajectories: list, norm: Normalizer) -> list:
    return [(torch.as_tensor(norm.u(u), dtype=torch.float32), torch.as_tensor(norm.y(y), dtype=torch.float32))
            for u, y in trajectories]


def _batch(data: list, length: int, cfg: FreeRunConfig, rng: np.random.Generator):
    picks = rng.integers(len(data), size=cfg.batch)
    us, ys = [], []
    for i in picks:
        u, y = data[i]
        start = 0 if rng.random() < cfg.from_rest else int(rng.integers(0, len(u) - length + 1))
        us.append(u[start:start + length])
        ys.append(y[start:start + length])
    u = torch.stack(us)
    if cfg.input_offset or cfg.input_noise:
        # The same motion can take other torques on another day (friction with temperature): a
        # constant offset per window and channel, and white noise, in normalised units.
        g = torch.Generator().manual_seed(int(rng.integers(2 ** 31)))
        u = u + cfg.input_offset * torch.randn(u.shape[0], 1, u.shape[2], generator=g)
        u = u + cfg.input_noise * torch.randn(u.shape, generator=g)
    return u, torch.stack(ys)


def validation_loss(model: FreeRunModel, val: list, warmup: int = 1) -> float:
    """Mean squared free-run error (normalised units) of whole validation trajectories from rest."""
    model.eval()
    with torch.no_grad():
        errs = [((simulate(model, u[None], y[None, :warmup]) - y[None]) ** 2)[:, warmup:].mean().item() for u, y in val]
    return float(np.mean(errs))


def fit(model: FreeRunModel, train: list, val: list, cfg: FreeRunConfig = FreeRunConfig(),
        log=None) -> dict:
    """Trains ``model`` on free-run simulation error; returns its :class:`Normalizer` and a record
    (iterations run, best validation loss, the last training windows' loss, seconds). ``train``/``val``: ``[(u, y)]`` in data units."""
    if not train or not val:
        raise FreeRunError("free-run training needs training and validation trajectories")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    norm = Normalizer.of(train)
    data, vdata = _tensors(train, norm), _tensors(val, norm)
    full = min(len(u) for u, _ in data)
    if full <= cfg.warmup + 1:
        raise FreeRunError(f"training trajectories of {full} samples are too short for a warm-up of {cfg.warmup}")
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.iterations, eta_min=cfg.lr * 0.05)
    best, best_state, bad, t0, it = validation_loss(model, vdata), copy.deepcopy(model.state_dict()), 0, time.time(), 0
    losses, last_train = [], float("nan")
    for it in range(1, cfg.iterations + 1):
        # windows grow from window_min to whole trajectories over the first half of training
        length = int(min(full, cfg.window_min + (full - cfg.window_min) * min(1.0, 2 * it / cfg.iterations)))
        u, y = _batch(data, length, cfg, rng)
        model.train()
        state = model.start(_history(y, cfg.warmup, model.lag), _history(u, cfg.warmup, model.lag))
        for c0 in range(cfg.warmup, length, cfg.tbptt):
            c1 = min(length, c0 + cfg.tbptt)
            state, pred = model.run(state, u[:, c0:c1])
            loss = ((pred - y[:, c0:c1]) ** 2).mean()
            losses.append(loss.item())
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            opt.step()
            state = model.detach(state)
        sched.step()
        if it % cfg.val_every == 0:
            v = validation_loss(model, vdata)
            last_train = float(np.mean(losses))
            if log:
                log(f"iteration {it}: window {length}, training MSE {np.mean(losses):.4f}, validation free-run "
                    f"MSE {v:.4f} (best {min(best, v):.4f})")
            losses = []
            if v < best:
                best, best_state, bad = v, copy.deepcopy(model.state_dict()), 0
            else:
                bad += 1
            if bad >= cfg.patience:
                break
        if time.time() - t0 > cfg.time_budget_s:
            break
    model.load_state_dict(best_state)
    return {"normalizer": norm, "iterations": it, "best_val": best, "last_train": last_train,
            "seconds": time.time() - t0}
