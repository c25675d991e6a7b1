"""Predictor latency: one trajectory (context 200, horizon 800) through ``Predictor.simulate``.

Times the full call (numpy in, numpy out, normalization included) for the default CPU
model and the paper's size, after a warm-up, on the CPU (and the GPU when there is one).

    python benchmarks/predict.py [--repeats 50] [--threads 2]

Goal: <= 50 ms for the default model on CPU.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from common import print_provenance

from robomorph.data.statistics import Stats
from robomorph.inference.checkpoint import TrainedModel
from robomorph.model.transformer import ModelConfig
from robomorph.predictor import Predictor

CONFIGS = {
    "default CPU (d128, 4+4, patch 10)": {"d_model": 128, "n_head": 4, "n_layer": 4, "patch": 10},
    "default, patch 1": {"d_model": 128, "n_head": 4, "n_layer": 4, "patch": 1},
    "paper (d192, 12+12, 12 heads, patch 1)": {"d_model": 192, "n_head": 12, "n_layer": 12, "patch": 1},
}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeats", type=int, default=50)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args()
    print_provenance()
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    u, y = rng.normal(size=(1000, 7)).astype(np.float32), rng.normal(size=(1000, 14)).astype(np.float32)
    stats = Stats.from_arrays(u[None], y[None])
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    for device in devices:
        for name, cfg in CONFIGS.items():
            model = TrainedModel(ModelConfig(n_u=7, n_y=14, **cfg))
            model.normalizer.set_stats(stats)
            pred = Predictor(model, device=device)
            for _ in range(3):
                pred.simulate(u[:200], y[:200], u[200:])
            times = []
            for _ in range(args.repeats if "paper" not in name else max(5, args.repeats // 10)):
                t0 = time.perf_counter()
                pred.simulate(u[:200], y[:200], u[200:])
                times.append(time.perf_counter() - t0)
            print(f"{device} {name}: median {np.median(times) * 1e3:.1f} ms, p90 {np.percentile(times, 90) * 1e3:.1f} ms "
                  f"per trajectory (context 200, horizon 800)")


if __name__ == "__main__":
    main()
