"""The sizes and budgets of ``python -m robomorph.reproduce`` at each scale: ci, small, gpu, paper.

Budgets are optimizer steps, not wall-clock time, so a scale trains the same models on any
machine and a resumed run stops where an uninterrupted one would. What each scale costs in
time (measured where it was run, estimated from step times otherwise) is in
docs/guide/reproducing.md.

``ci``: tiny stores (16 training robots
of 90 steps, context 30 + horizon 60), d_model 16 models of 1, 2 and 3 layers, 10-20
steps. It checks the pipeline end to end; its numbers mean nothing.

``small`` (results in ``results/paper/small/``): the CPU-sized model of
``datamodules/train_cpu.yaml`` (d_model 128, 4 heads, patches of 10 steps, batch 32) on the
paper's window (context 200 + horizon 800 of 1000 steps), at depths 2, 4 and 6 (encoder =
decoder):

- data: 4096 + 3 x 256 multi-sine, 4096 mixture, 1024 + 256 spiral robots
  (4096 training robots: with fewer, 4000 steps of 32 would pass over each robot often
  enough to memorize it, see the README's quality-against-time figures);
- table 1: 4000 steps per depth;
- table 2: pre-training 8000 steps, fine-tuning B = 2000 steps and scratch 2000 steps
  (``scratch_ratio`` 1: the same budget as the fine-tuning, the fair comparison when B is
  this short); then the context figure's sweeps.

``gpu`` (one GPU, 16 cores): the paper's model at the paper's depths 10, 12 and 16, and the
project's model beside it at 12 (the improved row), with the optimized training step
(:mod:`robomorph.training.compiling`), sized towards the 15 minutes of one H100 machine:
about 19 minutes, estimated from the parts measured there (docs/guide/reproducing.md), of
which about 9 are the six compilations of the step (about 90 seconds each) and 5 the improved
row's 1000 eager steps; not yet run end to end at these budgets.

- data: 1024 multi-sine, 3 x 128 test, 1024 mixture, 256 + 128 spiral robots;
- table 1: 1000 steps per depth (batch 16: 16,000 windows, 16 per training robot);
- table 2: pre-training 1500 steps, fine-tuning B = 400 and scratch 400 steps
  (``scratch_ratio`` 1, as ``small``: the paper's 3.6 would be most of the budget).

``paper`` (a GPU): the paper's model (d_model 192, 12 heads, patch 1, batch 16, lr 6e-4, 10k warmup steps) at 10,
12 and 16 layers on 40 000 training robots per store (the paper used millions; 40 000 x
1000 x 21 float32 still fits the 4 GiB in-memory budget of the DataModule).

- table 1: 287 000 steps per depth (the paper's base model);
- table 2: pre-training 326 000 steps, fine-tuning 51 000 steps and scratch 183 600 steps
  (``scratch_ratio`` 3.6 as in the paper), at 12 layers;
- data: about 94 000 open-loop and 11 000 spiral robots.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from robomorph.core.config import ConfigError
from robomorph.core.names import COMPILE_MODES


@dataclass(frozen=True)
class Scale:
    """Sizes and budgets of one reproduction scale.

    Attributes:
        name: ``ci``, ``small``, ``gpu`` or ``paper``.
        steps: samples per trajectory in every store.
        train_robots: Table 1's multi-sine training store.
        test_robots: each test store (test0..test2 and the spiral test store).
        mixture_robots: Table 2's pre-training store (multi-sine + chirp mixture).
        spiral_robots: Table 2's spiral training store (fine-tuning and scratch).
        context_len, horizon: the training and evaluation window.
        d_model, n_head, patch: the model (decoder depth = encoder depth).
        depths: Table 1's three encoder depths; the middle one is the transfer and
            context-figure model (the paper's best, 12 layers).
        batch_size, lr, warmup_steps: optimization.
        train_steps: Table 1 budget per depth.
        pretrain_steps: Table 2 pre-training budget on the mixture.
        finetune_steps: Table 2 fine-tuning budget B on the spiral.
        scratch_ratio: the scratch run trains ``round(scratch_ratio * B)`` steps.
        finetune_lr: fine-tuning learning rate (None: :data:`robomorph.training.transfer.FINETUNE_LR`).
        val_every: validation interval in steps (capped at the budget).
        val_fraction, val_subset: validation split of each training store, and its cap.
        max_time: optional wall-clock cap per run (``DD:HH:MM:SS``).
        accelerator: Lightning accelerator.
        compile: every run's ``--model.compile`` (:data:`robomorph.core.names.COMPILE_MODES`).
        eval_n: evaluate the first n trajectories of each test store (None: all).
        sweep_horizon, sweep_context: the context figure's sweeps (``a:b:s`` or ``a,b,c``).
        samples: sample-trajectory plots per evaluation.
    """

    name: str
    steps: int
    train_robots: int
    test_robots: int
    mixture_robots: int
    spiral_robots: int
    context_len: int
    horizon: int
    d_model: int
    n_head: int
    patch: int
    depths: tuple[int, int, int]
    batch_size: int
    lr: float
    warmup_steps: int
    train_steps: int
    pretrain_steps: int
    finetune_steps: int
    scratch_ratio: float
    sweep_horizon: str
    sweep_context: str
    finetune_lr: float | None = None
    val_every: int = 500
    val_fraction: float = 0.1
    val_subset: int = 200
    max_time: str | None = None
    accelerator: str = "auto"
    compile: str = "auto"
    eval_n: int | None = None
    samples: int = 2

    def __post_init__(self):
        if len(self.depths) != 3 or min(self.depths) < 1:
            raise ConfigError(f"{self.name}: depths must be three positive layer counts, got {self.depths}")
        if self.context_len % self.patch:
            raise ConfigError(f"{self.name}: context_len {self.context_len} must be a multiple of patch {self.patch}")
        if self.context_len + self.horizon > self.steps:
            raise ConfigError(f"{self.name}: context_len + horizon exceeds the {self.steps} steps per trajectory")
        if self.d_model % self.n_head:
            raise ConfigError(f"{self.name}: d_model {self.d_model} must be divisible by n_head {self.n_head}")
        for field in ("train_steps", "pretrain_steps", "finetune_steps", "batch_size", "val_every"):
            if getattr(self, field) < 1:
                raise ConfigError(f"{self.name}: {field} must be >= 1, got {getattr(self, field)}")
        if self.compile not in COMPILE_MODES:
            raise ConfigError(f"{self.name}: compile must be one of {', '.join(COMPILE_MODES)}, got {self.compile!r}")
        if not self.scratch_ratio > 0:
            raise ConfigError(f"{self.name}: scratch_ratio must be > 0, got {self.scratch_ratio}")
        if not 0 < self.val_fraction < 1:
            raise ConfigError(f"{self.name}: val_fraction must lie in (0, 1), got {self.val_fraction}")

    @property
    def transfer_depth(self) -> int:
        """The middle depth: Table 2's and the context figure's model."""
        return self.depths[1]

    @property
    def scratch_steps(self) -> int:
        return max(1, round(self.scratch_ratio * self.finetune_steps))

    def scaled(self, steps_factor: float = 1.0, scratch_ratio: float | None = None,
               compile: str | None = None) -> "Scale":
        """A copy with every training budget times ``steps_factor`` and, optionally, another
        scratch ratio and ``--model.compile``."""
        if not steps_factor > 0:
            raise ConfigError(f"steps_factor must be > 0, got {steps_factor}")

        def f(n: int) -> int:
            return max(1, round(n * steps_factor))

        return dataclasses.replace(
            self, train_steps=f(self.train_steps), pretrain_steps=f(self.pretrain_steps),
            finetune_steps=f(self.finetune_steps),
            scratch_ratio=self.scratch_ratio if scratch_ratio is None else scratch_ratio,
            compile=self.compile if compile is None else compile)

    def budgets(self) -> dict[str, int | str | None]:
        """The training budgets in steps, for table headers."""
        return {"table1_steps_per_depth": self.train_steps, "pretrain_steps": self.pretrain_steps,
                "finetune_steps": self.finetune_steps, "scratch_steps": self.scratch_steps,
                "batch_size": self.batch_size, "max_time": self.max_time, "compile": self.compile}


SCALES: dict[str, Scale] = {
    "ci": Scale(
        name="ci", steps=90, train_robots=16, test_robots=6, mixture_robots=16, spiral_robots=12,
        context_len=30, horizon=60, d_model=16, n_head=2, patch=5, depths=(1, 2, 3), batch_size=8, lr=3e-3,
        warmup_steps=2, train_steps=10, pretrain_steps=20, finetune_steps=10, scratch_ratio=1.0, finetune_lr=1e-3,
        sweep_horizon="20:60:20", sweep_context="10:30:10", val_every=5, val_fraction=0.25, val_subset=4,
        accelerator="cpu", samples=0),
    "small": Scale(
        name="small", steps=1000, train_robots=4096, test_robots=256, mixture_robots=4096, spiral_robots=1024,
        context_len=200, horizon=800, d_model=128, n_head=4, patch=10, depths=(2, 4, 6), batch_size=32, lr=1e-3,
        warmup_steps=300, train_steps=4000, pretrain_steps=8000, finetune_steps=2000, scratch_ratio=1.0,
        sweep_horizon="100:800:100", sweep_context="20:200:20"),
    "gpu": Scale(
        name="gpu", steps=1000, train_robots=1024, test_robots=128, mixture_robots=1024, spiral_robots=256,
        context_len=200, horizon=800, d_model=192, n_head=12, patch=1, depths=(10, 12, 16), batch_size=16, lr=6e-4,
        warmup_steps=300, train_steps=1000, pretrain_steps=1500, finetune_steps=400, scratch_ratio=1.0,
        sweep_horizon="100:800:100", sweep_context="20:200:20", val_every=500, val_fraction=0.05, val_subset=200),
    "paper": Scale(
        name="paper", steps=1000, train_robots=40_000, test_robots=1000, mixture_robots=40_000, spiral_robots=10_000,
        context_len=200, horizon=800, d_model=192, n_head=12, patch=1, depths=(10, 12, 16), batch_size=16, lr=6e-4,
        warmup_steps=10_000, train_steps=287_000, pretrain_steps=326_000, finetune_steps=51_000, scratch_ratio=3.6,
        sweep_horizon="100:800:100", sweep_context="20:200:20", val_every=5000, val_fraction=0.02, val_subset=500),
}
