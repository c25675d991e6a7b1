#!/usr/bin/env bash
# A reproduction on a GPU box lent for a fixed time, in one command: install the wheels of
# tools/device_site.sh (if .devsite/ is there), run `reproduce TARGET` until SECONDS have passed
# (then SIGTERM: a run saves last.ckpt at its next step and the command stops; a step still
# compiling finishes first, so leave a minute or two), and pack every evaluation, training log
# and table into OUT/evaluations.tgz (metrics.json and CSV files only: no checkpoints, no stores).
#
#   bash tools/device_reproduce.sh SECONDS OUT [reproduce options...]
#   bash tools/device_reproduce.sh 480 "$OUT" all --scale gpu --steps-factor 0.5
#
# Back here: tar xzf evaluations.tgz -C some/folder, then
#   python -m robomorph.reproduce collect --scale gpu --steps-factor 0.5 --work some/folder/data/reproduce/gpu
# writes the tables and the figure from whatever was scored. Re-running the same command on the same machine
# resumes where it stopped. The log is OUT/reproduce.log.
set -uo pipefail
if [ $# -lt 3 ]; then
    echo "usage: bash tools/device_reproduce.sh SECONDS OUT TARGET [reproduce options...]" >&2
    exit 2
fi
seconds=$1 out=$2
shift 2
mkdir -p "$out"
python=${PYTHON:-python3}
# The wheels only where the project's own packages are missing (a bare CUDA image).
if ! "$python" -c "import mujoco, zarr, dm_control" 2>/dev/null && compgen -G ".devsite/*.whl" >/dev/null; then
    "$python" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .devsite/*.whl \
        || { echo "device_reproduce: the wheels of .devsite/ did not install" >&2; exit 2; }
    export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1 WANDB_MODE=disabled
# Where the runs and tables go: the defaults, or what --work and --out name.
places="data/reproduce results/paper"
args=("$@")
for i in "${!args[@]}"; do
    case "${args[$i]}" in --work|--out) places="$places ${args[$((i + 1))]:-}" ;; esac
done
# Into a file, not a pipe: the compiler's worker processes outlive a stopped run and would
# hold a pipe open, so that the command never returned (an H100 lease lost that way,
# 2026-11-27). KILL a minute after TERM, for a step that does not stop. Progress bars and font
# warnings are filtered out afterwards.
timeout -k 60 -s TERM "$seconds" "$python" -m robomorph reproduce "$@" --wandb disabled >"$out/reproduce.raw" 2>&1 </dev/null
status=$?
tr '\r' '\n' <"$out/reproduce.raw" | grep -v -E "findfont|batch/s\]|window/s\]|^ *$" >"$out/reproduce.log"
rm -f "$out/reproduce.raw"
tail -n 40 "$out/reproduce.log"
echo "device_reproduce: reproduce exited with $status" | tee -a "$out/reproduce.log"
# shellcheck disable=SC2086  # the places are separate words
find $places -type f \( -name metrics.json -o -name '*.csv' -o -name 'table*.md' \
    -o -name 'table*.json' -o -name config.yaml -o -name reproduce_done.json \) -size -4M 2>/dev/null \
    | tar czf "$out/evaluations.tgz" -T -
echo "device_reproduce: packed $(tar tzf "$out/evaluations.tgz" | wc -l) files into $out/evaluations.tgz"
