"""Copies a wheel without the files under some folders, its RECORD listing only what is left.

    python tools/trim_wheel.py SRC.whl DEST_DIR dm_control/suite dm_control/locomotion ...

Used by tools/device_site.sh: dm_control's suite, locomotion and Blender assets (50 of its 56
MB) are not needed to build the Panda's MJCF and would not fit what travels to a GPU box. pip
installs the trimmed wheel as any other; its RECORD (the installed files, which pip's
uninstall reads) names no file that is not there.
"""

from __future__ import annotations

import pathlib
import sys
import zipfile


def trim_wheel(src: pathlib.Path, dest_dir: pathlib.Path, folders: list[str]) -> pathlib.Path:
    """Writes ``dest_dir/<src name>`` without the entries under ``folders``; returns its path."""
    cut = tuple(f.rstrip("/") + "/" for f in folders)
    out = dest_dir / src.name
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            if item.filename.startswith(cut):
                continue
            data = zin.read(item)
            if item.filename.endswith(".dist-info/RECORD"):
                kept = [line for line in data.decode().splitlines(True) if not line.startswith(cut)]
                data = "".join(kept).encode()
            zout.writestr(item, data)
    return out


if __name__ == "__main__":
    if len(sys.argv) < 4:
        sys.exit("usage: python tools/trim_wheel.py SRC.whl DEST_DIR FOLDER [FOLDER ...]")
    print(trim_wheel(pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]), sys.argv[3:]))
