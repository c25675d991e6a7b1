#!/usr/bin/env bash
# The docs' "Your own robot" walk-through end to end on the real-log fixture; prints the
# ingest report, each fit's final line and the evaluation table of the model of several
# arms fine-tuned on the logs, beside hold, ARX (per context and fitted on the training
# store) and the scratch model.
#
#   bash benchmarks/your_own_robot.sh [OUT (default data/own_robot)] [MAX_STEPS (default 1500)]
#
# Set PYTHON to the interpreter (default .venv/bin/python). Reuses nothing: OUT is rebuilt.
set -euo pipefail
OUT=${1:-data/own_robot}
STEPS=${2:-1500}
PY=${PYTHON:-.venv/bin/python}
rm -rf "$OUT"
mkdir -p "$OUT"
# What made this output: the command, commit, date and machine (its log is a result file).
$PY -c 'import sys; from robomorph.core.results import provenance, provenance_markdown as p
print(p(provenance(sys.argv[1:])))' bash benchmarks/your_own_robot.sh "$@"

# 1. Logs like a real arm's: 6 torques in, 6 joint angles out, 10 Hz, noise, unequal lengths.
$PY benchmarks/real_log_fixture.py --out "$OUT/logs"

# 2. Ingest with units: recordings 0-2 train (overlapping windows), 3 validates, 4 tests.
#    --layout joints names the channels by role (tau0.., q0..), as every simulated arm's.
COLS=(--u-cols tau1,tau2,tau3,tau4,tau5,tau6 --y-cols q1,q2,q3,q4,q5,q6 --time-col t --layout joints
      --u-units "N m,N m,N m,N m,N m,N m" --y-units rad,rad,rad,rad,rad,rad --steps 100)
$PY -m robomorph.ingest "$OUT"/logs/rec{0,1,2}.csv "${COLS[@]}" --stride 10 --out "$OUT/train.zarr"
$PY -m robomorph.ingest "$OUT/logs/rec3.csv" "${COLS[@]}" --stride 50 --out "$OUT/val.zarr"
$PY -m robomorph.ingest "$OUT/logs/rec4.csv" "${COLS[@]}" --stride 50 --out "$OUT/test.zarr"

# 3. One network shape for every run: context 40 (4 s), horizon 60 (6 s).
NET=(--data.context_len 40 --data.horizon 60 --data.batch_size 32 --data.recenter true
     --model.d_model 64 --model.n_head 4 --model.n_layer 2 --model.patch 10
     --model.warmup_steps 100 --trainer.val_check_interval 250 --runs_dir "$OUT/runs" --wandb disabled
     --trainer.enable_progress_bar false)
HELD_OUT=(--data.val_store "$OUT/val.zarr" --data.test_store "$OUT/test.zarr")

# 4. From scratch, validated on its own recording.
$PY -m robomorph.fit --data.stores "$OUT/train.zarr" "${HELD_OUT[@]}" "${NET[@]}" \
    --trainer.max_steps "$STEPS" --run scratch

# 5. A model of several simulated arms (7- and 6-joint: 7 torques -> EE pose and 7 joint angles,
#    joint dropout), then fine-tuned on the logs in its own channel set: the arm's 6 joints map
#    onto its tau0..5 and q0..5 by name, the rest is absent, nothing is re-initialized.
ARMS=()
for ROBOT in panda ur5e iiwa; do
    $PY -m robomorph.generate --robot $ROBOT --task multisine --robots 128 --steps 100 --seed 1 --quiet \
        --out "$OUT/$ROBOT.zarr"
    ARMS+=("$OUT/$ROBOT.zarr")
done
STORES=$(IFS=,; echo "[${ARMS[*]}]")
$PY -m robomorph.fit --data.stores "$STORES" --data.joint_dropout 0.2 "${NET[@]}" --trainer.max_steps "$STEPS" \
    --run arms
$PY -m robomorph.fit --data.stores "$OUT/train.zarr" "${HELD_OUT[@]}" "${NET[@]}" \
    --trainer.max_steps "$STEPS" --model.init_ckpt "$OUT/runs/arms/checkpoints/best.ckpt" --run tuned

# 6. The test recording: the fine-tuned model beside hold, both ARX models and the scratch model.
$PY -m robomorph.evaluate --ckpt "$OUT/runs/tuned/checkpoints/best.ckpt" --data "$OUT/test.zarr" \
    --baselines hold,arx,arx_train --compare "scratch=$OUT/runs/scratch/checkpoints/best.ckpt" \
    --out "$OUT/eval"
