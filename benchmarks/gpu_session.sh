#!/usr/bin/env bash
# One GPU session's checks, in the order that matters if time runs out: the GPU tests
# (compiled and eager training agree; fit on the GPU), then benchmarks/train.py's paper-model
# speeds (eager and optimized, bf16 and fp32; gpu_speedup last).
#
#   bash benchmarks/gpu_session.sh [OUT_DIR]
#
# On a bare GPU box whose Python lacks this project's dependencies (MuJoCo, Zarr,
# jsonargparse), build their wheels first, where PyPI is reachable: bash tools/device_site.sh
# (then carry .devsite). They are installed into /tmp/site, not over the box's own packages.
# Logs go to OUT_DIR (default /tmp/gpu_session).
set -u
out=${1:-/tmp/gpu_session}
mkdir -p "$out"
if compgen -G ".devsite/*.whl" >/dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .devsite/*.whl \
        && export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1 WANDB_MODE=disabled
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
python3 -m pytest -q -p no:cacheprovider -m gpu tests/test_gpu.py 2>&1 | tee "$out/gpu_tests.log"
python3 benchmarks/train.py --paper-only 2>&1 | grep -v -E "Tip:|available:|stopped:|LOCAL_RANK|^$" | tee "$out/train_gpu.log"
