#!/usr/bin/env bash
# One GPU lease's work in one command, within SECONDS (default 570):
#   1. the GPU tests (tests/test_gpu.py: compiled and eager training agree; fit on the GPU);
#   2. `reproduce all --scale gpu` (tools/device_reproduce.sh: SIGTERM at its share of the time,
#      evaluations packed into OUT_DIR/evaluations.tgz for `reproduce collect` back home);
#   3. benchmarks/train.py's paper-model step speeds (VARIANTS, default every one; bf16 and fp32).
#
#   bash benchmarks/gpu_session.sh [OUT_DIR] [SECONDS]
#   VARIANTS=before,auto TESTS="agree" RESERVE=200 bash benchmarks/gpu_session.sh "$OUT" 570
#
# On a bare GPU box whose Python lacks this project's dependencies (MuJoCo, Zarr,
# jsonargparse), build their wheels first, where PyPI is reachable: bash tools/device_site.sh
# (then carry .devsite). They are installed into /tmp/site, not over the box's own packages.
# Logs go to OUT_DIR (default /tmp/gpu_session).
set -u
out=${1:-/tmp/gpu_session}
budget=${2:-570}
start=$SECONDS
left() { echo $((budget - (SECONDS - start))); }
mkdir -p "$out"
if ! python3 -c "import mujoco, zarr, dm_control, jsonargparse" 2>/dev/null && compgen -G ".devsite/*.whl" >/dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .devsite/*.whl \
        || { echo "gpu_session: the wheels of .devsite/ did not install" >&2; exit 2; }
    export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1 WANDB_MODE=disabled
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
python3 -c "import torch, lightning; print('torch', torch.__version__, 'lightning', lightning.__version__)" | tee -a "$out/gpu.txt"
# Every step writes into a file, not a pipe: the compiler's worker processes outlive a step
# stopped by its timeout and would hold a pipe open, so that the command never returned (an H100
# lease lost that way, 2026-11-27). -k: KILL what does not stop 10 s after TERM.
# 1. The GPU tests (TESTS: a pytest -k filter), at most 90 s.
timeout -k 10 90 python3 -m pytest -q -p no:cacheprovider -m gpu tests/test_gpu.py -k "${TESTS:-gpu}" \
    >"$out/gpu_tests.log" 2>&1 </dev/null
tail -n 5 "$out/gpu_tests.log"
# 2. The reproduction, leaving RESERVE seconds (default 120) for the step speeds.
bash tools/device_reproduce.sh $(($(left) - ${RESERVE:-120})) "$out" all --scale gpu --workers "$(nproc)" \
    --out results/paper/gpu
echo "gpu_session: reproduction done at $((SECONDS - start)) s" | tee -a "$out/reproduce.log"
# 3. The paper model's step speeds in what is left (if 30 s or more).
if [ "$(left)" -ge 30 ]; then
    timeout -k 10 $(($(left) - 15)) python3 benchmarks/train.py --paper-only --paper-steps 30 \
        --variants "${VARIANTS:-before,off,auto}" >"$out/train_gpu.log" 2>&1 </dev/null
    grep -E "^paper|gpu_speedup" "$out/train_gpu.log"
fi
echo "gpu_session: done at $((SECONDS - start)) s"
