"""Training-step speed of the meta-model on CPU: forward, backward and one AdamW step.

Batch 16, context 200, horizon 800 (the paper's 20 % / 80 % split of 1000 steps), random
normalized data, MSE loss. Prints, per architecture, the parameter count, seconds per
iteration (median of the timed iterations, after one untimed warm-up) and trajectories/s.

    python benchmarks/model_speed.py [--threads 2] [--iters 5] [--big-iters 2] [--no-big]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
import torch.nn.functional as F
from common import print_provenance

from robomorph.model.transformer import MetaModel, ModelConfig

BATCH, CONTEXT, HORIZON = 16, 200, 800


def time_config(cfg: ModelConfig, iters: int) -> tuple[int, float]:
    """Parameter count and median seconds per training iteration."""
    torch.manual_seed(0)
    model = MetaModel(cfg).train()
    opt = torch.optim.AdamW(model.parameters(), lr=6e-4, betas=(0.9, 0.95), weight_decay=0.0)
    u_ctx = torch.randn(BATCH, CONTEXT, cfg.n_u)
    y_ctx = torch.randn(BATCH, CONTEXT, cfg.n_y)
    u_query = torch.randn(BATCH, HORIZON, cfg.n_u)
    y_query = torch.randn(BATCH, HORIZON, cfg.n_y)
    times = []
    for i in range(iters + 1):
        t0 = time.perf_counter()
        loss = F.mse_loss(model(u_ctx, y_ctx, u_query), y_query)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if i > 0:  # the first iteration allocates the optimizer state and warms the allocator
            times.append(time.perf_counter() - t0)
    return model.num_params(), statistics.median(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--iters", type=int, default=5, help="timed iterations for the small models")
    p.add_argument("--big-iters", type=int, default=2, help="timed iterations for the paper-size model")
    p.add_argument("--no-big", action="store_true", help="skip the paper-size model (about 1-2 min)")
    args = p.parse_args()
    print_provenance()
    torch.set_num_threads(args.threads)

    common = dict(max_context=CONTEXT, max_horizon=HORIZON)
    runs = [(f"d128 4+4L 4h patch {k}", ModelConfig(d_model=128, n_head=4, n_layer=4, patch=k, **common), args.iters)
            for k in (1, 5, 10, 20)]
    if not args.no_big:
        runs.append(("d192 12+12L 12h patch 1 (paper)",
                     ModelConfig(d_model=192, n_head=12, n_layer=12, patch=1, **common), args.big_iters))

    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, "
          f"batch {BATCH}, context {CONTEXT}, horizon {HORIZON}, fwd+bwd+AdamW")
    print(f"{'model':34s} {'params':>8s} {'tokens c/q':>11s} {'s/iter':>8s} {'traj/s':>8s}")
    for name, cfg, iters in runs:
        n, sec = time_config(cfg, iters)
        tokens = f"{CONTEXT // cfg.patch}/{-(-HORIZON // cfg.patch)}"
        print(f"{name:34s} {n / 1e6:7.2f}M {tokens:>11s} {sec:8.3f} {BATCH / sec:8.1f}", flush=True)


if __name__ == "__main__":
    main()
