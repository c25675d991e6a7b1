#!/usr/bin/env bash
# The learned residual's confirm run in one GPU lease (16 cores, one GPU), within about 9 minutes:
#   1. SHARDS shards of ROBOTS realistic Panda robots of seed 542 (800 steps), one process per shard;
#   2. the hybrid's priors over each shard (windows from steps 0 and 300, context 200, horizon 300), one
#      process per shard (each a single hybrid: the cores are the shards), stopped at PRIOR_SECONDS;
#   3. robomorph fit --config datamodules/residual.yaml on every complete prior store (the GPU),
#      stopped at TRAIN_TIME; best.ckpt, the fit log and metrics, and the shards' logs (logs.tgz) go to OUT_DIR.
# The held-out robots (seed 5455) are never generated here: benchmarks/residual.py scores the checkpoint
# back home, beside the hybrid alone, on the same windows as the CPU screen.
#
#   ROBOTS=768 SHARDS=16 bash benchmarks/gpu_residual.sh "$OUT"      # carry .devsite (tools/device_site.sh)
set -u
out=${1:-/tmp/gpu_residual}
robots=${ROBOTS:-768}
shards=${SHARDS:-16}
prior_seconds=${PRIOR_SECONDS:-200}
train_time=${TRAIN_TIME:-00:00:03:00}
steps=${STEPS:-3000}
mkdir -p "$out" data/gpu/logs
if ! python3 -c "import mujoco, zarr, dm_control, jsonargparse" 2>/dev/null && compgen -G ".devsite/*.whl" >/dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .devsite/*.whl \
        || { echo "gpu_residual: the wheels of .devsite/ did not install" >&2; exit 2; }
    export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1 WANDB_MODE=disabled OMP_NUM_THREADS=1 \
    ROBOMORPH_PROGRESS_SECONDS=30
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee "$out/gpu.txt"
t0=$SECONDS
for i in $(seq 0 $((shards - 1))); do
    python3 -m robomorph generate --config realistic --robot panda --robots "$robots" --steps 800 --seed 542 \
        --shard "$i/$shards" --workers 1 --quiet --out "data/gpu/train_$i.zarr" > "data/gpu/logs/generate_$i.log" 2>&1 &
done
wait
echo "generate: $((SECONDS - t0)) s" | tee -a "$out/times.txt"
t0=$SECONDS
for i in $(seq 0 $((shards - 1))); do
    timeout -s INT "$prior_seconds" python3 -m robomorph priors "data/gpu/train_$i.zarr" \
        --out "data/gpu/priors_$i.zarr" --offsets 0,300 --set workers=1 --batch-size 8 > "data/gpu/logs/priors_$i.log" 2>&1 &
done
wait
echo "priors: $((SECONDS - t0)) s" | tee -a "$out/times.txt"
stores=$(python3 - <<'EOF'
import glob
from robomorph.data.store import open_store
done = []
for p in sorted(glob.glob("data/gpu/priors_*.zarr")):
    try:
        open_store(p)
        done.append(p)
    except Exception as exc:  # an interrupted store: left out
        print(f"left out {p}: {exc}", file=__import__("sys").stderr)
print("[" + ", ".join(done) + "]")
EOF
)
echo "prior stores: $stores" | tee -a "$out/times.txt"
t0=$SECONDS
python3 -m robomorph fit --config datamodules/residual.yaml --data.stores "$stores" --data.batch_size 64 \
    --data.num_workers 4 --model.compile off --trainer.max_steps "$steps" --trainer.max_time "$train_time" \
    --trainer.val_check_interval 500 --model.warmup_steps 300 --run residual-gpu --runs_dir data/gpu/runs \
    --wandb disabled > "$out/fit.log" 2>&1
rc=$?
echo "fit: $((SECONDS - t0)) s (exit $rc)" | tee -a "$out/times.txt"
cp data/gpu/runs/residual-gpu/checkpoints/best.ckpt "$out/best.ckpt" 2>/dev/null
cp data/gpu/runs/residual-gpu/logs/metrics.csv "$out/metrics.csv" 2>/dev/null
tar czf "$out/logs.tgz" data/gpu/logs 2>/dev/null
tail -n 5 data/gpu/logs/priors_0.log
tr '\r' '\n' < "$out/fit.log" | tail -n 25
cat "$out/times.txt"
