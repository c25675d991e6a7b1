#!/usr/bin/env bash
# Creates .venv and installs robomorph into it, offline-safe and CUDA-safe:
# - a CPU-only machine gets the local CPU wheel torch==2.13.0 (never a CUDA download);
# - a base Python that already has a CUDA torch is reused (--system-site-packages) and
#   that torch is pinned, so pip can never replace it.
# Called by the Makefile only when pyproject.toml changed, so a second run is a no-op.
set -euo pipefail
PYTHON=${PYTHON:-python3}
VENV=${VENV:-.venv}
TORCH_CPU=2.13.0

cuda_torch=$("$PYTHON" - <<'PY' 2>/dev/null || true
import torch
print(torch.__version__ if torch.version.cuda else "")
PY
)

if [ ! -x "$VENV/bin/python" ]; then
  if [ -n "$cuda_torch" ]; then
    echo "install: base Python has CUDA torch $cuda_torch; reusing it"
    "$PYTHON" -m venv --system-site-packages "$VENV"
  else
    "$PYTHON" -m venv "$VENV"
  fi
fi
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check)
"${PIP[@]}" install -q --upgrade pip >/dev/null 2>&1 || true

constraints="$VENV/constraints.txt"
if [ -n "$cuda_torch" ]; then
  echo "torch==$cuda_torch" > "$constraints"
else
  echo "torch==$TORCH_CPU" > "$constraints"
  "${PIP[@]}" install -q -c "$constraints" "torch==$TORCH_CPU"
fi
# docs: MkDocs, Material and mkdocstrings, so `make docs` and its strict-build test work.
"${PIP[@]}" install -q -c "$constraints" -e ".[test,docs]"
# dm-robotics-panda ships the Panda MJCF and meshes (Apache-2.0); its own dependencies
# (the dm_robotics stack) are not needed to read the assets, so they are skipped.
"${PIP[@]}" install -q --no-deps "dm-robotics-panda==0.4.8"
# robosuite (the `arms` extra, MIT) ships the MJCF and meshes of the other arms
# (robomorph.sim.arms); only its asset files are read, so its dependencies are skipped.
"${PIP[@]}" install -q --no-deps "robosuite==1.5.2"
"$VENV/bin/python" -c "import torch, mujoco, dm_control, zarr, rosbags; print(f'install: torch {torch.__version__}, mujoco {mujoco.__version__}, zarr {zarr.__version__}')"
