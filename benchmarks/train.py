"""Training throughput: the LightningModule against a plain PyTorch loop, same model and batches.

Both run in this process on identical pre-built batches (batch 16, context 200, horizon
800 by default): the plain loop does normalize -> forward -> Huber loss -> backward ->
clip -> AdamW -> scheduler step by hand; Lightning runs ``MetaModule.training_step`` under
a ``Trainer`` (logging on, checkpointing and validation off). Then trajectories/s for the
default CPU config, the paper's config (d_model 192, 12+12 layers, 12 heads) and the
token-reduction option; on a GPU, the same in bf16.

On a GPU it then times what ``fit`` runs for the paper's model (batch 16, context 200 +
horizon 800, 12 + 12 layers, d_model 192, patch 1): the Lightning step as it was (eager,
unfused AdamW), eager with the fused AdamW, and optimized (``--model.compile auto``: the step
compiled with CUDA graphs, fused AdamW; see robomorph.training.compiling), each in bf16 and
fp32, in steps/s after warm-up steps that include the compilation, and how long those first
steps took.

    python benchmarks/train.py [--steps 30] [--threads 2]
    python benchmarks/train.py --paper-only   # on a GPU: the paper model's runs alone
    python benchmarks/train.py --paper-only --variants before,auto

The last line is ``lightning_vs_plain_ratio=<float>`` on a CPU (Lightning time / plain time;
goal <= 1.05) and ``gpu_speedup=<float>`` on a GPU (optimized bf16 steps/s over the step as it
was, eager bf16 with the unfused AdamW; goal: optimized bf16 >= 28 steps/s).
"""

from __future__ import annotations

import argparse
import time

import lightning.pytorch as L
import numpy as np
import torch
import torch.nn.functional as F
from common import print_provenance

from robomorph.data.statistics import Stats
from robomorph.training import optim
from robomorph.training.module import MetaModule
from robomorph.training.progress import quiet_lightning

N_U, N_Y = 7, 14


def make_batches(n: int, batch: int, ctx: int, hor: int, seed: int = 0) -> list[dict]:
    g = torch.Generator().manual_seed(seed)
    t = ctx + hor
    out = []
    for _ in range(n):
        u = torch.randn(batch, t, N_U, generator=g)
        y = torch.cumsum(torch.randn(batch, t, N_Y, generator=g), dim=1) * 0.05
        out.append({"u_ctx": u[:, :ctx], "y_ctx": y[:, :ctx], "u_query": u[:, ctx:], "y_query": y[:, ctx:]})
    return out


def _stats(batches) -> Stats:
    u = torch.cat([torch.cat([b["u_ctx"], b["u_query"]], 1) for b in batches]).numpy()
    y = torch.cat([torch.cat([b["y_ctx"], b["y_query"]], 1) for b in batches]).numpy()
    return Stats.from_arrays(u, y)


def _module(cfg: dict, stats: Stats, device: str, compile: str = "off") -> MetaModule:
    torch.manual_seed(0)
    m = MetaModule(n_u=N_U, n_y=N_Y, max_context=1024, max_horizon=1024, compile=compile, **cfg)
    m.normalizer.set_stats(stats)
    m.stats_ready.fill_(True)
    return m.to(device)


def plain_loop(module: MetaModule, batches: list[dict], device: str, bf16: bool) -> float:
    net, norm = module.net, module.normalizer
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, betas=(0.9, 0.95))
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 1.0)
    _sync(device)
    t0 = time.perf_counter()
    for b in batches:
        b = {k: v.to(device, non_blocking=True) for k, v in b.items()}
        with torch.autocast(device_type=device, dtype=torch.bfloat16, enabled=bf16):
            uc, yc, uq = norm.encode(b["u_ctx"], b["y_ctx"], b["u_query"])
            loss = F.huber_loss(net(uc, yc, uq), norm.encode_target(b["y_query"], b["y_ctx"]), delta=1.0)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        sched.step()
    _sync(device)
    return time.perf_counter() - t0


class _Timer(L.Callback):
    def __init__(self, warmup: int = 1) -> None:
        self.warmup = warmup

    def on_train_batch_start(self, trainer, *args):
        if trainer.global_step == self.warmup:  # skip the first steps (lazy init, compilation)
            _sync(trainer.strategy.root_device.type)
            self.t0 = time.perf_counter()

    def on_train_end(self, trainer, *args):
        _sync(trainer.strategy.root_device.type)
        self.elapsed = time.perf_counter() - self.t0


def lightning_loop(module: MetaModule, batches: list[dict], device: str, bf16: bool, warmup: int = 1) -> float:
    """Seconds of the last ``len(batches) - warmup`` steps of ``fit``'s Lightning step."""
    timer = _Timer(warmup)
    module.hparams.warmup_steps = 0
    with quiet_lightning(False):  # no tips, accelerator lines or deprecation warnings between the figures
        trainer = L.Trainer(max_steps=len(batches), accelerator="gpu" if device == "cuda" else "cpu", devices=1,
                            precision="bf16-mixed" if bf16 else "32-true", logger=False, enable_checkpointing=False,
                            enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0,
                            gradient_clip_val=1.0, callbacks=[timer])
        trainer.fit(module, train_dataloaders=torch.utils.data.DataLoader(batches, batch_size=None))
    return timer.elapsed


def _sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def compare(cfg: dict, steps: int, batch: int, ctx: int, hor: int, device: str, bf16: bool, repeats: int = 2):
    batches = make_batches(steps + 1, batch, ctx, hor)
    stats = _stats(batches[:4])
    plain, light = [], []
    for _ in range(repeats):  # alternate so drift in machine speed hits both alike
        m = _module(cfg, stats, device)
        plain_loop(m, batches[:1], device, bf16)  # warm-up
        plain.append(plain_loop(m, batches[1:], device, bf16) / steps)
        # the timer starts at step 1, so it covers the last `steps` of the steps + 1 batches
        light.append(lightning_loop(_module(cfg, stats, device), batches, device, bf16) / steps)
    return float(np.median(plain)), float(np.median(light))


PAPER = {"d_model": 192, "n_head": 12, "n_layer": 12, "patch": 1}


VARIANTS = {"before": "eager, unfused AdamW (the step as it was)", "off": "eager, fused AdamW",
            "auto": "optimized (compiled step, CUDA graphs, fused AdamW)"}


def paper_speed(args) -> float | None:
    """Steps/s of the paper's model under ``fit``'s Lightning step on this GPU, for each of
    ``args.variants`` (:data:`VARIANTS`) in bf16 and fp32, and the seconds its first steps took
    (the compilation, where there is one); returns optimized bf16 over the step as it was in
    bf16 (printed as gpu_speedup), None when either was not run."""
    warmup = 8  # compilation and the CUDA graphs' recording happen in the first steps
    batches = make_batches(warmup + args.paper_steps, args.batch, args.context, args.horizon)
    stats = _stats(batches[:4])
    batches = [{k: v.pin_memory() for k, v in b.items()} for b in batches]  # as fit's loader pins them
    rates = {}
    for bf16 in (True, False):  # bf16 first: the speed-up is read from it
        for variant in args.variants:
            torch._dynamo.reset()
            optim.FUSED_ON_GPU = variant != "before"
            try:
                module = _module(PAPER, stats, "cuda", "auto" if variant == "auto" else "off")
                start = time.perf_counter()
                seconds = lightning_loop(module, batches, "cuda", bf16, warmup=warmup)
                first = time.perf_counter() - start - seconds
            finally:
                optim.FUSED_ON_GPU = True
            rates[variant, bf16] = args.paper_steps / seconds
            print(f"paper model {'bf16' if bf16 else 'fp32'} {VARIANTS[variant]}: {rates[variant, bf16]:.2f} steps/s "
                  f"({1e3 / rates[variant, bf16]:.1f} ms/step), first {warmup} steps {first:.1f} s, peak memory "
                  f"{torch.cuda.max_memory_allocated() / 2**30:.2f} GiB", flush=True)
            torch.cuda.reset_peak_memory_stats()
            del module
            torch.cuda.empty_cache()
    if ("auto", True) in rates:
        print(f"paper_steps_per_s_optimized_bf16={rates['auto', True]:.2f} (goal >= 28)")
    if ("auto", True) not in rates or ("before", True) not in rates:
        return None
    return rates["auto", True] / rates["before", True]


def _variants(text: str) -> list[str]:
    names = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown variant(s) {unknown}: choose from {', '.join(VARIANTS)}")
    return names


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--context", type=int, default=200)
    p.add_argument("--horizon", type=int, default=800)
    p.add_argument("--paper-steps", type=int, default=40, help="timed steps of each paper-model run on a GPU")
    p.add_argument("--paper-only", action="store_true", help="on a GPU, only the paper model's runs")
    p.add_argument("--variants", type=_variants, default=list(VARIANTS),
                   help=f"the paper model's runs on a GPU, comma-separated from {', '.join(VARIANTS)} (default: all)")
    args = p.parse_args()
    print_provenance()
    torch.set_num_threads(args.threads)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda":
        print(f"gpu={torch.cuda.get_device_name()} torch={torch.__version__}", flush=True)
    if args.paper_only and device == "cuda":
        _print_speedup(paper_speed(args))
        return
    default = {"d_model": 128, "n_head": 4, "n_layer": 4, "patch": 10}
    configs = {
        "default (d128, 4+4, patch 10)": (default, args.steps),
        "token reduction off (d128, 4+4, patch 1)": ({**default, "patch": 1}, max(4, args.steps // 6)),
        "token reduction patch 20": ({**default, "patch": 20}, args.steps),
        "paper (d192, 12+12, 12 heads, patch 1)": ({"d_model": 192, "n_head": 12, "n_layer": 12, "patch": 1}, 4),
    }
    print(f"device={device} threads={args.threads} batch={args.batch} context={args.context} horizon={args.horizon}")
    ratio = None
    for bf16 in ([False, True] if device == "cuda" else [False]):
        for name, (cfg, steps) in configs.items():
            plain, light = compare(cfg, steps, args.batch, args.context, args.horizon, device, bf16)
            tag = " bf16" if bf16 else ""
            print(f"{name}{tag}: plain {plain * 1e3:.1f} ms/it, lightning {light * 1e3:.1f} ms/it, "
                  f"{args.batch / light:.1f} traj/s (lightning), ratio {light / plain:.3f}")
            if ratio is None:
                ratio = light / plain
    print(f"lightning_vs_plain_ratio={ratio:.3f}")
    if device == "cuda":
        _print_speedup(paper_speed(args))


def _print_speedup(speedup: float | None) -> None:
    print("gpu_speedup=" + ("n/a (run the variants before and auto)" if speedup is None else f"{speedup:.2f}"))


if __name__ == "__main__":
    main()
