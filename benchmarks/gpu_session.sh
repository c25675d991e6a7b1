#!/usr/bin/env bash
# One GPU lease's work in one command, within SECONDS (default 570):
#   1. the GPU tests (tests/test_gpu.py: compiled and eager training agree; fit on the GPU);
#   2. `reproduce all --scale gpu` (tools/device_reproduce.sh: SIGTERM at its share of the time,
#      evaluations packed into OUT_DIR/evaluations.tgz for `reproduce collect` back home);
#   3. benchmarks/train.py's paper-model step speeds (VARIANTS, default every one; bf16 and fp32).
#
#   bash benchmarks/gpu_session.sh [OUT_DIR] [SECONDS]
#   VARIANTS=before,regional TESTS="regional or varying" bash benchmarks/gpu_session.sh "$OUT" 570
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
# 1. The GPU tests (TESTS: a pytest -k filter), at most 75 s: if regional compilation fails
#    here, the reproduction falls back to --compile auto (the whole step with CUDA graphs).
compile=regional
timeout 75 python3 -m pytest -q -p no:cacheprovider -m gpu tests/test_gpu.py -k "${TESTS:-gpu}" 2>&1 \
    | grep -v -E "Warning|warn|^  " | tee "$out/gpu_tests.log"
grep -q "FAILED.*regional" "$out/gpu_tests.log" && compile=auto
# 2. The reproduction, leaving RESERVE seconds (default 40) for the step speeds.
bash tools/device_reproduce.sh $(($(left) - ${RESERVE:-40})) "$out" all --scale gpu --workers "$(nproc)" \
    --compile "$compile" --out results/paper/gpu
echo "gpu_session: reproduction (--compile $compile) done at $((SECONDS - start)) s" | tee -a "$out/reproduce.log"
# 3. The paper model's step speeds in what is left (if 30 s or more).
if [ "$(left)" -ge 30 ]; then
    timeout $(($(left) - 3)) python3 benchmarks/train.py --paper-only --paper-steps 30 \
        --variants "${VARIANTS:-before,off,auto,regional}" 2>&1 \
        | grep -v -E "Tip:|available:|stopped:|LOCAL_RANK|^$" | tee "$out/train_gpu.log"
fi
echo "gpu_session: done at $((SECONDS - start)) s"
