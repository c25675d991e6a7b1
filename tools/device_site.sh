#!/usr/bin/env bash
# Builds .devsite/: wheels of the packages this project needs that a bare GPU box's Python
# lacks, so that the box (which reaches no package index) can generate, train, evaluate and
# reproduce (the Panda's meshes come from dm-robotics-panda). The box's own torch, Lightning,
# NumPy, SciPy, Matplotlib, Jinja2, tabulate and safetensors are used as they are; the versions
# fetched are those of this checkout's .venv.
#
#   bash tools/device_site.sh            # here, where PyPI is reachable
#   # there, in the repository root (the device tool: carry .devsite):
#   python3 -m pip install -q --no-index --no-deps --target /tmp/site .devsite/*.whl
#   PYTHONPATH=/tmp/site:$PWD python3 -m robomorph reproduce all --scale gpu --workers 16 --wandb disabled
#
# dm_control's wheel is rebuilt without its suite, locomotion and Blender assets (100 MB
# unpacked, 50 of its 56 MB): building the Panda's MJCF needs none of them, and they would not
# fit the 64 MiB that travels to the box. PY (default 3.12) is the box's Python version.
set -euo pipefail
py=${PY:-3.12}
dest=.devsite
wheels=$(mktemp -d)
trap 'rm -rf "$wheels"' EXIT
packages="mujoco glfw websockets dm-control dm-env zarr numcodecs donfig google-crc32c jsonargparse
          docstring-parser typeshed-client dm-robotics-panda"
platforms=""
for p in manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_17_x86_64 manylinux2014_x86_64 manylinux1_x86_64 \
         manylinux_2_5_x86_64; do
    platforms="$platforms --platform $p"
done
for name in $packages; do
    version=$(.venv/bin/python -m pip show "$name" 2>/dev/null | sed -n 's/^Version: //p')
    if [ -z "$version" ]; then
        echo "device_site: $name is not installed in .venv: run make install first" >&2
        exit 2
    fi
    # shellcheck disable=SC2086  # the platform flags are separate words
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version "$py" --implementation cp $platforms \
        -d "$wheels" "$name==$version" 2>&1 | grep -v "^WARNING" || true
done
rm -rf "$dest"
mkdir -p "$dest"
for w in "$wheels"/*.whl; do
    case "$(basename "$w")" in
        dm_control-*) python3 tools/trim_wheel.py "$w" "$dest" dm_control/suite dm_control/locomotion dm_control/blender \
                          >/dev/null ;;
        *) cp "$w" "$dest/" ;;
    esac
done
exclude=$(git rev-parse --git-path info/exclude)
grep -qx "/$dest/" "$exclude" 2>/dev/null || echo "/$dest/" >> "$exclude"
echo "device_site: $(du -sm "$dest" | cut -f1) MB in $dest/ ($(ls "$dest" | wc -l) wheels for Python $py); carry $dest"
